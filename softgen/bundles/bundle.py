"""What a model's generated bundle contains, and ``softgen generate``.

Composes the symbolic layer (``symbolic/``, ``control/``) with the robot-agnostic
code generator (``codegen/``): for a rigid model, the functions of issue 2
(inertia, coriolis, gravity, regressor, ...) plus the Slotine–Li step and its
closed loop, written to ``generated/<model>/``.
"""
from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softgen.codegen.generate import BundleSpec, Generated, content_hash, write_bundle
from softgen.control.slotine_li import closed_loop_fun, controller_fun, plant_step_fun
from softgen.core.errors import BundleError, ModelError
from softgen.modelfile.model import (MAX_NAME, MODELS_DIR, RobotModel, list_models, load_model,
                    shipped_model_file)
from softgen.runtime.library import Bundle
from softgen.symbolic.rigid import RigidDynamics

from softgen.core.paths import GENERATED_DIR  # noqa: E402


@dataclass(frozen=True)
class BundleOptions:
    """Options that change the generated code (part of the content hash)."""

    route: str = "auto"             # how C q̇_r is built (symbolic/rigid.py, mechanics.py)
    loop_steps: int = 1000          # controller samples per call of <model>_slotine_li_loop
    loop_substeps: int = 1          # RK4 steps per controller sample in that loop

    def check(self) -> BundleOptions:
        if self.route not in ("auto", "recursive", "matrix-free", "explicit"):
            raise ValueError(f"route: expected 'auto', 'recursive', 'matrix-free' or "
                             f"'explicit', got {self.route!r}")
        for name in ("loop_steps", "loop_substeps"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"{name}: expected a positive integer, got {v!r}")
        return self


def bundle_spec(model: RobotModel, options: BundleOptions = BundleOptions()) -> BundleSpec:
    """The functions, parameter vector and identity of ``model``'s bundle."""
    if not isinstance(model, RobotModel):         # soft bodies (thesis ch. 3, 12)
        from softgen.bundles.soft import soft_bundle_spec
        return soft_bundle_spec(model, options)
    options.check()
    dyn = RigidDynamics(model, route=options.route)
    n = model.dof
    fns = [
        Generated(dyn.inertia_fun(), "inertia matrix B(q) (eq. 2.1)"),
        Generated(dyn.coriolis_fun(), "Coriolis matrix C(q, qd) from Christoffel symbols "
                                      "(Bdot - 2C skew)"),
        Generated(dyn.gravity_fun(), "gravity vector G(q) = dU/dq"),
        Generated(dyn.regressor_fun(), "Slotine-Li regressor: Y pi = B qdd_r + C qd_r + G"
                                       + (" + K q" if model.has_stiffness() else "")
                                       + (" + D qd" if model.has_damping() else "")
                                       + " (eq. 9.1)"),
        Generated(dyn.regressor_times_fun(), "Y(q, qd, qd_r, qdd_r) pi"),
        Generated(dyn.regressor_transpose_times_fun(), "Y(q, qd, qd_r, qdd_r)^T s"),
        Generated(dyn.inverse_dynamics_fun(), "nominal B qdd_r + C qd_r + G (+ K q + D qd), "
                                              "computed directly"),
        Generated(dyn.forward_dynamics_fun(), "nominal forward dynamics qdd = B^-1 (tau - C qd "
                                              "- G - K q - D qd)"),
        Generated(dyn.physical_to_base_fun, "map from the uncertain physical parameters "
                                            f"({', '.join(model.uncertain)}) to pi"),
        Generated(dyn.tip_fun(), "tip position and 6xn geometric Jacobian [Jv; Jw]"),
        Generated(plant_step_fun(dyn), "one RK4 step of the nominal plant, x = (q, qd), "
                                       "tau held"),
        Generated(controller_fun(dyn), "one sample of Slotine-Li adaptive control (Prop. 10), "
                                       "Euler update of pi_hat"),
        Generated(closed_loop_fun(dyn, steps=options.loop_steps, substeps=options.loop_substeps),
                  f"{options.loop_steps} samples of Slotine-Li control + RK4 plant "
                  f"({options.loop_substeps} substep(s)) in one call"),
    ]
    known = dyn.known_torque_fun()
    if known is not None:
        fns.append(Generated(known, "terms of the dynamics multiplying no uncertain parameter"))
    estimators = _actuator_functions(model, dyn, fns)
    params = {
        "names": dyn.parameter_names,
        "nominal": [float(v) for v in dyn.parameter_nominal],
        "expressions": list(dyn.base.expressions),
        "physical": list(model.uncertain),
        "physical_nominal": [float(model.nominal[k]) for k in model.uncertain],
    }
    identity = identity_bytes(model.source_text(), options)
    extra = {"dof": n, **model_source(model),
             "options": dict(options.__dict__), "route": dyn.route,
             "full_parameter_count": dyn.base.full_rank,
             # Which route built each product, and the instruction counts it chose by.
             "route_detail": dyn.route_detail}
    if model.actuator_type is not None:
        extra["actuator"] = model.actuator_type
        extra["estimators"] = {e.step_fun().name(): e.describe() for e in estimators}
    if model.actuator_type == "mckibben":
        from softgen.control.feedback_linearization import GAIN_NAMES as FL_GAIN_NAMES
        from softgen.control.pneumatic import KINDS, REFERENCE_BLOCKS, PneumaticArm
        arm = PneumaticArm(model, dyn=dyn)
        extra["controllers"] = {
            "steps": {k: f"{model.name}_{v}" for k, v in KINDS.items()},
            "reference_layout": list(REFERENCE_BLOCKS),
            "state_layout": {"theorem5": ["nu", "Pi_hat"], "corollary2": ["nu", "Pi_hat"],
                             "open_loop": ["Pi_hat"], "prop11": ["Pi_hat"]},
            "Pi_names": arm.parameter_names,
            "Pi_nominal": [float(v) for v in arm.Pi_nominal],
            "K1": arm.K1,
            "pressure_unit": "Pa",
            "feedback_linearization": {
                "step": f"{model.name}_feedback_linearization",
                "lie_derivatives": f"{model.name}_fl_lie",
                "state_layout": ["q", "qd", "p"],
                "gains": list(FL_GAIN_NAMES),
            },
        }
    return BundleSpec(name=model.name, functions=fns, parameters=params, identity=identity,
                      extra=extra)


def _actuator_functions(model: RobotModel, dyn: RigidDynamics, fns: list) -> list:
    """Actuator model, actuated plants, estimators (thesis defaults) and, for McKibben
    pairs, the chapter-10 controllers of ``model``."""
    from softgen.estimation.estimators import EstimatorConfig, StiffnessEstimator
    from softgen.control.feedback_linearization import FeedbackLinearization
    from softgen.control.pneumatic import PneumaticArm
    from softgen.symbolic.actuated import electric_plant_fun, pneumatic_plant_fun, valve_plant_fun
    from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings

    if model.actuator_type is None:
        return []
    if model.actuator_type == "mckibben":
        act = McKibbenPairs(model)
        fns += [Generated(f, doc) for f, doc in act.functions()]
        fns.append(Generated(pneumatic_plant_fun(dyn, act, substeps=PLANT_SUBSTEPS),
                             f"{PLANT_SUBSTEPS} RK4 steps of the pneumatic robot (eq. 2.5) "
                             "over one sample, pressures held"))
        fns.append(Generated(valve_plant_fun(dyn, act, substeps=PLANT_SUBSTEPS),
                             f"{PLANT_SUBSTEPS} RK4 steps of the pneumatic robot with "
                             "first-order valves (sec. 10.4), commands clipped to [0, p_max]"))
        fns += [Generated(f, doc) for f, doc in PneumaticArm(model, dyn=dyn, act=act).functions()]
        fns += [Generated(f, doc) for f, doc in
                FeedbackLinearization(model, dyn=dyn, act=act).functions()]
        methods = ["pneumatic"] if model.dof == 1 else []
    else:
        springs = QbmoveSprings(model)
        fns += [Generated(f, doc) for f, doc in springs.functions()]
        fns.append(Generated(electric_plant_fun(dyn, springs, substeps=PLANT_SUBSTEPS),
                             f"{PLANT_SUBSTEPS} RK4 steps of the electric VSA robot (eq. 2.6) "
                             "over one sample, motor torques held"))
        from softgen.control.electric import CASCADE_MODELS, bundle_functions
        if model.name in CASCADE_MODELS:        # chapter-11 cascades (Theorems 6-9)
            fns += [Generated(f, doc) for f, doc in
                    bundle_functions(model, dyn=dyn, springs=springs)]
        methods = ["electric", "noninvasive"]
    estimators = [StiffnessEstimator(model, EstimatorConfig(m)) for m in methods]
    for e in estimators:
        c = e.config
        fns.append(Generated(e.step_fun(), f"{c.method} stiffness estimator step, T = {c.dt} s, "
                             f"delay {c.delay}: (state, y_k) -> estimates for sample k - "
                             f"{c.delay} (chapters 6-7)"))
    return estimators


#: RK4 steps per sample in the generated actuated plants.
PLANT_SUBSTEPS = 10


def identity_bytes(model_text: str, options: BundleOptions) -> bytes:
    """What the bundle hash covers besides CasADi's and the code generator's versions."""
    return model_text.encode() + b"\n" + json.dumps(options.__dict__, sort_keys=True).encode()


def model_source(model: RobotModel) -> dict:
    """``model_file`` and ``model_sha256`` of the manifest: where the model came from.

    A shipped model is recorded as ``models/<file>`` (relative, so ``generated/`` is
    the same on every machine); any other file by its absolute path.
    """
    if model.path is None:
        return {"model_file": f"{model.name}.toml",
                "model_sha256": hashlib.sha256(b"").hexdigest()}
    path = Path(model.path).resolve()
    try:
        shown = f"models/{path.relative_to(MODELS_DIR.resolve()).as_posix()}"
    except ValueError:
        shown = str(path)
    return {"model_file": shown, "model_sha256": hashlib.sha256(path.read_bytes()).hexdigest()}


def model_file_path(manifest: dict) -> Path:
    """The model file a manifest was generated from (``model_file``, made absolute)."""
    p = Path(manifest.get("model_file", ""))
    return p if p.is_absolute() else MODELS_DIR.parent / p


def identity_hash(manifest: dict) -> str | None:
    """The hash a bundle would have if generated now from its model file (None if absent)."""
    if not manifest.get("model_file"):
        return None
    path = model_file_path(manifest)
    if not path.is_file():
        return None
    options = BundleOptions(**manifest.get("options", {}))
    return content_hash(identity_bytes(path.read_text(), options))


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
    spec = bundle_spec(load_model(path), BundleOptions(**manifest.get("options", {})))
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
            what = f"joint {j + 1} ({links[j].name})" if links is not None else \
                f"configuration variable {j + 1}"
            raise ModelError(f"{where}: B(q) is not positive definite at q = "
                             f"{np.round(q, 4).tolist()} (smallest eigenvalue {lam.min():.3g}); "
                             f"{what} moves no mass or inertia")


def generate(name_or_path: str | Path, out_root: Path = GENERATED_DIR,
             options: BundleOptions = BundleOptions()) -> Path:
    """Write ``out_root/<model>/`` for one model; return the bundle directory.

    A model file outside ``models/`` that takes the name of a shipped model is
    refused for the shipped ``generated/`` (it would replace that bundle); write it
    elsewhere with ``out_root``.
    """
    model = load_model(name_or_path)
    out_root = Path(out_root)
    shipped = shipped_model_file(model.name)
    if (model.path is not None and shipped is not None
            and Path(model.path).resolve() != shipped.resolve()
            and out_root.resolve() == GENERATED_DIR.resolve()):
        raise ModelError(f"{model.path}: model.name: {model.name!r} is the name of a shipped "
                         f"model (models/{shipped.name}); rename the model or generate it "
                         "elsewhere (--out DIR)")
    spec = bundle_spec(model, options)
    inertia = next((g.function for g in spec.functions
                    if g.function.name() == f"{model.name}_inertia"), None)
    if inertia is not None:
        check_inertia_positive_definite(model, inertia)
    return write_bundle(spec, out_root)


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
