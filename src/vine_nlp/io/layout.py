"""The core layout of result archives (spec/formats.md, "Result archives"), as data.

One table of the groups, datasets and attributes every archive has, for the code that writes, checks and documents
archives to share: the documentation's format reference is rendered from it and checked, at every build, against
archives that the command line writes (docs/gen_reference.py). Shapes are given in the spec's symbols: ``N`` target
points, ``M`` segments, ``P`` shape points (``P = N`` for design runs).

Groups outside this layout (``/measured``, ``/frames``, ``/targets``, ``/tip``,
``/obstacles``, per-level groups of multishape runs) belong to the commands that add them."""

from __future__ import annotations

from dataclasses import dataclass

RUN = "<run>"  # stands for any run name in a path ("nlp", "greedy", "forward", "fit", ...)


@dataclass(frozen=True)
class Node:
    """One group or dataset of the core layout.

    Parameters
    ----------
    path : str
        Absolute path; ``<run>`` stands for a run name.
    kind : str
        ``"group"`` or ``"dataset"``.
    shape : tuple
        Dataset shape: ints and the symbols ``"N"``, ``"M"``, ``"M+1"``, ``"P"``.
    attrs : tuple of str
        Attributes the node always has.
    when : str
        ``"always"``, ``"design"`` (archives of design problems only) or ``"optional"``.
    meaning : str
        What it holds, in the words of the spec.
    """

    path: str
    kind: str
    shape: tuple = ()
    attrs: tuple = ()
    when: str = "always"
    meaning: str = ""


CORE_LAYOUT = (
    Node("/", "group", attrs=("format", "format_version", "software_version", "created", "units"),
         meaning='`format` = "vine_nlp/result", `format_version` = 1, `created` in ISO 8601, `units` of every length'),
    Node("/problem", "group", attrs=("name", "kind", "source"), meaning="the problem: its name, kind and the problem file's text"),
    Node("/tube", "group", attrs=("diameter",), meaning="the tube"),
    Node("/target", "group", when="design", meaning="design problems: the target"),
    Node("/target/points", "dataset", ("N", 3), when="design", meaning="the target curve as sampled"),
    Node("/runs", "group", meaning="one group per run"),
    Node(f"/runs/{RUN}", "group", attrs=("method", "status", "solve_time_s", "iterations"),
         meaning="one run: the method that made it and the solver's status"),
    Node(f"/runs/{RUN}/design", "group", meaning="the routing"),
    Node(f"/runs/{RUN}/design/theta", "dataset", ("M",), meaning="drawn angle per segment, rad"),
    Node(f"/runs/{RUN}/design/lambda", "dataset", ("M",), meaning="contraction ratio per segment (repeated for an sPAM)"),
    Node(f"/runs/{RUN}/design/length", "dataset", ("M",), meaning="unactuated center-line length of each segment"),
    Node(f"/runs/{RUN}/design/phi", "dataset", ("M+1",), meaning="actuator angle around the tube at the segment ends, rad, phi[0] = 0"),
    Node(f"/runs/{RUN}/design/initial_pose", "dataset", (4, 4), meaning="base pose T^0_w"),
    Node(f"/runs/{RUN}/shape", "group", meaning="the modeled lines; design runs: row i pairs with target row i"),
    Node(f"/runs/{RUN}/shape/center", "dataset", ("P", 3), meaning="center line"),
    Node(f"/runs/{RUN}/shape/inner", "dataset", ("P", 3), meaning="actuator line"),
    Node(f"/runs/{RUN}/shape/outer", "dataset", ("P", 3), meaning="line opposite the actuator"),
    Node(f"/runs/{RUN}/metrics", "group", attrs=("tv_theta", "tv_lambda"),
         meaning="total variations of theta and lambda; design and fit runs also `rmse`, `max_error` (in `units`)"),
    Node(f"/runs/{RUN}/solver", "group", when="optional",
         meaning="solver settings and statistics: IPOPT return status, build time, objective terms, options"),
)
