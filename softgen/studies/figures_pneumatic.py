"""Figures of the pneumatic and rigid studies (thesis chapters 6, 9 and 10).

Each function draws from traces (:class:`~softgen.runtime.simulate.Trace` or arrays)
and writes one PNG; no function computes a metric.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from softgen.runtime.simulate import Trace
from softgen.studies.plotting import envelope, save

#: Panels of :func:`gioste_runs`: signal, y label.
PANELS = {"q": "q [rad]", "sigma": "σ [N m/rad]", "nu": "ν [p per unit of Φ⊥]",
          "Pi_hat": "Π̂ [each its own unit, Π = π/K₁]", "V": "V [V]"}


def _save(fig: Figure, path, dpi: int) -> None:
    save(fig, path, dpi)


def _stop_time(tr: Trace) -> float:
    return float(tr.stopped_at if tr.stopped_at is not None else tr.t[-1])


def mark_stop(ax, runs: list[Trace]) -> None:
    """Clip a time axis to the simulated span of ``runs`` and mark their emergency stops."""
    ax.set_xlim(0.0, max(_stop_time(r) for r in runs))
    for r in runs:
        if r.stopped_at is not None:
            ax.axvline(r.stopped_at, color="r", lw=0.8, ls=":")


def gioste_runs(path, columns: list, parameter_names, titles: list[str] | None = None, *,
                labels=None, panels=tuple(PANELS)) -> None:
    """One column per entry of ``columns`` (a trace, or traces overlaid and named by
    ``labels``), one row per panel: q and σ (the map the controller reads, and −∂τ/∂q)
    against their references, ν, Π̂ and the valve voltages, as the thesis plots them
    (Fig. 10.6-10.13). Time axes end at the runs' emergency stops, marked and named."""
    fig = Figure(figsize=(5.5 * len(columns), 2.4 * len(panels)))
    # Shared time axis per column (mark_stop gives every panel of a column the same
    # limits): inner panels draw no tick labels, the costliest part of these figures.
    ax = fig.subplots(len(panels), len(columns), squeeze=False, sharex="col")
    titles = titles or ([f"run {j + 1}" for j in range(len(columns))] if len(columns) > 1
                        else ["run"])
    for j, col in enumerate(columns):
        col = list(col) if isinstance(col, (list, tuple)) else [col]
        for r, lab in zip(col, labels or [""] * len(col)):
            pre = f"{lab} " if lab else ""
            lines = {"q": [(r["plant.q"], "-", "q")], "nu": [(r["ctrl.nu"], "-", "ν")],
                     "sigma": [(r["stiff.sigma"], "-", "σ (map)")] + (
                         [(r["plant.sigma_physical"], ":", "σ (−∂τ/∂q)")] if not lab else []),
                     "Pi_hat": [(r["ctrl.Pi_hat"], "-", "")], "V": [(r["valves.V"], "-", "V")]}
            for a, panel in zip(ax[:, j], panels):
                for y, style, name in lines[panel]:
                    names = (list(parameter_names) if panel == "Pi_hat" else
                             [f"{name}{m // 2 + 1}{'ab'[m % 2]}" for m in range(y.shape[1])]
                             if panel == "V" else [f"{name}{i + 1}" for i in range(y.shape[1])])
                    a.plot(*envelope(r.t, y), style, lw=0.9, label=[pre + x for x in names])
        for a, panel in zip(ax[:, j], panels):
            if panel in ("q", "sigma"):
                a.plot(*envelope(col[0].t, col[0]["ref.q_d" if panel == "q" else
                                                    "ref.sigma_d"]), "k--", lw=0.7)
            a.set_ylabel(PANELS[panel])
            if j == 0:    # every column draws the same names: one legend per row
                a.legend(fontsize=6, loc="upper left")
            mark_stop(a, col)
        stops = [f"{lab or 'run'} stopped at {r.stopped_at:.4g} s" for r, lab in
                 zip(col, labels or [""] * len(col)) if r.stopped_at is not None]
        ax[0, j].set_title(titles[j] + (f" ({'; '.join(stops)})" if stops else ""), fontsize=9)
        ax[-1, j].set_xlabel("t [s]")
    _save(fig, path, 90)


def theorem5_tracking(out: Path, tr: Trace, Pi_nominal, parameter_names, phase_starts) -> None:
    """Fig. 10.2 (q, σ, pressures and ν per joint) and Fig. 10.3 (Π̂/Π) of section 10.2."""
    t, p = tr.t, tr["ctrl.p"]
    fig = Figure(figsize=(11, 10))
    ax = fig.subplots(4, 2, sharex=True)
    for j in range(2):
        for row, (ref, act, lbl, unit) in enumerate((("ref.q_d", "plant.q", "q", "rad"), (
                "ref.sigma_d", "plant.sigma", "σ", "N m/rad"))):
            ax[row, j].plot(t, tr[ref][:, j], "k--", lw=1, label=f"{lbl}_d")
            ax[row, j].plot(t, tr[act][:, j], lw=1, label=lbl)
            ax[row, j].set_ylabel(f"{lbl}{j + 1} [{unit}]")
        ax[2, j].plot(t, p[:, 2 * j] / 1e5, lw=1, label="p_a")
        ax[2, j].plot(t, p[:, 2 * j + 1] / 1e5, lw=1, label="p_b")
        ax[2, j].set_ylabel("pressure [bar]")
        ax[3, j].plot(t, tr["ctrl.nu"][:, j], lw=1)
        ax[3, j].set_ylabel(f"ν{j + 1} [p per unit of Φ⊥]")
        ax[3, j].set_xlabel("t [s]")
        for a in ax[:3, j]:
            a.legend(loc="upper left", fontsize=7)
        for t0 in phase_starts:
            for a in ax[:, j]:
                a.axvline(t0, color="0.7", lw=0.8)
    fig.suptitle("Theorem 5 on the two-link McKibben arm (cf. Fig. 10.2)")
    _save(fig, out / "fig10_2_tracking.png", 110)
    fig = Figure(figsize=(8, 4))
    ax = fig.subplots()
    ax.plot(t, tr["ctrl.Pi_hat"] / Pi_nominal, lw=1)
    ax.legend(parameter_names, fontsize=7, loc="upper right")
    ax.set(xlabel="t [s]", ylabel="Π̂ / Π [1]", title="Parameter estimates (cf. Fig. 10.3)")
    _save(fig, out / "fig10_3_parameters.png", 110)


def fl_comparison(out: Path, traces: dict, titles: list[str], Pi_nominal, parameter_names,
                  phase_starts) -> None:
    """Fig. 10.14 (q and σ against their references per case), tracking errors and Π̂/Π."""
    fig = Figure(figsize=(18, 7))
    ax = fig.subplots(2, 4, sharex=True, sharey="row")
    for k, (title, tr) in enumerate(zip(titles, traces.values())):
        for row, (y, lbl, unit) in enumerate((("q", "q", "rad"), ("sigma", "σ", "N m/rad"))):
            ax[row, k].plot(tr["t"], tr[f"{y}_d"], "k--", lw=0.8)
            ax[row, k].plot(tr["t"], tr[y], lw=1, label=[f"{lbl}{j + 1}" for j in range(2)])
            ax[row, 0].set_ylabel(f"{lbl} [{unit}] (dashed: {lbl}_d)")
            ax[row, k].legend(loc="upper right", fontsize=7)
            for t0 in phase_starts:
                ax[row, k].axvline(t0, color="0.8", lw=0.8)
        ax[0, k].set_title(title, fontsize=10)
        ax[1, k].set_xlabel("t [s]")
    fig.suptitle("Positions and stiffnesses, FL against Theorem 5 (cf. Fig. 10.14)")
    _save(fig, out / "fig10_14_comparison.png", 100)
    fig = Figure(figsize=(16, 4))
    ax = fig.subplots(1, 3)
    for name, tr in traces.items():
        for a, y, lbl in zip(ax, ("q", "sigma"), ("q_i − q_d,i| [rad]", "σ_i − σ_d,i| [N m/rad]")):
            a.semilogy(tr["t"], np.maximum(np.abs(tr[y] - tr[f"{y}_d"]).max(axis=1), 1e-12),
                       lw=0.8, label=name)
            a.set_ylabel(f"max_i |{lbl}")
    for name, style in (("adaptive_exact", "--"), ("adaptive_1pct", "-")):
        ax[2].set_prop_cycle(None)
        ax[2].plot(traces[name]["t"], traces[name]["Pi_hat"] / Pi_nominal, style, lw=0.8,
                   label=parameter_names if style == "-" else None)
    ax[2].set_ylabel("Π̂ / Π [1] (solid: Π̂(0) = 0.99 Π, dashed: Π̂(0) = Π)")
    for a in ax:
        a.set_xlabel("t [s]")
        a.legend(loc="upper right", fontsize=7)
    _save(fig, out / "fig10_14_errors.png", 100)


def adaptive_tracking(out: Path, t, err, P, names, nominal) -> None:
    """Tracking error (linear and log) and the estimates against their true values (Prop. 10)."""
    fig = Figure(figsize=(8, 6))
    ax = fig.subplots(2, 1, sharex=True)
    for i in range(err.shape[1]):
        ax[0].plot(t, err[:, i], lw=1, label=f"joint {i + 1}")
    ax[0].set_ylabel("q_d - q [rad]")
    ax[0].legend(fontsize=8, loc="upper right")
    ax[0].set_title("Slotine-Li adaptive tracking, planar_2link, pi_hat(0) = 0")
    ax[1].plot(t, np.abs(err), lw=1)
    ax[1].set(yscale="log", ylabel="|q_d - q| [rad]", xlabel="t [s]")
    _save(fig, out / "tracking_error.png", 110)
    fig = Figure(figsize=(8, 4))
    ax = fig.subplots()
    # Each estimate over its true value: one unit for parameters of several (issue 32).
    scale = np.where(np.asarray(nominal, dtype=float) == 0, 1.0, np.asarray(nominal, dtype=float))
    for j, name in enumerate(names):
        ax.plot(t, P[:, j] / scale[j], lw=1, label=name)
    ax.axhline(1.0, color="0.5", ls=":", lw=1)
    ax.set(xlabel="t [s]", ylabel="π̂_i / π_i [1]",
           title="Base-parameter estimates over their true values (dotted: 1)")
    ax.legend(fontsize=7, loc="upper right")
    _save(fig, out / "parameter_estimates.png", 110)


def robustness(path, errors: dict[str, dict[str, np.ndarray]], tolerances: dict[str, float],
               sizes, tracks, runaway, title: str) -> None:
    """Per study the bounded samples' phase-3 rms errors against the ch10 tolerances;
    tracking and runaway fractions against the muscle-length error."""
    fig = Figure(figsize=(12, 4.2))
    ax = fig.subplots(1, 3)
    names = list(errors)
    for k, (key, label) in enumerate((("pos", "position rms, phase 3 [rad]"),
                                      ("sti", "stiffness rms, phase 3 [N m/rad]"))):
        for i, name in enumerate(names):
            v = errors[name][key]
            v = v[np.isfinite(v)]
            jitter = np.random.default_rng(i).uniform(-0.25, 0.25, v.size)
            ax[k].scatter(i + jitter, np.clip(v, 1e-7, 1e6), s=5, alpha=0.5)
        ax[k].axhline(tolerances[key], color="k", ls="--", lw=0.8, label="ch10 tolerance")
        ax[k].set_yscale("log")
        ax[k].set_xticks(range(len(names)), names, rotation=35, fontsize=7, ha="right")
        ax[k].set_xlabel("study [name]", fontsize=8)
        ax[k].set_ylabel(label + " (bounded samples)", fontsize=8)
        ax[k].legend(fontsize=7)
    ax[2].plot(np.array(sizes) * 100, tracks, "o-", label="tracks (ch10 tolerance)")
    ax[2].plot(np.array(sizes) * 100, runaway, "s--", label="runaway (> 1 rad)")
    ax[2].set(xscale="log", xlabel="muscle length error [± %]", ylabel="fraction of samples [1]")
    ax[2].legend(fontsize=7)
    fig.suptitle(title)
    _save(fig, path, 110)


def pendulum_tracking(path, t, q, q_d, sigma, sigma_d, p) -> None:
    """Position and stiffness against their references, and the pressures (bar)."""
    fig = Figure(figsize=(7, 7))
    ax = fig.subplots(3, 1, sharex=True)
    for a, ys, labels, unit in ((ax[0], (q_d, q), ("q_d", "q"), "q [rad]"),
                                (ax[1], (sigma_d, sigma), ("sigma_d", "sigma"),
                                 "sigma [N m/rad]"),
                                (ax[2], (p[:, :1] / 1e5, p[:, 1:] / 1e5), ("p_a", "p_b"),
                                 "pressure [bar]")):
        for y, lab in zip(ys, labels):
            a.plot(t, y, label=lab)
        a.set_ylabel(unit)
        a.legend(loc="upper left")
    ax[2].set_xlabel("t [s]")
    _save(fig, path, 100)
