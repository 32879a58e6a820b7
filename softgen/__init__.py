"""softgen: symbolic models, regressors, generated C and closed loops for soft robots.

The main entry points, importable from here (each is loaded on first use, so that
``import softgen`` and the command line stay fast)::

    import softgen
    model = softgen.load_model("planar_2link")          # a validated model file
    softgen.decide(model)                               # what it gets, and why not
    dyn = softgen.RigidDynamics(model)                  # symbolic B, C, G, regressors
    arm = softgen.load_bundle("planar_2link")           # compiled functions
    arm.regressor                                       # <planar_2link_regressor(q[2], ...)>
    ex = softgen.example_for(model)                     # its registered example loop
    trace = ex.scenario.run()                           # run by the one driver

See :data:`__all__` for the whole list and ``help(softgen.<name>)`` for each.
"""
from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("softgen")
except PackageNotFoundError:     # run from a checkout without installing
    __version__ = "0+unknown"

#: Public name -> the module that defines it.
_EXPORTS = {
    # model files
    "load_model": "softgen.modelfile.load",
    "list_models": "softgen.modelfile.load",
    "RobotModel": "softgen.modelfile.model",
    "SoftModel": "softgen.modelfile.soft",
    "ActuatorLaw": "softgen.modelfile.laws",
    # symbolic derivations
    "RigidDynamics": "softgen.symbolic.rigid",
    "SoftDynamics": "softgen.symbolic.pcc",
    "Actuation": "softgen.symbolic.actuation",
    # capabilities, bundles, generated code
    "decide": "softgen.bundles.bundle",
    "Decision": "softgen.bundles.registry",
    "generate": "softgen.bundles.bundle",
    "bundle_spec": "softgen.bundles.bundle",
    "load_bundle": "softgen.bundles.bundle",
    "Bundle": "softgen.runtime.library",
    # closed loops
    "Block": "softgen.blocks",
    "ClosedLoop": "softgen.blocks",
    "simulate": "softgen.runtime.simulate",
    "Trace": "softgen.runtime.simulate",
    "Scenario": "softgen.studies.scenario",
    "example_for": "softgen.studies.examples",
    "EXAMPLES": "softgen.studies.examples",
    # export, estimation
    "export": "softgen.export.project",
    "design_uio": "softgen.estimation",
    "discretize": "softgen.estimation",
    # errors
    "SoftgenError": "softgen.core.errors",
    "ModelError": "softgen.core.errors",
    "BundleError": "softgen.core.errors",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    """Load a public name on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'softgen' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
