"""Identification regressors and optimised excitation trajectories (``softgen identify``).

:class:`IdentificationRegressor`
    The model's base-parameter regressor (thesis eq. 9.1, ``RigidDynamics.base``) at
    q̇_r = q̇, q̈_r = q̈, so that τ = Y(q, q̇, q̈) π + τ₀(q, q̇, q̈), followed by
    viscous and Coulomb friction columns (:mod:`softgen.symbolic.friction`), evaluated
    on many samples at once (one mapped ``casadi.Function`` call).
:class:`FourierTrajectory`
    The finite Fourier series of Swevers, Ganseman, Tükel, De Schutter and Van Brussel,
    "Optimal robot excitation and identification", IEEE Trans. Robot. Autom. 13(5),
    1997, per joint i with L harmonics of the fundamental ω_f = 2π/T:

        q_i(t) = q_i0 + Σ_l [a_il/(ω_f l) sin(ω_f l t) − b_il/(ω_f l) cos(ω_f l t)]

    so q̇ and q̈ are exact (no differentiation of data) and the trajectory is periodic.
:func:`optimise_excitation`
    Coefficients minimising the condition number of the stacked regressor (Swevers
    et al.'s criterion) subject to joint position, velocity and acceleration limits
    on a time grid. q, q̇ and q̈ are linear in the coefficients, so the limits are
    linear inequality constraints (exact gradients); the objective, log cond W, has an
    exact gradient too, from the singular vectors and a reverse-mode derivative of
    uᵀ Y v (SLSQP, no finite differences).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.optimize import minimize

from softgen.core.errors import SoftgenError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.friction import friction_columns
from softgen.symbolic.rigid import RigidDynamics


#: Samples per call of the mapped regressor (IdentificationRegressor.evaluate).
CHUNK = 256


class IdentificationRegressor:
    """τ = Y(q, q̇, q̈) θ + τ₀ with θ = (base parameters π, friction coefficients).

    Parameters
    ----------
    model
        A rigid model (TOML or URDF).
    viscous, coulomb
        Add a viscous / Coulomb column per joint. A joint whose damping is already an
        uncertain parameter of the model gets no extra viscous column (it would repeat
        a base column and make the data matrix singular).
    dyn
        An existing :class:`RigidDynamics` of ``model`` (built if not given).
    """

    def __init__(self, model: RobotModel, *, viscous: bool = True, coulomb: bool = True,
                 dyn: RigidDynamics | None = None):
        if not isinstance(model, RobotModel):
            raise SoftgenError(f"{getattr(model, 'name', model)}: identification needs a rigid "
                               "model (links and joints), not a soft body")
        self.model = model
        self.dyn = dyn if dyn is not None else RigidDynamics(model)
        self.n = n = model.dof
        base = self.dyn.base
        m = self.dyn.nominal
        qdd = ca.SX.sym("qdd", n)
        # Slotine-Li regressor at qd_r = qd, qdd_r = qdd is the inverse-dynamics regressor.
        Yb = ca.substitute([base.Y], [m.qd_r, m.qdd_r], [m.qd, qdd])[0]
        tau0 = (ca.substitute([base.constant], [m.qd_r, m.qdd_r], [m.qd, qdd])[0]
                if base.constant is not None else ca.SX.zeros(n, 1))
        damped = tuple(link.damping is not None and link.damping in model.uncertain
                       for link in model.links)
        Yf, fnames = friction_columns(m.qd, viscous=tuple(viscous and not d for d in damped),
                                      coulomb=coulomb)
        self.base_names = list(base.names)
        self.friction_names = fnames
        self.names = self.base_names + fnames
        self.expressions = list(base.expressions) + [
            ("viscous friction of joint " if f.startswith("fv") else "Coulomb friction of joint ")
            + f[2:] for f in fnames]
        self.n_base = len(base.names)
        self.p = len(self.names)
        self._fun = ca.Function("identification_regressor", [m.q, m.qd, qdd],
                                [ca.densify(ca.horzcat(Yb, Yf)), ca.densify(tau0)],
                                ["q", "qd", "qdd"], ["Y", "tau0"], {"cse": True})
        self._mapped: dict[int, ca.Function] = {}
        # ∇_(q, q̇, q̈) of uᵀ Y v: the derivative of a singular value of the stacked
        # regressor (σ = uᵀ W v, dσ = uᵀ dW v) by reverse mode, for the excitation optimiser.
        u, v = ca.SX.sym("u", n), ca.SX.sym("v", self.p)
        s = ca.dot(u, ca.mtimes(ca.horzcat(Yb, Yf), v))
        self._uyv_grad = ca.Function("uYv_gradient", [m.q, m.qd, qdd, u, v],
                                     [ca.gradient(s, m.q), ca.gradient(s, m.qd),
                                      ca.gradient(s, qdd)], {"cse": True})
        self._grad_mapped: dict[int, ca.Function] = {}

    @property
    def nominal(self) -> np.ndarray:
        """The model's base parameters at its nominal values; friction 0 where not declared."""
        return np.concatenate([self.dyn.parameter_nominal, np.zeros(len(self.friction_names))])

    def evaluate(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(Y, τ₀) at K samples: ``q``, ``qd``, ``qdd`` are K×n; Y is K×n×p, τ₀ K×n."""
        q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, qd, qdd))
        K = q.shape[0]
        if q.shape != (K, self.n) or qd.shape != q.shape or qdd.shape != q.shape:
            raise SoftgenError(f"identification regressor: expected K x {self.n} arrays, got "
                               f"{q.shape}, {qd.shape}, {qdd.shape}")
        # One mapped Function per chunk size (building a map costs ~K; calling it reuses it):
        # the samples go through in chunks of CHUNK, the last one padded.
        Y = np.empty((K, self.n, self.p))
        tau0 = np.empty((K, self.n))
        f = self._mapped.get(CHUNK)
        if f is None:
            f = self._mapped[CHUNK] = self._fun.map(CHUNK)
        for k0 in range(0, K, CHUNK):
            k1 = min(K, k0 + CHUNK)
            args = []
            for a in (q, qd, qdd):
                block = np.zeros((CHUNK, self.n))
                block[:k1 - k0] = a[k0:k1]
                args.append(block.T)
            Yc, tc = f(*args)
            # map() concatenates the outputs horizontally: n × (p CHUNK).
            Y[k0:k1] = Yc.full().reshape(self.n, CHUNK, self.p).transpose(1, 0, 2)[:k1 - k0]
            tau0[k0:k1] = tc.full().T[:k1 - k0]
        return Y, tau0

    def singular_value_gradient(self, q, qd, qdd, U: np.ndarray, v: np.ndarray):
        """∂(Σ_k U_kᵀ Y(q_k, q̇_k, q̈_k) v) / ∂(q_k, q̇_k, q̈_k): three K×n arrays.

        With (U, v) a pair of singular vectors of the stacked regressor (U reshaped K×n),
        these are the derivatives of that singular value with respect to each sample's
        motion (Coulomb columns contribute none: sign(q̇) is flat almost everywhere).
        """
        K = q.shape[0]
        f = self._grad_mapped.get(K)
        if f is None:
            f = self._grad_mapped[K] = self._uyv_grad.map(K)
        out = f(q.T, qd.T, qdd.T, U.T, np.repeat(v[:, None], K, axis=1))
        return tuple(o.full().T for o in out)

    def physical_to_base(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(self.dyn.physical_to_base_fun(p)).ravel()


# --------------------------------------------------------------------------- trajectories


@dataclass(frozen=True)
class FourierTrajectory:
    """Swevers et al.'s finite Fourier series (module docstring); a, b are n × L."""

    period: float
    q0: np.ndarray
    a: np.ndarray
    b: np.ndarray

    @property
    def harmonics(self) -> int:
        return self.a.shape[1]

    def basis(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(S_q, S_qd, S_qdd), each len(t) × L: q_i = q_i0 + S_q (a_i; b_i) stacked."""
        t = np.asarray(t, dtype=float)[:, None]
        w = 2 * math.pi / self.period
        lw = w * np.arange(1, self.harmonics + 1)[None, :]
        s, c = np.sin(lw * t), np.cos(lw * t)
        return (np.hstack([s / lw, -c / lw]), np.hstack([c, s]), np.hstack([-s * lw, c * lw]))

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q̇, q̈), each len(t) × n, exact."""
        Sq, Sqd, Sqdd = self.basis(t)
        ab = np.hstack([self.a, self.b])            # n × 2L
        return self.q0[None, :] + Sq @ ab.T, Sqd @ ab.T, Sqdd @ ab.T


@dataclass(frozen=True)
class JointLimits:
    """Per joint: position range [rad or m], velocity and acceleration bounds."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    source: str


#: Limits used where a model file declares none (TOML models have no limits): ±1 rad
#: about the zero configuration, 2 rad/s, 20 rad/s² (a gentle, safe default; give
#: tighter ones for a real robot).
DEFAULT_LIMITS = (-1.0, 1.0, 2.0, 20.0)


def joint_limits(model: RobotModel, *, margin: float = 0.1) -> JointLimits:
    """The joint limits of ``model``: a URDF file's ``<limit>`` elements, else defaults.

    Positions are shrunk by ``margin`` (fraction of the range, half at each end) so the
    trajectory keeps clear of the stops; a URDF velocity limit is used as given and the
    acceleration bound is 10 × the velocity limit per second (URDF has none).
    """
    n = model.dof
    lo, hi, vel, acc = (np.full(n, v) for v in DEFAULT_LIMITS)
    source = "defaults (the model file declares no limits)"
    path = model.path
    if path is not None and Path(path).suffix.lower() == ".urdf":
        try:
            root = ET.fromstring(Path(path).read_text())
        except (OSError, ET.ParseError):
            root = None
        if root is not None:
            joints = {j.get("name"): j for j in root.iter("joint")}
            found = 0
            for i, link in enumerate(model.links):
                # The URDF reader names each link of the chain after its child link; find
                # the movable joint whose child that is.
                for j in joints.values():
                    child = j.find("child")
                    lim = j.find("limit")
                    if child is None or child.get("link") != link.name or lim is None:
                        continue
                    try:
                        if lim.get("lower") is not None and lim.get("upper") is not None:
                            lo[i], hi[i] = float(lim.get("lower")), float(lim.get("upper"))
                        if lim.get("velocity") is not None:
                            vel[i] = float(lim.get("velocity"))
                            acc[i] = 10.0 * vel[i]
                        found += 1
                    except ValueError:
                        pass
            if found:
                source = f"URDF <limit> of {found} joint(s), defaults elsewhere"
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * (1 - margin)
    return JointLimits(mid - half, mid + half, vel, acc, source)


@dataclass
class Excitation:
    """Result of :func:`optimise_excitation`."""

    trajectory: FourierTrajectory
    condition: float              # cond of the stacked regressor on the optimisation grid
    initial_condition: float
    limits: JointLimits
    iterations: int
    message: str


def _constraint_matrix(traj0: FourierTrajectory, t: np.ndarray, lim: JointLimits):
    """Linear inequalities G x <= h on x = (q0, a, b) for the limits on the grid ``t``."""
    n, L = traj0.a.shape
    Sq, Sqd, Sqdd = traj0.basis(t)
    rows, rhs = [], []
    nv = n * (1 + 2 * L)
    for i in range(n):
        def block(S, with_q0):
            G = np.zeros((S.shape[0], nv))
            if with_q0:
                G[:, i] = 1.0
            # x layout: q0 (n), then per joint its 2L coefficients (a_i, b_i).
            G[:, n + i * 2 * L: n + (i + 1) * 2 * L] = S
            return G
        for S, with_q0, lo, hi in ((Sq, True, lim.lower[i], lim.upper[i]),
                                   (Sqd, False, -lim.velocity[i], lim.velocity[i]),
                                   (Sqdd, False, -lim.acceleration[i], lim.acceleration[i])):
            G = block(S, with_q0)
            rows += [G, -G]
            rhs += [np.full(S.shape[0], hi), np.full(S.shape[0], -lo)]
    return np.vstack(rows), np.concatenate(rhs)


def _unpack(x: np.ndarray, n: int, L: int, period: float) -> FourierTrajectory:
    ab = x[n:].reshape(n, 2 * L)
    return FourierTrajectory(period, x[:n].copy(), ab[:, :L].copy(), ab[:, L:].copy())


def _pack(tr: FourierTrajectory) -> np.ndarray:
    return np.concatenate([tr.q0, np.hstack([tr.a, tr.b]).ravel()])


def stacked_condition(reg: IdentificationRegressor, traj: FourierTrajectory,
                      t: np.ndarray) -> float:
    """cond of the regressor stacked over the samples ``t`` (Swevers et al.'s criterion)."""
    Y, _ = reg.evaluate(*traj.evaluate(t))
    s = np.linalg.svd(Y.reshape(-1, reg.p), compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


def optimise_excitation(reg: IdentificationRegressor, *, harmonics: int = 5,
                        period: float = 10.0, limits: JointLimits | None = None,
                        grid: int = 100, seed: int = 0, maxiter: int = 100) -> Excitation:
    """Fourier coefficients minimising cond(W) within the joint limits (module docstring).

    The start is a seeded random series scaled into the limits; the limits are
    enforced on ``grid`` points per period (also used for the objective). Returns
    the best feasible point SLSQP reached.
    """
    if harmonics < 1 or period <= 0 or grid < 2:
        raise SoftgenError(f"excitation: expected harmonics >= 1, period > 0 and grid >= 2, got "
                           f"{harmonics}, {period}, {grid}")
    lim = limits if limits is not None else joint_limits(reg.model)
    n, L = reg.n, harmonics
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, period, grid, endpoint=False)
    mid = 0.5 * (lim.lower + lim.upper)
    start = FourierTrajectory(period, mid, rng.normal(size=(n, L)), rng.normal(size=(n, L)))
    # Scale the random start into the limits (half of each bound: a strictly feasible start).
    q, qd, qdd = start.evaluate(t)
    ratio = np.max(np.vstack([np.abs(q - mid) / (0.5 * (lim.upper - lim.lower)),
                              np.abs(qd) / lim.velocity, np.abs(qdd) / lim.acceleration]),
                   axis=0)
    scale = 0.5 / np.maximum(ratio, 1e-12)
    start = FourierTrajectory(period, mid, start.a * scale[:, None], start.b * scale[:, None])
    G, h = _constraint_matrix(start, t, lim)
    x0 = _pack(start)
    c0 = stacked_condition(reg, start, t)

    def objective(x):
        """log cond W and its gradient: d log(σ_1/σ_r) = dσ_1/σ_1 − dσ_r/σ_r, each dσ from
        the singular vectors (:meth:`IdentificationRegressor.singular_value_gradient`)
        and the Fourier basis (q, q̇, q̈ are linear in x)."""
        tr = _unpack(x, n, L, period)
        q, qd, qdd = tr.evaluate(t)
        feasible = bool(np.all(G @ x <= h + 1e-9))
        Y, _ = reg.evaluate(q, qd, qdd)
        U, sv, Vt = np.linalg.svd(Y.reshape(-1, reg.p), full_matrices=False)
        if not sv[-1] > 0:
            return 1e3, np.zeros_like(x)
        grad = np.zeros_like(x)
        for idx, sign in ((0, 1.0), (-1, -1.0)):
            gq, gqd, gqdd = reg.singular_value_gradient(q, qd, qdd, U[:, idx].reshape(-1, n),
                                                        Vt[idx])
            g_ab = gq.T @ Sq + gqd.T @ Sqd + gqdd.T @ Sqdd          # n × 2L
            grad += sign / sv[idx] * np.concatenate([gq.sum(axis=0), g_ab.ravel()])
        value = math.log(sv[0] / sv[-1])
        if feasible and value < best[0]:
            best[:] = [value, x.copy()]
        return value, grad

    # SLSQP's iterates may leave the limits by round-off: keep the best feasible one seen.
    best: list = [math.inf, x0]

    Sq, Sqd, Sqdd = start.basis(t)
    res = minimize(objective, x0, method="SLSQP", jac=True,
                   constraints=[{"type": "ineq", "fun": lambda x: h - G @ x,
                                 "jac": lambda x: -G}],
                   options={"maxiter": maxiter, "ftol": 1e-6})
    objective(res.x)
    tr = _unpack(best[1], n, L, period)
    return Excitation(tr, stacked_condition(reg, tr, t), c0, lim, int(res.nit),
                      str(res.message))
