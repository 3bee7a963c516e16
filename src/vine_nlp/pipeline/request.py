"""What a door asks of the pipeline beyond the problem (:class:`Request`), and what a problem of each
kind cannot be asked (:func:`check_request`): parsed and checked before any solver loads, so a bad
request is bad input (exit 2, nothing written) through every door, sweeps included."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from vine_nlp.errors import InputError
from vine_nlp.io.problems import ProblemFile
from vine_nlp.model.routing import Routing, Sigmas
from vine_nlp.problem import METHODS

# greedy_filtered: the paper's low-pass filter of the greedy design; nlp_free: the free design (the one the
# buildable nlp starts from, or one of its own where the nlp is one solve), kept as its own run;
# greedy_buildable: the greedy under the buildable rules (methods.greedy)
DESIGN_METHODS = (*METHODS, "greedy_filtered", "nlp_free", "greedy_buildable")
COMPARE = ("nlp", "nlp_free", "greedy", "greedy_buildable", "greedy_filtered")  # free and buildable, both methods


@dataclass(frozen=True)
class Request:
    """What a door asks for beyond the problem itself.

    Parameters
    ----------
    methods : tuple of str
        Design problems: the design runs, of ``DESIGN_METHODS`` (default: the problem's method).
    robust : Sigmas, optional
        Also a robust design under these construction errors (run ``nlp_robust``).
    robust_weight : float
        Weight of the robust design's expected error increase.
    clearance : float, optional
        Also a design clear of itself by this gap beyond D (run ``nlp_clearance``).
    starts, hops, budget, workers, warm
        The nlp design's multi-start, basin hopping, seconds for the whole design (pipeline.run), processes and warm start
        (None: the problem's own settings).
    fit_starts, seed : int
        The fit's starting orientations and seed.
    frames : tuple of arrays
        The fit: further frames of the same actuator, fitted in order.
    progress, note : callable, optional
        ``progress(done, total)`` of long work; ``note(line)`` a line of progress.
    """

    methods: tuple = ()
    robust: Sigmas | None = None
    robust_weight: float = 1.0
    clearance: float | None = None
    starts: int | None = None
    hops: int | None = None
    budget: float | None = None
    workers: int = 1
    warm: Routing | None = None
    fit_starts: int = 24
    seed: int = 0
    frames: tuple = ()
    progress: Callable | None = field(default=None, compare=False)
    note: Callable | None = field(default=None, compare=False)



# what each kind can be asked beyond its problem (design problems: everything)
KIND_OPTIONS = {"tip": {"starts"}, "multishape": {"starts"}, "forward": set(), "fit": set(), "actuators": {"starts"},
                "actuators-forward": set()}


def check_request(pf: ProblemFile, rq: Request) -> None:
    """What a problem of this kind cannot be asked for: one InputError ``(file, option, reason)`` before any solve."""
    problem, kind = pf.problem, pf.kind
    methods = rq.methods or ((problem.options.method,) if kind == "design" else ())
    unknown = [m for m in methods if m not in DESIGN_METHODS]
    if unknown:
        raise InputError(pf.path, "method", f"unknown design method {unknown[0]!r}; one of {', '.join(DESIGN_METHODS)}")
    asked = [k for k, on in (("method", methods not in ((), ("nlp",))), ("warm", rq.warm is not None), ("hops", bool(rq.hops)),
                             ("budget", rq.budget is not None), ("robust", rq.robust is not None),
                             ("clearance", rq.clearance is not None), ("starts", rq.starts is not None)) if on]
    if kind != "design":
        for key in asked:
            if key not in KIND_OPTIONS[kind]:
                raise InputError(pf.path, key, f"not available for {kind} problems")
        return
    for run, base in (("greedy_filtered", "greedy"), ("nlp_free", "nlp")):
        if run in methods and base not in methods:
            raise InputError(pf.path, "method", f"{run} needs {base}")
    if problem.obstacles and set(methods) - {"nlp"}:  # their design's start is kept as nlp_no_obstacles
        raise InputError(pf.path, "method", "obstacles are designed by the nlp formulation only")
    needs_nlp = [k for k in ("robust", "clearance", "warm", "hops") if k in asked]
    if needs_nlp and "nlp" not in methods:
        raise InputError(pf.path, needs_nlp[0], "needs the nlp design to start from")
