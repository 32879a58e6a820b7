"""The three stiffness estimators of thesis Part II, each one generated step function.

Every estimator is ``state_next, outputs = step(state, y_k)`` with an explicit
sample time (docs/design.md section 1): a delayed unknown-input observer (chapter 5)
designed by :func:`~softgen.estimation.uio.design_uio` for a linear model whose
unknown input collects every nonlinearity, a nonlinear correction derived from the
symbolic robot model, and one RLS (eq. 5.5) per spring or joint.

Each method is its own class sharing :class:`EstimatorBase`:
:class:`PneumaticInvasiveEstimator`, :class:`ElectricInvasiveEstimator` and
:class:`NoninvasiveEstimator`; :func:`StiffnessEstimator` picks one from
``config.method``. Every estimator gives its step as a generated function
(:meth:`~EstimatorBase.step_fun`) and as a :class:`~softgen.blocks.Block`
(:meth:`~EstimatorBase.block`) to run in a diagram with plant and sensors.

``method="pneumatic"`` (section 6.1, Theorem 1; McKibben pairs, any number of joints)
    y = (q, p_a, p_b) per joint. Linear part M₀ q̈ + D₀ q̇ = u with M₀ = B(0) and D₀ the
    viscous damping, both ∂/∂q̈ and ∂/∂q̇ of the model's inverse dynamics by CasADi (I
    and β for one link, Theorem 1). The flexibility torque is the inverse dynamics at the
    observer's estimates: τ̂_e = û + (C q̂̇ + G(q̂) + K q̂ + D q̂̇ − D₀ q̂̇) + (B(q̂) − M₀) q̈̂
    with M₀ q̈̂ = û − D₀ q̂̇; for one link the last term is zero and this is eq. 6.3 (eq. 6.3
    prints û − m g l sin q̂; with the proof's own u = τ_e − m g l sin q the sign is +).
    Theorem 1 is proved for one link and the thesis leaves the multi-link case as future
    work (section 6.1.4): here the UIO conditions (Props. 7-9, eq. 5.3) are evaluated
    for the model (:func:`pneumatic_conditions`; with every joint angle measured CB = 0
    and CAB = T² M₀⁻¹, so they hold whenever B(0) is invertible) and recorded in the
    manifest. One RLS per joint on τ̂_e,i = (p_a,i q_i^j, p_b,i q_i^j)_j Π_i (pressures in
    bar), σ̂_i = −∂(Φ_iΠ̂_i)/∂q_i (σ = −∂τ/∂q, eq. 2.3). The observer and RLS work with a
    zero-order-hold model only in name: ZOH sampling of this relative-degree-2 model has
    a sampling zero at −1, so no stable delayed UIO exists for it (``design_uio`` says
    so); Euler, as the thesis, is the default. Its q̈̂ is a second difference one
    sample late, so on a continuous plant the stiffness error is first order in T
    (2-DoF McKibben arm: 14.5 % at 10 ms, 1.0 % at 1 ms; exact on the Euler plant).
``method="electric"`` (section 6.2, Theorem 2; qbmove, any number of joints)
    y = (q, q_a, q_b, τ_a, τ_b). One observer per motor on b q̈_j + d q̇_j = τ^e_j + τ_j
    with unknown input (τ^e_j, τ_j) and outputs (q_j, τ_j) (Remark 2). RLS per
    motor on odd powers of φ_j = q − q_j, σ̂_j = ∂(ΦΠ̂)/∂φ_j; joint totals eq. 2.7, 2.9.
``method="noninvasive"`` (chapter 7, Theorem 4; qbmove, any number of joints)
    y = (q, q_a, q_b). Observer on q^(3) = U (triple integrator, L = 3 by default;
    NOTES section 2 item 3: four samples q_k … q_{k+3}). Rotatum eq. 7.9:
    p̂_e = −d/dt[B q̈ + C q̇ + G + D q̇ + K q], the time derivative of the symbolic
    inverse dynamics along (q̇̂, q̈̂, Û) — B, Ḃ, Ċ, Ġ by the chain rule, no numerical
    differentiation. The deflection rates φ̇ come from a second copy of the same
    observer on the measured deflections, so they refer to the same sample. RLS per
    joint on (φ̇_a φ_a^j, φ̇_b φ_b^j)_j; σ̂_i = Σ_j π_a,j φ_a^j + π_b,j φ_b^j (eq. 7.12;
    eq. 7.13's powers are shifted by one against its own regressor).

Timing: the observer runs L samples behind (NOTES section 2 item 1). The step at
sample k consumes y_k and returns the estimates **for sample k − L**; RLS updates
start once the observer has converged (L + n_x samples for a deadbeat design).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics
from softgen.estimation.discretize import discretize
from softgen.estimation.rls import ExcitationGate, excitation_step, rls_step
from softgen.estimation.uio import UIO, ExistenceCheck, design_uio, existence_conditions

METHODS = ("pneumatic", "electric", "noninvasive")

#: Pressures (Pa in the measurements) are scaled to bar in the pneumatic regressor.
PRESSURE_SCALE = 1e-5

#: Thesis settings per method: sample time, delay, powers, P(0) (sections 6.1.3, 6.2.3, 7.3).
DEFAULTS = {
    "pneumatic": {"dt": 1e-2, "delay": 2, "powers": (0, 1, 2), "p0": 1e9},
    "electric": {"dt": 1e-3, "delay": 2, "powers": (1, 3, 5, 7), "p0": 1e8},
    "noninvasive": {"dt": 5e-3, "delay": 3, "powers": (0, 2, 4), "p0": 1e8},
}


@dataclass(frozen=True)
class EstimatorConfig:
    """Settings of one estimator (every field changes the generated code).

    Parameters
    ----------
    method
        ``"pneumatic"``, ``"electric"`` or ``"noninvasive"``.
    dt
        Sample time T [s].
    delay
        Observer delay L (default: the thesis's, 2 invasive, 3 non-invasive).
    powers
        Exponents j of the RLS regressor (see the module docstring).
    p0
        Initial RLS covariance: a scalar (times I) or one value per parameter.
    forgetting
        RLS forgetting factor λ in (0, 1].
    gate
        Update-stop rule (:class:`~softgen.estimation.rls.ExcitationGate`), or None.
    discretization
        ``"euler"`` (the thesis) or ``"zoh"`` for the observer's model.
    pole
        Place every observer eigenvalue at this real value in [0, 1) (default None:
        deadbeat, the thesis's F̂1 = 0). It only slows the initial transient; it does
        **not** low-pass: for these models every output sequence is a trajectory for
        some unknown input, so the delayed observer reproduces noisy outputs exactly
        (measured on the 1-DoF run of ch7-noninvasive-protocol, 8192-count encoders:
        with poles 0, 0.9, 0.98, 0.995 the observer's rotatum error is 11.9 N m/s rms
        in all four, to 1e-14, and the stiffness MSE 1.29e4 to 1.28e4, differing only
        by the later start of the RLS). Use ``lowpass`` to filter.
    lowpass
        Cutoff [Hz] of an identical low-pass on the RLS target and every regressor
        entry (default None: none), generated inside the step: ``lowpass_order``
        first-order state-variable sections, each a discrete ω_c/(s + ω_c)
        (pole e^{−ω_c T}, unit DC gain), updated once the observer has
        converged. Since f = φᵀΠ is linear in the signals, F[f] = F[φ]ᵀΠ holds for the
        filtered pair, while the noise of the differenced encoders, far above the
        cutoff, is removed from both (issue 13, chapter 7 on quantised encoders).
    """

    method: str
    dt: float | None = None
    delay: int | None = None
    powers: tuple[int, ...] | None = None
    p0: float | tuple[float, ...] | None = None
    forgetting: float = 1.0
    gate: ExcitationGate | None = None
    discretization: str = "euler"
    pole: float | None = None
    warmup: int | None = None            # samples before RLS starts (default L + n_x)
    lowpass: float | None = None         # Hz, identical low-pass of target and regressor
    lowpass_order: int = 4

    def resolved(self) -> EstimatorConfig:
        """A copy with the thesis defaults filled in and every field checked."""
        if self.method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {self.method!r}")
        d = DEFAULTS[self.method]
        c = replace(self, dt=d["dt"] if self.dt is None else self.dt,
                    delay=d["delay"] if self.delay is None else self.delay,
                    powers=tuple(d["powers"] if self.powers is None else self.powers),
                    p0=d["p0"] if self.p0 is None else self.p0)
        if not (isinstance(c.dt, (int, float)) and np.isfinite(c.dt) and c.dt > 0):
            raise ValueError(f"dt: expected a positive sample time, got {c.dt!r}")
        if not c.powers or any(not isinstance(j, int) or j < 0 for j in c.powers) \
                or len(set(c.powers)) != len(c.powers):
            raise ValueError(f"powers: expected distinct non-negative integers, got {c.powers!r}")
        if c.method == "electric" and any(j % 2 == 0 for j in c.powers):
            raise ValueError(f"powers: the electric estimator fits an odd spring torque "
                             f"(section 6.2.2): expected odd powers, got {c.powers!r}")
        if not 0 < c.forgetting <= 1:
            raise ValueError(f"forgetting: expected 0 < lambda <= 1, got {c.forgetting!r}")
        if c.discretization not in ("euler", "zoh"):
            raise ValueError(f"discretization: expected 'euler' or 'zoh', "
                             f"got {c.discretization!r}")
        if c.gate is not None:
            c.gate.check()
        if c.lowpass is not None and not (isinstance(c.lowpass, (int, float))
                                          and 0 < c.lowpass < 0.5 / c.dt):
            raise ValueError(f"lowpass: expected a cutoff in (0, {0.5 / c.dt:g}) Hz, got "
                             f"{c.lowpass!r}")
        if not (isinstance(c.lowpass_order, int) and c.lowpass_order >= 1):
            raise ValueError(f"lowpass_order: expected a positive integer, got "
                             f"{c.lowpass_order!r}")
        if c.pole is not None and not (isinstance(c.pole, (int, float)) and 0 <= c.pole < 1):
            raise ValueError(f"pole: expected a real observer pole in [0, 1), got {c.pole!r}")
        return c


@dataclass
class _Observer:
    name: str
    uio: UIO
    select: list[int]        # measurement entries forming its output Y


@dataclass
class _Layout:
    slices: dict[str, slice] = field(default_factory=dict)
    size: int = 0

    def add(self, name: str, n: int) -> slice:
        s = slice(self.size, self.size + n)
        self.slices[name] = s
        self.size += n
        return s


class EstimatorBase:
    """Builds the step function of one estimator for one model (one subclass per method).

    Attributes
    ----------
    name
        ``<model>_<method>_estimator`` unless given: prefix of the step's name.
    measurements
        Names of the entries of y_k, in order (also the CSV column names of
        ``softgen estimate``).
    groups
        ``[(signal, size), ...]``: the measurement vector as the block's named inputs.
    n_out
        Joints (entries of σ̂ and τ̂).
    layout
        State vector layout: name -> slice.
    """

    method = ""

    def __init__(self, model: RobotModel, config: EstimatorConfig, *, name: str | None = None):
        self.model = model
        self.config = c = config.resolved()
        if c.method != self.method:
            raise ValueError(f"method: {type(self).__name__} runs {self.method!r}, "
                             f"got {c.method!r}")
        self.n = model.dof
        self.dyn = RigidDynamics(model)
        # Variants of one method in one bundle need their own names.
        self.name = name or f"{model.name}_{c.method}_estimator"
        if not self.name.startswith(f"{model.name}_"):
            raise ValueError(f"name: expected a name starting with {model.name + '_'!r}, "
                             f"got {self.name!r}")
        self._setup()
        self.measurements = self._measurement_names()
        self.n_meas = len(self.measurements)
        self.observers = self._observers()
        self.n_out = self.n
        self._build()

    # -- per method ----------------------------------------------------------------------
    def _setup(self) -> None:
        """Check the model, set ``actuator`` and ``groups``."""
        raise NotImplementedError

    def _measurement_names(self) -> list[str]:
        return [f"{g}{i + 1}" for g, size in self.groups for i in range(size)]

    def _observers(self) -> list[_Observer]:
        raise NotImplementedError

    def _observer_rows(self, ob: _Observer, w):
        return ca.vertcat(*[w[i] for i in ob.select])

    @property
    def n_parameters(self) -> int:
        return 2 * len(self.config.powers)

    def _rls_instances(self) -> tuple[list[str], dict[str, list[tuple[str, int]]]]:
        """RLS names (``joint<i>`` or ``joint<i><side>``) and the signals their gate watches."""
        names = [f"joint{i + 1}" for i in range(self.n)]
        return names, {f"joint{i + 1}": [("phia", i), ("phib", i)] for i in range(self.n)}

    def parameter_names(self, r: str) -> list[str]:
        """Names of the RLS parameters of instance ``r`` (e.g. ``pi_a2`` for φ_a² terms)."""
        pw = self.config.powers
        return [f"pi_a{j}" for j in pw] + [f"pi_b{j}" for j in pw]

    def _estimates(self, y0, est):
        """RLS targets, regressors and the σ̂, τ̂ maps of each RLS instance."""
        raise NotImplementedError

    # -- observers ---------------------------------------------------------------------
    def _design(self, Ac, Bc, C, D, name, select) -> _Observer:
        c = self.config
        A, B = discretize(Ac, Bc, c.dt, method=c.discretization)
        poles = None if not c.pole else [float(c.pole)] * A.shape[0]
        uio = design_uio(A, B, np.atleast_2d(C), np.atleast_2d(D), delay=c.delay,
                         poles=poles, dt=c.dt)
        return _Observer(name, uio, select)

    # -- the step function ----------------------------------------------------------------
    def _build(self) -> None:
        c, n, L = self.config, self.n, self.config.delay
        lay = _Layout()
        lay.add("buffer", L * self.n_meas)
        lay.add("count", 1)
        for ob in self.observers:
            lay.add(f"xhat_{ob.name}", ob.uio.n_states)
        self.rls_names, self.rls_signals = self._rls_instances()
        n_par = self.n_parameters
        for r in self.rls_names:
            lay.add(f"theta_{r}", n_par)
            lay.add(f"P_{r}", n_par * n_par)
            k = len(self.rls_signals[r])
            lay.add(f"exc_mean_{r}", k)
            lay.add(f"exc_var_{r}", k)
            if c.lowpass:
                lay.add(f"lowpass_{r}", c.lowpass_order * (1 + n_par))
        self.layout = lay.slices
        self.n_state = lay.size
        n_x = max(ob.uio.n_states for ob in self.observers)
        if c.pole:
            # Until the initial error has decayed by 1e-9 (|E^k| ~ k^(n-1) p^k).
            n_x += int(np.ceil(np.log(1e-9) / np.log(c.pole))) + n_x
        self.warmup = c.warmup if c.warmup is not None else L + n_x

        s = ca.SX.sym("state", lay.size)
        y = ca.SX.sym("y", self.n_meas)
        part = {k: s[v] for k, v in lay.slices.items()}
        buf = ca.reshape(part["buffer"], self.n_meas, L) if L else ca.SX(self.n_meas, 0)
        window = [buf[:, j] for j in range(L)] + [y]       # y_{k-L}, ..., y_k
        count = part["count"]
        valid = count >= self.warmup
        y0 = window[0]                                     # the sample estimated now

        new = {}
        est = {}
        for ob in self.observers:
            rows = [self._observer_rows(ob, w) for w in window]
            xh = part[f"xhat_{ob.name}"]
            x_next, u_hat = _uio_step(ob.uio, xh, rows)
            new[f"xhat_{ob.name}"] = x_next
            est[ob.name] = (xh, u_hat)

        f_vals, regs, sigma_of, torque_of, tau_uio = self._estimates(y0, est)
        sigma_hat = ca.SX.zeros(n)
        tau_hat = ca.SX.zeros(n)
        flags = []
        alpha = c.dt / c.gate.window if c.gate is not None else 0.0
        for r in self.rls_names:
            theta = part[f"theta_{r}"]
            P = ca.reshape(part[f"P_{r}"], n_par, n_par)
            sig = ca.vertcat(*[self._signal(y0, *spec) for spec in self.rls_signals[r]])
            mean, var = part[f"exc_mean_{r}"], part[f"exc_var_{r}"]
            # Start the excitation statistics at the first valid sample, not at zero.
            first = count < self.warmup + 0.5
            mean = ca.if_else(first, sig, mean)
            var = ca.if_else(first, ca.SX.zeros(var.shape[0]), var)
            mean_n, var_n = excitation_step(mean, var, sig, alpha)
            if c.gate is not None:
                excited = ca.mmax(var_n) >= c.gate.threshold ** 2
            else:
                excited = 1
            active = ca.logic_and(valid, excited)
            target, reg = f_vals[r], regs[r]
            if c.lowpass:
                target, reg, new[f"lowpass_{r}"] = self._lowpass(
                    part[f"lowpass_{r}"], target, reg, valid)
            theta_n, P_n = rls_step(theta, P, reg, target, forgetting=c.forgetting,
                                    active=active)
            new[f"theta_{r}"] = theta_n
            new[f"P_{r}"] = ca.vec(P_n)
            new[f"exc_mean_{r}"] = ca.if_else(valid, mean_n, part[f"exc_mean_{r}"])
            new[f"exc_var_{r}"] = ca.if_else(valid, var_n, part[f"exc_var_{r}"])
            j = rls_joint(r)
            sigma_hat[j] += sigma_of[r](theta_n)
            tau_hat[j] += torque_of[r](theta_n)
            flags.append(active)

        new["buffer"] = ca.vec(ca.horzcat(*window[1:])) if L else ca.SX(0, 1)
        new["count"] = ca.fmin(count + 1, 1e9)
        s_next = ca.vertcat(*[new[k] for k in lay.slices])
        self._step = ca.Function(
            f"{self.name}_step", [s, y],
            [s_next, sigma_hat, tau_hat, tau_uio, ca.vertcat(*flags)],
            ["state", "y"], ["state_next", "sigma_hat", "tau_hat", "tau_uio", "updating"],
            FUNCTION_OPTS)

    def _lowpass(self, z, target, reg, valid):
        """Filtered (target, regressor) and the next filter state (``lowpass``)."""
        c = self.config
        a = float(np.exp(-2 * np.pi * c.lowpass * c.dt))
        m = 1 + reg.shape[0]
        Z = ca.reshape(z, m, c.lowpass_order)          # one column per section
        u, cols = ca.vertcat(target, reg), []
        for i in range(c.lowpass_order):
            u = a * Z[:, i] + (1 - a) * u               # section i at this sample
            cols.append(u)
        z_next = ca.if_else(valid, ca.vec(ca.horzcat(*cols)), z)
        return u[0], u[1:], z_next

    def _signal(self, w, kind: str, i: int):
        """Link position ``"q"`` or deflection ``"phia"``/``"phib"`` of joint i in sample w."""
        n = self.n
        if kind == "q":
            return w[i]
        return w[i] - w[(n if kind == "phia" else 2 * n) + i]

    # -- public -----------------------------------------------------------------------------
    def step_fun(self) -> ca.Function:
        """``<model>_<method>_estimator_step``: (state, y_k) -> (state_next, σ̂, τ̂, τ̂_UIO,
        updating), estimates for sample k − L."""
        return self._step

    def block(self, name: str = "est", *, hold: bool = False, p0=None) -> Block:
        """The step as a diagram block (estimates for sample k − L at sample k).

        Inputs: the measurement groups (:attr:`groups`, e.g. ``q``, ``qa``, ``qb``,
        ``tau_motor``), and with ``hold`` an input ``hold``: from the first sample where
        it is 1 on, every RLS covariance is zero, so the gain of eq. 5.5 is zero and Π̂
        and P stay as they are (the thesis's stop "once the parameters have converged",
        section 7.4) and ``updating`` reads 0. State: the layout of :attr:`layout`
        (``buffer``, ``count``, ``xhat_<observer>``, ``theta_<rls>``, ``P_<rls>``, ...).
        Outputs: ``sigma_hat``, ``tau_hat``, ``tau_uio`` (n each), ``updating`` (one per
        RLS) and ``theta`` (every RLS's parameters after the update, in
        :attr:`rls_names` order). ``p0`` as :meth:`initial_state`.
        """
        f = self._step
        n_par = self.n_parameters
        p_sl = [self.layout[f"P_{r}"] for r in self.rls_names]
        st = [(k, v.stop - v.start) for k, v in self.layout.items()]
        ins = list(self.groups) + ([("hold", 1)] if hold else [])

        def body(x, u, p):
            s = ca.vertcat(*[x[k] for k, _ in st])
            if hold:
                keep = ca.SX.ones(self.n_state)
                for sl in p_sl:
                    keep[sl] = 0
                s = ca.if_else(u["hold"] > 0.5, s * keep, s)
            y = ca.vertcat(*[u[g] for g, _ in self.groups])
            s_next, sig, tau, tau_u, upd = f(s, y)
            if hold:
                upd = ca.if_else(u["hold"] > 0.5, ca.SX.zeros(upd.shape[0]), upd)
            xn = {k: s_next[v] for k, v in self.layout.items()}
            theta = ca.vertcat(*[s_next[self.layout[f"theta_{r}"]] for r in self.rls_names])
            return xn, {"sigma_hat": sig, "tau_hat": tau, "tau_uio": tau_u, "updating": upd,
                        "theta": theta}

        return Block.define(
            name, dt=self.config.dt, state=st, inputs=ins,
            outputs=[("sigma_hat", self.n, "N m/rad"), ("tau_hat", self.n),
                     ("tau_uio", self.n), ("updating", len(self.rls_names)),
                     ("theta", n_par * len(self.rls_names))],
            body=body, x0=self.initial_state(p0), doc=f"{self.name}: {type(self).__doc__}",
            meta={"delay": self.config.delay, "rls": list(self.rls_names)})

    def initial_state(self, p0=None) -> np.ndarray:
        """Zero observer states and parameters; P(0) = diag(p0).

        ``p0`` defaults to the config's (one for every RLS); a list with one entry per
        RLS instance (scalar or diagonal each) sets them apart, as the per-joint
        P₁, P₂ of section 7.4.
        """
        s = np.zeros(self.n_state)
        n_par = self.n_parameters
        per = [self.config.p0] * len(self.rls_names) if p0 is None else list(p0)
        if len(per) != len(self.rls_names):
            raise ValueError(f"p0: expected one entry per RLS ({', '.join(self.rls_names)}), "
                             f"got {len(per)}")
        for r, v in zip(self.rls_names, per):
            diag = np.asarray(v, dtype=float)
            if diag.ndim > 1 or diag.size not in (1, n_par) or np.any(diag <= 0):
                raise ValueError(f"p0 of {r}: expected a positive scalar or {n_par} positive "
                                 f"values, got {v!r}")
            s[self.layout[f"P_{r}"]] = np.diag(np.broadcast_to(diag, (n_par,))).ravel(order="F")
        return s

    def theta(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """RLS parameters by instance, from a state vector (or an array of them, last axis)."""
        return {r: np.asarray(state)[..., self.layout[f"theta_{r}"]] for r in self.rls_names}

    def describe(self) -> dict:
        """Manifest entry: what the state and the measurement vector hold."""
        c = self.config
        return {"method": c.method, "dt": c.dt, "delay": c.delay, "powers": list(c.powers),
                "measurements": self.measurements, "warmup": self.warmup,
                "state": {k: [v.start, v.stop] for k, v in self.layout.items()},
                "rls": {r: self.parameter_names(r) for r in self.rls_names},
                "gate": None if c.gate is None else {"window": c.gate.window,
                                                     "threshold": c.gate.threshold},
                "forgetting": c.forgetting, "discretization": c.discretization,
                "pole": c.pole, **({"lowpass": c.lowpass, "lowpass_order": c.lowpass_order}
                                   if c.lowpass else {})}


def _qbmove(est: EstimatorBase) -> QbmoveSprings:
    if est.model.actuator_type != "qbmove":
        raise ModelError(f"{est.model.name}: the {est.method} estimator needs qbmove "
                         f"actuators, got {est.model.actuator_type or 'none'}")
    return QbmoveSprings(est.model)


def pneumatic_linear_part(model: RobotModel, dyn: RigidDynamics | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(M₀, D₀): the linear part M₀ q̈ + D₀ q̇ = u of the n-DoF pneumatic observer.

    Theorem 1's linear part I q̈ + β q̇ (eq. 6.1a) generalised to n McKibben joints
    (the multi-link case the thesis names as future work, section 6.1.4):
    ``M₀ = ∂h/∂q̈`` at ``q = 0`` (the inertia matrix B(0)) and ``D₀ = ∂h/∂q̇`` at
    ``q = q̇ = 0`` (the viscous damping: C(q, q̇) q̇ is quadratic in q̇), both
    derived by CasADi from the model's inverse dynamics
    ``h(q, q̇, q̈) = B q̈ + C q̇ + G + K q + D q̇``. With one link they are I and β.
    """
    dyn = dyn or RigidDynamics(model)
    m = dyn.nominal
    h = ca.substitute(m.slotine_li(dyn.route), m.qd_r, m.qd)      # h(q, q̇, q̈ = q̈_r)
    z = ca.DM.zeros(model.dof)
    f = ca.Function("pneumatic_linear_part", [m.q, m.qd, m.qdd_r],
                    [ca.jacobian(h, m.qdd_r), ca.jacobian(h, m.qd)])
    M0, D0 = (np.array(v, dtype=float) for v in f(z, z, z))
    return M0, D0


def pneumatic_observer_system(model: RobotModel, config: EstimatorConfig | None = None,
                              dyn: RigidDynamics | None = None):
    """Discrete (A, B, C, D) of the pneumatic observer (eq. 5.1) for ``model``.

    ``Ẋ = A_c X + B_c u`` with ``X = (q, q̇)``, ``A_c = [[0, I], [0, −M₀⁻¹D₀]]``,
    ``B_c = [0; M₀⁻¹]``, ``Y = q`` (``C = [I, 0]``, ``D = 0``), discretised as the
    config says (Euler by default, as the proof of Theorem 1).
    """
    c = (config or EstimatorConfig("pneumatic")).resolved()
    n = model.dof
    M0, D0 = pneumatic_linear_part(model, dyn)
    if n == 1:     # scalar division: Theorem 1's −β/I and 1/I bit for bit
        MiD, Mi = D0 / M0, 1.0 / M0
    else:
        MiD, Mi = np.linalg.solve(M0, D0), np.linalg.inv(M0)
    Z, I = np.zeros((n, n)), np.eye(n)
    Ac = np.block([[Z, I], [Z, -MiD]])
    Bc = np.vstack([Z, Mi])
    A, B = discretize(Ac, Bc, c.dt, method=c.discretization)
    return A, B, np.hstack([I, Z]), np.zeros((n, n))


def pneumatic_conditions(model: RobotModel, config: EstimatorConfig | None = None,
                         dyn: RigidDynamics | None = None) -> list[ExistenceCheck]:
    """The existence conditions (Props. 7-9, eq. 5.3) of the n-DoF pneumatic observer,
    each with its value, at the config's delay (thesis default L = 2)."""
    c = (config or EstimatorConfig("pneumatic")).resolved()
    return existence_conditions(*pneumatic_observer_system(model, c, dyn), c.delay)


class PneumaticInvasiveEstimator(EstimatorBase):
    """Section 6.1, Theorem 1, on n McKibben joints; y = (q_1..q_n, p_1a, p_1b, ..., p_nb).

    Linear part M₀ q̈ + D₀ q̇ = u (:func:`pneumatic_linear_part`; I q̈ + β q̇ with one
    link). The observer reconstructs u; the flexibility torque is the inverse dynamics
    at the observer's estimates, τ̂_e = h(q̂, q̂̇, q̈̂) with M₀ q̈̂ = û − D₀ q̂̇, i.e.
    τ̂_e = û + (C q̂̇ + G + K q̂ + D q̂̇ − D₀ q̂̇) + (B(q̂) − M₀) q̈̂ (eq. 6.3 for one link,
    where the last term vanishes). One RLS per joint on (p_a,i q_i^j, p_b,i q_i^j)_j
    (each pair's torque depends on its own joint and pressures, eq. 2.2), pressures in
    bar; σ̂_i = −∂(Φ_iΠ̂_i)/∂q_i (module docstring).
    """

    method = "pneumatic"

    def _setup(self) -> None:
        model = self.model
        if model.actuator_type != "mckibben":
            raise ModelError(f"{model.name}: the pneumatic estimator needs McKibben "
                             f"actuators, got {model.actuator_type or 'none'}")
        self.actuator = McKibbenPairs(model)
        self.groups = [("q", self.n), ("p", 2 * self.n)]

    def _measurement_names(self) -> list[str]:
        n = self.n
        return [f"q{i + 1}" for i in range(n)] + [f"p{i + 1}{s}" for i in range(n) for s in "ab"]

    def _observers(self) -> list[_Observer]:
        n = self.n
        M0, D0 = pneumatic_linear_part(self.model, self.dyn)
        self.inertia_matrix, self.damping_matrix = M0, D0
        # Is B(q) constant (one revolute link)? Then the (B(q̂) − M₀) q̈̂ term is zero.
        inertia = self.dyn.inertia_fun()
        rng = np.random.default_rng(0)
        self.constant_inertia = all(
            np.allclose(np.array(inertia(q)), M0, rtol=1e-12, atol=0)
            for q in (0.7 * np.ones(n), -1.3 * np.ones(n), rng.uniform(-3, 3, n)))
        if n == 1:
            self.inertia, self.beta = float(M0[0, 0]), float(D0[0, 0])
        checks = pneumatic_conditions(self.model, self.config, self.dyn)
        self.uio_conditions = checks
        failed = [ch for ch in checks if ch.holds is False]
        if failed:
            raise ModelError(f"{self.model.name}: no delayed UIO for the pneumatic estimator "
                             f"with delay {self.config.delay}: {failed[0].line()}")
        A, B, C, D = pneumatic_observer_system(self.model, self.config, self.dyn)
        c = self.config
        poles = None if not c.pole else [float(c.pole)] * A.shape[0]
        uio = design_uio(A, B, C, D, delay=c.delay, poles=poles, dt=c.dt)
        return [_Observer("link", uio, list(range(n)))]

    def _rls_instances(self):
        names = [f"joint{i + 1}" for i in range(self.n)]
        return names, {r: [("q", i)] for i, r in enumerate(names)}

    def describe(self) -> dict:
        """The base entry plus the UIO existence conditions checked, each with its value."""
        return {**super().describe(),
                "uio_conditions": [ch.as_dict() for ch in self.uio_conditions]}

    def _estimates(self, y0, est):
        n, pw = self.n, self.config.powers
        m = self.dyn.nominal
        f, regs, sig, tor, tau_uio = {}, {}, {}, {}, ca.SX.zeros(n)
        xh, u = est["link"]
        q_hat, qd_hat = xh[:n], xh[n:]
        # Nonlinear part of the model: inverse dynamics at q̈ = 0 minus the linear D₀ q̇.
        tau_id = ca.substitute(m.slotine_li(self.dyn.route),
                               ca.vertcat(m.q, m.qd, m.qd_r, m.qdd_r),
                               ca.vertcat(q_hat, qd_hat, qd_hat, ca.SX.zeros(n)))
        if n == 1:    # Theorem 1 as before: u + h(q̂, q̂̇, 0) − β q̂̇
            tau_e = u[0] + tau_id[0] - self.beta * qd_hat
        else:
            M0, D0 = ca.DM(self.inertia_matrix), ca.DM(self.damping_matrix)
            tau_e = u + tau_id - D0 @ qd_hat
        if not self.constant_inertia:
            # (B(q̂) − M₀) q̈̂ with M₀ q̈̂ = û − D₀ q̂̇: the inertia the linear part left out.
            M0, D0 = ca.DM(self.inertia_matrix), ca.DM(self.damping_matrix)
            qdd_hat = ca.solve(M0, u - D0 @ qd_hat)
            B_hat = ca.substitute(m.inertia(), m.q, q_hat)
            tau_e = tau_e + (B_hat - M0) @ qdd_hat
        # Pressures enter the regressor in bar. With P(0) = 1e9 I and pressures in
        # Pa, the covariance along the regressor (1/|φ|² ≈ 1e-10) falls below the
        # round-off of the update (1e9 · 2e-16) and the estimates blow up;
        # in bar it is ≈ 0.1 (measured in ch6-pneumatic-invasive).
        qs = ca.SX.sym("qs")
        for i in range(n):
            r = f"joint{i + 1}"
            q = y0[i]
            pa = y0[n + 2 * i] * PRESSURE_SCALE
            pb = y0[n + 2 * i + 1] * PRESSURE_SCALE
            phi_s = ca.vertcat(*[pa * qs ** j for j in pw], *[pb * qs ** j for j in pw])
            dphi_s = ca.jacobian(phi_s, qs)
            reg = ca.substitute(phi_s, qs, q)
            dreg = ca.substitute(dphi_s, qs, q)
            tau_uio[i] = tau_e[i] if n > 1 else tau_e
            f[r], regs[r] = tau_uio[i], reg
            sig[r] = lambda th, d=dreg: -ca.dot(d, th)
            tor[r] = lambda th, rr=reg: ca.dot(rr, th)
        return f, regs, sig, tor, tau_uio


class ElectricInvasiveEstimator(EstimatorBase):
    """Section 6.2, Theorem 2: qbmove joints; y = (q, q_a, q_b, τ_a, τ_b).

    One observer per motor with unknown input (τ^e_j, τ_j), one RLS per motor on odd
    powers of φ_j; σ̂ = Σ_j ∂(ΦΠ̂)/∂φ_j (module docstring).
    """

    method = "electric"

    def _setup(self) -> None:
        self.actuator = _qbmove(self)
        n = self.n
        self.groups = [("q", n), ("qa", n), ("qb", n), ("tau_motor", 2 * n)]

    def _measurement_names(self) -> list[str]:
        return [f"{g}{i + 1}" for g in ("q", "qa", "qb", "tau_a", "tau_b")
                for i in range(self.n)]

    def _observers(self) -> list[_Observer]:
        n, obs, act = self.n, [], self.actuator
        for side, b, d in (("a", act.b_a, act.d_a), ("b", act.b_b, act.d_b)):
            for i in range(n):
                Ac = np.array([[0.0, 1.0], [0.0, -d[i] / b[i]]])
                Bc = np.array([[0.0, 0.0], [1.0 / b[i], 1.0 / b[i]]])
                q_idx = (1 if side == "a" else 2) * n + i
                t_idx = (3 if side == "a" else 4) * n + i
                obs.append(self._design(Ac, Bc, [[1.0, 0.0], [0.0, 0.0]],
                                        [[0.0, 0.0], [0.0, 1.0]], f"motor{i + 1}{side}",
                                        [q_idx, t_idx]))
        return obs

    @property
    def n_parameters(self) -> int:
        return len(self.config.powers)

    def _rls_instances(self):
        sides = [(s, i) for s in "ab" for i in range(self.n)]
        return ([f"joint{i + 1}{s}" for s, i in sides],
                {f"joint{i + 1}{s}": [(f"phi{s}", i)] for s, i in sides})

    def parameter_names(self, r: str) -> list[str]:
        return [f"pi{j}" for j in self.config.powers]

    def _estimates(self, y0, est):
        n, pw = self.n, self.config.powers
        f, regs, sig, tor, tau_uio = {}, {}, {}, {}, ca.SX.zeros(n)
        for k, ob in enumerate(self.observers):
            _, u = est[ob.name]
            i, side = k % n, "ab"[k // n]
            r = f"joint{i + 1}{side}"
            phi = self._signal(y0, f"phi{side}", i)
            ps = ca.SX.sym("ps")
            basis = ca.vertcat(*[ps ** j for j in pw])
            reg = ca.substitute(basis, ps, phi)
            dreg = ca.substitute(ca.jacobian(basis, ps), ps, phi)
            f[r], regs[r] = u[0], reg
            sig[r] = lambda th, d=dreg: ca.dot(d, th)
            tor[r] = lambda th, rr=reg: ca.dot(rr, th)
            tau_uio[i] += u[0]
        return f, regs, sig, tor, tau_uio


class NoninvasiveEstimator(EstimatorBase):
    """Chapter 7, Theorem 4: qbmove joints, encoders only; y = (q, q_a, q_b).

    Link observer on q⁽³⁾ = U, rotatum from eq. 7.9 on the symbolic inverse dynamics,
    deflection rates from a second observer on the measured deflections, one RLS per
    joint on (φ̇_a φ_a^j, φ̇_b φ_b^j) (module docstring).
    """

    method = "noninvasive"

    def _setup(self) -> None:
        self.actuator = _qbmove(self)
        n = self.n
        self.groups = [("q", n), ("qa", n), ("qb", n)]

    def _observers(self) -> list[_Observer]:
        n = self.n

        def triple(m):     # q^(3) = U on the links, and the same on the 2n deflections
            Z, I = np.zeros((m, m)), np.eye(m)
            Ac = np.block([[Z, I, Z], [Z, Z, I], [Z, Z, Z]])
            Bc = np.vstack([Z, Z, I])
            C = np.hstack([I, Z, Z])
            return Ac, Bc, C, np.zeros((m, m))
        link = self._design(*triple(n), "link", list(range(n)))
        defl = self._design(*triple(2 * n), "deflection", [])   # fed with φ, not raw y
        return [link, defl]

    def _observer_rows(self, ob: _Observer, w):
        n = self.n
        if ob.name == "deflection":
            return ca.vertcat(w[:n] - w[n:2 * n], w[:n] - w[2 * n:3 * n])
        return super()._observer_rows(ob, w)

    def _estimates(self, y0, est):
        n, pw = self.n, self.config.powers
        m = self.dyn.nominal
        f, regs, sig, tor = {}, {}, {}, {}
        tau_uio = ca.SX.zeros(n)
        xh, u = est["link"]
        q_hat, qd_hat, qdd_hat = xh[:n], xh[n:2 * n], xh[2 * n:]
        h = m.slotine_li(self.dyn.route)           # B q̈_r + C q̇_r + G (+ D q̇ + K q)
        h = ca.substitute(h, m.qd_r, m.qd)         # inverse dynamics h(q, q̇, q̈)
        z = ca.vertcat(m.q, m.qd, m.qdd_r)
        zdot = ca.SX.sym("zdot", 3 * n)
        hdot = ca.jtimes(h, z, zdot)               # d/dt h along (q̇, q̈, q⁽³⁾)
        p_e = -ca.substitute(hdot, ca.vertcat(z, zdot),
                             ca.vertcat(q_hat, qd_hat, qdd_hat, qd_hat, qdd_hat, u))
        xd, _ = est["deflection"]
        for i in range(n):
            r = f"joint{i + 1}"
            pa, pb = self._signal(y0, "phia", i), self._signal(y0, "phib", i)
            pad, pbd = xd[2 * n + i], xd[3 * n + i]      # φ̇ from the deflection observer
            reg = ca.vertcat(*[pad * pa ** j for j in pw], *[pbd * pb ** j for j in pw])
            sbasis = ca.vertcat(*[pa ** j for j in pw], *[pb ** j for j in pw])
            f[r], regs[r] = p_e[i], reg
            sig[r] = lambda th, b=sbasis: ca.dot(b, th)
            tor[r] = lambda th, rr=reg: ca.dot(rr, th)
            tau_uio[i] = p_e[i]
        return f, regs, sig, tor, tau_uio


ESTIMATORS = {cls.method: cls for cls in (PneumaticInvasiveEstimator,
                                          ElectricInvasiveEstimator, NoninvasiveEstimator)}


def StiffnessEstimator(model: RobotModel, config: EstimatorConfig, *,  # noqa: N802
                       name: str | None = None) -> EstimatorBase:
    """The estimator class of ``config.method`` for ``model`` (backward-compatible factory)."""
    return ESTIMATORS[config.resolved().method](model, config, name=name)


def rls_joint(r: str) -> int:
    """0-based joint of an RLS instance name (``joint12a`` -> 11)."""
    return int(r.rstrip("ab")[len("joint"):]) - 1


def _uio_step(uio: UIO, xh, rows):
    """Eq. 5.4 on symbols: rows = (Y_{k-L}, …, Y_k), the forward-stacked history."""
    Y = ca.vertcat(*rows)
    E, F, G = (ca.DM(M) for M in (uio.E, uio.F, uio.G))
    A, C = ca.DM(uio.A), ca.DM(uio.C)
    x_next = E @ xh + F @ Y
    u = G @ ca.vertcat(x_next - A @ xh, rows[0] - C @ xh)
    return x_next, u
