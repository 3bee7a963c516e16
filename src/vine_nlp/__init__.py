"""vine_nlp: inverse design of actuator routings for vine robots.

Model after Blumenschein et al., "Geometric Solutions for General Actuator
Routing on Inflated-Beam Soft Growing Robots", IEEE T-RO 2021.

The Python API (``vine_nlp.api``, see the README's "Python API")::

    import vine_nlp as vn
    r = vn.design(points, diameter=2.43)
    r.rmse, r.status, r.routing.theta
    r.save("out.h5"); a = vn.load("out.h5")
    p = vn.solve("problems/obstacle-gap.toml")     # what `vine-nlp design` runs

Importing the package is cheap: the API's names are imported from ``vine_nlp.api`` on first use (PEP 562), so ``import
vine_nlp`` loads no CasADi, matplotlib, h5py or SciPy and never touches the matplotlib backend."""

from importlib import import_module as _import_module

__version__ = "0.1.0"

__all__ = ["__version__", "design", "forward", "fit", "load", "solve", "correct", "Design", "Project", "ArgumentError",
           "DesignProblem", "ForwardProblem", "FitProblem", "MultiShapeProblem", "TipProblem", "Actuator", "DesignOptions",
           "Calibration", "Load", "Routing", "Sigmas", "Result"]

def __getattr__(name):
    if name in __all__:
        value = getattr(_import_module("vine_nlp.api"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
