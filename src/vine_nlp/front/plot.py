"""Figures of result archives."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vine_nlp.io.archive import load_archive, write_atomic  # noqa: E402


def set_equal_3d(ax, points):
    """Equal scaling on all three axes (a helix must look round)."""
    pts = np.concatenate([np.asarray(p).reshape(-1, 3) for p in points])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid, half = 0.5 * (lo + hi), 0.5 * max(float((hi - lo).max()), 1e-9)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_box_aspect((1, 1, 1))


def plot_shape_3d(ax, archive):
    """Center line with the actuator (inner, blue) and opposite (outer, red) lines, as in the paper's Fig. 3."""
    u = archive.units
    everything = []
    if archive.target is not None:
        ax.plot(*archive.target.T, "k--", lw=1.0, label="target")
        everything.append(archive.target)
    for name, r in archive.runs.items():
        c = ax.plot(*r.shape.center.T, lw=2.0, label=f"{name}: center line")[0].get_color()
        ax.plot(*r.shape.inner.T, color="tab:blue", lw=0.8, label=f"{name}: actuator line" if len(archive.runs) == 1 else None)
        ax.plot(*r.shape.outer.T, color="tab:red", lw=0.5, alpha=0.6)
        ax.scatter(*r.shape.center[0], color=c, marker="o", s=20)
        everything += [r.shape.inner, r.shape.outer]
    ax.set_xlabel(f"x [{u}]")
    ax.set_ylabel(f"y [{u}]")
    ax.set_zlabel(f"z [{u}]")
    set_equal_3d(ax, everything)
    ax.legend(loc="upper left", fontsize=7)


def plot_archive_file(archive_path, figure_path):
    archive = load_archive(archive_path)
    fig = plt.figure(figsize=(6, 5.5))
    ax = fig.add_subplot(111, projection="3d")
    plot_shape_3d(ax, archive)
    ax.set_title(f"{archive.name} ({archive.kind})", fontsize=9)
    fig.tight_layout()
    suffix = str(figure_path).rsplit(".", 1)[-1]
    write_atomic(figure_path, lambda tmp: fig.savefig(tmp, dpi=150, format=suffix))
    plt.close(fig)
