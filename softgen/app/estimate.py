"""Stiffness from a recorded log (``softgen estimate``): method choice, columns, the run.

The command line only parses arguments; this module decides which estimator a model
and method mean (thesis chapter 6: invasive, pneumatic or electric; chapter 7:
non-invasive), which columns its log needs, runs the estimator over the log through
the one loop driver, and writes the estimates. A sample log ships with the package
(:func:`sample_log`), made by :func:`make_sample_log` from the emulated qbmove
pendulum, so a first run needs no data of one's own.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from softgen.core.stop import Stop, ignore_signals, interrupted, signal_name, stopping
from softgen.core.paths import derived_output
from softgen.core.errors import NonFiniteError, SoftgenError
from softgen.estimation.csvlog import first_non_finite, read_log, step_tolerance, write_estimates
from softgen.estimation.estimators import EstimatorConfig, StiffnessEstimator, estimator_problem
from softgen.estimation.offline import estimation_result, offline_diagram, split_measurements
from softgen.modelfile.model import RobotModel
from softgen.modelfile.load import as_model, list_models, load_model
from softgen.runtime.simulate import simulate

METHODS = ("invasive", "noninvasive")

#: Largest exponent of ``--powers`` (the RLS regressor's powers of the spring deflection
#: φ, thesis eq. 6.22 and 7.13; the thesis uses at most 7). φ is a fraction of a radian,
#: so φ^j for larger j is numerically zero against the other columns, or overflows for
#: |φ| > 1: ``--powers 100000`` gave σ̂ = 0 in every row with status 0 (issue 23).
MAX_POWER = 15

#: Most exponents in ``--powers`` (parameters the RLS fits per spring).
MAX_POWERS = 8

#: Accepted sample times [s] of a log (``--dt`` or the log's median step): a
#: measurement log is sampled between a microsecond and a second. Outside, the
#: discretised model the observer is designed on is degenerate (1e-300 s) or not
#: observable (1e6 s), or its exponentials overflow (1e300 s).
DT_RANGE = (1e-6, 1.0)


def check_powers(powers: tuple[int, ...] | None) -> None:
    """``--powers`` within ``0..MAX_POWER``, at most ``MAX_POWERS`` of them, distinct."""
    if powers is None:
        return
    bad = [p for p in powers if isinstance(p, bool) or not isinstance(p, int)
           or not 0 <= p <= MAX_POWER]
    if bad or not powers or len(powers) > MAX_POWERS or len(set(powers)) != len(powers):
        raise SoftgenError(f"estimate: --powers: expected 1 to {MAX_POWERS} distinct integers "
                           f"in 0..{MAX_POWER}, got {','.join(map(str, powers))}")


def check_dt(dt: float, where: str) -> None:
    """A sample time within :data:`DT_RANGE` (``where`` names the option or the log)."""
    lo, hi = DT_RANGE
    if not (math.isfinite(dt) and lo <= dt <= hi):
        raise SoftgenError(f"estimate: {where}: {dt:.9g} s, expected a sample time between "
                           f"{lo:g} and {hi:g} s; check the unit of the time column")


def estimator_method(model: RobotModel, method: str) -> str:
    """The estimator a model's declared laws and ``method`` call for (raises with the
    reason): ``invasive`` is the pneumatic estimator (section 6.1) of pressure-driven
    pairs or the electric one (section 6.2) of spring drives with motors, whichever the
    model's actuators are (:func:`~softgen.estimation.estimators.estimator_problem`, the
    registry's conditions); ``noninvasive`` is chapter 7's, of spring drives."""
    if method not in METHODS:
        raise SoftgenError(f"estimate: --method: expected one of {', '.join(METHODS)}, "
                           f"got {method!r}")
    if not isinstance(model, RobotModel):
        raise SoftgenError(f"estimate: model {model.name!r} is a soft body; the stiffness "
                           "estimators are for rigid chains with antagonistic actuators")
    kinds = ("pneumatic", "electric") if method == "invasive" else ("noninvasive",)
    why = {k: estimator_problem(model, k) for k in kinds}
    fits = [k for k in kinds if why[k] is None]
    if len(fits) == 1:
        return fits[0]
    if fits:
        raise SoftgenError(f"estimate: model {model.name!r} has both pressure pairs and "
                           "spring drives; one log runs one invasive estimator, and "
                           "softgen estimate does not choose between them")
    kind = model.actuator_type or ", ".join(sorted({a.type for a in model.actuators})) \
        or "none"
    needs = ("McKibben or declared pressure pairs (section 6.1), or qbmove or declared "
             "spring drives with motor dynamics (section 6.2)" if method == "invasive" else
             "qbmove actuators or declared spring drives (chapter 7)")
    # The reason when the model has the drives but they do not qualify (a field to fix);
    # "no such drive" is what the first part of the line says already.
    detail = [str(why[k]) for k in kinds if not str(why[k]).startswith("actuators: no ")]
    raise SoftgenError(f"estimate: model {model.name!r} has actuator type {kind}; --method "
                       f"{method} needs {needs}" + "".join(f": {d}" for d in detail))


def log_columns() -> list[tuple[str, str, list[str]]]:
    """``(model, method, columns)`` for every shipped model that has an estimator."""
    out = []
    for name in list_models():
        model = load_model(name)
        for method in METHODS:
            try:
                est = StiffnessEstimator(model, EstimatorConfig(estimator_method(model, method)))
            except SoftgenError:
                continue
            out.append((name, method, list(est.measurements)))
    return out


@dataclass(frozen=True)
class EstimateRun:
    """What :func:`estimate_log` did: samples, sample time, method, delay, output, the
    low-pass it used and what the plausibility check found (:func:`plausibility`)."""

    samples: int
    dt: float
    method: str
    delay: int
    out: Path
    wall_seconds: float
    lowpass: float | None = None
    warnings: tuple[str, ...] = ()


# -- the low-pass that makes a log of quantised encoders estimable ------------------------

#: The measured anchor of :func:`default_lowpass`: 1 Hz on 5 ms samples of 8192-count
#: encoders. On the shipped sample log (120 s) the non-invasive estimate's median error
#: over the last fifth is 2.0 % at 1 Hz, 3.0 % at 0.5 Hz, ≥ 20 % unfiltered
#: (σ̂ negative); with the thesis's 20 s it does not converge at any cutoff.
LOWPASS_ANCHOR = (1.0, 5e-3, 2 * math.pi / 8192)


def encoder_resolution(columns: np.ndarray) -> float | None:
    """The quantum of position columns recorded by encoders (rad), or None if they are
    not quantised: the smallest step between distinct values, accepted when (nearly)
    every step is a whole multiple of it."""
    best = None
    for col in np.atleast_2d(columns.T):
        v = np.unique(col[np.isfinite(col)])
        d = np.diff(v)
        d = d[d > 1e-12 * max(1.0, float(np.abs(v).max(initial=0.0)))]
        if d.size < 10:
            continue
        quantum = float(d.min())
        ratio = d / quantum
        if np.mean(np.abs(ratio - np.round(ratio)) < 0.02) < 0.99:
            return None                                # not quantised (or not uniformly)
        best = quantum if best is None else min(best, quantum)
    return best


def default_lowpass(dt: float, resolution: float | None) -> float:
    """Cutoff [Hz] of the identical low-pass of RLS target and regressor (thesis ch. 7
    with quantised encoders; issue 13) for a log of sample time ``dt`` whose encoders
    have quantum ``resolution``.

    Quantisation is white noise of variance Δ²/12 per sample; its first difference over
    ``dt`` (the deflection rates the non-invasive estimator differentiates) has a power
    spectral density ∝ Δ² ω² dt, so below a cutoff ω_c it carries a variance ∝ Δ² ω_c³ dt.
    Holding that variance at the anchor's (:data:`LOWPASS_ANCHOR`, measured) gives
    f_c = f_0 (Δ_0/Δ)^(2/3) (dt_0/dt)^(1/3), capped at a tenth of the Nyquist frequency
    (also the cutoff for unquantised logs).
    """
    f0, dt0, res0 = LOWPASS_ANCHOR
    cap = 0.1 * 0.5 / dt
    if resolution is None:
        return cap
    return float(min(cap, f0 * (res0 / resolution) ** (2 / 3) * (dt0 / dt) ** (1 / 3)))


#: A direction of the RLS parameters is *informed* by the log when the data shrank its
#: covariance below this fraction of P(0) (P(N) = (P(0)⁻¹ + Σ φφᵀ)⁻¹ for λ = 1): at 0.5
#: the log weighs as much as the prior. On the shipped sample log every direction ends
#: below 1.2e-5 of P(0); with ``--p0 1e-300`` all six stay at 1 − 1e-290.
INFORMED = 0.5


def uninformed(P0: np.ndarray, PN: np.ndarray) -> int:
    """How many directions of an RLS's parameters the log left at their prior: the
    eigenvalues of P(0)^(-1/2) P(N) P(0)^(-1/2) above :data:`INFORMED` (P(0) diagonal)."""
    d = 1.0 / np.sqrt(np.diag(P0))
    M = PN * d[:, None] * d[None, :]
    lam = np.linalg.eigvalsh(0.5 * (M + M.T))
    return int(np.sum(~(lam <= INFORMED)))        # NaN counts as uninformed


def plausibility(t: np.ndarray, result, est, *, lowpass: float | None = None,
                 covariance: dict | None = None, p0: float | None = None,
                 default_p0: float | None = None) -> list[str]:
    """What makes the estimate implausible, one line each (empty when nothing does):

    - an RLS whose covariance the log left at its prior in some direction
      (``covariance``: RLS name -> (P(0), P(N)); :func:`uninformed`): too little
      excitation, or a ``--p0`` (``p0``, against the method's ``default_p0``) too small
      for the regressor's scale, so that the estimate stays at its initial value;
    - a non-positive stiffness (with the hint of a low-pass only when none was used);
    - an RLS whose parameters still move, or too little excitation for the RLS to
      update. Judged on the second half of the log, where the estimate should have
      converged.
    """
    found = []
    stuck = False
    for r, (P0, PN) in (covariance or {}).items():
        k = uninformed(P0, PN)
        if not k:
            continue
        n = P0.shape[0]
        stuck = stuck or k == n
        small = p0 is not None and default_p0 is not None and p0 < default_p0
        stays = ("the estimate stays at its initial value" if k == n else
                 "those directions stay near their initial value")
        cause = (f"--p0 {p0:g} is too small for the regressor's scale (the method's default "
                 f"is {default_p0:g}): {stays}" if small else
                 f"too little excitation in those directions: {stays}")
        found.append(f"RLS {r}: the log informs {n - k} of {n} parameter directions "
                     f"(P(N) ≥ {INFORMED:g} P(0) in the others): {cause}")
    half = t >= t[0] + 0.5 * (t[-1] - t[0])
    s = result.sigma_hat[half]
    s = s[np.all(np.isfinite(s), axis=1)]
    if s.size:
        neg = float(np.mean(s <= 0))
        if neg > 0.01:
            hint = (" (unfiltered differences of quantised encoders? try --lowpass)"
                    if lowpass is None and not stuck else "")
            found.append(f"σ̂ ≤ 0 in {100 * neg:.0f} % of the second half of the log: not a "
                         f"stiffness{hint}")
    upd = result.updating[half]
    if upd.size and float(np.mean(upd)) < 0.05:
        found.append(f"the RLS updated in {100 * float(np.mean(upd)):.1f} % of the second "
                     "half: too little excitation to estimate")
    last = t >= t[0] + 0.75 * (t[-1] - t[0])
    for r, th in result.theta.items():
        th = th[last]
        th = th[np.all(np.isfinite(th), axis=1)]
        if len(th) < 2:
            continue
        # Relative to the largest parameter: norms of raw values as small as 1e-298
        # underflow to 0 (issue 36: --p0 1e-300 passed this check).
        big = float(np.max(np.abs(th[-1]))) or 1.0
        scale = float(np.linalg.norm(th[-1] / big)) or 1.0
        drift = float(np.linalg.norm((th[-1] - th[0]) / big)) / scale
        if drift > 0.1:
            found.append(f"RLS {r}: parameters moved by {100 * drift:.0f} % over the last "
                         "quarter of the log: not converged (a longer log, or more "
                         "excitation)")
    return found


def check_excitation(log: Path, Y: np.ndarray, names) -> None:
    """Refuse a log in which every measured column is constant (all zero, a robot at
    rest): nothing in it can move an estimate (issue 36: such logs blamed quantised
    encoders)."""
    span = np.ptp(Y, axis=0) if len(Y) else np.zeros(len(names))
    scale = np.maximum(np.abs(Y).max(axis=0, initial=0.0), 1.0)
    if np.all(span <= 1e-12 * scale):
        raise SoftgenError(f"estimate: {log}: too little excitation: every measured column "
                           f"({', '.join(names)}) is constant over the log; the estimator "
                           "needs the joints moving and the springs deflecting")


def check_output(out: Path, log: Path, *, force: bool) -> None:
    """Refuse an output that is the log, a directory, unwritable, or exists (no ``force``)."""
    if out.resolve() == log.resolve():
        raise SoftgenError(f"estimate: --out {out} is the log itself; choose another file")
    if out.is_dir():
        raise SoftgenError(f"estimate: --out {out} is a directory; give a file name")
    if (out.exists() or out.is_symlink()) and not out.is_file():
        # A device or a FIFO: the atomic rename would replace the node itself (as root,
        # --out /dev/full --force did, issue 36).
        raise SoftgenError(f"estimate: --out {out} is not a regular file; give a file name")
    if out.exists() and not force:
        raise SoftgenError(f"estimate: --out {out} exists; add --force to overwrite it")
    if not out.parent.is_dir():
        raise SoftgenError(f"estimate: --out {out}: no directory {out.parent}")
    if not os.access(out.parent, os.W_OK):
        raise SoftgenError(f"estimate: --out {out}: directory {out.parent} is not writable")


def estimate_log(model_name, log: str | Path, *, method: str = "invasive",
                 out: str | Path | None = None, dt: float | None = None,
                 powers: tuple[int, ...] | None = None, p0: float | None = None,
                 lowpass: float | None = None, force: bool = False) -> EstimateRun:
    """Run the model's estimator over a CSV log and write ``<log>_estimate.csv``.

    ``lowpass``: cutoff [Hz] of the identical low-pass of RLS target and regressor; 0
    for none; default :func:`default_lowpass` of the log's sample time and encoder
    resolution for the non-invasive method (which differentiates the encoders), none
    for the invasive ones. Everything is checked before the log is processed (method,
    settings, output path). A diverged estimate raises :class:`NonFiniteError` naming
    the first column and time, after the estimates (``nan``/``inf`` where diverged) are
    written; an implausible one is returned with :attr:`EstimateRun.warnings`.
    """
    log = Path(log)
    out = Path(out) if out else derived_output(log, "_estimate.csv")
    # SIGINT/SIGTERM at any moment: one line, status 130/143; the output is written
    # atomically, so an earlier file is kept whole (issue 23).
    with stopping():
        try:
            return _estimate_log(model_name, log, out, method=method, dt=dt, powers=powers,
                                 p0=p0, lowpass=lowpass, force=force)
        except Stop as stop:
            ignore_signals()
            state = "unchanged" if out.exists() else "not written"
            raise interrupted(stop.signum, f"estimate: interrupted by "
                              f"{signal_name(stop.signum)}; {out} {state}") from None


def _estimate_log(model_name, log: Path, out: Path, *, method: str, dt: float | None,
                  powers: tuple[int, ...] | None, p0: float | None,
                  lowpass: float | None, force: bool) -> EstimateRun:
    t0 = time.perf_counter()
    check_powers(powers)
    model = as_model(model_name)           # a name, a file or a loaded chain
    kind = estimator_method(model, method)
    for flag, v in (("--dt", dt), ("--p0", p0)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise SoftgenError(f"estimate: {flag}: expected a positive number, got {v!r}")
    if lowpass is not None and not (math.isfinite(lowpass) and lowpass >= 0):
        raise SoftgenError(f"estimate: --lowpass: expected a cutoff in Hz (0 for none), "
                           f"got {lowpass!r}")
    if dt is not None:
        check_dt(dt, "--dt")
    check_output(out, log, force=force)
    config = EstimatorConfig(kind, dt=dt, powers=powers, p0=p0)
    est = StiffnessEstimator(model, config)      # checks the settings before reading the log
    t, Y, log_dt = read_log(log, est.measurements, min_rows=est.config.delay + 2)
    check_excitation(log, Y, est.measurements)
    if dt is not None and abs(dt - log_dt) > step_tolerance(log_dt):
        raise SoftgenError(f"estimate: --dt {dt:g} s disagrees with the median time step "
                           f"{log_dt:.9g} s of {log}; drop --dt or resample the log")
    if dt is None:
        check_dt(log_dt, f"{log}: median time step")
    if lowpass is None and kind == "noninvasive":
        positions = [i for i, c in enumerate(est.measurements) if c.startswith("q")]
        lowpass = default_lowpass(log_dt, encoder_resolution(Y[:, positions]))
    lowpass = lowpass or None                      # 0: no filter
    if lowpass is not None and lowpass >= 0.5 / log_dt:
        raise SoftgenError(f"estimate: --lowpass {lowpass:g} Hz: expected less than the "
                           f"Nyquist frequency {0.5 / log_dt:g} Hz of the log")
    if dt is None or lowpass is not None:
        est = StiffnessEstimator(model, replace(config, dt=log_dt if dt is None else dt,
                                                lowpass=lowpass))
    # A diverged estimator stays non-finite: stop there, the rest is NaN.
    trace = simulate(offline_diagram(est), steps=len(Y), externals=split_measurements(est, Y),
                     on_nonfinite="stop")
    result = estimation_result(est, trace, samples=len(Y))
    write_estimates(out, t, result, est)
    bad = first_non_finite(t, result, est)
    if bad is not None:
        k, column, value = bad
        raise NonFiniteError(f"estimate: diverged: {column} is {value!r} at t = {float(t[k])!r} s "
                             f"(sample {k} of {log}); estimates written to {out} ('nan'/'inf' "
                             f"where diverged, empty only where there is no estimate yet)")
    P0 = est.initial_state()
    covariance = {r: (P0[est.layout[f"P_{r}"]].reshape(n, n),
                      np.asarray(trace.final_state[f"est.P_{r}"], dtype=float).reshape(n, n))
                  for r in est.rls_names for n in [est.rls_sizes[r]]}
    default_p0 = EstimatorConfig(kind).resolved().p0
    return EstimateRun(len(t), est.config.dt, kind, est.config.delay, out,
                       time.perf_counter() - t0, lowpass,
                       tuple(plausibility(t, result, est, lowpass=lowpass,
                                          covariance=covariance, p0=p0,
                                          default_p0=default_p0)))


# -- the shipped sample log ------------------------------------------------------------

#: File name of the shipped sample log (package data, ``softgen/samples/``).
SAMPLE = "pendulum_qbmove_log.csv"


def sample_log() -> Path:
    """The shipped sample log: the emulated qbmove pendulum (``pendulum_qbmove``), 120 s at
    5 ms (the non-invasive estimate needs about a minute to converge), encoders of 8192
    counts, columns ``t, q1, qa1, qb1, tau_a1, tau_b1`` (every
    method's columns). Made by :func:`make_sample_log`."""
    return Path(str(resources.files("softgen") / "samples" / SAMPLE))


def make_sample_log(path: str | Path, *, duration: float = 120.0, dt: float = 5e-3) -> Path:
    """Write the sample log: sinusoidal position and stiffness references tracked through the
    motors' servos on ``pendulum_qbmove``, read by 8192-count encoders and the motors'
    torque sensing, every column rounded to 9 significant digits."""
    from softgen.plants.qbmove import (Sinusoids, hardware_diagram, motor_references,
                                phased_references, servo_initial_state)
    from softgen.symbolic.actuated import servo_plant_block
    from softgen.symbolic.actuators import QbmoveSprings
    from softgen.symbolic.rigid import RigidDynamics
    model = load_model("pendulum_qbmove")
    K = int(round(duration / dt))
    t = np.arange(K) * dt
    q_spec: Sinusoids = ((0.0, 0.3, np.pi / 4),)      # the references of section 7.3's run
    s_spec: Sinusoids = ((5.0, 2.0, np.pi / 6),)
    q_d, qd_d, qdd_d, sigma_d = phased_references(t, q_spec, s_spec)
    refs = motor_references(model, q_d, qd_d, qdd_d, sigma_d)
    plant = servo_plant_block(RigidDynamics(model), QbmoveSprings(model), dt, substeps=10,
                              bandwidth=300.0)
    d = hardware_diagram("sample_log_pendulum_qbmove", plant, counts_per_rev=8192)
    x0 = servo_initial_state(q_d, qd_d, refs)
    tr = simulate(d, steps=K, x0={f"plant.{k}": v for k, v in x0.items()},
                  externals={"q_ref": refs}, record=["enc.q_m", "enc.qa_m", "enc.qb_m",
                                                     "plant.tau_motor"])
    cols = {"t": t, "q1": tr["enc.q_m"][:, 0], "qa1": tr["enc.qa_m"][:, 0],
            "qb1": tr["enc.qb_m"][:, 0], "tau_a1": tr["plant.tau_motor"][:, 0],
            "tau_b1": tr["plant.tau_motor"][:, 1]}
    path = Path(path)
    with path.open("w") as fh:
        fh.write(",".join(cols) + "\n")
        for k in range(K):
            fh.write(",".join(f"{v[k]:.9g}" for v in cols.values()) + "\n")
    return path
