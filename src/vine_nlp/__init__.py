"""vine_nlp: inverse design of actuator routings for vine robots.

Model after Blumenschein et al., "Geometric Solutions for General Actuator
Routing on Inflated-Beam Soft Growing Robots", IEEE T-RO 2021.

The Python API (``vine_nlp.api``, see the README's "Python API")::

    import vine_nlp as vn
    r = vn.design(points, diameter=2.43)
    r.rmse, r.status, r.routing.theta
    r.save("out.h5"); a = vn.load("out.h5")

Importing the package is cheap: the API's names load on first use (PEP 562), and
nothing here imports CasADi, matplotlib, h5py or SciPy or touches the matplotlib
backend.

``vine_nlp.design`` is both the subpackage of design methods and the API function
``design``: the subpackage module is callable and a call goes to
``vine_nlp.api.design``, so ``vn.design(points, ...)``,
``vine_nlp.design.run_design`` and ``from vine_nlp.design.nlp import design_nlp``
all work whatever was imported first. Any other submodule named like an API
function gets the same treatment.
"""

# private names: tab completion on the package shows the API, not these
import sys as _sys
from importlib import import_module as _import_module
from importlib import util as _import_util
from inspect import signature as _signature
from types import ModuleType as _ModuleType

__version__ = "0.1.0"

# API functions, classes and the problem types, all defined in (or re-exported by) vine_nlp.api
_API_NAMES = (
    "design",
    "forward",
    "fit",
    "load",
    "solve",
    "correct",
    "Design",
    "Project",
    "ArgumentError",
    "DesignProblem",
    "ForwardProblem",
    "FitProblem",
    "MultiShapeProblem",
    "TipProblem",
    "Actuator",
    "DesignOptions",
    "Routing",
    "Sigmas",
    "Result",
)
_API_FUNCTIONS = ("design", "forward", "fit", "load", "solve")

__all__ = ["__version__", *_API_NAMES]


def _api():
    return _import_module("vine_nlp.api")


class _CallableModule(_ModuleType):
    """A submodule that shares its name with an API function: calling it calls the function,
    and help() and notebooks (``vn.design?``) show the function's signature and docstring."""

    def _function(self):
        return getattr(_api(), self.__name__.rpartition(".")[2])

    def __call__(self, *args, **kwargs):
        return self._function()(*args, **kwargs)

    @property
    def __signature__(self):
        return _signature(self._function())

    def _get_doc(self):
        own = self.__dict__.get("__doc__") or ""
        return f"{self._function().__doc__}\n\n(The subpackage {self.__name__}: {own.strip()})"

    def _set_doc(self, value):
        self.__dict__["__doc__"] = value

    __doc__ = property(_get_doc, _set_doc)


class _Package(_ModuleType):
    """The package module: submodules named like API functions become callable when the import system sets them."""

    def __setattr__(self, name, value):
        if name in _API_FUNCTIONS and type(value) is _ModuleType:
            value.__class__ = _CallableModule
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package


def __getattr__(name):
    if name in _API_FUNCTIONS and _import_util.find_spec(f"{__name__}.{name}") is not None:
        # the submodule of that name, made callable by _Package.__setattr__ as it is imported
        _import_module(f"{__name__}.{name}")
        return globals()[name]
    if name in _API_NAMES:
        value = getattr(_api(), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(n for n in set(globals()) | set(__all__) if not n.startswith("_") or n in __all__)
