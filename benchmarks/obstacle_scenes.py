"""Random obstacle scenes with a clear routing known to exist by construction (issue 33).

Writes problem files (``<name>.toml`` with its target ``<name>.csv``) into ``--out DIR``: ``--per-target``
scenes (default 16) over each of four targets, so 64 by default, plus the issue's own slot scene; with
``--mirrors`` every scene also mirrored in y as ``<name>-mirror.toml``. Seeded and deterministic.

Construction
------------
1. A base target (``BASES``): a straight line (100 cm), a gentle Bezier, the trefoil of
   problems/trefoil-m4.toml, the hook of problems/hook.toml. Its obstacle-free design (the pipeline's
   ``nlp`` run, no obstacles) is the *known routing* R; S, R's modeled center line paired with the
   target points, is a shape the robot realizes exactly.
2. One or two *sites* along S (arc length 20 % to 85 % of S, sites at least 25 cm apart): the local
   frame (t tangent, n a random normal, b = t x n). At each site an obstacle is placed on the n side of
   S so that S's tube surface clears it by c = margin + U(0.2, 1.0) cm:
   - slot: two walls (boxes, normal to t, 2 to 6 cm thick, 20 cm deep along n and 30 cm along b) with a
     gap of D + 2 (margin + 0.2) + U(0.5, 4) cm along n; S passes through the gap off its middle by o,
     |o| <= gap/2 - D/2 - margin - 0.2;
   - pole: a capsule (radius 0.5 to 2.5, 20 to 40 cm long) crossing the path (axis in the t-b plane,
     tilted up to 45 deg from b), its axis D/2 + c + r from S;
   - pipe bend: a 1 to 2 cm radius pipe in the t-b plane at D/2 + c + r from S: a straight leg along b,
     a quarter circle of 5 to 12 cm radius in six chords, a straight leg along t (as
     problems/obstacle-pipe-bend.toml); the middle of the bend sits over S at the site;
   - box: 2 to 6 cm along n, 3 to 10 cm along t, 5 to 20 cm along b, turned about n by up to 45 deg;
   - sphere: radius 1.5 to 5.
3. The scene's target T is S pushed into the obstacle at each site: T_i = S_i + a w(s_i) n with a
   cos^2 bump w of half-width max(6 cm, 2.5 a + the obstacle's extent along t). The trefoil's obstacles and
   bump widths are scaled down by 0.3 (SIZE: it fills a 21 x 20 x 8 cm box; a sphere's radius by 0.4). "Beside": the target's
   tube cuts 0.3 to 2 cm into the obstacle (a = c + pen); "across": the target's center line runs through
   the obstacle's middle (pole, sphere, box, pipe) or 1 to 4 cm deep into a slot wall.
4. Checks (a scene is drawn again, from the same seeded stream, until both hold): R clears every
   obstacle by margin + 0.1 cm (``obstacle_report`` on R, densely, growth while actuated), and T's own
   tube misses the margin somewhere (the obstacle is in the way). So every scene has a clear routing
   (R itself, a few mm to cm from the target at the sites and equal to S elsewhere).

The issue's slot scene (``issue-slot``): a straight 100 cm target (D = 2.5 cm, margin 0.5 cm) running
2 cm into a wall (4 cm thick, at x = 50) beside a 6 cm slot whose middle is 5 cm off the target. Its
known routing is the straight line moved 5 cm sideways (clears both walls by 1.75 cm); checked likewise.

Mirror scenes: target points and obstacles with y -> -y (a box's rotation R -> M R M, M = diag(1, -1, 1)).
The mirror of a routing (theta -> -theta, the base pose mirrored) realizes the mirrored shape, so the
mirror scene has a clear routing too.

Every scene file keeps the problem's defaults otherwise (base free, growth while actuated, nlp).
Run: PYTHONPATH=src python3 benchmarks/obstacle_scenes.py --out DIR [--mirrors] [--seed 33] [--per-target 16]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("slot", "pole", "pipe", "box", "sphere")
MIRROR = np.diag([1.0, -1.0, 1.0])
SIZE = {"trefoil": 0.3}  # the trefoil fills a 21 x 20 x 8 cm box: its obstacles are scaled down (extents, site spacing)

BASES = {
    "line": {"diameter": 2.5, "target": 'curve = "polyline"\ncontrol_points = [[0, 0, 0], [100, 0, 0]]\nsamples = 301'},
    "bezier": {"diameter": 2.43, "target": 'curve = "bezier"\ncontrol_points = [[0, 0, 0], [30, 0, 0], [50, 10, 5], [80, -5, 10], [100, 0, 5]]\nsamples = 301'},
    "trefoil": {"diameter": 2.43, "target": 'curve = "trefoil"\nscale = [4.0, 4.0, 4.0]\nt_range = [-0.6283185307179586, 4.71238898038469]\nsamples = 400'},
    "hook": {"diameter": 2.5, "target": f'curve = "points"\nfile = "{(ROOT / "problems" / "data" / "hook.csv").as_posix()}"'},
}

HEAD = """name = "{name}"
units = "cm"

[tube]
diameter = {D}

[target]
{target}

[actuator]
kind = "tendon"
lambda_min = 0.4
theta_max_deg = 60.0

[design]
points_per_segment = 10
"""


def _v(x) -> str:
    return "[" + ", ".join(f"{float(c):.10g}" for c in x) + "]"


def obstacle_toml(ob: dict) -> str:
    """One [[obstacles]] table of a dict (shape, name and the shape's parameters)."""
    lines = ["[[obstacles]]", f'name = "{ob["name"]}"', f'shape = "{ob["shape"]}"']
    for k, v in ob.items():
        if k in ("shape", "name"):
            continue
        if k == "rotation":
            lines.append("rotation = [" + ", ".join(_v(r) for r in np.asarray(v)) + "]")
        elif np.ndim(v) == 0:
            lines.append(f"{k} = {float(v):.10g}")
        else:
            lines.append(f"{k} = {_v(v)}")
    return "\n".join(lines)


def mirrored(ob: dict) -> dict:
    out = dict(ob)
    for k in ("center", "p0", "p1"):
        if k in out:
            out[k] = MIRROR @ np.asarray(out[k], float)
    if "rotation" in out:
        out["rotation"] = MIRROR @ np.asarray(out["rotation"], float) @ MIRROR
    return out


def write_scene(out: Path, name: str, D: float, margin: float, target: np.ndarray, obstacles: list, comment: str) -> Path:
    """<name>.csv (the target points) and <name>.toml."""
    np.savetxt(out / f"{name}.csv", target, delimiter=",", fmt="%.9f", header="x,y,z", comments="")
    text = "# " + "\n# ".join(comment.splitlines()) + "\n" + HEAD.format(name=name, D=D, target=f'curve = "points"\nfile = "{name}.csv"')
    text += f"obstacle_margin = {margin:g}\n\n" + "\n\n".join(obstacle_toml(ob) for ob in obstacles) + "\n"
    path = out / f"{name}.toml"
    path.write_text(text)
    return path


# ------------------------------------------------------------------ the known routing of each base target


def known_routing(base: str):
    """(R, S, D): the obstacle-free design of the base target (pipeline run nlp) and its paired center line."""
    from vine_nlp.io.problems import load_problem
    from vine_nlp.pipeline import run

    b = BASES[base]
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"{base}.toml"
        p.write_text(HEAD.format(name=base, D=b["diameter"], target=b["target"]))
        outcome = run(load_problem(p))
    r = outcome.runs["nlp"]
    return r.routing, np.asarray(r.shape.center, float), b["diameter"]


def _frame(S, i, rng):
    t = S[min(i + 1, len(S) - 1)] - S[max(i - 1, 0)]
    t /= np.linalg.norm(t)
    a = np.array([0.0, 0.0, 1.0]) if abs(t[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(t, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(t, e1)
    ang = rng.uniform(0, 2 * math.pi)
    n = math.cos(ang) * e1 + math.sin(ang) * e2
    return t, n, np.cross(t, n)


def _site(kind, P, t, n, b, D, margin, rng, k, f=1.0):
    """Obstacles at one site and the bump (amplitude a along n, extent along t); f scales their extents (SIZE)."""
    c = margin + rng.uniform(0.2, 1.0)
    across = rng.random() < 0.5
    pen = rng.uniform(0.3, 2.0)
    tag = f"{kind} {k}" + (" (across)" if across else " (beside)")
    if kind == "slot":
        gap = D + 2 * (margin + 0.2) + rng.uniform(0.5, 4.0)
        omax = gap / 2 - D / 2 - margin - 0.2
        o = rng.uniform(-omax, omax)
        th = rng.uniform(2.0, 6.0)
        R = np.column_stack([t, n, b])
        obs = []
        for sgn, side in ((1, "far"), (-1, "near")):
            center = P + (o + sgn * (gap / 2 + 10.0 * f)) * n
            obs.append({"name": f"{tag} {side} wall", "shape": "box", "center": center, "size": [th, 20.0 * f, 30.0 * f], "rotation": R})
        a = (o + gap / 2 + rng.uniform(1.0, 4.0)) if across else (o + gap / 2 - D / 2 + pen)
        return obs, a, th
    if kind == "pole":
        r = rng.uniform(0.5, 2.5)
        half = f * rng.uniform(10.0, 20.0)
        al = math.radians(rng.uniform(-45, 45))
        axis = math.cos(al) * b + math.sin(al) * t
        C = P + (D / 2 + c + r) * n
        obs = [{"name": tag, "shape": "capsule", "p0": C - half * axis, "p1": C + half * axis, "radius": r}]
        a = (D / 2 + c + r) if across else (c + pen)
        return obs, a, 2 * r + 2 * half * abs(math.sin(al))
    if kind == "pipe":
        r = rng.uniform(1.0, 2.0)
        Rb = f * rng.uniform(5.0, 12.0)
        leg = f * rng.uniform(15.0, 30.0)
        # in (u along t, v along b): leg along +v at u = -Rb, arc about (0, 0) to (0, Rb), leg along +u
        ang = np.linspace(math.pi, math.pi / 2, 7)
        arc = np.column_stack([Rb * np.cos(ang), Rb * np.sin(ang)])
        mid = np.array([Rb * math.cos(0.75 * math.pi), Rb * math.sin(0.75 * math.pi)])
        pts = np.vstack([[[-Rb, -leg]], arc, [[leg, Rb]]]) - mid
        off = D / 2 + c + r
        W = [P + off * n + u * t + v * b for u, v in pts]
        obs = [{"name": f"{tag} piece {j}", "shape": "capsule", "p0": W[j], "p1": W[j + 1], "radius": r} for j in range(len(W) - 1)]
        a = off if across else (c + pen)
        return obs, a, 2 * r + 4.0
    if kind == "box":
        h, lt, lb = f * rng.uniform(2.0, 6.0), f * rng.uniform(3.0, 10.0), f * rng.uniform(5.0, 20.0)
        al = math.radians(rng.uniform(-45, 45))
        tt = math.cos(al) * t + math.sin(al) * b
        bb = np.cross(tt, n)
        R = np.column_stack([tt, n, bb])
        R = R if np.linalg.det(R) > 0 else np.column_stack([tt, n, -bb])
        obs = [{"name": tag, "shape": "box", "center": P + (D / 2 + c + h / 2) * n, "size": [lt, h, lb], "rotation": R}]
        a = (D / 2 + c + h / 2) if across else (c + pen)
        return obs, a, lt * abs(math.cos(al)) + lb * abs(math.sin(al))
    r = max(f, 0.4) * rng.uniform(1.5, 5.0)
    obs = [{"name": tag, "shape": "sphere", "center": P + (D / 2 + c + r) * n, "radius": r}]
    a = (D / 2 + c + r) if across else (c + pen)
    return obs, a, 2 * r


def _arc(S):
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(S, axis=0), axis=1))])


def make_scene(base, idx, kind, R, S, D, rng, parse):
    """Draw a scene until the construction's checks hold; returns (obstacles, target, margin, notes)."""
    from vine_nlp.analysis.obstacles import min_gap, obstacle_report

    s = _arc(S)
    L = s[-1]
    f = SIZE.get(base, 1.0)
    for _attempt in range(200):
        margin = float(rng.choice([0.3, 0.5]))
        nsites = 1 if (rng.random() < 0.6 or L < 60) else 2
        centers = []
        for _ in range(nsites):
            for _ in range(50):
                s0 = rng.uniform(0.2 * L, 0.85 * L)
                if all(abs(s0 - x) > 25.0 * f for x in centers):
                    centers.append(s0)
                    break
        obstacles, target, notes = [], S.copy(), []
        for k, s0 in enumerate(centers):
            i = int(np.searchsorted(s, s0))
            t, n, b = _frame(S, i, rng)
            obs, a, ext = _site(kind, S[i], t, n, b, D, margin, rng, k, f)
            hw = max(6.0 * f, 2.5 * a + ext)
            w = np.where(np.abs(s - s0) < hw, np.cos(0.5 * math.pi * (s - s0) / hw) ** 2, 0.0)
            target = target + a * w[:, None] * n
            obstacles += obs
            notes.append(f"{obs[0]['name']}: at s = {s0:.1f} cm, bump {a:.2f} cm over +-{hw:.1f} cm")
        objs = parse(obstacles)
        rep = obstacle_report(R, D, objs, "while-actuated", margin, per_segment=40)
        g_known = min(rep["min_gap"], rep["min_gap_intermediate"])
        g_target = float(min_gap(target, D, objs).min())
        if g_known >= margin + 0.1 and g_target < margin - 0.05:
            return obstacles, target, margin, notes, g_known, g_target
    raise RuntimeError(f"no scene for {base} {idx} {kind} in 200 draws")


def parse_obstacles_dicts(obstacles: list):
    """The model's obstacle objects of our dicts (through the problem file parser's own types)."""
    from vine_nlp.model.obstacles import Box, Capsule, Sphere

    out = []
    for ob in obstacles:
        if ob["shape"] == "box":
            out.append(Box(tuple(ob["center"]), tuple(ob["size"]), tuple(map(tuple, np.asarray(ob["rotation"]))), ob["name"]))
        elif ob["shape"] == "capsule":
            out.append(Capsule(tuple(ob["p0"]), tuple(ob["p1"]), float(ob["radius"]), ob["name"]))
        else:
            out.append(Sphere(tuple(ob["center"]), float(ob["radius"]), ob["name"]))
    return out


def issue_slot(out: Path, mirrors: bool) -> list[Path]:
    """The issue's slot scene (module docstring) and its known routing's check."""
    from dataclasses import replace

    from vine_nlp.analysis.obstacles import min_gap, obstacle_report

    D, margin = 2.5, 0.5
    R, S, _ = known_routing("line")
    target = S
    gap, mid, th, x = 6.0, 5.0, 4.0, 50.0
    obstacles = [
        {"name": "wall (target side)", "shape": "box", "center": [x, mid - gap / 2 - 10.0, 0.0], "size": [th, 20.0, 30.0]},
        {"name": "wall (far side)", "shape": "box", "center": [x, mid + gap / 2 + 10.0, 0.0], "size": [th, 20.0, 30.0]},
    ]
    objs = parse_obstacles_dicts([dict(o, rotation=np.eye(3)) for o in obstacles])
    pose = np.array(R.initial_pose, float)
    pose[1, 3] += mid
    rep = obstacle_report(replace(R, initial_pose=pose), D, objs, "while-actuated", margin, per_segment=40)
    g_known = min(rep["min_gap"], rep["min_gap_intermediate"])
    g_target = float(min_gap(target, D, objs).min())
    assert g_known >= margin + 0.1 and g_target < margin, (g_known, g_target)
    comment = (f"Issue 33's slot: straight 100 cm target (D = 2.5 cm, margin 0.5 cm) running 2 cm into a wall beside a 6 cm slot\n"
               f"whose middle is 5 cm off the target. Known clear routing: the straight line moved 5 cm sideways (min gap {g_known:.3f} cm);\n"
               f"the target's own tube: min gap {g_target:.3f} cm. Made by benchmarks/obstacle_scenes.py.")
    paths = [write_scene(out, "issue-slot", D, margin, target, obstacles, comment)]
    if mirrors:
        paths.append(write_scene(out, "issue-slot-mirror", D, margin, target @ MIRROR, [mirrored(o) for o in obstacles],
                                 comment + "\nMirrored in y."))
    return paths


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--seed", type=int, default=33)
    ap.add_argument("--per-target", type=int, default=16)
    ap.add_argument("--mirrors", action="store_true")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    paths = issue_slot(args.out, args.mirrors)
    for bi, base in enumerate(BASES):
        R, S, D = known_routing(base)
        rng = np.random.default_rng([args.seed, bi])
        for j in range(args.per_target):
            kind = KINDS[j % len(KINDS)]
            obstacles, target, margin, notes, g_known, g_target = make_scene(base, j, kind, R, S, D, rng, parse_obstacles_dicts)
            name = f"{base}-{j:02d}-{kind}"
            comment = (f"Random scene (issue 33), seed {args.seed}: the {base} target's obstacle-free design S pushed into {kind} obstacles.\n"
                       + "\n".join(notes)
                       + f"\nKnown clear routing: S's own (min gap {g_known:.3f} cm >= margin + 0.1); the target's tube: min gap {g_target:.3f} cm."
                       + "\nMade by benchmarks/obstacle_scenes.py.")
            paths.append(write_scene(args.out, name, D, margin, target, obstacles, comment))
            if args.mirrors:
                paths.append(write_scene(args.out, f"{name}-mirror", D, margin, target @ MIRROR, [mirrored(o) for o in obstacles],
                                         comment + "\nMirrored in y."))
            print(f"{name}: {len(obstacles)} obstacles, known gap {g_known:.3f}, target gap {g_target:.3f}", flush=True)
    print(f"{len(paths)} scenes in {args.out}")


if __name__ == "__main__":
    main()
