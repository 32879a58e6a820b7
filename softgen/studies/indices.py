"""Indices of the studies as metric records.

Chapter 10: phase rms errors, the position/stiffness coupling index, the parameter-estimate
ratio. Estimation chapters (section 6.1.3): MSE and MSREP (in percent: 100 ·
mean(((χ − χ̂)/χ)²), NOTES section 2 item 9) over a metric window, per joint, of stiffness
and torque (or rotatum) estimates; update fractions, excitation and noise statistics; the
figure of estimates against truth.

Coupling index (one definition for every chapter-10 experiment)
---------------------------------------------------------------
The thesis defines no number for decoupling. It states the property in words: "position
commands are followed with almost null influence on the robot's joint stiffness and
viceversa" (section 10.2, Fig. 10.2), "the impact of stiffness reference change on the
position is larger in the case of the open-loop solution" (section 10.3.4, Fig. 10.11),
"no significant mutual impact between position and stiffness control" (section 10.3.5,
Fig. 10.12), and feedback linearisation leaves the stiffness "untouched" (section 10.4).
Each says how much one error *changes* when only the other reference steps, so the
index measures that change, per unit of the step:

    c_i = max over windows w = [t₀, t₁) of  max_{t ∈ w} |d_i(t) − d̄_i,w| / Δ_w,

d the deviation (σ − σ_d for position steps, q − q_d for stiffness steps), Δ_w the
largest step of the moving references in w, and d̄_i,w the level d_i held before the
step: its mean over the ``baseline`` seconds before t₀, or with ``baseline`` = 0 its
value at t₀. A steady offset (an adaptation not yet finished, a model error) is then not
counted as coupling. Windows (:func:`windows`) are intervals in which only the other
references move. A window that ends after a run's emergency stop does not count; with
none left the index is NaN.

``baseline`` is the experiment's choice, stated where it is made: GioSte's stiffness is
read through encoder counts, so its level is averaged (``baseline`` = 2 s of its
config); the simulated arms of sections 10.2 and 10.4 are noise-free and their schedules
start a window right where the previous reference change ends (section 10.4: a σ step
at 48 s with a 2 s rise, then a q step at 50 s), where an average would take in that
transient: they use the value at t₀ (``baseline`` = 0).

Until 2026-12 three functions wrote the same metric names: ``ch10-pneumatic-adaptive``
took |d| itself (no level; its deviations before the windows are at the 1e-12 level, so
its numbers do not move), ``ch10-feedback-linearization`` |d(t) − d(t₀)| and the GioSte
experiments the baseline mean, both of which this definition is.
"""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from softgen.core.metrics import Metrics
from softgen.estimation.offline import EstimationResult
from softgen.studies.plotting import envelope, save

#: Metric quantities and units of the two coupling directions.
POSITION_TO_STIFFNESS = ("position_to_stiffness_coupling", "N m/rad per rad")
STIFFNESS_TO_POSITION = ("stiffness_to_position_coupling", "rad per N m/rad")


def windows(own, other, *, settle: float, end: float) -> list[tuple[float, float, float]]:
    """``(t0, t1, step)``: intervals in which only the ``own`` references move.

    ``own`` and ``other`` are lists of :class:`~softgen.control.references.SmoothSteps`
    (e.g. positions and stiffnesses). Each step of ``own`` opens a window that lasts to
    the next change of any reference (or ``end``); steps before ``settle`` (an
    adaptation transient) or within one rise time of a step of ``other`` are left out.
    """
    other_times = {t for s in other for t in s.times[1:]}
    changes = sorted({t for s in [*own, *other] for t in s.times[1:]})
    return [(float(t0), float(min([u for u in changes if u > t0] + [end])), abs(b - a))
            for s in own for t0, a, b in zip(s.times[1:], s.values, s.values[1:])
            if t0 >= settle and all(abs(t0 - u) >= s.rise for u in other_times)]


def coupling_index(t, deviation, wins, *, baseline: float,
                   stop: float | None = None) -> np.ndarray:
    """Per joint, the coupling index c_i of the module docstring (NaN: no window counts).

    ``deviation``: samples × n; ``wins``: ``(t0, t1, step)``; ``baseline``: seconds
    before t0 the level is averaged over (0: the value at t0); ``stop``: the run's
    emergency-stop time (windows ending after it are skipped).
    """
    t, dev = np.asarray(t), np.asarray(deviation)
    res = np.full(dev.shape[1], np.nan)
    for t0, t1, step in wins:
        if stop is not None and t1 > stop:
            continue
        pre, win = (t >= t0 - baseline) & (t < t0), (t >= t0) & (t < t1)
        if win.any() and step > 0:
            level = dev[pre].mean(axis=0) if pre.any() else dev[np.argmax(win)]
            v = np.abs(dev[win] - level).max(axis=0) / step
        else:
            v = np.zeros(dev.shape[1])
        res = np.where(np.isnan(res), v, np.maximum(res, v))
    return res


def coupling_records(m: Metrics, t, deviation, wins, which: tuple[str, str], *,
                     prefix: str = "", **kw) -> Metrics:
    """:func:`coupling_index` as records ``which`` = (quantity, unit), one per joint."""
    for i, v in enumerate(coupling_index(t, deviation, wins, **kw), 1):
        m.add(which[0], v, which[1], joint=i, prefix=prefix)
    return m


def phase_rms_records(m: Metrics, t, err, phases, quantity: str, unit: str, *,
                      prefix: str = "") -> Metrics:
    """``quantity`` per joint and phase: rms of ``err`` (samples × n) over the second
    half of each phase ``(t0, t1)`` (after the transient of the phase's first step)."""
    t, err = np.asarray(t), np.asarray(err)
    for k, (t0, t1) in enumerate(phases, 1):
        mask = (t >= (t0 + t1) / 2) & (t < t1)
        if not mask.any():
            raise ValueError(f"phase {k} ({t0}, {t1}) holds no samples")
        for i in range(err.shape[1]):
            m.add(quantity, np.sqrt(np.mean(err[mask, i] ** 2)), unit, joint=i + 1, phase=k,
                  prefix=prefix)
    return m


def parameter_ratio(Pi_hat, Pi) -> float:
    """Largest ‖Π̂(t)‖/‖Π‖ seen: bounded estimates (Fig. 10.3) keep it O(1)."""
    return float(np.max(np.linalg.norm(np.asarray(Pi_hat), axis=1)) / np.linalg.norm(Pi))


#: "Bounded" as a trend: ‖π̂‖ changes by less than this fraction along its least-squares
#: line over the window :func:`norm_drift` reads (issue 24; chapters 10 and 12).
DRIFT = 0.05


def norm_drift(t: np.ndarray, norm: np.ndarray, *, since: float | None = None) -> float:
    """Relative change of ‖π̂‖ over the window t ≥ ``since`` (default: the second half of
    the run) along its least-squares line: slope × window length / mean. "Bounded" as a
    trend (issue 24): a threshold on max ‖π̂‖ passes an estimate that still drifts
    linearly at the end of a finite run."""
    t, norm = np.asarray(t), np.asarray(norm)
    half = t >= (t[0] + (t[-1] - t[0]) / 2 if since is None else since)
    th, nh = t[half], norm[half]
    if th.size < 3 or not np.all(np.isfinite(nh)):
        return float("nan")
    slope = np.polyfit(th - th[0], nh, 1)[0]
    mean = float(np.mean(nh))
    return float(abs(slope) * (th[-1] - th[0]) / mean) if mean > 0 else 0.0


def rms(e, axis=None):
    """Root mean square of ``e`` (over ``axis``)."""
    return np.sqrt(np.mean(np.asarray(e) ** 2, axis=axis))


# -- estimation chapters (section 6.1.3) -----------------------------------------------

def mse(true: np.ndarray, est: np.ndarray) -> float:
    """Mean square error (section 6.1.3)."""
    return float(np.mean((true - est) ** 2))


def msrep(true: np.ndarray, est: np.ndarray) -> float:
    """Mean square relative error, in percent: 100 · mean(((χ − χ̂)/χ)²) (section 6.1.3).

    Samples where the true value is exactly zero are left out (the ratio is undefined).
    """
    ok = true != 0
    return float(100.0 * np.mean(((true[ok] - est[ok]) / true[ok]) ** 2))


def window_mask(t: np.ndarray, window, res: EstimationResult | None = None) -> np.ndarray:
    """Samples in ``window`` = [t0, t1] (None: after the first 10 % of the run) that
    carry estimates (the last L samples have none)."""
    t0, t1 = (0.1 * t[-1], t[-1]) if window is None else window
    m = (t >= t0) & (t <= t1)
    if res is not None:
        m &= np.all(np.isfinite(res.sigma_hat), axis=1)
    return m


def error_records(m: Metrics, truth_sigma, truth_tau, res: EstimationResult, mask, *,
                  prefix: str = "", tau_unit: str = "N m", est_tau=None) -> Metrics:
    """``stiffness_mse/msrep`` and ``torque_mse/msrep`` per joint over ``mask``."""
    est_tau = res.tau_hat if est_tau is None else est_tau
    for i in range(truth_sigma.shape[1]):
        a, b = truth_sigma[mask, i], res.sigma_hat[mask, i]
        m.add("stiffness_mse", mse(a, b), "(N m/rad)^2", joint=i + 1, prefix=prefix)
        m.add("stiffness_msrep", msrep(a, b), "%", joint=i + 1, prefix=prefix)
        a, b = truth_tau[mask, i], est_tau[mask, i]
        m.add("torque_mse", mse(a, b), f"({tau_unit})^2", joint=i + 1, prefix=prefix)
        m.add("torque_msrep", msrep(a, b), "%", joint=i + 1, prefix=prefix)
    return m


def estimation_figure(path, t, truth_sigma, truth_tau, res: EstimationResult, *,
                      title: str, names: dict[str, list[str]],
                      torque_label: str = "tau_e [N m]") -> None:
    """Estimate against truth, relative error, and RLS parameters over time (long runs
    are drawn from their min/max envelope, :func:`~softgen.studies.plotting.envelope`;
    the relative errors are formed from every sample before thinning)."""
    n, tt = truth_sigma.shape[1], t
    with np.errstate(divide="ignore", invalid="ignore"):
        rel_tau = np.abs(100 * (res.tau_hat - truth_tau) / truth_tau)
        rel_sig = np.abs(100 * (res.sigma_hat - truth_sigma) / truth_sigma)
    t, truth_sigma = envelope(tt, truth_sigma)
    truth_tau, tau_hat, tau_uio, sigma_hat, rel_tau, rel_sig = (
        envelope(tt, v)[1] for v in (truth_tau, res.tau_hat, res.tau_uio, res.sigma_hat,
                                     rel_tau, rel_sig))
    theta = {r: envelope(tt, v)[1] for r, v in res.theta.items()}
    fig = Figure(figsize=(5.5 * n, 9))
    ax = fig.subplots(4, n, sharex=True, squeeze=False)
    for i in range(n):
        ax[0, i].plot(t, truth_tau[:, i], "k", lw=1.2, label="true")
        ax[0, i].plot(t, tau_hat[:, i], "--", lw=1, label="RLS model")
        ax[0, i].plot(t, tau_uio[:, i], ":", lw=0.8, label="observer")
        ax[0, i].set_ylabel(torque_label)
        ax[0, i].set_title(f"{title}, joint {i + 1}")
        ax[1, i].plot(t, truth_sigma[:, i], "k", lw=1.2, label="true")
        ax[1, i].plot(t, sigma_hat[:, i], "--", lw=1, label="estimate")
        ax[1, i].set_ylabel("sigma [N m/rad]")
        ax[2, i].semilogy(t, rel_sig[:, i], lw=0.8, label="stiffness")
        ax[2, i].semilogy(t, rel_tau[:, i], lw=0.8, label="torque")
        ax[2, i].set_ylabel("|relative error| [%]")
        for r, th in theta.items():
            if int(r.rstrip("ab")[len("joint"):]) - 1 == i:
                # Each parameter over its final value on a linear axis (issue 32: the
                # symlog axis of the raw values, several units on one axis, was unreadable).
                rows = np.all(np.isfinite(th), axis=1)
                end = th[rows][-1] if rows.any() else np.ones(th.shape[1])
                end = np.where(np.abs(end) > 0, end, 1.0)
                for j in range(th.shape[1]):
                    ax[3, i].plot(t, th[:, j] / end[j], lw=0.8, label=f"{r} {names[r][j]}")
        ax[3, i].set_ylabel("RLS Π̂_p / Π̂_p(end) [1]")
        ax[3, i].set_ylim(-1.0, 3.0)
        ax[3, i].set_xlabel("t [s]")
        for a in ax[:, i]:
            a.legend(fontsize=7, ncol=2, loc="upper left")
    save(fig, path, dpi=100)


def phase_records(m: Metrics, quantity: str, values: dict[int, np.ndarray], mask, phase,
                  fn, unit: str = "", *, prefix: str = "") -> Metrics:
    """``fn(values[j][sel])`` per joint j (1-based key) and phase k inside ``mask``
    (NaN for a phase with no sample in it)."""
    for k in range(int(phase.max()) + 1):
        sel = mask & (phase == k)
        for j, v in values.items():
            m.add(quantity, fn(*(a[sel] for a in v)) if sel.any() else float("nan"), unit,
                  joint=j, phase=k + 1, prefix=prefix)
    return m


def update_fraction_records(m: Metrics, res: EstimationResult, phase, *,
                            prefix: str = "") -> Metrics:
    """Fraction of samples (all RLS instances pooled) with the RLS updating, per phase."""
    K = res.updating.shape[0] - res.delay          # the last L rows carry no estimate
    upd, ph = res.updating[:K], phase[:K]
    for k in range(int(phase.max()) + 1):
        m.add("update_fraction", upd[ph == k].mean(), "1", phase=k + 1, prefix=prefix)
    return m


def excitation_records(m: Metrics, t, phase, std: np.ndarray, window: float, *,
                       prefix: str = "") -> Metrics:
    """Median, 5th and 95th percentile of an excitation statistic ``std`` per phase.

    Pooled over its columns, leaving out the first ``window`` seconds of each phase
    (the statistic still remembers the previous phase) unless the phase is shorter.
    """
    for k in range(int(phase.max()) + 1):
        start = t[phase == k][0]
        sel = (phase == k) & (t >= start + window)
        v = std[sel if sel.any() else phase == k].ravel()
        m.add("deflection_std", np.median(v), "rad", phase=k + 1, prefix=prefix)
        m.add("deflection_std_p05", np.percentile(v, 5), "rad", phase=k + 1, prefix=prefix)
        m.add("deflection_std_p95", np.percentile(v, 95), "rad", phase=k + 1, prefix=prefix)
    return m


def noise_records(m: Metrics, t, rotatum, res: EstimationResult, phi_measured, phid_true,
                  window) -> Metrics:
    """How far the non-invasive estimator's inputs are from the truth: the observer's
    rotatum (the RLS target; ``rotatum_rms``, ``rotatum_uio_rms_error`` per joint), and
    the first difference of the measured deflections, the quantisation-limited
    counterpart of the regressor's φ̇ (``deflection_rate_rms``, ``..._rms_error``)."""
    mask = window_mask(t, window) & np.all(np.isfinite(res.tau_uio), axis=1)
    for i in range(rotatum.shape[1]):
        r = rotatum[mask, i]
        m.add("rotatum_rms", np.sqrt(np.mean(r ** 2)), "N m/s", joint=i + 1)
        m.add("rotatum_uio_rms_error", np.sqrt(np.mean((res.tau_uio[mask, i] - r) ** 2)),
              "N m/s", joint=i + 1)
    fd = np.vstack([np.full((1, phi_measured.shape[1]), np.nan),
                    np.diff(phi_measured, axis=0) / (t[1] - t[0])])
    mask[0] = False
    m.add("deflection_rate_rms", np.sqrt(np.mean(phid_true[mask] ** 2)), "rad/s")
    m.add("deflection_rate_rms_error", np.sqrt(np.mean((fd[mask] - phid_true[mask]) ** 2)),
          "rad/s")
    return m
