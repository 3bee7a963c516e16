"""Tutorial 6: design among obstacles.

``problems/obstacle-pipe-bend.toml``: the target crosses a pipe (2 cm radius) right where
it bends up from the floor; the pipe is drawn as capsules. The tube must pass beside it,
``obstacle_margin = 0.3`` cm clear of its surface, and come back to the target behind it.
The design command also solves the same target without the obstacles (run ``nlp_no_obstacles``),
to show what staying clear costs.

Run:  python3 examples/06_obstacles.py [--out DIR]
Makes: pipe-bend.h5, pipe-bend.png, summary.json.
"""

import tomllib

import h5py
from _common import PROBLEMS, arguments, vine_nlp, write_summary

args = arguments("06_obstacles", __doc__.splitlines()[0])
out = args.out
problem = PROBLEMS / "obstacle-pipe-bend.toml"
archive = out / "pipe-bend.h5"

vine_nlp("design", problem, "-o", archive, "--plot", out / "pipe-bend.png", "--force")

with h5py.File(archive, "r") as h5:
    runs = {name: (str(g.attrs["status"]), dict(g["metrics"].attrs)) for name, g in h5["runs"].items()}
    shapes = sorted({str(g.attrs["shape"]) for g in h5["obstacles"].values()})
    obstacles = len(h5["obstacles"])
status, kept = runs["nlp"]
_, free = runs["nlp_no_obstacles"]
margin = tomllib.loads(problem.read_text())["design"]["obstacle_margin"]
print(f"with the obstacles:    RMSE {kept['rmse'] * 10:.2f} mm, tube surface {kept['min_obstacle_gap']:.3f} cm from the pipe")
print(f"without the obstacles: RMSE {free['rmse'] * 10:.4f} mm, tube surface {free['min_obstacle_gap']:.3f} cm from the pipe")

write_summary(
    out,
    {
        "status": status,
        "obstacles": obstacles,
        "obstacle_shapes": shapes,
        "margin_cm": float(margin),
        "min_obstacle_gap_cm": float(kept["min_obstacle_gap"]),
        "rmse_mm": float(kept["rmse"]) * 10.0,
        "free_min_obstacle_gap_cm": float(free["min_obstacle_gap"]),
        "free_rmse_mm": float(free["rmse"]) * 10.0,
        "files": ["pipe-bend.h5", "pipe-bend.png"],
    },
)
