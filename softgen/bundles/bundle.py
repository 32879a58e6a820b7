"""What a model's generated bundle contains, and ``softgen generate``.

Composes the symbolic layer (``symbolic/``, ``control/``, ``estimation/``) with the
robot-agnostic code generator (``codegen/``) through the capability registry
(:mod:`softgen.bundles.registry`): a bundle is every registered capability whose
conditions the model meets, in registration order, written to ``generated/<model>/``.
This module knows no model name and no controller.
"""
from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

# The builder modules have registered their capabilities (softgen/bundles/__init__.py).
from softgen.bundles.common import (DEFAULT_OPTIONS, BundleOptions, actuator_record,
                                    identity_bytes, model_chain, model_file_path, model_source)
from softgen.bundles.floating import model_layout
from softgen.bundles.registry import Capability, Context, Decision, merge
from softgen.bundles.registry import decide as _decide
from softgen.codegen.generate import (LARGE_FUNCTION, BundleSpec, code_size, content_hash,
                                      write_bundle)
from softgen.core.errors import BundleError, ModelError
from softgen.core.paths import GENERATED_DIR
from softgen.modelfile.model import MAX_NAME, RobotModel
from softgen.modelfile.load import list_models, load_model, shipped_model_file
from softgen.modelfile.cosserat import CosseratModel
from softgen.modelfile.soft import SoftModel
from softgen.runtime.library import Bundle
from softgen.symbolic.cosserat_dynamics import CosseratDynamics
from softgen.symbolic.pcc import SoftDynamics
from softgen.symbolic.rigid import RigidDynamics
from softgen.modelfile.limits import check_expression_size


def decide(model) -> Decision:
    """The one capability decision for ``model`` (:class:`~softgen.bundles.registry.Decision`):
    what ``info`` lists, ``generate`` builds, ``export`` and ``bench`` run. Every builder
    module is imported above, so the registry is complete."""
    return _decide(model)


def capabilities(model) -> list[tuple[Capability, str | None]]:
    """Every registered capability with None (``model`` gets it) or why it does not."""
    return list(decide(model).results)


def bundle_spec(model: RobotModel | SoftModel,
                options: BundleOptions = DEFAULT_OPTIONS) -> BundleSpec:
    """The functions, parameter vector and identity of ``model``'s bundle.

    Bundles of a model read from a file are kept per process (:data:`_SPECS_KEPT`), keyed
    by what :func:`derivation` keys on (the bundle's identity: model source and options;
    the file's path, the chain, the name) and by the model's value: the derivation takes
    seconds and several callers (generate, info, bench, tests) ask. A model built in
    memory (no file) is derived each time. The spec returned is shared: callers read it
    and never change it.
    """
    options.check()
    # Refuse, in microseconds and one line, a model whose derivation would run for many
    # minutes and gigabytes (a 60-link chain, a 40-segment PCC body; issue 23).
    check_expression_size(model)
    key = _spec_key(model, options)
    if key is None:
        return _assemble(model, options)
    spec = _SPECS.pop(key, None)
    if spec is None:
        spec = _assemble(model, options)
    _SPECS[key] = spec
    while len(_SPECS) > _SPECS_KEPT:
        _SPECS.pop(next(iter(_SPECS)), None)
    return spec


#: Bundle specs kept per process (:func:`bundle_spec`), most recent last. Every shipped
#: model's and every tests/data/user_models model's spec together (34) took a process
#: from 84 to 242 MB (RSS); the 3D PCC arm (~50 MB) and the rod (~30 MB) are the largest.
_SPECS: dict[tuple, BundleSpec] = {}
_SPECS_KEPT = 64


def _spec_key(model, options: BundleOptions) -> tuple | None:
    """The key of ``model``'s spec in :data:`_SPECS`, None when it is not kept (no file,
    or a model whose value cannot be hashed)."""
    if getattr(model, "path", None) is None:
        return None
    try:
        hash(model)
    except TypeError:
        return None
    # The derivation's key (identity, path, chain, name), the options, and the model
    # itself (compared by value: a model replaced in memory after loading is another).
    return (identity_bytes(model.source_text(), options), str(model.path),
            getattr(model, "chain", None), model.name, options, type(model), model)


#: Capabilities whose functions are compiled at :data:`STEP_LEVEL` inside the -O3
#: bundle (issue 25): their steps are a large part of the bundle's compile time and
#: measured no slower at -O1. cbench, old (-O3) and new C of the same bundle, load ~1-2
#: on 2 CPUs, time per call at -O1 over -O3 (unchanged -O3 functions of the same runs
#: read 0.94-1.03): electric_cascade (the shipped 2-link electric arm) 1.00-1.10;
#: theorem10 (the shipped planar 4-segment PCC arm) steps 0.89-1.12, closed loop 1.09.
#: Not chosen, being slower at -O1: the Theorem 5 steps 1.20 and closed loop 1.15 (the
#: shipped 2-link McKibben arm), the Slotine-Li loop 1.13, the estimator steps (about
#: 3x); the model quantities (dynamics, regressors, plants) keep -O3, where the
#: regressors gain 10-30 %. Experiments never call these bundle functions: they compile
#: their own diagrams at -O1 (runtime.compiled), so no metric depends on this choice.
O1_CAPABILITIES = ("electric_cascade", "theorem10")
STEP_LEVEL = "-O1"
#: Functions of at least :data:`~softgen.codegen.generate.LARGE_FUNCTION` CasADi
#: instructions, counting those of the SX functions they call
#: (:func:`~softgen.codegen.generate.code_size`), are compiled at :data:`STEP_LEVEL` too,
#: whatever their capability (issue 34; the measurements are given there).


#: Derivations kept per process (:func:`derivation`), most recent last: as many as the
#: specs (:data:`_SPECS_KEPT`), each spec's functions being built from its derivation.
_DERIVATIONS: dict[tuple, Context] = {}
_DERIVATIONS_KEPT = 64


def derivation(model: RobotModel | SoftModel,
               options: BundleOptions = DEFAULT_OPTIONS) -> Context:
    """The model's symbolic derivation (dynamics, actuators, routes: a
    :class:`~softgen.bundles.registry.Context`), made once per model content and options
    in a process and shared by the bundle, the examples and the experiments' loops (a
    closed loop takes the model's functions from the same derivation as its bundle,
    never from a second one). Keyed by the bundle's identity (model source and options),
    the chain and the file's path; a model built in memory (no file) by the object."""
    if getattr(model, "path", None) is None:
        key: tuple = ("object", id(model), options)
    else:
        key = (identity_bytes(model.source_text(), options), str(model.path),
               getattr(model, "chain", None), model.name)
    ctx = _DERIVATIONS.pop(key, None)
    if ctx is None or (key[0] == "object" and ctx.model is not model):
        dyn = SoftDynamics(model, route=options.route) if isinstance(model, SoftModel) \
            else CosseratDynamics(model) if isinstance(model, CosseratModel) \
            else RigidDynamics(model, route=options.route)
        ctx = Context(model, options, dyn)
    _DERIVATIONS[key] = ctx
    while len(_DERIVATIONS) > _DERIVATIONS_KEPT:
        _DERIVATIONS.pop(next(iter(_DERIVATIONS)))
    return ctx


def _assemble(model, options: BundleOptions) -> BundleSpec:
    ctx = derivation(model, options)
    dyn = ctx.dyn
    extra = {"dof": model.dof, **model_source(model), **model_layout(model),
             "options": dict(options.__dict__), "route": dyn.route,
             "full_parameter_count": dyn.base.full_rank}
    if isinstance(dyn, RigidDynamics):
        # Which route built each product, and the instruction counts it chose by.
        extra["route_detail"] = dyn.route_detail
    decision = decide(model)
    fns, caps = [], decision.granted
    for cap in caps:
        part = cap.build(ctx)
        fns += [replace(g, optimization=g.optimization or STEP_LEVEL)
                if cap.name in O1_CAPABILITIES
                or code_size(g.function) >= LARGE_FUNCTION else g
                for g in part.functions]
        merge(extra, part.extra)
    if isinstance(dyn, RigidDynamics):
        # Recorded as each product is first built; the derivation is shared with the
        # examples and experiments of the process (derivation), so the order in which
        # they asked varies: sorted, the manifest is the same bytes whatever ran first.
        extra["route_detail"] = dict(sorted(dyn.route_detail.items()))
    extra.update(decision.manifest())
    extra["actuators"] = actuator_record(model)
    if getattr(model, "original_name", ""):
        # The file's own name, when it had to be sanitised into a C identifier (a URDF
        # <robot name="ur5-e">): users search the manifest for the name they wrote.
        extra["original_name"] = model.original_name
    params = {
        "names": dyn.parameter_names,
        "nominal": [float(v) for v in dyn.parameter_nominal],
        "expressions": list(dyn.base.expressions),
        "physical": list(model.uncertain),
        "physical_nominal": [float(model.nominal[k]) for k in model.uncertain],
    }
    return BundleSpec(name=model.name, functions=fns, parameters=params,
                      identity=identity_bytes(model.source_text(), options), extra=extra)


def identity_hash(manifest: dict) -> str | None:
    """The hash a bundle would have if generated now from its model file (None if absent)."""
    if not manifest.get("model_file"):
        return None
    path = model_file_path(manifest)
    if not path.is_file():
        return None
    options = BundleOptions(**manifest.get("options", {}))
    # What generation hashed (bundle_spec): the model's source_text, which besides the
    # file holds a chain's root and tip links and the URDF file a TOML [urdf] model
    # references. (The file's text alone made every such bundle "stale".)
    text = load_model(path, **model_chain(manifest)).source_text()
    return content_hash(identity_bytes(text, options))


#: Model files already reported missing (the warning is given once per file).
_WARNED_MISSING: set[str] = set()


def check_model_unchanged(manifest: dict, bundle_dir: Path | str | None = None) -> None:
    """Refuse a bundle generated from an older version of its model file.

    Compares ``model_sha256`` with the file's current content, then the whole
    identity hash (CasADi version, code generator, options). With the file gone,
    the bundle loads and a warning says so, once per file.

    Raises
    ------
    BundleError
        The model file changed, or the bundle was generated by another CasADi or
        code generator; names the file.
    """
    if "model_file" not in manifest:
        return   # not a model bundle (the schema requires it for model bundles)
    where = bundle_dir or f"generated/{manifest['model']}"
    path = model_file_path(manifest)
    if not path.is_file():
        key = str(path)
        if key not in _WARNED_MISSING:
            _WARNED_MISSING.add(key)
            warnings.warn(f"{where}: its model file {path} is gone; loading the bundle as "
                          "generated, without a staleness check", RuntimeWarning, stacklevel=3)
        return
    regen = f"run `softgen generate {manifest['model_file']}`"
    if "model_sha256" in manifest and \
            hashlib.sha256(path.read_bytes()).hexdigest() != manifest["model_sha256"]:
        raise BundleError(f"{where} is stale: {path} changed since it was generated; {regen}")
    if identity_hash(manifest) != manifest["hash"]:
        raise BundleError(f"{where} is stale: generated by another CasADi "
                          f"({manifest.get('casadi_version')}), code generator or options "
                          f"than now, or {path} changed; {regen}")


def casadi_functions(manifest: dict) -> dict:
    """The bundle's casadi.Functions rebuilt from its model file (no-compiler fallback)."""
    path = model_file_path(manifest)
    spec = bundle_spec(load_model(path, **model_chain(manifest)),
                       BundleOptions(**manifest.get("options", {})))
    return {g.function.name(): g.function for g in spec.functions}


#: Configurations at which B(q) must be positive definite before generation.
PD_SAMPLES = 16


def check_inertia_positive_definite(model: RobotModel, inertia_fun, *,
                                    samples: int = PD_SAMPLES, seed: int = 0) -> None:
    """B(q) symmetric positive definite and finite at seeded random configurations.

    Revolute joints are drawn in [-pi, pi], prismatic ones in [-1, 1] (times the
    chain's largest length when it has lengths). Raises one :class:`ModelError`
    naming the file and the first configuration that fails.
    """
    rng = np.random.default_rng(seed)
    links = getattr(model, "links", None)
    where = model.path or model.name
    if links is None:
        # Soft bodies: curvatures and (3D) elongations within half a unit of straight.
        draw = lambda: rng.uniform(-0.5, 0.5, model.dof)   # noqa: E731
    else:
        scale = max([abs(v) for k, v in model.nominal.items() if k[:1] in "lp"] + [1.0])
        prismatic = np.array([link.joint == "prismatic" for link in links], dtype=bool)

        def draw():
            q = rng.uniform(-np.pi, np.pi, model.dof)
            q[prismatic] = rng.uniform(-scale, scale, int(prismatic.sum()))
            if model.floating:          # a base pose first: position, unit quaternion
                quat = rng.normal(size=4)
                q = np.r_[rng.uniform(-scale, scale, 3), quat / np.linalg.norm(quat), q]
            return q
    for _ in range(samples):
        q = draw()
        B = np.array(inertia_fun(q), dtype=float)
        if not np.all(np.isfinite(B)):
            raise ModelError(f"{where}: B(q) has non-finite entries at q = "
                             f"{np.round(q, 4).tolist()}; check the magnitudes of masses, "
                             "lengths and inertias")
        lam = np.linalg.eigvalsh(0.5 * (B + B.T))
        if not lam.min() > 1e-12 * max(abs(lam).max(), 1e-300):
            j = int(np.argmin(np.abs(np.diag(B))))
            base = 6 if getattr(model, "floating", False) else 0
            what = (f"configuration variable {j + 1}" if links is None else
                    f"the floating base's velocity {j + 1}" if j < base else
                    f"joint {j + 1 - base} ({links[j - base].name})")
            raise ModelError(f"{where}: B(q) is not positive definite at q = "
                             f"{np.round(q, 4).tolist()} (smallest eigenvalue {lam.min():.3g}); "
                             f"{what} moves no mass or inertia")


def generate(name_or_path: str | Path | RobotModel | SoftModel,
             out_root: Path = GENERATED_DIR,
             options: BundleOptions = DEFAULT_OPTIONS) -> Path:
    """Write ``out_root/<model>/`` for one model (a name, a file or a loaded model, such
    as a URDF chain cut with ``load_model(path, root=, tip=)``); return the bundle
    directory.

    A model file outside ``models/`` that takes the name of a shipped model is
    refused for the shipped ``generated/`` (it would replace that bundle), and so is a
    chain cut out of a shipped file; write it elsewhere with ``out_root``.
    """
    model = name_or_path if isinstance(name_or_path, (RobotModel, SoftModel, CosseratModel)) \
        else load_model(name_or_path)
    out_root = Path(out_root)
    shipped = shipped_model_file(model.name)
    if (model.path is not None and shipped is not None
            and (Path(model.path).resolve() != shipped.resolve()
                 or getattr(model, "chain", None) is not None)
            and out_root.resolve() == GENERATED_DIR.resolve()):
        if getattr(model, "chain", None) is not None:
            raise ModelError(f"{model.path}: the chain {model.name!r} (--root/--tip) would "
                             f"replace the bundle of the shipped model models/{shipped.name}; "
                             "generate it elsewhere (--out DIR)")
        raise ModelError(f"{model.path}: model.name: {model.name!r} is the name of a shipped "
                         f"model (models/{shipped.name}); rename the model or generate it "
                         "elsewhere (--out DIR)")
    spec = bundle_spec(model, options)
    inertia = next((g.function for g in spec.functions
                    if g.function.name() == f"{model.name}_inertia"), None)
    if inertia is not None:
        check_inertia_positive_definite(model, inertia)
    return write_bundle(spec, out_root)


def up_to_date(model: RobotModel | SoftModel, bundle: Path,
               options: BundleOptions = DEFAULT_OPTIONS) -> bool:
    """Whether ``bundle`` is what generating ``model`` now would write.

    Its manifest's hash covers the model file's text, the options, the CasADi version
    and :data:`~softgen.codegen.generate.CODEGEN_VERSION` (bumped whenever the C for
    the same model changes), and its C and header must match the manifest's sha256;
    then deriving again gives the same bytes (tests/test_codegen.py checks that the
    shipped generated/ is exactly what derivation writes). Deriving every model costs
    ~24 CPU-s of ``softgen generate --all`` (issue 25), for nothing on a fresh clone.
    """
    from softgen.codegen.build import check_source, read_manifest
    try:
        manifest = read_manifest(bundle)
        check_source(bundle, manifest)
    except BundleError:
        return False
    return (manifest.get("options") == json.loads(json.dumps(options.__dict__))
            and manifest["hash"] == content_hash(identity_bytes(model.source_text(), options))
            and manifest.get("model_file") == model_source(model)["model_file"])


def generate_all(out_root: Path = GENERATED_DIR) -> list[Path]:
    """Bundles of every model in ``models/``."""
    return [generate(name, out_root) for name in list_models()]


def load_bundle(name_or_path: str | Path, *, generated_root: Path | None = None,
                **kwargs) -> Bundle:
    """Load ``generated/<model>`` (or a bundle directory path), checked against its model.

    A bare name (no path separator) is the bundle of that model under
    ``generated_root``, even if a directory of that name is in the current
    directory; give ``./name`` or another path to load a directory. The bundle is
    refused if its model file changed since generation (:func:`check_model_unchanged`);
    without a C compiler its functions are rebuilt from the model file.
    """
    kwargs.setdefault("model_check", check_model_unchanged)
    kwargs.setdefault("fallback", casadi_functions)
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or "/" in text or "\\" in text or text in (".", ".."):
        return Bundle(Path(name_or_path), **kwargs)
    if not (len(text) <= MAX_NAME and text.isascii() and text.isidentifier()):
        raise BundleError(f"model name {text[:40]!r}{'...' if len(text) > 40 else ''}: "
                          f"expected a C identifier of at most {MAX_NAME} characters, or a "
                          "path to a bundle directory")
    return Bundle(Path(generated_root or GENERATED_DIR) / text, **kwargs)
