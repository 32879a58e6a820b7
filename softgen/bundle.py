"""What a model's generated bundle contains, and ``softgen generate``.

Composes the symbolic layer (``symbolic/``, ``control/``) with the robot-agnostic
code generator (``codegen/``): for a rigid model, the functions of issue 2
(inertia, coriolis, gravity, regressor, ...) plus the Slotine–Li step and its
closed loop, written to ``generated/<model>/``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .codegen.generate import BundleSpec, Generated, content_hash, write_bundle
from .control.slotine_li import closed_loop_fun, controller_fun, plant_step_fun
from .model import MODELS_DIR, RobotModel, list_models, load_model
from .symbolic.rigid import RigidDynamics

GENERATED_DIR = MODELS_DIR.parent / "generated"


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
    extra = {"dof": n, "model_file": f"models/{model.name}.toml",
             "options": dict(options.__dict__), "route": dyn.route,
             "full_parameter_count": dyn.base.full_rank,
             # Which route built each product, and the instruction counts it chose by.
             "route_detail": dyn.route_detail}
    if model.actuator_type is not None:
        extra["actuator"] = model.actuator_type
        extra["estimators"] = {e.step_fun().name(): e.describe() for e in estimators}
    if model.actuator_type == "mckibben":
        from .control.feedback_linearization import GAIN_NAMES as FL_GAIN_NAMES
        from .control.pneumatic import KINDS, REFERENCE_BLOCKS, PneumaticArm
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
    from .estimation.estimators import EstimatorConfig, StiffnessEstimator
    from .control.feedback_linearization import FeedbackLinearization
    from .control.pneumatic import PneumaticArm
    from .symbolic.actuated import electric_plant_fun, pneumatic_plant_fun, valve_plant_fun
    from .symbolic.actuators import McKibbenPairs, QbmoveSprings

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


def identity_hash(manifest: dict) -> str | None:
    """The hash a bundle would have if generated now from its model file (None if absent)."""
    path = MODELS_DIR.parent / manifest.get("model_file", "")
    if not manifest.get("model_file") or not path.is_file():
        return None
    options = BundleOptions(**manifest.get("options", {}))
    return content_hash(identity_bytes(path.read_text(), options))


def casadi_functions(manifest: dict) -> dict:
    """The bundle's casadi.Functions rebuilt from its model file (no-compiler fallback)."""
    path = MODELS_DIR.parent / manifest["model_file"]
    spec = bundle_spec(load_model(path), BundleOptions(**manifest.get("options", {})))
    return {g.function.name(): g.function for g in spec.functions}


def generate(name_or_path: str | Path, out_root: Path = GENERATED_DIR,
             options: BundleOptions = BundleOptions()) -> Path:
    """Write ``out_root/<model>/`` for one model; return the bundle directory."""
    model = load_model(name_or_path)
    return write_bundle(bundle_spec(model, options), Path(out_root))


def generate_all(out_root: Path = GENERATED_DIR) -> list[Path]:
    """Bundles of every model in ``models/``."""
    return [generate(name, out_root) for name in list_models()]
