"""Chapter-11 studies: section 11.2's references and gains as data, the cascade's diagram
as a :class:`~softgen.studies.Scenario`, a measurement helper and the figure.

The library (:mod:`softgen.control.electric`) builds the cascade, plant and reference
blocks for any gains and sinusoids; what the thesis printed for its runs lives here,
as frozen data. Every run goes through the one driver (:meth:`Scenario.run`).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.blocks.sensors import encoder_block
from softgen.control.electric import (REFERENCE_BLOCKS, ElectricArm, cascade_block,
                                      initial_plant_state, integral_start,
                                      near_singular_events, plant_block, reference_block,
                                      sigma_feedback_block)
from softgen.estimation.estimators import StiffnessEstimator
from softgen.core.errors import ShapeError
from softgen.core.metrics import Metrics
from softgen.runtime.simulate import Trace
from softgen.studies.scenario import Scenario

#: The plant block's state, in the order of the cascade's measurement x.
PLANT_STATE = ("q", "qd", "qa", "qad", "qb", "qbd")


@dataclass(frozen=True)
class Sinusoid:
    """``offset + amplitude sin(omega t)`` (one joint's reference)."""

    offset: float
    amplitude: float
    omega: float                                     # rad/s

    def derivatives(self, t: np.ndarray, order: int) -> list[np.ndarray]:
        """The value and its first ``order`` derivatives, A ω^k sin(ωt + kπ/2)."""
        out = [self.offset + self.amplitude * np.sin(self.omega * t)]
        for k in range(1, order + 1):
            out.append(self.amplitude * self.omega ** k * np.sin(self.omega * t + k * np.pi / 2))
        return out


@dataclass(frozen=True)
class CascadeReferences:
    """Per-joint sinusoids for q_d and σ_d (section 11.2 by default)."""

    q: tuple[Sinusoid, ...]
    sigma: tuple[Sinusoid, ...]

    def __post_init__(self) -> None:
        if len(self.sigma) != len(self.q):
            raise ShapeError(f"sigma: expected {len(self.q)} joints like q, got "
                             f"{len(self.sigma)}")

    def block(self, name: str = "ref") -> Block:
        """The reference block (:func:`softgen.control.electric.reference_block`)."""
        return reference_block(_spec(self.q), _spec(self.sigma), name=name)

    def columns(self, t) -> np.ndarray:
        """Reference columns (9n × K) for the sample times ``t`` (K,), rows in the order
        of :data:`~softgen.control.electric.REFERENCE_BLOCKS`."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        q = [s.derivatives(t, 4) for s in self.q]
        s = [s.derivatives(t, 3) for s in self.sigma]
        rows = [np.stack([d[k] for d in q]) for k in range(5)]
        rows += [np.stack([d[k] for d in s]) for k in range(4)]
        assert len(rows) == len(REFERENCE_BLOCKS)
        return np.concatenate(rows, axis=0)

    def at(self, t: float) -> np.ndarray:
        """The 9n reference column at ``t``."""
        return self.columns(t)[:, 0]


def _spec(s: tuple[Sinusoid, ...]) -> tuple[tuple[float, float, float], ...]:
    return tuple((x.offset, x.amplitude, x.omega) for x in s)


#: Section 11.2: q_d = 1 + 0.5 sin(πt/10) on both joints; σ_1d = 8 + 3 sin(πt/8),
#: σ_2d = 4 + sin(πt/8).
THESIS_REFERENCES = CascadeReferences(
    q=(Sinusoid(1.0, 0.5, np.pi / 10), Sinusoid(1.0, 0.5, np.pi / 10)),
    sigma=(Sinusoid(8.0, 3.0, np.pi / 8), Sinusoid(4.0, 1.0, np.pi / 8)))


def sinusoid_references(t, refs: CascadeReferences = THESIS_REFERENCES) -> np.ndarray:
    """Reference columns (9n × K) of ``refs`` at ``t`` (default: section 11.2)."""
    return refs.columns(t)


class _GainMapping(Mapping):
    """A frozen gain set read as ``{gain name: value}`` (absent gains are None fields),
    the form :func:`~softgen.control.electric.check_gains` and the blocks take."""

    def _present(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) is not None}

    def __getitem__(self, key: str):
        return self._present()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._present())

    def __len__(self) -> int:
        return len(self._present())

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True, eq=False)
class PDGains(_GainMapping):
    """Theorems 6-7 (Remark 10 with ``ki``): inner k_p, k_d; outer k_p, k_d, k_σ, Δ."""

    kp_m: float
    kd_m: float
    kp: float
    kd: float
    ksigma: float
    delta: float
    ki: float | None = None


@dataclass(frozen=True, eq=False)
class AdaptiveGains(_GainMapping):
    """Theorems 8-9 (Remark 11 with ``ki``): inner Λ_m, k_m, k_π,m (per motor parameter,
    layout of π̂_m); outer Λ, k, k_π, k_σ, Δ; ``b_min`` for the projected cascades."""

    lam_m: float
    k_m: float
    kpi_m: tuple[float, ...]
    lam: float
    k: float
    kpi: float
    ksigma: float
    delta: float
    ki: float | None = None
    b_min: float | None = None


#: Gains of section 11.2 (NOTES section 1, ch11-electric-pd / -adaptive). The adaptive
#: "k_p, k_d" are read as (Λ, k) (module docstring of :mod:`softgen.control.electric`);
#: k_π of the motors per joint (1a, 2a, 1b, 2b) for both b and d.
THESIS_GAINS: Mapping[str, PDGains | AdaptiveGains] = {
    "pd": PDGains(kp_m=50, kd_m=25, kp=25, kd=10, ksigma=150, delta=70),
    "pd_integral": PDGains(kp_m=50, kd_m=25, kp=0.05, kd=0.75, ksigma=30, ki=15, delta=70),
    "adaptive": AdaptiveGains(lam_m=0.1, k_m=0.1, kpi_m=(6e-4, 1e-3, 1e-4, 1e-4) * 2,
                              lam=0.1, k=0.5, kpi=0.2, ksigma=20, delta=145),
    "adaptive_integral": AdaptiveGains(lam_m=0.1, k_m=0.1,
                                       kpi_m=(6e-4, 1e-3, 1e-4, 1e-4) * 2, lam=0.1, k=0.1,
                                       kpi=7, ksigma=20, ki=25, delta=145),
}


def cascade_start(arm: ElectricArm, variant: str, gains: Mapping, ctrl: Block, *,
                  refs: CascadeReferences = THESIS_REFERENCES, nominal: bool = False) -> dict:
    """Initial state ``{"plant.<s>", "ctrl.<part>"}`` of a cascade diagram: the plant on
    the references (quasi-steady stiffness without the integral, the integral holding
    the Δ offset with it), estimates at 0 or (``nominal``) at the model's values."""
    integral = variant.endswith("_integral")
    x0 = initial_plant_state(arm, refs.at, **({} if integral else dict(
        ksigma=gains["ksigma"], delta=gains["delta"])))
    z0 = arm.initial_state(
        variant, x0,
        xi0=integral_start(arm, x0, gains["delta"], gains["ki"]) if integral else None,
        pi_hat0=arm.parameter_nominal if nominal else None,
        pi_m_hat0=arm.motor_parameter_nominal if nominal else None)
    init = {f"plant.{k}": x0[i * arm.n:(i + 1) * arm.n] for i, k in enumerate(PLANT_STATE)}
    init.update({f"ctrl.{k}": v for k, v in ctrl.state.split(z0).items()})
    return init


#: What a cascade scenario records by default.
RECORD = ("ref.q_d", "ref.sigma_d", "plant.q", "plant.qa", "plant.qb", "plant.sigma",
          "plant.tau_e", "ctrl.tau_m", "ctrl.q_m_ref", "ctrl.det")


def cascade_scenario(arm: ElectricArm, variant: str, gains: Mapping, *, dt: float,
                     duration: float, refs: CascadeReferences = THESIS_REFERENCES,
                     nominal: bool = False, chunk: int = 1000, name: str | None = None,
                     record=None) -> Scenario:
    """Reference → cascade ``variant`` → plant (section 11.2's loop) as a scenario that
    stops at the first non-finite value. Adaptive variants also record π̂ and π̂_m."""
    ctrl = cascade_block(arm, variant, dt, gains=gains)
    d = ClosedLoop(name or f"ch11_{arm.step_name(variant)}_{round(1e6 * dt)}us",
                   [refs.block(), ctrl, plant_block(arm, dt)])
    if record is None:
        record = RECORD + (("ctrl.pi_hat", "ctrl.pi_m_hat") if variant.startswith("adaptive")
                           else ())
    return Scenario(d.name, d, duration=duration, chunk=chunk, record=tuple(record),
                    x0=cascade_start(arm, variant, gains, ctrl, refs=refs, nominal=nominal),
                    on_nonfinite="stop")


#: The fed-back σ per value of the selector's ``source`` (:func:`sigma_feedback_block`).
FEEDBACK_SOURCES = {"true_feedback": 0, "estimated_feedback_invasive": 1,
                    "estimated_feedback_noninvasive": 2, "delayed_true_feedback": 3}

#: What a feedback scenario records.
FEEDBACK_RECORD = ("ref.q_d", "ref.sigma_d", "plant.q", "plant.sigma", "sw.sigma_fb",
                   "inv.sigma_hat", "non.sigma_hat")


def feedback_scenario(name: str, arm: ElectricArm, variant: str, gains: Mapping,
                      estimators: Mapping[str, StiffnessEstimator], *, dt: float,
                      duration: float, chunk: int = 1000, counts_per_rev: int | None = None,
                      refs: CascadeReferences = THESIS_REFERENCES) -> Scenario:
    """The cascade (``arm`` with ``sigma_input``) fed back a σ chosen by the selector
    ``sw`` among the plant's, the invasive estimate (block ``inv``, reading the motor
    torque), the non-invasive one (``non``) and the plant's delayed as the non-invasive
    estimate is (L + 1 samples); both estimators read the encoders (``counts_per_rev``,
    None: exact angles). ``sw.source`` (:data:`FEEDBACK_SOURCES`) and ``sw.t_on`` are
    parameters of each run; the scenario stops at a non-finite value."""
    n, ctrl = arm.n, cascade_block(arm, variant, dt, gains=gains)
    blocks = [refs.block(), ctrl, plant_block(arm, dt),
              encoder_block("enc", {"q": n, "qa": n, "qb": n}, counts_per_rev),
              *(e.block(k) for k, e in estimators.items()),
              sigma_feedback_block(n, estimators["non"].config.delay + 1)]
    wires = [("inv.sigma_hat", "sw.sigma_inv"), ("non.sigma_hat", "sw.sigma_non"),
             ("plant.sigma", "sw.sigma"), ("ctrl.tau_m", "inv.tau_motor")]
    wires += [(f"enc.{s}_m", f"{e}.{s}") for e in estimators for s in ("q", "qa", "qb")]
    d = ClosedLoop(name, blocks, wires)
    return Scenario(d.name, d, duration=duration, chunk=chunk, record=FEEDBACK_RECORD,
                    x0=cascade_start(arm, variant, gains, ctrl, refs=refs), on_nonfinite="stop")


def cascade_records(tr: Trace, variant: str, gains: Mapping, *, window: int) -> Metrics:
    """Section 11.2's indices of one run of :func:`cascade_scenario` (suffix ``variant``).

    Per joint, over the second half: position and stiffness rms errors, the signed mean
    stiffness error and, without the integral, the offset −Δ(τ^e_a − τ^e_b)/k_σ at which
    the stiffness row of eq. 11.4 is at rest (Remark 10) that it should equal; per motor
    (joint ``"1a"`` …) the rms error against its reference; position rms over the first
    and the last ``window`` samples. Over the run: largest |motor torque|, spans where
    eq. 11.4 is near singular (:func:`near_singular_events`), simulated s per wall s.
    A run that stopped at a non-finite value gives ``divergence_time`` alone.
    """
    m, n, K = Metrics(), tr["plant.q"].shape[1], tr.t.size
    if tr.stopped_at is not None:
        return m.add("divergence_time", tr.stopped_at, "s", suffix=variant)
    half = slice(K // 2, None)
    e_q, e_s = tr["plant.q"] - tr["ref.q_d"], tr["plant.sigma"] - tr["ref.sigma_d"]
    e_m = np.hstack([tr["plant.qa"], tr["plant.qb"]]) - tr["ctrl.q_m_ref"]
    tau_e, delta = tr["plant.tau_e"], gains["delta"]
    offset = -np.asarray(delta) * (tau_e[:, :n] - tau_e[:, n:]) / np.asarray(gains["ksigma"])

    def rms(e, sl=half):
        return np.sqrt(np.mean(e[sl] ** 2, axis=0))
    for i in range(n):
        j, kw = i + 1, {"joint": i + 1, "suffix": variant}
        m.add("position_rms_error", rms(e_q)[i], "rad", **kw)
        m.add("stiffness_rms_error", rms(e_s)[i], "N m/rad", **kw)
        m.add("stiffness_mean_error", e_s[half, i].mean(), "N m/rad", **kw)
        if not variant.endswith("_integral"):
            m.add("delta_offset_mean", offset[half, i].mean(), "N m/rad", **kw)
        for s, col in (("a", i), ("b", n + i)):
            m.add("motor_rms_error", rms(e_m)[col], "rad", joint=f"{j}{s}", suffix=variant)
        for name, sl in (("start", slice(0, window)), ("end", slice(K - window, K))):
            m.add(f"position_rms_error_{name}", rms(e_q, sl)[i], "rad", **kw)
    m.add("motor_torque_max_abs", np.abs(tr["ctrl.tau_m"]).max(), "N m", suffix=variant)
    m.add("near_singular_events", len(near_singular_events(tr.t, tr["ctrl.det"], delta)), "1",
          suffix=variant)
    m.add("simulated_seconds_per_wall_second", tr.realtime_factor, "s/s", suffix=variant)
    return m


def thesis_run(arm: ElectricArm, variant: str, *, duration: float = 40.0, dt: float = 1e-3,
               chunk: int = 1000, initial: str = "zero", window: float = 5.0,
               **gains) -> Metrics:
    """Section 11.2's run of one cascade and its :func:`cascade_records` (a measurement
    helper; ``window`` in s). ``gains`` override :data:`THESIS_GAINS` (a filter route
    needs ``omega_f``); ``initial``: ``"zero"`` (π̂(0) = 0, as the thesis) or
    ``"nominal"``."""
    g = {**THESIS_GAINS[variant], **gains}
    tr = cascade_scenario(arm, variant, g, dt=dt, duration=duration, chunk=chunk,
                          nominal=initial == "nominal").run()
    return cascade_records(tr, variant, g, window=int(round(window / dt)))


def cascade_figure(path, tr: Trace, title: str, *, parameter_nominal=None,
                   motor_parameter_nominal=None) -> None:
    """Fig. 11.2-11.5's quantities of one run: link angles, stiffness, motor angles with
    their references and motor torques per joint (``tr``: a trace of
    :func:`cascade_scenario`); adaptive runs add π̂/π and b̂/b."""
    # matplotlib is imported here: only figure-making runs pay its start-up time.
    from matplotlib.figure import Figure

    from softgen.studies.plotting import save
    t, n = tr.t, tr["plant.q"].shape[1]
    adaptive = "ctrl.pi_hat" in tr.signals
    fig = Figure(figsize=(11, 12 if adaptive else 10))
    ax = fig.subplots(5 if adaptive else 4, 2, sharex=True)
    qm = np.hstack([tr["plant.qa"], tr["plant.qb"]])
    for i in range(n):
        ax[0, i].plot(t, tr["ref.q_d"][:, i], "k--", lw=1, label="q_d")
        ax[0, i].plot(t, tr["plant.q"][:, i], lw=1, label="q")
        ax[0, i].set_ylabel(f"q{i + 1} [rad]")
        ax[1, i].plot(t, tr["ref.sigma_d"][:, i], "k--", lw=1, label="σ_d")
        ax[1, i].plot(t, tr["plant.sigma"][:, i], lw=1, label="σ")
        ax[1, i].set_ylabel(f"σ{i + 1} [N m/rad]")
        for s, col in (("a", i), ("b", n + i)):
            ax[2, i].plot(t, tr["ctrl.q_m_ref"][:, col], "k--", lw=0.8)
            ax[2, i].plot(t, qm[:, col], lw=1, label=f"q{i + 1}{s}")
            ax[3, i].plot(t, tr["ctrl.tau_m"][:, col], lw=1, label=f"τ{i + 1}{s}")
        ax[2, i].set_ylabel("motor angle [rad] (-- ref)")
        ax[3, i].set_ylabel("motor torque [N m]")
        for a in ax[:4, i]:
            a.legend(loc="upper right", fontsize=7)
    if adaptive:
        ax[4, 0].plot(t, tr["ctrl.pi_hat"] / parameter_nominal, lw=1)
        ax[4, 0].set_ylabel("π̂ / π (link) [1]")
        ax[4, 1].plot(t, tr["ctrl.pi_m_hat"][:, :2 * n] / motor_parameter_nominal[:2 * n],
                      lw=1)
        ax[4, 1].set_ylabel("b̂ / b (motors) [1]")
    for a in ax[-1]:
        a.set_xlabel("t [s]")
    fig.suptitle(title)
    save(fig, path, dpi=100)


def feedback_figure(path, traces: Mapping[str, Trace], t_on: float) -> None:
    """σ per joint under each fed-back source (``traces``: source -> trace, one of them
    ``true_feedback``, whose estimates are drawn against the plant's σ), switch at
    ``t_on``."""
    # matplotlib is imported here: only figure-making runs pay its start-up time.
    from matplotlib.figure import Figure

    from softgen.studies.plotting import save
    tr0 = traces["true_feedback"]
    fig = Figure(figsize=(11, 8))
    ax = fig.subplots(2, tr0["plant.sigma"].shape[1], sharex=True, squeeze=False)
    for j in range(tr0["plant.sigma"].shape[1]):
        ax[0, j].plot(tr0.t, tr0["ref.sigma_d"][:, j], "k--", lw=1, label="σ_d")
        for s, tr in traces.items():
            if tr.stopped_at is None:
                ax[0, j].plot(tr.t, tr["plant.sigma"][:, j], lw=0.8, label=s)
        ax[1, j].plot(tr0.t, tr0["plant.sigma"][:, j], "k", lw=1, label="σ (plant)")
        for k in ("inv", "non"):
            ax[1, j].plot(tr0.t, tr0[f"{k}.sigma_hat"][:, j], lw=0.8, label=f"σ̂ {k}")
        ax[0, j].set_ylabel(f"σ{j + 1} [N m/rad]")
        ax[1, j].set_ylabel(f"σ̂{j + 1}, loop on true σ [N m/rad]")
        ax[1, j].set_ylim(0, 2 * tr0["ref.sigma_d"][:, j].max())
        ax[1, j].set_xlabel("t [s]")
        for a in ax[:, j]:
            a.axvline(t_on, color="0.6", lw=0.8)
            a.legend(fontsize=7, loc="upper right")
    fig.suptitle("Adaptive cascade with the fed-back σ from true, invasive and non-invasive "
                 "estimates (switch at t_on)")
    save(fig, path, dpi=100)


# -- references derived from a model (issue 22: any qbmove-style arm) ---------------------

#: Least ratio σ_d(t) / σ_min(τ(t)) the derived stiffness references keep on every joint
#: (:func:`model_references`). Below 1 the reference is not realisable: no co-contraction
#: of the springs gives σ_d while holding the arm. That is what failed on the user's
#: arms with section 11.2's references (measured, 10 s runs of the exported example):
#: user_arm3_urdf's shoulder, σ_d = 4 + sin(πt/8), has a least ratio of 0.36: its
#: stiffness collapsed to 0.38 N m/rad at 0.4 s, the arm fell (position error up to
#: 1.04 rad on the shoulder and 2.37 rad on the elbow it carries; with ω rounded to
#: 5 digits the motor torque went non-finite at 0.587 s), and user_arm3_qbmove's
#: shoulder has no quasi-steady stiffness at t = 0. At 1 the reference touches the
#: boundary where the co-contraction is zero (the arccosh of
#: :meth:`QbmoveSprings.preset` at 1, ∂φ/∂σ unbounded). Measured with
#: :func:`model_gains`: ratios 1.0, 1.1, 1.25, 1.5 and 2.0 all track on both user arms
#: (position rms ≤ 2e-4 rad over the second half of 10 s), so 1.5 is headroom, not a
#: threshold: it keeps the references off that boundary for a model that is not exact,
#: and the thesis's arm (least ratio 1.86 with the printed references) keeps them.
STIFFNESS_MARGIN = 1.5

#: Samples per second of the reference grid over which :func:`model_references` checks
#: the margin (the references' fastest period is 16 s).
GRID_RATE = 20.0


def least_stiffness_fun(arm: ElectricArm) -> ca.Function:
    """σ_min(τ) (n → n): the least joint stiffness σ = τ'_a(φ_a) + τ'_b(φ_b) whose springs
    hold the total torque τ_a(φ_a) + τ_b(φ_b) = τ (eq. 2.7, 2.9), from the model's
    declared laws by CasADi.

    The minimum over the co-contraction is where the gradients are parallel (Lagrange):
    τ''_a / τ'_a = τ''_b / τ'_b, solved with the torque balance by Newton's method
    (``ca.rootfinder``) from the equal split τ_a = τ_b = τ/2 of the mean spring. For the
    sinh law with equal springs this is φ_a = φ_b and σ_min = a √(4k² + τ²).
    """
    s, n = arm.springs, arm.n
    pa, pb, tau = ca.SX.sym("phi_a", n), ca.SX.sym("phi_b", n), ca.SX.sym("tau", n)
    ones = ca.DM.ones(n)
    # The laws act joint-wise (element-wise), so the directional derivative along ones
    # is the diagonal of the Jacobian: τ'_j and τ''_j by differentiation, not by hand.
    ta, tb = s.spring_torque(pa, "a"), s.spring_torque(pb, "b")
    da, db = ca.jtimes(ta, pa, ones), ca.jtimes(tb, pb, ones)
    dda, ddb = ca.jtimes(da, pa, ones), ca.jtimes(db, pb, ones)
    x = ca.vertcat(pa, pb)
    # The parallel-gradient condition divided by τ'_a τ'_b (> 0, a stiffness): for
    # exponential laws τ''/τ' stays bounded (a tanh(aφ)) where the product grows like
    # e^{2aφ}, which is what lets Newton converge at large torques.
    g = ca.Function("g", [x, tau], [ca.vertcat(ta + tb - tau, dda / da - ddb / db)])
    solve = ca.rootfinder("least_stiffness", "newton", g,
                          {"abstol": 1e-13, "max_iter": 100, "error_on_fail": True})
    a, k = 0.5 * (s.a_a + s.a_b), 0.5 * (s.k_a + s.k_b)
    guess = ca.vertcat(*[ca.asinh(tau / (2 * k)) / a] * 2)
    xs = solve(guess, tau)
    sigma = ca.Function("sigma", [x], [da + db])(xs)
    return ca.Function("least_stiffness", [tau], [sigma], ["tau"], ["sigma_min"])


def reference_torque(arm: ElectricArm, refs: CascadeReferences, t) -> np.ndarray:
    """Joint torque the springs must give on the position references (K × n):
    τ = −(B q̈_d + C q̇_d + G) of eq. 11.1a (the plant's sign: B q̈ + … = −τ^e)."""
    n = arm.n
    q, qd, qdd = (ca.SX.sym(x, n) for x in ("q", "qd", "qdd"))
    f = ca.Function("id", [q, qd, qdd], [arm.inverse_dynamics(q, qd, qd, qdd)])
    c = refs.columns(t)
    return -np.array(f.map(c.shape[1])(c[:n], c[n:2 * n], c[2 * n:3 * n])).T


def model_references(arm: ElectricArm, base: CascadeReferences = THESIS_REFERENCES, *,
                     margin: float = STIFFNESS_MARGIN) -> CascadeReferences:
    """Section 11.2's references made feasible for ``arm``, joint by joint.

    Positions: ``base``'s sinusoids cycled over the joints (q_d = 1 + 0.5 sin(πt/10)).
    The sinh springs of eq. 6.6 hold any torque, so the position amplitude is not
    limited by the springs' torque range; what a posture costs is stiffness: holding τ
    needs σ ≥ σ_min(τ) (:func:`least_stiffness_fun`). Stiffness: ``base``'s sinusoid of
    the joint, kept if σ_d(t) ≥ ``margin`` · σ_min(τ(t)) over the references' common
    period (τ(t) of :func:`reference_torque` on a :data:`GRID_RATE` grid), else scaled
    (offset and amplitude by one factor, the shape of the thesis's kept) to the least
    factor that meets the margin. The thesis's arm meets it with the printed values,
    so its references are section 11.2's exactly.
    """
    n = arm.n
    q = tuple(base.q[i % len(base.q)] for i in range(n))
    sig = [base.sigma[i % len(base.sigma)] for i in range(n)]
    periods = [2 * np.pi / s.omega for s in (*q, *sig) if s.omega > 0]
    span = float(np.lcm.reduce(np.round(periods).astype(int))) if periods else 1.0
    t = np.linspace(0.0, span, int(span * GRID_RATE) + 1)
    tau = reference_torque(arm, CascadeReferences(q, tuple(sig)), t)
    smin = np.array(least_stiffness_fun(arm).map(t.size)(tau.T)).T        # K × n
    for i, s in enumerate(sig):
        need = float(np.max(margin * smin[:, i] / s.derivatives(t, 0)[0]))
        if need > 1.0:
            sig[i] = Sinusoid(s.offset * need, s.amplitude * need, s.omega)
    return CascadeReferences(q, tuple(sig))


#: Largest ratio ω_l / λ of a joint's link spring mode ω_l = √(σ_max / B_ii,min) to the
#: pole λ of its loops that :func:`model_gains` keeps. The PD cascade cancels the
#: dynamics exactly, so in continuous time its error poles do not depend on the arm;
#: sampled at dt with the motor torques held, the hold leaves a disturbance that excites
#: the link through its springs, and the error it leaves grows with ω_l² and falls with
#: the loop gains. Measured on user_arm3_qbmove's hand (B_33 = 3.0e-4 kg m², section
#: 11.2's σ_d = 8 + 3 sin(πt/8), thesis gains): position rms 6.3e-3 rad; halving σ_d
#: halves it (3.0e-3), ten times the link inertia gives 1.3e-3, doubling the outer
#: poles (k_p = 100, k_d = 20) or the inner ones (k_p,m = 200, k_d,m = 50) gives 1.5e-3.
#: The thesis's arm, at its printed gains (λ = √k_p = 5), has ω_l / λ ≤ 8.73 (elbow;
#: 7.66 at the shoulder), so a ratio ≥ 8.73 keeps its printed gains. Sweep of the ratio
#: with :func:`model_references` (position rms over the second half of 10 s, worst
#: joint): user_arm3_qbmove 4.7e-5 / 1.3e-4 / 4.8e-4 / 6.3e-3 rad at 5 / 10 / 20 / 40
#: (40: the printed gains); user_arm3_urdf 7.3e-5 / 1.7e-4 / 3.9e-4 rad at 5 / 10 / 20.
#: 10 is the least round ratio the thesis's arm meets.
MODE_RATIO = 10.0


def least_link_inertia(arm: ElectricArm, refs: CascadeReferences, t) -> np.ndarray:
    """min over ``t`` of the diagonal B_ii(q_d(t)) of the link inertia matrix (n): what a
    joint's springs move at the lightest posture of the reference. B = ∂τ/∂q̈ of the
    inverse dynamics, by CasADi."""
    n = arm.n
    q, z = ca.SX.sym("q", n), ca.SX.zeros(n)
    qdd = ca.SX.sym("qdd", n)
    b = ca.diag(ca.jacobian(arm.inverse_dynamics(q, z, z, qdd), qdd))
    f = ca.Function("b_diag", [q, qdd], [b])
    qd = refs.columns(t)[:n]
    return np.array(f.map(qd.shape[1])(qd, 0)).min(axis=1)


def model_gains(arm: ElectricArm, refs: CascadeReferences,
                base: PDGains = THESIS_GAINS["pd"], *, ratio: float = MODE_RATIO) -> PDGains:
    """``base`` (section 11.2's PD gains) with each joint's poles moved out as fast as
    its link spring mode needs (:data:`MODE_RATIO`), by pole placement.

    The outer position loop is ë + k_d ė + k_p e = 0 (Theorem 7 with the inner loop
    ideal) and the inner one ë_j + k_d,m ė_j + k_p,m e_j = 0 (Theorem 6); scaling every
    pole of joint i by s_i = max(1, ω_l,i / (ratio · √k_p)), with
    ω_l,i = √(max_t σ_d,i / min_t B_ii(q_d)) (:func:`least_link_inertia`), gives
    k_p s², k_d s, k_p,m s², k_d,m s (both motors of the joint). k_σ and Δ are kept: the
    stiffness row is first order at k_σ = 150 1/s (k_σ dt = 0.15), and Δ only keeps
    eq. 11.4 invertible (det ≥ 2Δ − |γ_a − γ_b|). A joint that meets the ratio at the
    printed gains keeps them exactly (the thesis's arm does: all its joints).
    """
    n = arm.n
    periods = [2 * np.pi / s.omega for s in (*refs.q, *refs.sigma) if s.omega > 0]
    span = float(np.lcm.reduce(np.round(periods).astype(int))) if periods else 1.0
    t = np.linspace(0.0, span, int(span * GRID_RATE) + 1)
    inertia = least_link_inertia(arm, refs, t)
    sigma_max = np.array([s.offset + abs(s.amplitude) for s in refs.sigma])
    omega = np.sqrt(sigma_max / inertia)
    lam = np.sqrt(np.broadcast_to(np.asarray(base.kp, float), (n,)))
    s = np.maximum(1.0, omega / (ratio * lam))
    if np.all(s == 1.0):
        return base
    s2 = np.concatenate([s, s])

    def scaled(g, f):
        v = np.broadcast_to(np.asarray(g, float), f.shape) * f
        return tuple(float(x) for x in v)
    return base.replace(kp=scaled(base.kp, s ** 2), kd=scaled(base.kd, s),
                        kp_m=scaled(base.kp_m, s2 ** 2), kd_m=scaled(base.kd_m, s2))
