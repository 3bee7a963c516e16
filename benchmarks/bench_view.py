"""View benchmark: size of the HTML view of a 40-segment design and its time to draw in headless Chromium.

    python benchmarks/bench_view.py [--loads 5]

1. ``vine-nlp design problems/trefoil-m4.toml`` (40 segments), then ``vine-nlp view``:
   the file's size (goal: <= 6 MB; plotly.js alone is about 4.8 MB of it);
2. the page opened from disk (file://) ``--loads`` times in Debian's headless Chromium
   (selenium, chromedriver given explicitly: no browser download): time from navigation
   start to "drawn", measured inside the page by a 5 ms poll installed before any page
   script runs (Chrome DevTools ``Page.addScriptToEvaluateOnNewDocument``). "Drawn":
   plotly has laid the figure out, the WebGL canvas of the 3-D scene exists and the
   slider frames are loaded (the figure answers the sliders). Median and best.
3. the same for a trivial 3-D plotly page (two points, plotly.js embedded the same
   way): the floor set by parsing plotly.js and starting software WebGL (--disable-gpu)
   on this machine, so the view's own cost is the difference.

Also checks each load: no SEVERE console message, the screenshot not blank.
Writes results/benchmarks/view.md. Goal: drawn within 2 s (2-core machine, shared).
"""

from __future__ import annotations

import argparse
import io
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from common import ROOT, table, write_report

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--window-size=1100,800")
GOAL_MB, GOAL_S = 6.0, 2.0

PROBE = """
(function () {
  var t = setInterval(function () {
    var gd = document.querySelector('.plotly-graph-div');
    if (window.__vineDrawn === undefined && gd && gd._fullLayout && gd.querySelector('.gl-container canvas')) {
      window.__vineDrawn = performance.now();
    }
    if (window.__vineDrawn !== undefined && gd._transitionData && (gd._transitionData._frames || []).length) {
      window.__vineFrames = performance.now();
      clearInterval(t);
    }
  }, 5);
})();
"""


def browser(profile: str):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    o = webdriver.ChromeOptions()
    o.binary_location = CHROMIUM
    for f in (*FLAGS, f"--user-data-dir={profile}"):
        o.add_argument(f)
    o.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    d = webdriver.Chrome(service=Service(CHROMEDRIVER), options=o)
    d.set_script_timeout(120)
    d.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": PROBE})
    return d


def time_load(d, path: Path, frames: bool) -> tuple[float, int, int]:
    """(seconds from navigation start to drawn, SEVERE console messages, distinct screenshot colours)."""
    from PIL import Image

    d.get_log("browser")
    d.get("about:blank")
    d.get(path.resolve().as_uri())
    ms = d.execute_async_script("""
        var done = arguments[arguments.length - 1], frames = arguments[0], t0 = Date.now();
        (function wait() {
          if (window.__vineDrawn !== undefined && (!frames || window.__vineFrames !== undefined)) {
            done(frames ? window.__vineFrames : window.__vineDrawn); return; }
          if (Date.now() - t0 > 100000) { done(null); return; }
          setTimeout(wait, 20);
        })();""", frames)
    if ms is None:
        raise RuntimeError(f"{path} was not drawn within 100 s")
    severe = sum(1 for m in d.get_log("browser") if m["level"] == "SEVERE")
    shot = np.asarray(Image.open(io.BytesIO(d.get_screenshot_as_png())).convert("RGB"))
    return ms / 1000.0, severe, len(np.unique(shot.reshape(-1, 3), axis=0))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loads", type=int, default=5)
    args = ap.parse_args(argv)
    import plotly.graph_objects as go

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        h5, html, tiny = tmp / "trefoil.h5", tmp / "view.html", tmp / "tiny.html"
        for cmd in (["design", str(ROOT / "problems" / "trefoil-m4.toml"), "-o", str(h5)], ["view", str(h5), "-o", str(html)]):
            subprocess.run([sys.executable, "-m", "vine_nlp", *cmd], check=True, capture_output=True)
        go.Figure(go.Scatter3d(x=[0, 1], y=[0, 1], z=[0, 1])).write_html(tiny, include_plotlyjs=True)
        size_mb = html.stat().st_size / 1e6
        d = browser(str(tmp / "profile"))
        try:
            rows, results = [], {}
            for name, path, frames in (("trivial 3-D page (floor)", tiny, False), ("trefoil-m4 view", html, True)):
                runs = [time_load(d, path, frames) for _ in range(args.loads)]
                times = [r[0] for r in runs]
                results[name] = times
                rows.append([name, f"{path.stat().st_size / 1e6:.2f}", f"{statistics.median(times):.2f}", f"{min(times):.2f}",
                             f"{max(times):.2f}", max(r[1] for r in runs), min(r[2] for r in runs)])
        finally:
            d.quit()
    view_med = statistics.median(results["trefoil-m4 view"])
    floor_med = statistics.median(results["trivial 3-D page (floor)"])
    verdict = (f"size {size_mb:.2f} MB ({'meets' if size_mb <= GOAL_MB else 'misses'} the {GOAL_MB:g} MB goal); "
               f"drawn in {view_med:.2f} s median ({'meets' if view_med <= GOAL_S else 'misses'} the {GOAL_S:g} s goal), "
               f"{view_med - floor_med:.2f} s more than a trivial 3-D page")
    print(table(["page", "MB", "median s", "best s", "worst s", "SEVERE console", "min colours"], rows))
    print(verdict)
    write_report(
        "view", "HTML view in headless Chromium",
        f"`vine-nlp view` of problems/trefoil-m4.toml designed (40 segments), opened from file:// {args.loads} times in "
        "Debian's headless Chromium (--disable-gpu: software WebGL); time from navigation start to drawn "
        "(plotly laid out, WebGL canvas present, slider frames loaded), measured inside the page.",
        table(["page", "MB", "median s", "best s", "worst s", "SEVERE console", "min colours"], rows),
        verdict,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
