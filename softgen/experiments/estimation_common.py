"""Shared pieces of the stiffness-estimation experiments (thesis chapters 6 and 7).

Compiling an experiment's functions, the sensor model of the hardware emulations,
the thesis's error indices and the figures they share.
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

from ..codegen.build import find_compiler
from ..codegen.generate import BundleSpec, Generated, signature, write_bundle
from ..estimation.estimators import rls_joint
from ..estimation.offline import EstimationResult
from ..runtime.library import Bundle, BundleFunction


def load_functions(name: str, functions: list[tuple[ca.Function, str]], out: Path,
                   config: dict) -> dict[str, BundleFunction]:
    """Generate, compile and load ``functions`` as bundle ``out/bundle/<name>``.

    Without a C compiler the casadi.Functions are evaluated directly (a warning says so).
    """
    if find_compiler() is None:
        warnings.warn(f"{name}: no C compiler found; evaluating with CasADi (slower)",
                      RuntimeWarning, stacklevel=2)
        return {f.name(): BundleFunction(f, signature(f)) for f, _ in functions}
    identity = json.dumps(config, sort_keys=True, default=str).encode()
    spec = BundleSpec(name=name, functions=[Generated(f, doc) for f, doc in functions],
                      identity=identity, extra={"experiment_config": json.loads(identity)})
    path = write_bundle(spec, Path(out) / "bundle")
    return Bundle(path).functions


# -- sensors ---------------------------------------------------------------------------

def quantize(x: np.ndarray, counts_per_rev: int | None) -> np.ndarray:
    """An incremental encoder's reading: the angle rounded to 2π/counts."""
    if not counts_per_rev:
        return x
    step = 2 * np.pi / counts_per_rev
    return np.round(x / step) * step


def noisy(x: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    return x + std * rng.standard_normal(x.shape) if std else x


# -- error indices (section 6.1.3) ----------------------------------------------------------

def mse(true: np.ndarray, est: np.ndarray) -> float:
    """Mean square error (section 6.1.3)."""
    return float(np.mean((true - est) ** 2))


def msrep(true: np.ndarray, est: np.ndarray) -> float:
    """Mean square relative error, in percent: 100 · mean(((χ − χ̂)/χ)²) (section 6.1.3).

    Samples where the true value is exactly zero are left out (the ratio is undefined).
    """
    ok = true != 0
    return float(100.0 * np.mean(((true[ok] - est[ok]) / true[ok]) ** 2))


def window_mask(t: np.ndarray, window: list[float] | None, valid: np.ndarray) -> np.ndarray:
    """Samples in ``window`` = [t0, t1] (default: after the first 10 % of the run)."""
    t0, t1 = (0.1 * t[-1], t[-1]) if window is None else window
    return (t >= t0) & (t <= t1) & valid


def error_metrics(t, truth_sigma, truth_tau, res: EstimationResult, window,
                  *, torque: str = "tau_hat") -> tuple[dict, list[float]]:
    """Per joint stiffness and torque MSE / MSREP over the metric window."""
    est_tau = getattr(res, torque)
    valid = np.all(np.isfinite(res.sigma_hat), axis=1)
    mask = window_mask(t, window, valid)
    out = {}
    for i in range(truth_sigma.shape[1]):
        j = i + 1
        out[f"stiffness_mse_joint{j}"] = mse(truth_sigma[mask, i], res.sigma_hat[mask, i])
        out[f"stiffness_msrep_joint{j}"] = msrep(truth_sigma[mask, i], res.sigma_hat[mask, i])
        out[f"torque_mse_joint{j}"] = mse(truth_tau[mask, i], est_tau[mask, i])
        out[f"torque_msrep_joint{j}"] = msrep(truth_tau[mask, i], est_tau[mask, i])
    tw = t[mask]
    return out, [float(tw[0]), float(tw[-1])]


# -- figures ------------------------------------------------------------------------------------

def estimation_figures(out: Path, t, truth_sigma, truth_tau, res: EstimationResult, *,
                       title: str, torque_label: str = "tau_e [N m]", prefix: str = "",
                       names: dict | None = None) -> None:
    """Estimate against truth, relative error, and RLS parameters over time."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = truth_sigma.shape[1]
    fig, ax = plt.subplots(4, n, figsize=(5.5 * n, 9), sharex=True, squeeze=False)
    for i in range(n):
        ax[0, i].plot(t, truth_tau[:, i], "k", lw=1.2, label="true")
        ax[0, i].plot(t, res.tau_hat[:, i], "--", lw=1, label="RLS model")
        ax[0, i].plot(t, res.tau_uio[:, i], ":", lw=0.8, label="observer")
        ax[0, i].set_ylabel(torque_label)
        ax[0, i].set_title(f"{title}, joint {i + 1}")
        ax[0, i].legend(fontsize=7)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_tau = 100 * (res.tau_hat[:, i] - truth_tau[:, i]) / truth_tau[:, i]
            rel_sig = 100 * (res.sigma_hat[:, i] - truth_sigma[:, i]) / truth_sigma[:, i]
        ax[1, i].plot(t, truth_sigma[:, i], "k", lw=1.2, label="true")
        ax[1, i].plot(t, res.sigma_hat[:, i], "--", lw=1, label="estimate")
        ax[1, i].set_ylabel("sigma [N m/rad]")
        ax[1, i].legend(fontsize=7)
        ax[2, i].semilogy(t, np.abs(rel_sig), lw=0.8, label="stiffness")
        ax[2, i].semilogy(t, np.abs(rel_tau), lw=0.8, label="torque")
        ax[2, i].set_ylabel("|relative error| [%]")
        ax[2, i].legend(fontsize=7)
        for r, th in res.theta.items():
            if rls_joint(r) == i:
                for j in range(th.shape[1]):
                    label = (names or {}).get(r, [f"pi{jj}" for jj in range(th.shape[1])])[j]
                    ax[3, i].plot(t, th[:, j], lw=0.8, label=f"{r} {label}")
        ax[3, i].set_ylabel("RLS parameters")
        ax[3, i].set_yscale("symlog", linthresh=1e-3)
        ax[3, i].legend(fontsize=6, ncol=2)
        ax[3, i].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(Path(out) / f"{prefix}estimation.png", dpi=100)
    plt.close(fig)

