"""Every capability's example: a registered scenario with a typed config (issue 31).

An *example* is the closed loop that shows what a capability does on a model: the
references, the controller and a plant that holds the model's declared actuators, wired
as a :class:`~softgen.blocks.ClosedLoop` of library blocks and wrapped in a
:class:`~softgen.studies.Scenario`. Each is registered here with

- ``id`` (``slotine-li``, ``theorem5``, ``electric-pd``, ...), the registry capability it
  runs, and a **typed config** (a :class:`~softgen.core.config.Config`) whose defaults are
  the example's gains and references: their one home. The experiments that run the same
  loop take their defaults from these configs, and ``softgen export MODEL [--example ID]
  [--set KEY=VALUE]`` builds from them with the same validation as ``reproduce --set``;
- ``serves``: whether the example's plant is the model's robot (its declared actuators,
  not a stand-in), beyond the capability the capability decision grants
  (:func:`softgen.bundles.bundle.decide`).

:func:`choose` picks a model's example: the first registered one the model's decision
grants and that serves it (the registration order is the priority), or the one named.
A model no example serves is refused in one line naming what is missing (``export``,
``bench``), never served a loop of another robot.

Every loop takes the model's symbolic objects from the bundle's derivation
(:func:`softgen.bundles.bundle.derivation`, cached per model content), so an example,
the bundle and the experiments derive a model once per process.

Sample time: 1 ms (:data:`DT`) unless the example's config sets ``dt``; the electric
cascade's default is the largest of 1 ms, 0.5 ms, 0.25 ms, ... that resolves its motors'
spring modes (:func:`motor_mode_step`), so that a model with light motors gets a faster
loop, not a loop of a rigid arm.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softgen.blocks import ClosedLoop
from softgen.bundles.bundle import decide, derivation
from softgen.bundles.registry import Context
from softgen.bundles.rigid import (PARTIAL_TRACKING_GAINS, SEA_GAINS, partial_reference,
                                   partial_tracking_gains)
from softgen.bundles.spring_pair import SpringPairExample
from softgen.bundles.spring_pair import example_loop as spring_pair_loop
from softgen.control.cosserat import GAINS as COSSERAT_GAINS
from softgen.control.cosserat import TIP_REFERENCE, TipGains
from softgen.control.cosserat import closed_loop as cosserat_tip_loop
from softgen.control.electric import (ElectricArm, cascade_block, initial_plant_state,
                                      plant_block as electric_plant_block)
from softgen.control.feasibility import stiffness_range
from softgen.control.partial import PartialArm
from softgen.control.partial import tracking_loop as partial_tracking_loop
from softgen.control.pneumatic import PneumaticArm
from softgen.control.pneumatic_loop import controller_block as pneumatic_controller_block
from softgen.control.pneumatic_loop import plant_block as pneumatic_plant_block
from softgen.control.pneumatic_loop import preset_nu
from softgen.control.references import (Sinusoid, SmoothSteps, sinusoid_block,
                                        stiffness_reference_block)
from softgen.control.sea import SeaArm
from softgen.control.sea import closed_loop as sea_closed_loop
from softgen.control.sea import initial_state as sea_initial_state
from softgen.control.slotine_li import controller_block as slotine_li_block
from softgen.control.slotine_li import plant_block as rigid_plant_block
from softgen.control.soft import plant_block as soft_plant_block
from softgen.control.soft import reference_block as soft_reference_block
from softgen.control.soft import tip_force_block
from softgen.control.soft_sampled import sampled_controller_block
from softgen.control.spring_pair import SpringPairArm
from softgen.core.config import Config
from softgen.core.errors import SoftgenError
from softgen.modelfile.cosserat import CosseratModel
from softgen.modelfile.load import load_model
from softgen.modelfile.model import RobotModel
from softgen.modelfile.soft import SoftModel
from softgen.plants.floating import floating_plant_block, joint_pd_block
from softgen.studies.electric import (MODE_RATIO, STIFFNESS_MARGIN, THESIS_GAINS,
                                      THESIS_REFERENCES, model_gains, model_references,
                                      sinusoid_references)
from softgen.studies.gains import (PLANAR_PCC_HIGHER_GAINS, PLANAR_PCC_REFERENCE, SECTION_10_2,
                                   STIFFNESS_RATE, thesis_to_physical)
from softgen.studies.scenario import Scenario

__all__ = ["DT", "DEFAULT_SECONDS", "Example", "ExampleSpec", "EXAMPLES", "choose",
           "example_for", "applicable", "parse_overrides", "motor_mode_step",
           "SlotineLiConfig", "Theorem5Config", "ElectricPdConfig", "SeaCascadeConfig",
           "PartialConfig", "Theorem10Config", "SpringPairExample", "FloatingConfig"]

#: Sample time of the example loops (s), unless a config sets its own, and their length.
DT = 1e-3
DEFAULT_SECONDS = 10.0
#: Largest ω·dt of a motor spring mode the electric example integrates with one RK4 step
#: per sample (:func:`motor_mode_step`).
MAX_MODE_STEP = 0.5
#: What an example's config may set (issue 36: ``export --set substeps=100000000`` ran
#: silently for minutes, ``substeps=0``, ``dt=1e-12`` and a negative stiffness margin
#: were exported with status 0): the sample time (s), RK4 substeps per sample and the
#: samples of one run (the exported program's default length, DEFAULT_SECONDS / dt).
DT_RANGE = (1e-6, 0.1)
MAX_SUBSTEPS = 100
MAX_LOOP_SAMPLES = 10_000_000
#: Gains of the example configs that must be positive, and those that may be zero.
_POSITIVE = ("lam", "kp", "kp_m", "stiffness_rate", "mode_ratio", "omega", "rise")
_NONNEGATIVE = ("kd", "kpi", "kd_m")


class ExampleConfig(Config):
    """The checks every example config shares (by field name: ``dt``, ``substeps`` and
    the gains of :data:`_POSITIVE` and :data:`_NONNEGATIVE`), before anything is built."""

    def validate(self) -> None:
        owner = type(self).__name__
        dt = getattr(self, "dt", None)
        lo, hi = DT_RANGE
        if dt is not None and not lo <= dt <= hi:
            raise ValueError(f"{owner}.dt: expected a sample time between {lo:g} and {hi:g} "
                             f"s, got {dt!r}")
        substeps = getattr(self, "substeps", None)
        if substeps is not None and not 1 <= substeps <= MAX_SUBSTEPS:
            raise ValueError(f"{owner}.substeps: expected 1 to {MAX_SUBSTEPS} RK4 steps per "
                             f"sample, got {substeps!r}")
        for name in _POSITIVE + _NONNEGATIVE:
            v = getattr(self, name, None)
            values = v if isinstance(v, tuple) else (v,)     # per-axis gains: each one
            if v is not None and not all(x > 0 if name in _POSITIVE else x >= 0
                                         for x in values):
                raise ValueError(f"{owner}.{name}: expected a "
                                 f"{'positive' if name in _POSITIVE else 'non-negative'} "
                                 f"number, got {v!r}")


@dataclass(frozen=True)
class Example:
    """The scenario of a model's example loop and what the exported README says of it.

    ``errors`` lists ``(reference, actual, unit)`` signal pairs whose rms and max the
    C program reports (``Trace.rms`` of the same pairs in Python); ``config`` is the typed
    config it was built from (its values are the exported scenario's).
    """

    kind: str
    title: str
    text: str
    scenario: Scenario
    errors: tuple[tuple[str, str, str], ...] = ()
    gains_source: str = ""
    config: Config | None = None

    @property
    def loop(self) -> ClosedLoop:
        return self.scenario.loop

    @property
    def dt(self) -> float:
        return float(self.loop.dt)


Builder = Callable[[Context, Any, int], Example]


@dataclass(frozen=True)
class ExampleSpec:
    """One registered example (module docstring)."""

    id: str
    capability: str
    title: str
    config: type[Config]
    build: Builder
    serves: Callable[[Any], str | None] = field(default=lambda model: None)

    def why_not(self, model) -> str | None:
        """None if this example runs on ``model``, else why not (one line)."""
        why = decide(model).why_not(self.capability)
        if why is not None:
            return why
        return self.serves(model)


#: The registered examples in order of priority (the first that applies is a model's);
#: filled at the end of this module, in that order.
EXAMPLES: dict[str, ExampleSpec] = {}


def register(id: str, *, capability: str, title: str, config: type[Config], build: Builder,
             serves: Callable[[Any], str | None] | None = None) -> ExampleSpec:
    """Register ``build(ctx, config, steps) -> Example`` as example ``id`` (last in
    priority)."""
    if id in EXAMPLES:
        raise ValueError(f"example {id!r} registered twice")
    spec = ExampleSpec(id, capability, title, config, build, serves or (lambda model: None))
    EXAMPLES[id] = spec
    return spec


def applicable(model) -> list[tuple[ExampleSpec, str | None]]:
    """Every registered example with None (it runs on ``model``) or why not."""
    return [(spec, spec.why_not(model)) for spec in EXAMPLES.values()]


def _where(model) -> str:
    return str(model.path) if getattr(model, "path", None) is not None else model.name


def choose(model, example: str | None = None) -> ExampleSpec:
    """The example of ``model``: ``example`` by id, or the first that applies.

    Raises
    ------
    SoftgenError
        One line: an unknown id, an example that does not apply (and why), or, when none
        applies, what the model lacks (the reason of the example its actuation calls for).
    """
    if example is not None:
        spec = EXAMPLES.get(example)
        if spec is None:
            raise SoftgenError(f"example {example!r}: expected one of "
                               f"{', '.join(EXAMPLES)}")
        why = spec.why_not(model)
        if why is not None:
            raise SoftgenError(f"example {example!r} does not apply to {model.name}: {why}")
        return spec
    results = applicable(model)
    for spec, why in results:
        if why is None:
            return spec
    why = _missing(model, results)
    raise SoftgenError(why if "no controller applies" in why
                       else f"{model.name}: no controller applies; {why}")


def _missing(model, results) -> str:
    """What a model no example serves lacks, as one clause: the reason of the example
    meant for its actuation (passive joints: the partly actuated one; springs: the
    spring ones; pressures: Theorem 5; none: Slotine–Li)."""
    why = dict((s.id, w) for s, w in results)
    if isinstance(model, SoftModel):
        return why.get("theorem10") or "no soft-body example applies"
    if not hasattr(model, "links"):            # a Cosserat rod: its tip-control example
        return why.get("cosserat-tip") or next((w for _, w in results if w),
                                               "no rod example applies")
    acts = tuple(getattr(model, "actuators", ()) or ())
    passive = sorted(set(range(model.dof)) - {a.joint for a in acts}) if acts else []
    drives = {a.drive for a in acts}
    if passive:
        order = ["partial"]
    elif "pressure" in drives:
        order = ["theorem5"]
    elif "spring" in drives:
        order = ["spring-pair", "electric-pd", "sea-cascade"]
    else:
        order = ["slotine-li"]
    for k in order:
        if why.get(k):
            return why[k]
    return next((w for _, w in results if w), "no registered example applies")


def parse_overrides(spec: ExampleSpec, items: list[str] | tuple[str, ...]) -> dict:
    """``KEY=VALUE`` strings for ``spec``'s config (VALUE a Python literal, else a
    string; lists become tuples), each checked by the typed config: one error line
    naming the key (the same rules as ``reproduce --set``)."""
    import ast
    out: dict[str, Any] = {}
    for item in items:
        key, eq, text = str(item).partition("=")
        key = key.strip()
        if not eq or not key:
            raise SoftgenError(f"--set {item!r}: expected KEY=VALUE")
        try:
            value = ast.literal_eval(text.strip())
        except (ValueError, SyntaxError, MemoryError, RecursionError):
            value = text.strip()
        if isinstance(value, list):
            value = tuple(value)
        out[key] = value
    try:
        spec.config().replace(**out)
    except (ValueError, TypeError) as exc:
        raise SoftgenError(f"--set: example {spec.id}: {str(exc).splitlines()[0]}") from None
    return out


def example_for(model, *, example: str | None = None, steps: int | None = None,
                overrides: Mapping[str, Any] | None = None, ctx: Context | None = None
                ) -> Example:
    """The example of ``model`` (a shipped name, a model file or a loaded model): the
    registered scenario :func:`choose` picks (or ``example``), built from its typed config
    with ``overrides``, ``steps`` samples long (default :data:`DEFAULT_SECONDS`)."""
    if not isinstance(model, (RobotModel, SoftModel, CosseratModel)):
        model = load_model(model)
    spec = choose(model, example)
    try:
        cfg = spec.config().replace(**dict(overrides or {}))
    except (ValueError, TypeError) as exc:
        raise SoftgenError(f"example {spec.id}: {str(exc).splitlines()[0]}") from None
    ctx = ctx or derivation(model)
    dt = _dt(cfg, model)
    if steps is None:
        steps = int(round(DEFAULT_SECONDS / dt))
    if not (isinstance(steps, int) and not isinstance(steps, bool)
            and 1 <= steps <= MAX_LOOP_SAMPLES):
        raise SoftgenError(f"steps: expected 1 to {MAX_LOOP_SAMPLES:,} samples, got {steps!r}")
    return spec.build(ctx, cfg, steps)


def _dt(cfg, model) -> float:
    dt = getattr(cfg, "dt", None)
    if dt is None:
        return motor_mode_step(model) if isinstance(cfg, ElectricPdConfig) else DT
    return float(dt)


def _cycle(values, n: int) -> np.ndarray:
    return np.array([float(values[i % len(values)]) for i in range(n)])


def _fmt(v) -> str:
    return ", ".join(f"{x:.4g}" for x in np.atleast_1d(v))


# --------------------------------------------------------------------------- which robot

def _torque_driven(model) -> str | None:
    """The Slotine–Li example's plant is the rigid arm driven by joint torques: every
    joint a direct torque, or no actuators declared (a bare chain is torque driven, eq.
    2.1). Springs, motors or pressures would be missing from its plant."""
    acts = tuple(getattr(model, "actuators", ()) or ())
    other = [a for a in acts if a.drive != "torque"]
    if not other:
        return None
    names = ", ".join(f"{model.links[a.joint].name} ({a.type})" for a in other)
    return (f"{_where(model)}: actuators of joints {names} are not joint torques: the "
            "Slotine-Li example's plant (the rigid arm driven by torques) would leave them "
            "out")


def motor_mode_step(model) -> float:
    """Sample time of the electric example: :data:`DT` halved until the fastest motor
    spring mode ω = √(σ_max/(2b)) has ω·dt ≤ :data:`MAX_MODE_STEP` (one RK4 step per
    sample follows it; measured: arm_2link_electric, b = 1e-3 kg m², ω·dt = 0.07 at 1 ms,
    tracks to 1e-4 rad; planar_2link, b = 3e-6, ω·dt = 1.35 at 1 ms, errs by 0.3 rad).
    σ_max is the example's largest reference stiffness (:func:`model_references`: section
    11.2's 11 N m/rad where the springs hold the arm with it, more where they need it;
    each spring carries σ/2)."""
    b = min(float(np.min(model.resolve(a.get("motor_inertia"), model.nominal)))
            for a in model.actuators)
    ctx = derivation(model)
    refs = model_references(ElectricArm(model, dyn=ctx.dyn, springs=ctx.springs))
    sigma_max = max(s.offset + abs(s.amplitude) for s in refs.sigma)
    omega = math.sqrt(sigma_max / (2 * b))
    dt = DT
    while omega * dt > MAX_MODE_STEP:
        dt /= 2
    return dt


# --------------------------------------------------------------------------- Slotine–Li

@dataclass(frozen=True)
class SlotineLiConfig(ExampleConfig):
    """Slotine–Li (Prop. 10) on the torque-driven arm: gains Λ (1/s), K_d (N m s/rad) and
    K_π (per base parameter), cycled over the joints, and references q_d,i = o_i + a_i
    sin(2π f_i t). The values of the ``rigid-2link-adaptive`` experiment, which takes its
    defaults from here."""

    lam: float = 10.0
    kd: float = 0.2
    kpi: float = 0.05
    amplitude: tuple[float, ...] = (0.6, 0.5)       # rad
    frequency: tuple[float, ...] = (0.25, 0.4)      # Hz
    offset: tuple[float, ...] = (0.0, 0.3)          # rad
    dt: float | None = None                         # s (None: 1 ms)



def _slotine_li(ctx: Context, c: SlotineLiConfig, steps: int) -> Example:
    model, dyn = ctx.model, ctx.dyn
    n, p, dt = model.dof, len(dyn.base.names), float(c.dt or DT)
    ref = Sinusoid(tuple(_cycle(c.amplitude, n)), tuple(_cycle(c.frequency, n)),
                   offset=tuple(_cycle(c.offset, n)))
    ctrl = slotine_li_block(dyn, dt).with_defaults(
        p0={"lam": np.full(n, c.lam), "kd": np.full(n, c.kd), "kpi": np.full(p, c.kpi)})
    d = ClosedLoop(f"{model.name}_loop",
                   [sinusoid_block("ref", ref), ctrl, rigid_plant_block(dyn, dt)])
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={"plant.q": _cycle(c.offset, n)})    # on the reference at t = 0
    return Example(
        "slotine_li", "Slotine-Li (Prop. 10) on the rigid arm",
        "Slotine–Li adaptive control (thesis Prop. 10, eq. 9.2; every base parameter "
        "unknown at the start, π̂(0) = 0) of the torque-driven arm (one RK4 step per "
        "sample, torque held), tracking sinusoids q_d,i = o_i + a_i sin(2π f_i t) with "
        "analytic derivatives, from rest on the reference.",
        sc, (("ref.q_d", "plant.q", "rad"),),
        f"Λ = {c.lam:g}, K_d = {c.kd:g} N m s/rad, K_π = {c.kpi:g} (SlotineLiConfig: the "
        "rigid-2link-adaptive experiment's gains)", c)


# --------------------------------------------------------------------------- Theorem 5

@dataclass(frozen=True)
class Theorem5Config(ExampleConfig):
    """Theorem 5 (section 10.2) on an arm of pressure pairs linear in p. Physical gains
    (softgen.control.pneumatic): Λ in 1/s; K_d in N m s/rad and K_π on the physical base
    parameters, ``None`` for section 10.2's printed K_d = 18, K_π = 35 converted with the
    thesis arm's muscle gain (models/arm_2link_pneumatic.toml, K_g R of Table 10.1:
    thesis_to_physical); the stiffness error's decay rate in 1/s; Π̂(0) as a ratio of the
    nominal Π (the thesis's "initially inflated" preset). References: smoothed steps (C³)
    of position (rad) and stiffness (N m/rad), with a rise time (s); a joint whose
    muscles cannot give the stiffness steps (within ``stiffness_headroom`` of their range
    while holding the arm) gets them scaled into it."""

    lam: float = SECTION_10_2.lam
    kd: float | None = None
    kpi: float | None = None
    stiffness_rate: float = STIFFNESS_RATE
    pi_hat0_ratio: float = 0.9
    q_times: tuple[float, ...] = (0.0, 0.2, 5.0)
    q_values: tuple[float, ...] = (0.0, 0.3, 0.1)
    sigma_times: tuple[float, ...] = (0.0, 2.5, 7.5)
    sigma_values: tuple[float, ...] = (3.0, 4.0, 2.5)
    rise: float = 1.0
    stiffness_headroom: float = 0.8
    substeps: int = 10
    dt: float | None = None

    def gains(self) -> tuple[float, float]:
        """(K_d, K_π) in physical units: the config's, or section 10.2's converted."""
        if self.kd is not None and self.kpi is not None:
            return float(self.kd), float(self.kpi)
        act = _thesis_mckibben()
        kd, kpi = thesis_to_physical(act, np.full(len(act), SECTION_10_2.kd), SECTION_10_2.kpi)
        return (float(kd[0]) if self.kd is None else float(self.kd),
                float(kpi) if self.kpi is None else float(self.kpi))


def _thesis_mckibben() -> np.ndarray:
    """K_g R per muscle of the thesis's McKibben arm (Table 10.1, its model file)."""
    m = load_model("arm_2link_pneumatic")
    return np.array([[dict(s.constants)["K"] for s in a.sides] for a in m.actuators])


def _theorem5(ctx: Context, c: Theorem5Config, steps: int) -> Example:
    model = ctx.model
    arm = PneumaticArm(model, dyn=ctx.dyn, act=ctx.mckibben)
    n, dt = arm.n, float(c.dt or DT)
    kd_v, kpi_v = c.gains()
    q_steps = [SmoothSteps(c.q_times, c.q_values, c.rise)] * n
    s_steps, scaled = pneumatic_stiffness_steps(arm, c)
    ref = stiffness_reference_block("ref", q_steps, s_steps)
    lam, kd, kinv = np.full(n, c.lam), np.full(n, kd_v), np.ones(n)
    ctrl = pneumatic_controller_block(arm, "theorem5", dt).with_defaults(p0={
        "lam": lam, "kd": kd, "kpi": np.full(arm.n_params, kpi_v),
        "ksigma": np.full(n, c.stiffness_rate), "kinv": kinv})
    d = ClosedLoop(f"{model.name}_loop",
                   [ref, ctrl, pneumatic_plant_block(arm, dt, substeps=c.substeps)],
                   [("ctrl.p", "plant.p_cmd")])
    # The "initially inflated" preset of section 10.2: ν and the pressures of the
    # open-loop stiffness step (K_π = 0) at rest on the reference at t = 0.
    pi0 = c.pi_hat0_ratio * arm.Pi_nominal
    ref0 = d.blocks["ref"].eval(u=[0.0])[1][:6 * n]
    q0 = ref0[:n]
    out = arm.step_fun("open_loop")(pi0, q0, np.zeros(n), ref0, lam, kd,
                                    np.zeros(arm.n_params), kinv, dt)
    p_max = np.repeat(arm.act.pressure_max, 2)
    p0 = np.clip(np.array(out[1]).ravel(), 0.0, p_max)
    nu0 = preset_nu(arm, pi0, q0, ref0, lam=lam, kd=kd, dt=dt)
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={"plant.q": q0, "plant.p": p0, "ctrl.nu": nu0, "ctrl.Pi_hat": pi0})
    return Example(
        "theorem5", "Theorem 5 on the McKibben arm",
        "decoupled adaptive position and stiffness control (thesis Theorem 5, section "
        "10.2) of the arm's pressure pairs, pressures applied as commanded and clipped to "
        f"[0, p_max] ({c.substeps} RK4 steps per sample), the stiffness σ read from the "
        "pressures acting at each sample. ν and the pressures start from the open-loop "
        "stiffness step (K_π = 0) at rest, the thesis's \"initially inflated\" preset; "
        f"Π̂(0) = {c.pi_hat0_ratio:g} Π. References: smoothed steps (C³) of position and "
        "stiffness." + scaled,
        sc, (("ref.q_d", "plant.q", "rad"), ("ref.sigma_d", "plant.sigma", "N m/rad")),
        f"Λ = {c.lam:g} 1/s, K_d = {kd_v:.4g} N m s/rad, K_π = {kpi_v:.4g}, stiffness rate "
        f"{c.stiffness_rate:g} 1/s (Theorem5Config: section 10.2's K_d = 18, K_π = 35 in "
        "physical units of the thesis's muscles unless set)", c)


def pneumatic_stiffness_steps(arm: PneumaticArm, c: Theorem5Config
                              ) -> tuple[list[SmoothSteps], str]:
    """The Theorem 5 example's stiffness steps, made reachable joint by joint, and a
    sentence saying which were scaled ("" if none).

    ``c.sigma_values`` on every joint, unless the joint's muscles cannot give those
    stiffnesses while holding the arm at rest on the position references (all joints at
    one angle of ``c.q_values``' range; :func:`stiffness_range`) with
    ``c.stiffness_headroom``: then its levels are scaled by one factor into the range. A
    stiffness the muscles cannot give drives the commanded pressures out of [0, p_max];
    the clipped plant no longer applies Φp = τ_*, s stops vanishing and K_π Yᵀ s
    integrates the clipping error: Π̂ drifts and the loop runs away (measured on
    user_arm3_mckibben with gains 0.16/0.14/0.12: the hand's muscle a is commanded above
    p_max from t = 2.90 s, on the step to σ_d = 4 N m/rad, beyond its 3.28; the joints
    leave by 0.05 rad at t = 3.0 s). An arm its muscles cannot hold at all is one clear
    error.
    """
    levels = c.sigma_values
    qs = np.linspace(min(c.q_values), max(c.q_values), 31)
    lo, hi = stiffness_range(arm, np.repeat(qs[:, None], arm.n, axis=1))
    h = c.stiffness_headroom
    out, notes = [], []
    for j in range(arm.n):
        where = (f"{arm.name}: joint {j + 1} ({arm.model.links[j].name}), q in "
                 f"[{qs[0]:g}, {qs[-1]:g}] rad")
        if not lo[j] <= hi[j]:
            raise SoftgenError(f"{where}: its muscles cannot hold the arm at rest with "
                               f"pressures in [0, {arm.act.pressure_max[j]:g}] Pa at any "
                               "stiffness; check the actuator's gain, radius and pressure_max")
        f = 1.0
        if max(levels) > h * hi[j]:
            f = h * hi[j] / max(levels)
        elif min(levels) < lo[j] / h:
            f = lo[j] / h / min(levels)
        if f * min(levels) < lo[j] / h * (1 - 1e-12) or f * max(levels) > h * hi[j] * (1 + 1e-12):
            raise SoftgenError(f"{where}: stiffness range [{lo[j]:.3g}, {hi[j]:.3g}] N m/rad "
                               f"too narrow for the example's steps {min(levels):g}-"
                               f"{max(levels):g} N m/rad with headroom {h:g}")
        if f != 1.0:
            notes.append(f"{j + 1} (x{f:.3g}, range [{lo[j]:.3g}, {hi[j]:.3g}] N m/rad)")
        out.append(SmoothSteps(c.sigma_times, tuple(f * v for v in levels), c.rise))
    scaled = (f" The stiffness steps of joints {', '.join(notes)} are scaled into "
              f"{h:g} of the range the muscles give while holding the arm at rest within "
              "[0, p_max] (pneumatic_stiffness_steps).") if notes else ""
    return out, scaled


# --------------------------------------------------------------------------- chapter 11

@dataclass(frozen=True)
class ElectricPdConfig(ExampleConfig):
    """The chapter-11 PD cascade (eq. 11.4-11.6) on an arm of sinh spring pairs with
    motors: section 11.2's references and PD gains (studies.electric: THESIS_REFERENCES,
    THESIS_GAINS["pd"], their one home), each joint's stiffness raised to
    ``stiffness_margin`` times what holds the arm and its poles moved out so that its link
    spring mode is at most ``mode_ratio`` times its outer pole (model_references,
    model_gains; the thesis's arm keeps the printed values). ``dt`` None: 1 ms, or finer
    where the motors' spring modes need it (motor_mode_step)."""

    stiffness_margin: float = STIFFNESS_MARGIN
    mode_ratio: float = MODE_RATIO
    dt: float | None = None

    def validate(self) -> None:
        super().validate()
        # At 1 the references touch the springs' zero co-contraction (STIFFNESS_MARGIN).
        if not self.stiffness_margin > 1:
            raise ValueError(f"ElectricPdConfig.stiffness_margin: expected a number > 1 (the "
                             f"stiffness over what holds the arm), got {self.stiffness_margin!r}")


def _electric_pd(ctx: Context, c: ElectricPdConfig, steps: int) -> Example:
    model = ctx.model
    arm = ElectricArm(model, dyn=ctx.dyn, springs=ctx.springs)
    n = arm.n
    dt = float(c.dt) if c.dt is not None else motor_mode_step(model)
    refs = model_references(arm, margin=c.stiffness_margin)
    base = THESIS_REFERENCES.sigma
    scaled = [f"{i + 1} (x{s.offset / base[i % len(base)].offset:.3g})"
              for i, s in enumerate(refs.sigma) if s != base[i % len(base)]]
    raised = (f" The stiffness sinusoids of joints {', '.join(scaled)} are scaled up to "
              f"{c.stiffness_margin:g} times the least stiffness with which the springs "
              f"hold the arm on the position reference (model_references).") if scaled else ""
    gains = model_gains(arm, refs, ratio=c.mode_ratio)
    g = dict(gains)
    d = ClosedLoop(f"{model.name}_loop",
                   [refs.block(), cascade_block(arm, "pd", dt, gains=g),
                    electric_plant_block(arm, dt)])
    x0 = initial_plant_state(arm, lambda t: sinusoid_references(t, refs)[:, 0],
                             ksigma=g["ksigma"], delta=g["delta"])
    z0 = arm.initial_state("pd", x0)
    init = {f"plant.{k}": x0[i * n:(i + 1) * n]
            for i, k in enumerate(("q", "qd", "qa", "qad", "qb", "qbd"))}
    init.update({f"ctrl.{k}": v for k, v in d.blocks["ctrl"].state.split(z0).items()})
    sc = Scenario(f"{model.name}_loop", d, steps=steps, x0=init)
    rate = "" if dt == DT else (f" Sampled at {dt * 1e3:g} ms: the motors' spring modes "
                                "are too fast for 1 ms (motor_mode_step).")
    return Example(
        "electric_pd", "the chapter-11 PD cascade on the electric VSA arm",
        "the chapter-11 PD cascade (thesis eq. 11.4-11.6: link position and stiffness "
        "loops, motor position loops) of the arm with its qbmove-style electric VSAs "
        "(eq. 11.1, one RK4 step per sample, motor torques held), tracking the section "
        "11.2 sinusoids of position and stiffness from rest on the reference, at the "
        "quasi-steady stiffness of Remark 10." + raised + rate,
        sc, (("ref.q_d", "plant.q", "rad"), ("ref.sigma_d", "plant.sigma", "N m/rad")),
        "the PD gains printed in section 11.2 (THESIS_GAINS['pd'])" + (
            "" if gains is THESIS_GAINS["pd"] else
            f", with each joint's poles scaled so that its link spring mode is at most "
            f"{c.mode_ratio:g} times its outer pole (model_gains): k_p = "
            f"{_fmt(g['kp'])}, k_d = {_fmt(g['kd'])}, k_p,m = {_fmt(g['kp_m'])}, "
            f"k_d,m = {_fmt(g['kd_m'])}"), c)


# --------------------------------------------------------------------------- SEA, partial

@dataclass(frozen=True)
class SeaCascadeConfig(ExampleConfig):
    """The PD cascade for linear series-elastic joints (control.sea): link PD k_p, k_d
    and motor PD k_p,m, k_d,m (the bundle's sea_cascade defaults, SEA_GAINS: their one
    home), references as Slotine–Li's, RK4 substeps per sample."""

    kp: float = SEA_GAINS["kp"]
    kd: float = SEA_GAINS["kd"]
    kp_m: float = SEA_GAINS["kp_m"]
    kd_m: float = SEA_GAINS["kd_m"]
    amplitude: tuple[float, ...] = SlotineLiConfig.amplitude
    frequency: tuple[float, ...] = SlotineLiConfig.frequency
    offset: tuple[float, ...] = SlotineLiConfig.offset
    substeps: int = 4
    dt: float | None = None


def _sea_cascade(ctx: Context, c: SeaCascadeConfig, steps: int) -> Example:
    model = ctx.model
    arm = SeaArm(model, dyn=ctx.dyn)
    n, dt = arm.n, float(c.dt or DT)
    g = {"kp": c.kp, "kd": c.kd, "kp_m": c.kp_m, "kd_m": c.kd_m}
    off, amp = _cycle(c.offset, n), _cycle(c.amplitude, n)
    omega = 2 * np.pi * _cycle(c.frequency, n)
    d = sea_closed_loop(arm, dt, offset=off, amplitude=amp, omega=omega, gains=g,
                        substeps=c.substeps, name=f"{model.name}_loop")
    ref0 = np.array(d.blocks["ref"].eval(u=[0.0])[1][:5 * n]).ravel()
    x0 = sea_initial_state(arm, ref0, g, dt)
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={f"plant.{k}": x0[i * n:(i + 1) * n]
                      for i, k in enumerate(("q", "qd", "th", "thd"))})
    return Example(
        "sea_cascade", "the PD cascade on the series-elastic arm",
        "the PD cascade for linear series-elastic joints (thesis Theorems 6-7 with a "
        "linear spring: outer link loop giving the spring torque, motor reference "
        "θ_d = q + v/k, inner motor loop; softgen.control.sea) of the arm with its SEAs "
        f"({c.substeps} RK4 steps per sample, motor torques held), tracking sinusoids "
        "q_d,i = o_i + a_i sin(2π f_i t) (C⁴, exact derivatives) from rest on the "
        "reference, motors on their reference deflection.",
        sc, (("ref.q_d", "plant.q", "rad"),),
        f"k_p = {c.kp:g}, k_d = {c.kd:g}, k_p,m = {c.kp_m:g}, k_d,m = {c.kd_m:g} "
        "(SeaCascadeConfig: the bundle's sea_cascade defaults, SEA_GAINS)", c)


@dataclass(frozen=True)
class PartialConfig(ExampleConfig):
    """Collocated partial feedback linearisation of a partly actuated arm
    (control.partial): link gains k_p, k_d (1/s², 1/s) and motor gains k_p,m, k_d,m of
    spring-driven joints (PARTIAL_TRACKING_GAINS, their one home), references of the
    actuated joints (PARTIAL_REFERENCE), RK4 substeps per sample."""

    kp: float = PARTIAL_TRACKING_GAINS["kp"]
    kd: float = PARTIAL_TRACKING_GAINS["kd"]
    kp_m: float = PARTIAL_TRACKING_GAINS["kp_m"]
    kd_m: float = PARTIAL_TRACKING_GAINS["kd_m"]
    substeps: int = 4
    dt: float | None = None


def _partial(ctx: Context, c: PartialConfig, steps: int) -> Example:
    model = ctx.model
    arm = PartialArm(model, dyn=ctx.dyn)
    dt = float(c.dt or DT)
    ref = partial_reference(arm)
    gains = partial_tracking_gains(arm, {"kp": c.kp, "kd": c.kd, "kp_m": c.kp_m,
                                         "kd_m": c.kd_m})
    d = partial_tracking_loop(arm, dt, reference=ref, gains=gains, substeps=c.substeps,
                              name=f"{model.name}_loop")
    # From rest at the equilibrium q̄ of the references' starting point (the passive
    # joints settled there, the motors holding it): the actuated joints start on q_d(0)
    # with the reference's velocity still to pick up.
    n, nm = arm.n, arm.nm
    x = arm.rest_state(list(ref.offset or ()))
    init = {"plant.q": x[:n]}
    if nm:
        init["plant.th"] = x[2 * n:2 * n + nm]
    sc = Scenario(f"{model.name}_loop", d, steps=steps, x0=init)
    return Example(
        "partial", "collocated tracking of the partly actuated arm",
        "collocated partial feedback linearisation (softgen.control.partial, "
        "PartialArm.tracking_fun): the actuated joints track sinusoids q_d,i = o_i + a_i "
        "sin(2π f_i t) exactly for ideal torques (ë + K_d ė + K_p e = 0); spring-driven "
        "joints realise their torque through their motors (deflection and its rate by the "
        "chain rule); the passive joints follow their internal dynamics under their own "
        f"stiffness and damping (no claim beyond boundedness seen in runs); {c.substeps} "
        "RK4 steps per sample, commands held.",
        sc, (("ref.q_d", "ctrl.q_a", "rad"),),
        f"k_p = {c.kp:g}, k_d = {c.kd:g} (link error, 1/s^2 and 1/s); motors k_p,m = "
        f"{c.kp_m:g}, k_d,m = {c.kd_m:g} (PartialConfig: PARTIAL_TRACKING_GAINS)", c)


# --------------------------------------------------------------------------- Theorem 10

@dataclass(frozen=True)
class Theorem10Config(ExampleConfig):
    """Theorem 10 (section 12.1) sampled at 1 ms on a soft body: the "higher" gains of the
    section 12.2.1 study (Λ, K_d, K_π; studies.soft.PLANAR_PCC_HIGHER_GAINS, their one
    home) and its sinusoids q_d,i = M_i sin(ω t + φ_i) (PLANAR_PCC_REFERENCE, rad),
    cycled over the configuration variables; for pcc-3d the amplitudes ``amplitude_3d``
    in m (Δx, Δy, δL); affine bodies regulate to upright from ``initial_error``."""

    lam: float = PLANAR_PCC_HIGHER_GAINS[0]
    kd: float = PLANAR_PCC_HIGHER_GAINS[1]
    kpi: float = PLANAR_PCC_HIGHER_GAINS[2]
    amplitude: tuple[float, ...] = PLANAR_PCC_REFERENCE["amplitude"]
    phase: tuple[float, ...] = PLANAR_PCC_REFERENCE["phase"]
    omega: float = PLANAR_PCC_REFERENCE["omega"]
    amplitude_3d: tuple[float, ...] = (0.2, 0.2, 0.05)
    phase_3d: tuple[float, ...] = (0.0, math.pi / 2, 0.0)
    initial_error: tuple[float, ...] = (0.2, -0.2)
    dt: float | None = None


def _theorem10(ctx: Context, c: Theorem10Config, steps: int) -> Example:
    model, dyn, lin = ctx.model, ctx.dyn, ctx.lin
    n, dt = model.dof, float(c.dt or DT)
    if model.kind == "pcc-3d":
        amp, phase, omega, error0 = c.amplitude_3d, c.phase_3d, c.omega, (0.0,)
    elif model.kind == "affine-planar":          # regulation to upright (section 12.2.2)
        amp, phase, omega, error0 = (0.0,), (0.0,), 0.0, c.initial_error
    else:
        amp, phase, omega, error0 = c.amplitude, c.phase, c.omega, (0.0,)
    amp, phase, error0 = _cycle(amp, n), _cycle(phase, n), _cycle(error0, n)
    unit = "m" if model.kind == "pcc-3d" else "rad"
    ref = soft_reference_block("ref", dt, tuple(amp), omega, tuple(phase), unit=unit)
    ctrl = sampled_controller_block(dyn, dt, lin=lin).with_defaults(
        p0={"lam": np.full(n, c.lam), "kd": np.full(n, c.kd), "kpi": np.full(lin.r, c.kpi)})
    # The measurement noise input stays an external input of the diagram (zero here,
    # in C as in Python); no tip force (the disturbance block's defaults). The
    # controller reads the plant's measured output, as on hardware.
    d = ClosedLoop(f"{model.name}_loop", [ref, tip_force_block("dist", model.n_segments),
                                          ctrl, soft_plant_block(dyn, dt)],
                   [("plant.q_meas", "ctrl.q"), ("plant.qd_meas", "ctrl.qd")],
                   externals={"noise": 2 * n})
    r0 = d.blocks["ref"].eval(u=[0.0])[1]
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={"plant.q": r0[:n] - error0, "plant.qd": r0[n:2 * n]},
                  externals={"noise": np.zeros((steps, 2 * n))})
    return Example(
        "theorem10", "Theorem 10 on the soft robot",
        "adaptive control of the soft body (thesis Theorem 10, section 12.1) sampled at "
        f"{dt * 1e3:g} ms: the controller (the linearly implicit step of "
        "softgen.control.soft_sampled, τ held over the sample) and the plant (one ROS2 "
        "step per sample) are separate blocks, the controller reading the plant's "
        "measurement, π̂(0) = 0; tracking sinusoids q_d,i = M_i sin(ω t + φ_i) from rest "
        "on the reference (affine bodies: regulation to upright, q_d = 0, from an initial "
        "error); no measurement noise (the external input `noise` is held at zero), no "
        "tip force.",
        sc, (("ref.q_d", "plant.q", unit),),
        f"Λ = {c.lam:g}, K_d = {c.kd:g}, K_π = {c.kpi:g} (Theorem10Config: the higher gains "
        "of the section 12.2.1 study)", c)


# --------------------------------------------------------------------------- spring pairs

def _spring_pair(ctx: Context, c: SpringPairExample, steps: int) -> Example:
    model = ctx.model
    d = spring_pair_loop(model, DT, c, arm=SpringPairArm(model, dyn=ctx.dyn))
    d = ClosedLoop(f"{model.name}_loop", list(d.blocks.values()))
    sc = Scenario(f"{model.name}_loop", d, steps=steps)       # the blocks start on the reference
    return Example(
        "spring_pair", "the spring-pair cascade on the arm's antagonistic springs",
        "position and stiffness control of antagonistic spring pairs with motors for any "
        "invertible declared law (softgen.control.spring_pair: a Theorem-7 link loop gives "
        "the spring torque, Newton on the declared laws the two deflections giving it and "
        "the stiffness reference, Theorem-6 motor loops track them; rates by implicit "
        f"differentiation) of the arm with its springs and motors ({c.substeps} RK4 steps "
        "per sample, motor torques held), tracking sinusoids of position and of stiffness "
        "(kept off the pair's singular stiffness) from rest on the reference.",
        sc, (("ref.q_d", "plant.q", "rad"), ("ref.sigma_d", "plant.sigma", "N m/rad")),
        f"k_p = {c.kp:g}, k_d = {c.kd:g}, k_p,m = {c.kp_m:g}, k_d,m = {c.kd_m:g} "
        "(SpringPairExample, bundles.spring_pair)", c)


# --------------------------------------------------------------------------- registration

# --------------------------------------------------------------------------- floating base

@dataclass(frozen=True)
class FloatingConfig(ExampleConfig):
    """A floating-base robot's dynamics (issue 35): released at rest ``height`` (m) above
    the origin, level, joints at 0, a joint PD (gains ``kp`` N m/rad, ``kd`` N m s/rad,
    example values) moving them to a posture (``posture``, rad, cycled over the joints);
    nothing touches the base, which falls and turns in reaction."""

    kp: float = 200.0
    kd: float = 5.0
    posture: tuple[float, ...] = (0.0, 0.3)
    height: float = 1.0
    dt: float | None = None                         # s (None: 1 ms)


def _floating(ctx: Context, c: FloatingConfig, steps: int) -> Example:
    model, dyn = ctx.model, ctx.dyn
    n, dt = model.dof, float(c.dt or DT)
    posture = _cycle(c.posture, n)
    ref = Sinusoid((0.0,) * n, (0.0,) * n, offset=tuple(posture))
    ctrl = joint_pd_block(model, dt).with_defaults(
        p0={"kp": np.full(n, c.kp), "kd": np.full(n, c.kd)})
    d = ClosedLoop(f"{model.name}_loop", [sinusoid_block("ref", ref), ctrl,
                                          floating_plant_block(dyn, dt)])
    q0 = np.concatenate([[0.0, 0.0, c.height, 0.0, 0.0, 0.0, 1.0], np.zeros(n)])
    sc = Scenario(f"{model.name}_loop", d, steps=steps, x0={"plant.q": q0})
    return Example(
        "floating", "a floating-base robot moving its joints in free fall",
        "The floating-base dynamics (q = [base position, quaternion x y z w, joints], "
        "v = [base velocity in the base frame, joint rates], Pinocchio's free flyer): "
        "semi-implicit Euler with the forward dynamics and the exponential map each "
        f"sample. The robot is released at rest {c.height:g} m up with its joints at 0, "
        "and a PD moves them to a posture; nothing touches the base, which falls and "
        "turns in reaction (its momentum about the centre of mass stays zero).",
        sc, (("ref.q_d", "plant.q_joints", "rad"),),
        f"K_p = {c.kp:g} N m/rad, K_d = {c.kd:g} N m s/rad on every joint (FloatingConfig: "
        "example values)", c)


# --------------------------------------------------------------------------- Cosserat rods

@dataclass(frozen=True)
class CosseratTipConfig(ExampleConfig):
    """Task-space adaptive tip control of a Cosserat rod (issue 33; Theorem 10's law with
    σ = J⁺ s, one-sided input allocation): gains Λ (1/s), K_d (N s/m), K_π (relative to
    each nominal π² when ``kpi_relative``), the pretension u_min (the inputs' unit), and
    the Lissajous tip reference about the straight rod's tip (``amplitude`` m, ``omega``
    rad/s per task axis). Defaults: :data:`softgen.control.cosserat.GAINS` and
    :data:`~softgen.control.cosserat.TIP_REFERENCE`, their one home."""

    lam: float = COSSERAT_GAINS.lam
    kd: float = COSSERAT_GAINS.kd
    kpi: float = COSSERAT_GAINS.kpi
    kpi_relative: bool = COSSERAT_GAINS.kpi_relative
    u_min: float = COSSERAT_GAINS.u_min
    amplitude: tuple[float, ...] = TIP_REFERENCE["amplitude"]
    omega: tuple[float, ...] = TIP_REFERENCE["omega"]
    dt: float | None = None                         # s (None: 1 ms)

    def validate(self) -> None:
        for k in ("amplitude", "omega"):                # before the shared gain checks
            v = getattr(self, k)
            if not isinstance(v, tuple | list) or len(v) != 2:
                raise ValueError(f"CosseratTipConfig.{k}: expected two numbers (one per "
                                 f"task axis), got {getattr(self, k)!r}")
        super().validate()                          # dt, lam, kd, kpi, omega (ExampleConfig)
        if self.kd <= 0:                            # a rod's tip loop needs damping
            raise ValueError(f"CosseratTipConfig.kd: expected a positive number, "
                             f"got {self.kd!r}")
        if self.u_min < 0:
            raise ValueError(f"CosseratTipConfig.u_min: expected a number >= 0, "
                             f"got {self.u_min!r}")


def _cosserat_tip(ctx: Context, c: CosseratTipConfig, steps: int) -> Example:
    model, dt = ctx.model, float(c.dt or DT)
    gains = TipGains(lam=c.lam, kd=c.kd, kpi=c.kpi, kpi_relative=c.kpi_relative,
                     u_min=c.u_min)
    d = cosserat_tip_loop(ctx.dyn, dt=dt, gains=gains, amplitude=c.amplitude,
                          omega=c.omega, name=f"{model.name}_loop")
    # The tip wrench disturbance stays an external input of the diagram, zero here.
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  externals={"w": np.zeros((steps, 6))})
    return Example(
        "cosserat_tip", "task-space adaptive tip control of the Cosserat rod",
        "task-space adaptive control of the rod's tip (Theorem 10's law with σ = J⁺ s, "
        "softgen.control.cosserat) sampled at "
        f"{dt * 1e3:g} ms: the controller adapts π̂ from 0 and allocates its inputs one-"
        "sidedly (tendons pull: every input at least u_min, the least-tension solution in "
        "the actuation's null space; `feasible` is 0 where no positive offset exists), the "
        "plant is one ROS2 step per sample; the tip tracks a Lissajous figure about the "
        "straight rod's tip from rest; no tip wrench (the external input `w` is held at "
        "zero).",
        sc, (("ref.x_d", "ctrl.x", "m"),),
        f"Λ = {c.lam:g}, K_d = {c.kd:g}, K_π = {c.kpi:g}"
        f"{' × π²' if c.kpi_relative else ''}, u_min = {c.u_min:g} (CosseratTipConfig: "
        "control.cosserat.GAINS)", c)


register("theorem10", capability="theorem10", title="Theorem 10 on the soft robot",
         config=Theorem10Config, build=_theorem10)
register("theorem5", capability="theorem5_loop", title="Theorem 5 on the McKibben arm",
         config=Theorem5Config, build=_theorem5)
register("electric-pd", capability="electric_cascade",
         title="the chapter-11 PD cascade on the electric VSA arm",
         config=ElectricPdConfig, build=_electric_pd)
register("spring-pair", capability="spring_pair_cascade",
         title="the spring-pair cascade on the arm's antagonistic springs",
         config=SpringPairExample, build=_spring_pair)
register("sea-cascade", capability="sea_cascade",
         title="the PD cascade on the series-elastic arm", config=SeaCascadeConfig,
         build=_sea_cascade)
register("partial", capability="partial_collocated",
         title="collocated tracking of the partly actuated arm", config=PartialConfig,
         build=_partial)
register("slotine-li", capability="slotine_li", title="Slotine-Li (Prop. 10) on the rigid arm",
         config=SlotineLiConfig, build=_slotine_li, serves=_torque_driven)
register("floating", capability="floating_dynamics",
         title="a floating-base robot moving its joints in free fall", config=FloatingConfig,
         build=_floating)
register("cosserat-tip", capability="cosserat_tip_control",
         title="task-space adaptive tip control of the Cosserat rod", config=CosseratTipConfig,
         build=_cosserat_tip)
