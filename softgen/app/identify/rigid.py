"""Base inertial parameters and joint friction from a log of q and τ (``softgen identify``).

The method (Gautier & Khalil's inverse-dynamics identification model, with the
filtering of Gautier 1997 and Swevers et al. 1997):

1. **Log.** ``t``, ``q1..qn`` and either ``tau1..taun`` [N m or N] or motor currents
   ``i1..in`` [A] with ``--torque-constant`` (τ = K_t i, gear ratio folded into K_t).
   Uniform sampling, finite cells (:func:`softgen.estimation.csvlog.read_log`: one
   error line naming the row and the column otherwise).
2. **Filtering and differentiation.** q is low-passed by a zero-phase Butterworth
   filter (order 4, run forward and backward by ``scipy.signal.filtfilt``: no phase
   lag, so q̇ and q̈ line up with τ), then differentiated by central differences
   (``numpy.gradient``, second order) once for q̇ and again for q̈. The *same* filter
   is applied to τ and to every column of the regressor (parallel filtering), so both
   sides of τ = Y θ see the same attenuation. The cut-off
   defaults to 5 × the frequency below which 99.9 % of the energy of the detrended
   q lies (the motion band), kept between 1 Hz and 0.4 × the Nyquist frequency;
   ``--cutoff`` sets it.
3. **Trim and decimate.** 2/f_c seconds at each end (the filter's start-up) are
   dropped, then every ``m``-th sample is kept with m = ⌊f_s / (2.5 f_c)⌋: the
   filtered signals hold nothing above f_c, so nothing aliases, and samples closer
   than the filter's memory would be correlated and make the covariance below
   optimistic.
4. **Least squares.** W θ = τ − τ₀ stacked over samples (W from the model's base
   regressor plus friction columns, :class:`~softgen.studies.excitation.IdentificationRegressor`).
   Ordinary least squares first; then each joint's rows are weighted by 1/σ_j, σ_j²
   = ‖r_j‖² / (K − p/n) its residual variance (joints differ in noise and in model
   error), and solved again (weighted least squares). Covariance
   C = σ_w² (W_wᵀ W_w)⁻¹ with σ_w² = ‖r_w‖² / (Kn − p); standard deviations
   √diag C; the relative ones 100 σ/|θ| as identification papers report them.
   The condition number of the (weighted) data matrix, raw and with unit-norm
   columns, says how well the log excites the parameters.
5. **Physical parameters and consistency.** Base parameters are combinations of the
   physical ones; the identified model file gets the physical values p closest to
   the model's nominal ones (relative, least squares) with π(p) = π̂, and every link
   is checked: positive mass, inertia about the centre of mass positive definite
   with principal moments satisfying the triangle inequality. If they fail, spatial
   links are projected (:func:`consistent_parameters`: a log-Cholesky
   parameterisation of the pseudo-inertia, in which every value is a consistent body,
   fitted to π̂ by least squares; no SDP solver needed) and the misfit of the
   projected values, max |π(p) − π̂|/σ, is reported beside the original violations.
   The base-parameter estimates themselves are never altered.

Floating bases (issue 35). The log then also holds the base pose in the world,
``base_x, base_y, base_z, base_qx, base_qy, base_qz, base_qw`` (a unit quaternion, x y z
w), and the measured wrench on the base in the base frame, ``base_fx, base_fy, base_fz,
base_mx, base_my, base_mz`` (contact or support forces; a log without these columns is
contact-free: the wrench is zero, as in flight or in orbit, and the joint torques alone
scale the parameters). The pose is filtered like q (the quaternion renormalised after),
the base velocity v = (Rᵀ ṗ, ω) with ω = 2 Im(q̄ ⊗ q̇) in the base frame, and v̇ its
derivative, as Pinocchio's free flyer; the regressor is the whole-body one, six base
rows and one per joint (:class:`FloatingRegressor`), friction on the joints only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.optimize import least_squares
from scipy.signal import butter, filtfilt

from softgen.core.errors import SoftgenError
from softgen.estimation.csvlog import LogError, read_header, read_log
from softgen.modelfile.model import RobotModel
from softgen.studies.excitation import IdentificationRegressor

#: Butterworth order of the zero-phase filter (filtfilt doubles it).
FILTER_ORDER = 4
#: Fraction of the detrended q's energy that defines the motion band.
BAND_ENERGY = 0.999
#: Cut-off = BAND_FACTOR × motion band, within [MIN_CUTOFF, MAX_CUTOFF_NYQUIST × f_Nyquist].
BAND_FACTOR = 5.0
MIN_CUTOFF = 1.0
MAX_CUTOFF_NYQUIST = 0.4
#: Samples per cut-off period kept after decimation: f_s,new = DECIMATE_RATE × f_c.
DECIMATE_RATE = 2.5
#: Fewest equations (samples × joints after decimation) per identified parameter.
MIN_ROWS_PER_PARAMETER = 3
#: Sample times [s] an identification log may have: it must resolve q̈ of a robot's
#: motion (a few Hz), so 10 Hz or faster; slower is most likely a time column in ms
#: (issue 36: a log with t in ms gave dt = 2 s and a model with negative inertias).
DT_RANGE = (1e-6, 0.1)
#: The fit must explain at least this fraction of each joint's torque variance (R²);
#: below, the identified numbers describe noise (issue 36: a log of noise gave R² 0.002).
MIN_EXPLAINED = 0.5
#: A logged torque this many times the model file's prediction (or its inverse) points
#: to a unit: mN·m, kN·m, or a current without --torque-constant.
TORQUE_RATIO = 30.0


@dataclass
class IdentificationLog:
    """A log read and checked: time, positions and torques (K × n; on a floating base q
    is K × (7 + n), [base position, quaternion, joints], and τ K × (6 + n), [base wrench,
    joint torques])."""

    path: Path
    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    dt: float
    torque_source: str          # "tau" or "current x K_t"


#: The log columns of a floating base's pose and of the wrench measured on it.
BASE_POSE_COLUMNS = ["base_x", "base_y", "base_z", "base_qx", "base_qy", "base_qz", "base_qw"]
BASE_WRENCH_COLUMNS = ["base_fx", "base_fy", "base_fz", "base_mx", "base_my", "base_mz"]


@dataclass
class RigidIdentification:
    """Result of :func:`identify_rigid` (module docstring for every quantity)."""

    model: RobotModel
    names: list[str]
    expressions: list[str]
    estimate: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    nominal: np.ndarray
    condition: float
    condition_scaled: float
    joint_sigma: np.ndarray        # residual std per joint (OLS), the WLS weights' inverse
    residual_rms: np.ndarray       # residual rms per joint after WLS [N m]
    samples: int                   # rows per joint used in the regression
    cutoff_hz: float
    decimation: int
    dt: float
    torque_source: str
    #: Fraction of the filtered torque's variance the fit explains, per joint (R²).
    explained: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: rms of the logged torque over rms of the model file's nominal prediction along the
    #: same motion, per joint: about 1 for a log in SI units of this robot.
    torque_ratio: np.ndarray = field(default_factory=lambda: np.zeros(0))
    physical: dict[str, float] = field(default_factory=dict)
    violations: list[str] = field(default_factory=list)
    #: Violations of the nearest values, when a projection (consistent_parameters) replaced
    #: them; then ``projection_misfit`` is max |π(p) − π̂|/σ of the projected values.
    projected_from: list[str] = field(default_factory=list)
    projection_misfit: float = 0.0

    @property
    def relative_std(self) -> np.ndarray:
        """100 σ / |θ| [%] (inf where the estimate is 0)."""
        with np.errstate(divide="ignore"):
            return 100.0 * self.std / np.abs(self.estimate)

    @property
    def consistent(self) -> bool:
        return not self.violations

    def friction(self, kind: str) -> dict[int, float]:
        """{joint index (0-based): coefficient} of ``kind`` "fv" or "fc"."""
        return {int(n[2:]) - 1: float(v) for n, v in zip(self.names, self.estimate)
                if n.startswith(kind) and n[2:].isdigit() and n not in self.model.nominal}


def read_identification_log(path: str | Path, n: int, *,
                            torque_constant: list[float] | None = None,
                            floating: bool = False) -> IdentificationLog:
    """Read ``t, q1..qn`` and ``tau1..taun`` (or ``i1..in`` with a torque constant); with
    ``floating`` also the base pose and, when logged, the base wrench (module docstring).

    Errors (one line, :class:`~softgen.estimation.csvlog.LogError`): missing column
    (named), non-numeric or NaN cell (row and column), time not increasing or not
    uniform (row).
    """
    path = Path(path)
    header = read_header(path)
    if floating:
        return _read_floating_log(path, header, n, torque_constant)
    q_cols = [f"q{i + 1}" for i in range(n)]
    tau_cols = [f"tau{i + 1}" for i in range(n)]
    cur_cols = [f"i{i + 1}" for i in range(n)]
    if torque_constant is not None:
        if len(torque_constant) == 1:
            torque_constant = torque_constant * n
        if len(torque_constant) != n:
            raise SoftgenError(f"--torque-constant: expected 1 or {n} values, got "
                               f"{len(torque_constant)}")
        cols, source = cur_cols, "motor current x torque constant"
    else:
        cols, source = tau_cols, "tau"
        if header and not all(c in header for c in tau_cols) and all(c in header for c in cur_cols):
            raise LogError(f"{path}: columns {', '.join(cur_cols)} are motor currents; give "
                           f"--torque-constant K_t [N m/A] (or log tau1..tau{n})")
    t, Y, dt = read_log(path, q_cols + cols, min_rows=10)
    q, tau = Y[:, :n], Y[:, n:]
    if torque_constant is not None:
        tau = tau * np.asarray(torque_constant, dtype=float)[None, :]
    return IdentificationLog(path, t, q, tau, dt, source)


def _read_floating_log(path: Path, header: list[str], n: int,
                       torque_constant: list[float] | None) -> IdentificationLog:
    joints = read_identification_log(path, n, torque_constant=torque_constant)
    wrench = [c for c in BASE_WRENCH_COLUMNS if c in header]
    if wrench and len(wrench) != 6:
        missing = next(c for c in BASE_WRENCH_COLUMNS if c not in header)
        raise LogError(f"{path}: column {missing!r} missing (a measured base wrench needs "
                       f"all of {', '.join(BASE_WRENCH_COLUMNS)}; none for a contact-free log)")
    t, Y, _ = read_log(path, BASE_POSE_COLUMNS + wrench, min_rows=10)
    quat = Y[:, 3:7]
    norm = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > 1e-3)
    if bad.size:
        raise LogError(f"{path}: row {int(bad[0]) + 2}: base_qx..base_qw is not a unit "
                       f"quaternion (norm {norm[bad[0]]:.6g})")
    # A quaternion and its negative are one rotation: keep the sign continuous.
    quat = quat / norm[:, None]
    for k in range(1, quat.shape[0]):
        if quat[k] @ quat[k - 1] < 0:
            quat[k] = -quat[k]
    q = np.hstack([Y[:, :3], quat, joints.q])
    base = Y[:, 7:13] if wrench else np.zeros((Y.shape[0], 6))
    source = joints.torque_source + (", measured base wrench" if wrench else
                                     ", contact-free (base wrench 0)")
    return IdentificationLog(path, t, q, np.hstack([base, joints.tau]), joints.dt, source)


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊗ b for K × 4 arrays of quaternions (x, y, z, w)."""
    av, aw, bv, bw = a[:, :3], a[:, 3:], b[:, :3], b[:, 3:]
    return np.hstack([aw * bv + bw * av + np.cross(av, bv),
                      aw * bw - np.sum(av * bv, axis=1, keepdims=True)])


def base_velocity(p: np.ndarray, quat: np.ndarray, dt: float) -> np.ndarray:
    """The free flyer's velocity (Rᵀ ṗ, ω) from K samples of the base pose: ṗ and q̇ by
    central differences, ω = 2 Im(q̄ ⊗ q̇) (base frame)."""
    pd = np.gradient(p, dt, axis=0)
    qd = np.gradient(quat, dt, axis=0)
    conj = quat * np.array([-1.0, -1.0, -1.0, 1.0])
    w = 2.0 * quaternion_product(conj, qd)[:, :3]
    x, y, z, s = quat.T
    # Rᵀ ṗ, R of each quaternion (rows of R are the columns of Rᵀ).
    R = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * s), 2 * (x * z + y * s)], -1),
                  np.stack([2 * (x * y + z * s), 1 - 2 * (x * x + z * z), 2 * (y * z - x * s)], -1),
                  np.stack([2 * (x * z - y * s), 2 * (y * z + x * s), 1 - 2 * (x * x + y * y)], -1)],
                 axis=1)
    u = np.einsum("kji,kj->ki", R, pd)
    return np.hstack([u, w])


class FloatingRegressor:
    """The whole-body regressor of a floating base, τ = Y(q, v, v̇) θ + τ₀ with θ = (base
    parameters, joint friction), τ = [base wrench, joint torques]: the interface of
    :class:`~softgen.studies.excitation.IdentificationRegressor` (``n`` the rows per
    sample, 6 + joints)."""

    def __init__(self, model: RobotModel, *, viscous: bool = True, coulomb: bool = True,
                 dyn=None):
        from softgen.symbolic.friction import friction_columns
        from softgen.symbolic.rigid import RigidDynamics
        self.model = model
        self.dyn = dyn if dyn is not None else RigidDynamics(model)
        self.n = model.nv
        base = self.dyn.base
        m = self.dyn.nominal
        vd = ca.SX.sym("vd", model.nv)
        Yb = ca.substitute([base.Y], [m.qd_r, m.qdd_r], [m.qd, vd])[0]
        tau0 = (ca.substitute([base.constant], [m.qd_r, m.qdd_r], [m.qd, vd])[0]
                if base.constant is not None else ca.SX.zeros(model.nv, 1))
        damped = tuple(link.damping is not None and link.damping in model.uncertain
                       for link in model.links)
        Yf, fnames = friction_columns(m.qd[6:], viscous=tuple(viscous and not d for d in damped),
                                      coulomb=coulomb)
        Yf = ca.vertcat(ca.SX.zeros(6, Yf.shape[1]), Yf)
        self.base_names = list(base.names)
        self.friction_names = fnames
        self.names = self.base_names + fnames
        self.expressions = list(base.expressions) + [
            ("viscous friction of joint " if f.startswith("fv") else "Coulomb friction of joint ")
            + f[2:] for f in fnames]
        self.n_base = len(base.names)
        self.p = len(self.names)
        self._fun = ca.Function("floating_regressor", [m.q, m.qd, vd],
                                [ca.densify(ca.horzcat(Yb, Yf)), ca.densify(tau0)],
                                ["q", "v", "vd"], ["Y", "tau0"], {"cse": True})

    @property
    def nominal(self) -> np.ndarray:
        return np.concatenate([self.dyn.parameter_nominal, np.zeros(len(self.friction_names))])

    def physical_to_base(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(self.dyn.physical_to_base_fun(p)).ravel()

    def evaluate(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray):
        """(Y, τ₀) at K samples: Y is K × (6 + n) × p, τ₀ K × (6 + n)."""
        K = q.shape[0]
        f = self._fun.map(K)
        Y, t0 = f(q.T, v.T, vd.T)
        return (Y.full().reshape(self.n, K, self.p).transpose(1, 0, 2), t0.full().T)


def motion_band(q: np.ndarray, dt: float, energy: float = BAND_ENERGY) -> float:
    """Frequency [Hz] below which ``energy`` of the detrended q's power lies (max over joints)."""
    x = q - np.linspace(0, 1, q.shape[0])[:, None] * (q[-1] - q[0])[None, :] - q[0][None, :]
    x = x - x.mean(axis=0)
    P = np.abs(np.fft.rfft(x, axis=0)) ** 2
    f = np.fft.rfftfreq(q.shape[0], dt)
    band = 0.0
    for j in range(q.shape[1]):
        c = np.cumsum(P[:, j])
        if c[-1] <= 0:
            continue
        band = max(band, float(f[np.searchsorted(c, energy * c[-1])]))
    return band


def default_cutoff(q: np.ndarray, dt: float) -> float:
    """The cut-off of step 2 of the module docstring [Hz]."""
    nyq = 0.5 / dt
    return float(min(max(BAND_FACTOR * motion_band(q, dt), MIN_CUTOFF), MAX_CUTOFF_NYQUIST * nyq))


@dataclass
class Filtered:
    """The regression's data after steps 2-3: W (K × n × p) and y = τ − τ₀ (K × n)."""

    W: np.ndarray
    y: np.ndarray
    cutoff: float
    decimation: int


def filter_and_differentiate(reg: IdentificationRegressor, q: np.ndarray, tau: np.ndarray,
                             dt: float, cutoff: float | None = None) -> Filtered:
    """Steps 2 and 3 of the module docstring.

    The filter runs twice: on q before differentiating (so the differences do not
    amplify encoder quantisation), and on τ and on every column of the regressor
    evaluated at the filtered motion (Gautier's *parallel filtering*). Filtering both
    sides of τ = W θ with one linear filter keeps the equation exact even for the
    columns that are not smooth in time (Coulomb friction's sign(q̇) steps, which
    the filter smears in τ exactly as it does in its column).
    """
    nyq = 0.5 / dt
    fc = default_cutoff(q, dt) if cutoff is None else float(cutoff)
    if not 0 < fc < nyq:
        raise SoftgenError(f"--cutoff: expected a frequency between 0 and the Nyquist "
                           f"frequency {nyq:.6g} Hz of the log, got {fc!r}")
    b, a = butter(FILTER_ORDER, fc / nyq)
    K = q.shape[0]
    trim = int(math.ceil(2.0 / (fc * dt)))
    padlen = min(3 * max(len(a), len(b)), K - 1)
    if K - 2 * trim < 20:
        raise SoftgenError(f"log: {K} samples are too few for a {fc:.3g} Hz cut-off at "
                           f"dt = {dt:.6g} s (need more than {2 * trim + 20}); log longer or "
                           "raise --cutoff")
    qf = filtfilt(b, a, q, axis=0, padlen=padlen)
    if getattr(reg.model, "floating", False):
        qf[:, 3:7] /= np.linalg.norm(qf[:, 3:7], axis=1)[:, None]
        qd = np.hstack([base_velocity(qf[:, :3], qf[:, 3:7], dt),
                        np.gradient(qf[:, 7:], dt, axis=0)])
    else:
        qd = np.gradient(qf, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    W, tau0 = reg.evaluate(qf, qd, qdd)
    W = filtfilt(b, a, W, axis=0, padlen=padlen)
    y = filtfilt(b, a, tau - tau0, axis=0, padlen=padlen)
    step = max(1, int(math.floor(1.0 / (DECIMATE_RATE * fc * dt))))
    sl = slice(trim, K - trim, step)
    return Filtered(W[sl], y[sl], fc, step)


def weighted_least_squares(W: np.ndarray, y: np.ndarray):
    """Step 4: W is K × n × p, y K × n. Returns (θ, C, σ_j, residual rms per joint,
    cond, cond with unit-norm columns)."""
    K, n, p = W.shape
    A, b = W.reshape(-1, p), y.reshape(-1)
    theta, *_ = np.linalg.lstsq(A, b, rcond=None)
    r = (b - A @ theta).reshape(K, n)
    dof_j = max(K - p / n, 1.0)
    sigma = np.sqrt(np.sum(r * r, axis=0) / dof_j)
    if np.any(sigma <= 0):
        sigma = np.where(sigma > 0, sigma, max(sigma.max(), 1e-300))
    w = (1.0 / sigma)[None, :, None]
    Aw, bw = (W * w).reshape(-1, p), (y * w[:, :, 0]).reshape(-1)
    theta, *_ = np.linalg.lstsq(Aw, bw, rcond=None)
    rw = bw - Aw @ theta
    s2 = float(rw @ rw) / max(K * n - p, 1)
    sv = np.linalg.svd(Aw, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    norms = np.linalg.norm(Aw, axis=0)
    svn = np.linalg.svd(Aw / np.where(norms > 0, norms, 1.0), compute_uv=False)
    cond_n = float(svn[0] / svn[-1]) if svn[-1] > 0 else math.inf
    if not math.isfinite(cond) or cond > 1e14:
        raise SoftgenError(f"log: the data matrix is rank deficient (condition number "
                           f"{cond:.3g}): the motion does not excite every base parameter; "
                           "use an excitation trajectory (softgen identify MODEL --excite)")
    C = s2 * np.linalg.inv(Aw.T @ Aw)
    resid = (y - np.einsum("knp,p->kn", W, theta))
    rms = np.sqrt(np.mean(resid * resid, axis=0))
    return theta, C, sigma, rms, cond, cond_n


def identify_rigid(model: RobotModel, log: IdentificationLog, *, cutoff: float | None = None,
                   viscous: bool = True, coulomb: bool = True,
                   regressor: IdentificationRegressor | None = None) -> RigidIdentification:
    """Steps 2-5 of the module docstring on a log already read."""
    if regressor is not None:
        reg = regressor
    elif model.floating:
        reg = FloatingRegressor(model, viscous=viscous, coulomb=coulomb)
    else:
        reg = IdentificationRegressor(model, viscous=viscous, coulomb=coulomb)
    if log.tau.shape[1] != reg.n:
        raise SoftgenError(f"log: {log.tau.shape[1]} torques, model {model.name} has {reg.n}")
    fil = filter_and_differentiate(reg, log.q, log.tau, log.dt, cutoff)
    W = fil.W
    if W.shape[0] * reg.n < MIN_ROWS_PER_PARAMETER * reg.p:
        raise SoftgenError(f"log: {W.shape[0]} samples per joint after filtering are too few "
                           f"for {reg.p} parameters (at least {MIN_ROWS_PER_PARAMETER} "
                           f"equations per parameter: {-(-MIN_ROWS_PER_PARAMETER * reg.p // reg.n)} "
                           "samples per joint); log longer or raise --cutoff")
    theta, C, sigma, rms, cond, cond_n = weighted_least_squares(W, fil.y)
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    res = RigidIdentification(model=model, names=list(reg.names),
                              expressions=list(reg.expressions), estimate=theta, std=std,
                              covariance=C, nominal=reg.nominal, condition=cond,
                              condition_scaled=cond_n, joint_sigma=sigma, residual_rms=rms,
                              samples=W.shape[0], cutoff_hz=fil.cutoff,
                              decimation=fil.decimation, dt=log.dt,
                              torque_source=log.torque_source)
    pred = np.einsum("knp,p->kn", W, theta)
    var = np.sum((fil.y - fil.y.mean(axis=0)) ** 2, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        res.explained = np.where(var > 0, 1.0 - np.sum((fil.y - pred) ** 2, axis=0) / var,
                                 0.0)
        nominal = np.einsum("knp,p->kn", W, np.nan_to_num(reg.nominal))
        res.torque_ratio = np.sqrt(np.mean(fil.y ** 2, axis=0)) / \
            np.sqrt(np.mean(nominal ** 2, axis=0))
    res.physical = physical_parameters(reg, theta[:reg.n_base], std[:reg.n_base])
    res.violations = consistency_violations(model, {**model.nominal, **res.physical})
    if res.violations:
        proj = consistent_parameters(reg, theta[:reg.n_base], std[:reg.n_base])
        if proj is not None:
            res.projected_from, res.physical = res.violations, proj
            res.violations = consistency_violations(model, {**model.nominal, **proj})
            pi = reg.physical_to_base(np.array([proj[k] for k in model.uncertain]))
            res.projection_misfit = float(np.max(np.abs(pi - theta[:reg.n_base])
                                                 / std[:reg.n_base]))
    return res


def physical_parameters(reg: IdentificationRegressor, pi_hat: np.ndarray,
                        pi_std: np.ndarray) -> dict[str, float]:
    """Uncertain physical parameters p with π(p) = π̂, closest to the nominal ones.

    Minimises ‖(π(p) − π̂)/σ_π‖² + λ² ‖(p − p₀)/s‖² with a small λ (1e-4: the first
    term wins wherever the base parameters determine p; the second picks, among the
    p that give π̂, the one nearest the model's values, relative to s = max(|p₀|, 1e-3)).
    """
    model = reg.model
    names = list(model.uncertain)
    p0 = np.array([model.nominal[k] for k in names], dtype=float)
    s = np.maximum(np.abs(p0), 1e-3)
    f = reg.dyn.physical_to_base_fun
    psym = ca.SX.sym("p", len(names))
    J = ca.Function("J", [psym], [ca.jacobian(f(psym), psym)])
    sig = np.where(pi_std > 0, pi_std, np.maximum(np.abs(pi_hat), 1e-12) * 1e-6)
    lam = 1e-4

    def resid(x):
        p = p0 + s * x
        return np.concatenate([(np.asarray(f(p)).ravel() - pi_hat) / sig, lam * x])

    def jacobian(x):
        p = p0 + s * x
        Jp = np.asarray(J(p)) * s[None, :]
        return np.vstack([Jp / sig[:, None], lam * np.eye(len(x))])

    out = least_squares(resid, np.zeros(len(names)), jac=jacobian, method="lm", xtol=1e-14,
                        ftol=1e-14, gtol=1e-14, max_nfev=2000)
    p = p0 + s * out.x
    return {k: float(v) for k, v in zip(names, p)}


#: The ten inertial fields of a spatial link, in the order of ``_link_fields``.
_FIELDS = 10


def _link_fields(link) -> list[str] | None:
    """Parameter names of a spatial link's mass, centre of mass and inertia (or None)."""
    names = [link.mass, *link.com, *link.inertia]
    return names if all(isinstance(x, str) for x in names) else None


def _pseudo_inertia(m: float, c: np.ndarray, I: np.ndarray, about_com: bool) -> np.ndarray:
    """4×4 pseudo-inertia J = [[Σ, h], [hᵀ, m]], Σ = ½ tr(I_o) 1 − I_o, h = m c (about the
    link frame's origin). J ≻ 0 exactly when the body is physically consistent (positive
    mass, inertia about the centre of mass with the triangle inequality): Wensing,
    Kim and Slotine, IEEE RA-L 3(1), 2018."""
    Io = I + m * (float(c @ c) * np.eye(3) - np.outer(c, c)) if about_com else I
    J = np.empty((4, 4))
    J[:3, :3] = 0.5 * np.trace(Io) * np.eye(3) - Io
    J[:3, 3] = J[3, :3] = m * c
    J[3, 3] = m
    return J


def _from_pseudo_inertia(J: np.ndarray, about_com: bool) -> tuple[float, np.ndarray, np.ndarray]:
    m = J[3, 3]
    c = J[:3, 3] / m
    Sigma = J[:3, :3]
    Io = np.trace(Sigma) * np.eye(3) - Sigma
    I = Io - m * (float(c @ c) * np.eye(3) - np.outer(c, c)) if about_com else Io
    return m, c, I


def _upper_cholesky(J: np.ndarray) -> np.ndarray:
    """U upper triangular with U Uᵀ = J (Cholesky of the reversed matrix, reversed)."""
    P = np.eye(4)[::-1]
    return P @ np.linalg.cholesky(P @ J @ P) @ P


def consistent_parameters(reg: IdentificationRegressor, pi_hat: np.ndarray,
                          pi_std: np.ndarray) -> dict[str, float] | None:
    """Physical parameters that are consistent by construction and fit π̂ best.

    Each spatial link whose ten inertial parameters are all uncertain is written through
    its pseudo-inertia J = U Uᵀ, U upper triangular with a positive (exponential)
    diagonal: the log-Cholesky parameterisation of Rucker and Wensing (IEEE RA-L 7(2),
    2022), in which every value is a physically consistent body. Minimises
    ‖(π(p) − π̂)/σ_π‖² + λ²‖θ − θ₀‖² (λ = 1e-4) from θ₀ of the model's nominal values
    (consistent: the model file was validated). Other uncertain parameters (damping,
    stiffness) stay free. Returns None when a link has only some of its inertial
    parameters uncertain (the parameterisation needs all ten).
    """
    model = reg.model
    names = list(model.uncertain)
    index = {k: j for j, k in enumerate(names)}
    links = []
    for link in model.inertial_bodies:
        fields = _link_fields(link)
        if fields is None:
            return None
        unc = [f in index for f in fields]
        if any(unc) and not all(unc):
            return None
        if all(unc):
            links.append((fields, link.inertia_about == "com"))
    if not links:
        return None
    free = [k for k in names if not any(k in f for f, _ in links)]
    tri = np.triu_indices(4)

    def theta_of(values):
        th = []
        for fields, about_com in links:
            v = [values[f] for f in fields]
            xx, yy, zz, xy, xz, yz = v[4:]
            I = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
            J = _pseudo_inertia(v[0], np.array(v[1:4]), I, about_com)
            try:
                U = _upper_cholesky(J)
            except np.linalg.LinAlgError:
                U = _upper_cholesky(J + 1e-9 * max(J[3, 3], 1e-9) * np.eye(4))
            U = U.copy()
            U[np.diag_indices(4)] = np.log(np.abs(np.diag(U)))
            th.append(U[tri])
        return np.concatenate(th + [np.array([values[k] for k in free])])

    th0 = theta_of(model.nominal)
    # θ -> p as one CasADi expression: the residual and its exact Jacobian are then one
    # Function call each (finite differences over ~10 n parameters were far too slow).
    th = ca.SX.sym("theta", len(th0))
    p_sx = [ca.SX(0)] * len(names)
    for li, (fields, about_com) in enumerate(links):
        U = ca.SX.zeros(4, 4)
        for e, (r, c) in enumerate(zip(*tri)):
            x = th[li * _FIELDS + e]
            U[int(r), int(c)] = ca.exp(x) if r == c else x
        J = ca.mtimes(U, U.T)
        m, h, Sigma = J[3, 3], J[0:3, 3], J[0:3, 0:3]
        com = h / m
        I = ca.trace(Sigma) * ca.SX.eye(3) - Sigma
        if about_com:
            I = I - m * (ca.dot(com, com) * ca.SX.eye(3) - ca.mtimes(com, com.T))
        vals = [m, com[0], com[1], com[2], I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2],
                I[1, 2]]
        for f_, v in zip(fields, vals):
            p_sx[index[f_]] = v
    for j, k in enumerate(free):
        p_sx[index[k]] = th[len(links) * _FIELDS + j]
    p_expr = ca.vertcat(*p_sx)
    f = reg.dyn.physical_to_base_fun
    sig = np.where(pi_std > 0, pi_std, np.maximum(np.abs(pi_hat), 1e-12) * 1e-6)
    lam = 1e-4
    r_expr = ca.vertcat((f(p_expr) - ca.DM(pi_hat)) / ca.DM(sig), lam * (th - ca.DM(th0)))
    F = ca.Function("projection", [th], [r_expr, ca.jacobian(r_expr, th), p_expr])

    out = least_squares(lambda x: np.asarray(F(x)[0]).ravel(), th0,
                        jac=lambda x: np.asarray(F(x)[1]), method="lm", xtol=1e-12,
                        ftol=1e-12, gtol=1e-12, max_nfev=100 * len(th0))
    p = np.asarray(F(out.x)[2]).ravel()
    return {k: float(v) for k, v in zip(names, p)}


def consistency_violations(model: RobotModel, values: dict[str, float]) -> list[str]:
    """Step 5's check of every link at ``values`` (parameter name -> value)."""
    out = []
    first = 0 if model.floating else 1          # the floating base is body 0
    for i, link in enumerate(model.inertial_bodies, start=first):
        m = float(model.resolve(link.mass, values))
        if not m > 0:
            out.append(f"link {i} ({link.name}): mass {m:.6g} kg is not positive")
        c = np.array([float(model.resolve(x, values)) for x in link.com])
        xx, yy, zz, xy, xz, yz = (float(model.resolve(x, values)) for x in link.inertia)
        I = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        if link.inertia_about == "joint":
            I = I - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
        if model.kind == "planar":
            if not I[2, 2] > 0:
                out.append(f"link {i} ({link.name}): inertia about the centre of mass "
                           f"{I[2, 2]:.6g} kg m^2 is not positive")
            continue
        lam = np.linalg.eigvalsh(I)
        if lam[0] <= 0:
            out.append(f"link {i} ({link.name}): inertia about the centre of mass not "
                       f"positive definite (principal moments {np.round(lam, 9).tolist()})")
        elif lam[0] + lam[1] < lam[2] * (1 - 1e-9):
            out.append(f"link {i} ({link.name}): principal moments "
                       f"{np.round(lam, 9).tolist()} violate the triangle inequality")
    for k, v in values.items():
        if k.startswith(("d", "k")) and k[1:].isdigit() and v < 0:
            out.append(f"{k} = {v:.6g}: {'damping' if k[0] == 'd' else 'stiffness'} is negative")
    return out


# -- plausibility before success (issue 36) -------------------------------------------------

def joint_columns(log: IdentificationLog, model: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """(q, τ) of the joints alone (K × n): a floating base's log puts its pose (7
    columns) before q and its wrench (6) before τ (issue 36: the checks below indexed the
    base's columns as joints, an IndexError on every floating log)."""
    if model.floating:
        return log.q[:, 7:], log.tau[:, 6:]
    return log.q, log.tau


def check_log(log: IdentificationLog, model: RobotModel) -> None:
    """Refuse a log whose sample time or signals rule an identification out: a time
    step outside :data:`DT_RANGE` (the time column in ms), a τ column that never
    changes (nothing logged), a q column that never moves."""
    lo, hi = DT_RANGE
    if not lo <= log.dt <= hi:
        unit = ("is the time column in milliseconds?" if log.dt > hi else
                "is the time column in seconds?")
        raise SoftgenError(f"identify: {log.path}: median time step {log.dt:.6g} s: an "
                           f"identification log needs q'' of the motion, so a sample time "
                           f"between {lo:g} and {hi:g} s; {unit}")
    q, tau = joint_columns(log, model)
    n = q.shape[1]
    flat_tau = [f"tau{j + 1}" for j in range(n) if np.ptp(tau[:, j]) == 0]
    if flat_tau:
        value = float(tau[0, int(flat_tau[0][3:]) - 1])
        raise SoftgenError(f"identify: {log.path}: {', '.join(flat_tau)} constant "
                           f"({value:g}) over the whole log: no torque was logged (or the "
                           "wrong column)")
    still = [f"q{j + 1}" for j in range(n) if np.ptp(q[:, j]) == 0]
    if still:
        raise SoftgenError(f"identify: {log.path}: {', '.join(still)} never moves: the log "
                           "does not excite those joints (softgen identify MODEL --excite "
                           "writes a trajectory that does)")


def unit_hints(log: IdentificationLog, model: RobotModel, res: RigidIdentification | None
               ) -> list[str]:
    """Likely causes of an implausible identification, read from the log's ranges: q of
    a revolute joint spanning more than a turn (degrees), a torque far from what the
    model file predicts along the same motion (mN·m, kN·m, currents)."""
    hints = []
    q, _ = joint_columns(log, model)
    for j, link in enumerate(model.links):
        span = float(np.ptp(q[:, j]))
        if link.joint == "revolute" and span > 2 * math.pi:
            hints.append(f"q{j + 1} spans {span:.4g}, more than a turn (2 pi rad): is q in "
                         "degrees?")
            break
    if res is not None and res.torque_ratio.size:
        r = res.torque_ratio
        big, small = np.nanmax(r), np.nanmin(r)
        if big > TORQUE_RATIO:
            hints.append(f"the logged torque is {big:,.0f} times what the model file predicts "
                         "along this motion: is tau in mN m (or a current without "
                         "--torque-constant)?")
        elif 0 < small < 1 / TORQUE_RATIO:
            hints.append(f"the logged torque is 1/{1 / small:,.0f} of what the model file "
                         "predicts along this motion: is tau in kN m, or another robot's?")
    return hints
