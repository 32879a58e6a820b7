"""Error indices of the estimation chapters (section 6.1.3) as metric records.

MSE and MSREP (in percent: 100 · mean(((χ − χ̂)/χ)²), NOTES section 2 item 9) over a
metric window, per joint, of stiffness and torque (or rotatum) estimates; the
figure of estimates against truth.
"""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from softgen.core.metrics import Metrics
from softgen.estimation.offline import EstimationResult


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
    are drawn every few samples: at most ~20 000 points per line)."""
    n = truth_sigma.shape[1]
    d = slice(None, None, max(1, len(t) // 20000))
    t, truth_sigma, truth_tau = t[d], truth_sigma[d], truth_tau[d]
    res = EstimationResult(res.sigma_hat[d], res.tau_hat[d], res.tau_uio[d], res.updating[d],
                           {r: v[d] for r, v in res.theta.items()}, res.delay,
                           res.wall_seconds)
    fig = Figure(figsize=(5.5 * n, 9))
    ax = fig.subplots(4, n, sharex=True, squeeze=False)
    for i in range(n):
        ax[0, i].plot(t, truth_tau[:, i], "k", lw=1.2, label="true")
        ax[0, i].plot(t, res.tau_hat[:, i], "--", lw=1, label="RLS model")
        ax[0, i].plot(t, res.tau_uio[:, i], ":", lw=0.8, label="observer")
        ax[0, i].set_ylabel(torque_label)
        ax[0, i].set_title(f"{title}, joint {i + 1}")
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_tau = 100 * (res.tau_hat[:, i] - truth_tau[:, i]) / truth_tau[:, i]
            rel_sig = 100 * (res.sigma_hat[:, i] - truth_sigma[:, i]) / truth_sigma[:, i]
        ax[1, i].plot(t, truth_sigma[:, i], "k", lw=1.2, label="true")
        ax[1, i].plot(t, res.sigma_hat[:, i], "--", lw=1, label="estimate")
        ax[1, i].set_ylabel("sigma [N m/rad]")
        ax[2, i].semilogy(t, np.abs(rel_sig), lw=0.8, label="stiffness")
        ax[2, i].semilogy(t, np.abs(rel_tau), lw=0.8, label="torque")
        ax[2, i].set_ylabel("|relative error| [%]")
        for r, th in res.theta.items():
            if int(r.rstrip("ab")[len("joint"):]) - 1 == i:
                for j in range(th.shape[1]):
                    ax[3, i].plot(t, th[:, j], lw=0.8, label=f"{r} {names[r][j]}")
        ax[3, i].set_ylabel("RLS parameters")
        ax[3, i].set_yscale("symlog", linthresh=1e-3)
        ax[3, i].set_xlabel("t [s]")
        for a in ax[:, i]:
            a.legend(fontsize=6, ncol=2, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


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
        m.add("update_fraction", upd[ph == k].mean(), "", phase=k + 1, prefix=prefix)
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
