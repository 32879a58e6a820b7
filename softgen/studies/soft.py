"""The simulation studies of thesis §12.2 as reusable pieces: loops, scenarios, records, figures.

A :class:`SoftLoop` is a closed-loop diagram of Theorem 10 on a soft robot
(references → controller → plant, a disturbance-force block, pre-generated
measurement noise as the external input ``noise``) together with the names of its
signals, so that every study reads q, π̂ and τ the same way whether the loop is
the continuous-time block of the stiff lumped-mass models
(:func:`tracking_loop`) or the sampled controller and plant of the affine
pendulum (:func:`sampled_loop`). A :class:`SoftCase` is one run of §12.2: gains,
noise, disturbance, initial error; :func:`run_cases` runs each as a
:class:`~softgen.studies.Scenario` through the one driver and reads the traces.

Records (:func:`tracking_records`), with e(t) = q_d(t) − q(t) the configuration
error (rad, or m for pcc-3d) of the true state:

- ``position_rms_error``: rms of ‖e(t)‖₂ over the last ``window`` seconds;
- ``position_max_error_final``: max of ‖e(t)‖₂ over the same window;
- ``parameter_estimate_max_ratio``: max over the run of ‖π̂(t)‖₂ / ‖π‖₂, π the model's
  true base parameters (a norm over parameters of different units, so relative to the
  truth: one unit, "1"; issue 32);
- ``parameter_estimate_norm_drift``: relative change of ‖π̂‖ along its trend over the
  second half of the run;
- ``input_max_abs``: max over the run and the actuators of |τ_i(t)|;
- ``convergence_time``: the first time after which ‖e‖ stays below ``band``;
- ``position_rms_error_initial``: rms of ‖e‖ over the first ``initial`` seconds;
- ``force_estimate_<name>_final`` (loops with force columns): the adapted force f̂ at
  the end of the run, per parameter (N).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from softgen.blocks import Block, ClosedLoop
from softgen.control.soft import (backbone_samples, closed_loop_block, controller_block,
                                  force_groups, force_names, plant_block, tip_force_block)
from softgen.core.config import Config
from softgen.core.metrics import Metrics
from softgen.studies.indices import norm_drift
from softgen.studies.plotting import save
from softgen.studies.scenario import Scenario
from softgen.symbolic.pcc import LinearRoute, SoftDynamics


@dataclass(frozen=True)
class SoftLoop:
    """A §12.2 diagram and where its signals live.

    ``plant`` is the block holding the true ``q``/``qd``, ``ctrl`` the block holding
    ``pi_hat``, ``tau`` and the gains ``lam``, ``kd``, ``kpi``; the reference block is
    ``ref`` and the disturbance ``dist``. ``forces``: the names of the adapted force
    parameters (force columns, :func:`softgen.control.soft.force_names`), whose estimate
    ``f_hat`` and gain ``kf`` the controller block then holds too.
    """

    diagram: ClosedLoop
    dyn: SoftDynamics
    plant: str
    ctrl: str
    r: int
    forces: tuple[str, ...] = ()

    @property
    def record(self) -> tuple[str, ...]:
        return ("ref.q_d", f"{self.plant}.q", f"{self.ctrl}.tau", f"{self.ctrl}.pi_hat") + \
            ((f"{self.ctrl}.f_hat",) if self.forces else ())

    def params(self, sc: SoftCase) -> dict:
        return {f"{self.ctrl}.lam": sc.lam, f"{self.ctrl}.kd": sc.kd,
                f"{self.ctrl}.kpi": sc.kpi, "dist.force": sc.force, "dist.t_on": sc.t_on,
                **({f"{self.ctrl}.kf": sc.kf} if self.forces else {})}

    def x0(self, q0, qd0) -> dict:
        return {f"{self.plant}.q": q0, f"{self.plant}.qd": qd0}


def tracking_loop(name: str, dyn: SoftDynamics, ref: Block, dt: float,
                  lin: LinearRoute | None = None, *, forces=()) -> SoftLoop:
    """References ``ref`` → continuous-time Theorem 10 + plant (one ROS2 step per sample),
    tip forces from ``dist``, noise from ``ext.noise`` (planar and 3D PCC). ``forces``:
    force columns (:func:`softgen.control.soft.force_groups`), default none."""
    lin = LinearRoute(dyn) if lin is None else lin
    n = dyn.model.dof
    groups = force_groups(dyn, forces)
    d = ClosedLoop(name, [ref, tip_force_block("dist", dyn.model.n_segments),
                          closed_loop_block(dyn, dt, lin=lin, forces=groups)],
                   externals={"noise": 2 * n})
    return SoftLoop(d, dyn, "loop", "loop", lin.r, tuple(force_names(dyn, groups)))


def sampled_loop(name: str, dyn: SoftDynamics, ref: Block, dt: float,
                 lin: LinearRoute | None = None, *, forces=()) -> SoftLoop:
    """References → sampled Theorem 10 (τ held) → plant (ROS2), the controller reading
    the noisy measurement ``plant.q_meas``/``qd_meas`` (the affine pendulum). ``forces``:
    force columns (:func:`softgen.control.soft.force_groups`), default none."""
    lin = LinearRoute(dyn) if lin is None else lin
    n = dyn.model.dof
    groups = force_groups(dyn, forces)
    d = ClosedLoop(name, [ref, tip_force_block("dist", dyn.model.n_segments),
                          controller_block(dyn, dt, lin=lin, forces=groups),
                          plant_block(dyn, dt)],
                   [("plant.q_meas", "ctrl.q"), ("plant.qd_meas", "ctrl.qd")],
                   externals={"noise": 2 * n})
    return SoftLoop(d, dyn, "plant", "ctrl", lin.r, tuple(force_names(dyn, groups)))


@dataclass(frozen=True)
class SoftStudyConfig(Config):
    """What the §12.2 studies share (:func:`run_cases` reads these): the run, sensing
    noise (case j seeded ``noise_seed`` + j), disturbance time, metric windows, shapes.
    Each experiment's config subclasses it with its own values."""

    model: str = ""
    dt: float = 1e-3                     # s
    duration: float = 0.0                # s
    noise_std: float = 0.0               # rad (or m)
    noise_seed: int = 0
    t_disturbance: float = 0.0           # s, tip forces from here
    noise_on_velocity: bool = False
    noise_reason: str = (
        "§12.2 puts the noise on 'each configuration variable'; q̇ is read clean. Measured: "
        "with the same σ on q̇ too, 5 of 6 seeds (1201-1206) of the planar disturbed "
        "scenario diverged between t = 31 and 44 s, all 6 converged with q only")
    metric_window: float = 10.0          # s, position_rms_error over the last window
    convergence_band: float = 0.05       # rad (or m), for convergence_time
    initial_window: float = 5.0          # s, for position_rms_error_initial
    shapes: int = 9
    shape_window: float = 2 * np.pi      # s: one period of the references, at the end

    def validate(self) -> None:
        if self.duration <= self.metric_window:
            raise ValueError(f"duration: expected more than metric_window, got {self.duration}")

    def cases(self, n_segments: int, rows) -> list[SoftCase]:
        """(suffix, gains, noisy, force, direction, e(0)[, noise index]) rows as cases,
        forces on from ``t_disturbance``, noise ``noise_std`` where noisy. Gains
        (Λ, K_d, K_π) or, for a loop with force columns, (Λ, K_d, K_π, K_f). The noise
        index (default the row's position) picks the seed: a variant given the index of
        the case it is compared with sees the same noise."""
        return [SoftCase.of(sfx, g, self.noise_std if noisy else 0.0, f, d, n_segments,
                            self.t_disturbance, e0, *k) for sfx, g, noisy, f, d, e0, *k in rows]


@dataclass(frozen=True)
class SoftCase:
    """One run: name suffix, gains (scalars: Λ = λI, K_d = k_d I, K_π = k_π I), noise
    standard deviation (0: ideal sensing), tip force (3 per tip) from ``t_on``, the
    initial tracking error e(0) = q_d(0) − q(0), K_f = k_f I (force columns only) and
    the noise index (seed ``noise_seed`` + index; None: the case's position)."""

    suffix: str
    lam: float
    kd: float
    kpi: float
    noise_std: float
    force: tuple[float, ...]
    t_on: float
    initial_error: tuple[float, ...]
    kf: float = 0.0
    noise_index: int | None = None

    @classmethod
    def of(cls, suffix: str, gains, noise_std: float, force: float, direction,
           n_segments: int, t_on: float, initial_error,
           noise_index: int | None = None) -> SoftCase:
        """The case with ``force`` along ``direction`` on every tip (:func:`tip_forces`);
        ``gains`` (Λ, K_d, K_π) or (Λ, K_d, K_π, K_f)."""
        lam, kd, kpi, *kf = gains
        return cls(suffix, lam, kd, kpi, noise_std, tip_forces(force, direction, n_segments),
                   t_on, tuple(initial_error), *(kf or [0.0]), noise_index)


def noise_sequence(steps: int, n: int, std: float, seed: int, *,
                   on_velocity: bool = True) -> np.ndarray:
    """Seeded Gaussian measurement noise (steps × 2n) for (q, q̇); zeros where std = 0."""
    if std == 0:
        return np.zeros((steps, 2 * n))
    e = np.random.default_rng(seed).normal(0.0, std, (steps, 2 * n))
    if not on_velocity:
        e[:, n:] = 0.0
    return e


def tip_forces(magnitude: float, direction, n_segments: int) -> tuple[float, ...]:
    """The same force, ``magnitude`` along the unit ``direction``, on every tip."""
    d = np.asarray(direction, dtype=float)
    return tuple(np.tile(magnitude * d / np.linalg.norm(d), n_segments).tolist())


def convergence_time(t: np.ndarray, err: np.ndarray, band: float) -> float:
    """First time after which ``err`` stays below ``band`` (inf if it ends above)."""
    above = np.flatnonzero(err >= band)
    if not above.size:
        return float(t[0])
    if above[-1] == len(t) - 1:
        return float("inf")
    return float(t[above[-1] + 1])


def tracking_records(t, q_d, q, pi_hat, tau, *, unit: str, window: float, band: float,
                     initial: float, suffix: str = "", pi_true) -> Metrics:
    """The §12.2 records of one scenario (module docstring); ``pi_true``: the plant's base
    parameters π, what ‖π̂‖ is measured against."""
    e = np.linalg.norm(q_d - q, axis=1)
    last = t >= t[-1] - window
    first = t <= t[0] + initial
    m = Metrics()
    m.add("position_rms_error", np.sqrt(np.mean(e[last] ** 2)), unit, suffix=suffix)
    m.add("position_max_error_final", e[last].max(), unit, suffix=suffix)
    norm = np.linalg.norm(pi_hat, axis=1)
    m.add("parameter_estimate_max_ratio", norm.max() / np.linalg.norm(pi_true), "1",
          suffix=suffix)
    m.add("parameter_estimate_norm_drift", norm_drift(t, norm), "1", suffix=suffix)
    m.add("input_max_abs", np.abs(tau).max(), "N m, N" if unit == "m" else "N m",
          suffix=suffix)
    m.add("convergence_time", convergence_time(t, e, band), "s", suffix=suffix)
    m.add("position_rms_error_initial", np.sqrt(np.mean(e[first] ** 2)), unit, suffix=suffix)
    return m


def shape_trace(dyn: SoftDynamics, Q: np.ndarray, per_segment: int = 8) -> np.ndarray:
    """Backbone points (len(Q) × points × 3) of the configurations ``Q`` (rows)."""
    return backbone_samples(dyn.backbone_fun(), Q, dyn.model.n_segments, per_segment)


def scenario_figure(t, q_d, q, pi_hat, tau, shapes, *, title: str, unit: str,
                    three_d: bool = False, t_on: float | None = None,
                    pi_true=None) -> Figure:
    """Two rows like Fig. 12.2-12.7: configuration and reference (dashed), errors
    θ̃ = q_d − q, estimates π̂ (each over its true value ``pi_true`` when given: one unit
    for parameters of many); inputs τ, ‖θ̃‖ (log), shape trace (backbone drawn at
    several instants, darker = later; 3D axes for pcc-3d)."""
    k = max(1, len(t) // 4000)           # enough points for a figure
    t, q_d, q, pi_hat, tau = (a[::k] for a in (t, q_d, q, pi_hat, tau))
    fig = Figure(figsize=(14, 8))
    axs = [fig.add_subplot(2, 3, k) for k in range(1, 6)]
    ax_s = fig.add_subplot(2, 3, 6, projection="3d" if three_d else None)
    colors = [f"C{i % 10}" for i in range(q.shape[1])]
    k = len(shapes)
    for i in range(q.shape[1]):
        axs[0].plot(t, q[:, i], lw=0.9, color=colors[i])
        axs[0].plot(t, q_d[:, i], "--", lw=0.8, color=colors[i])
        axs[1].plot(t, q_d[:, i] - q[:, i], lw=0.8, color=colors[i])
    axs[0].set_ylabel(f"q, q_d [{unit}]")
    axs[1].set_ylabel(f"q_d - q [{unit}]")
    if pi_true is not None:
        axs[2].plot(t, pi_hat / np.asarray(pi_true, dtype=float).ravel(), lw=0.7)
        axs[2].axhline(1.0, color="0.5", lw=0.6, ls=":")
        axs[2].set_ylabel("π̂_i / π_i [1] (base parameters)")
    else:
        axs[2].plot(t, pi_hat, lw=0.7)
        axs[2].set_ylabel("π̂ [units of each base parameter]")
    axs[3].plot(t, tau, lw=0.7)
    axs[3].set_ylabel("tau [N m" + (", N]" if unit == "m" else "]"))
    axs[4].semilogy(t, np.maximum(np.linalg.norm(q_d - q, axis=1), 1e-12), lw=0.8, color="k")
    axs[4].set_ylabel(f"||q_d - q|| [{unit}]")
    for a in axs:
        a.set_xlabel("t [s]")
        if t_on is not None and t_on < t[-1]:
            a.axvline(t_on, color="0.6", lw=0.8, ls=":")
    for j, P in enumerate(shapes):
        shade = f"{max(0.0, 0.8 * (1 - j / max(k - 1, 1))):.3f}"
        if three_d:
            ax_s.plot(P[:, 0], P[:, 1], P[:, 2], color=shade, lw=1.2)
        else:
            ax_s.plot(P[:, 0], P[:, 1], color=shade, lw=1.2)
    ax_s.set_xlabel("x [m]")
    ax_s.set_ylabel("y [m]")
    if three_d:
        ax_s.set_zlabel("z [m]")
    else:
        ax_s.set_aspect("equal", adjustable="datalim")
    ax_s.set_title("shape trace (darker = later)", fontsize=9)
    fig.suptitle(title)
    return fig


def run_cases(loop: SoftLoop, cases: list[SoftCase], c: SoftStudyConfig, out: Path,
              label: str, figures: dict[str, str], unit: str) -> Metrics:
    """Every case on the same diagram (one compilation): :func:`tracking_records`, a
    :func:`scenario_figure` per case (file names by suffix in ``figures``) and traces."""
    d, n = loop.diagram, loop.dyn.model.dof
    steps = int(round(c.duration / c.dt))
    ref = d.blocks["ref"]
    r0 = ref.outputs.split(ref.eval(u=[0.0])[1])
    m, wall = Metrics(), 0.0
    for j, sc in enumerate(cases):
        k = j if sc.noise_index is None else sc.noise_index
        noise = noise_sequence(steps, n, sc.noise_std, c.noise_seed + k,
                               on_velocity=c.noise_on_velocity)
        tr = Scenario(f"{label}{sc.suffix}", d, steps=steps, params=loop.params(sc),
                      x0=loop.x0(r0["q_d"] - np.array(sc.initial_error), r0["qd_d"]),
                      externals={"noise": noise}, record=loop.record).run()
        wall += tr.wall_seconds
        q_d, q = tr["ref.q_d"], tr[f"{loop.plant}.q"]
        tau, pi_hat = tr[f"{loop.ctrl}.tau"], tr[f"{loop.ctrl}.pi_hat"]
        pi_true = np.asarray(loop.dyn.parameter_nominal, dtype=float).ravel()
        m.extend(tracking_records(tr.t, q_d, q, pi_hat, tau, unit=unit, window=c.metric_window,
                                  band=c.convergence_band, initial=c.initial_window,
                                  suffix=sc.suffix.lstrip("_"), pi_true=pi_true))
        # Shape trace: ``shapes`` instants over the last ``shape_window`` s (0: the run).
        t0 = tr.t[-1] - c.shape_window if c.shape_window > 0 else tr.t[0]
        rows = np.searchsorted(tr.t, np.linspace(max(t0, tr.t[0]), tr.t[-1], c.shapes))
        fig = scenario_figure(tr.t, q_d, q, pi_hat, tau, shape_trace(loop.dyn, q[rows]),
                              title=f"{label}{sc.suffix}: Λ = {sc.lam:g}, K_d = {sc.kd:g}, "
                                    f"K_π = {sc.kpi:g}, noise σ = {sc.noise_std:g}, "
                                    f"|f| = {np.linalg.norm(sc.force[:3]):g} N",
                              unit=unit, three_d=unit == "m",
                              t_on=sc.t_on if any(sc.force) else None, pi_true=pi_true)
        if loop.forces:    # the adapted forces at the end of the run (force columns)
            f_end = tr[f"{loop.ctrl}.f_hat"][-1]
            for nm, v in zip(loop.forces, f_end):
                m.add(f"force_estimate_{nm}_final", v, "N", suffix=sc.suffix.lstrip("_"))
        save(fig, out / figures[sc.suffix], dpi=90)
        tr.save(out / f"traces{sc.suffix}.npz")
    m.add("simulated_seconds_per_wall_second", len(cases) * c.duration / wall, "s/s")
    return m


__all__ = ["SoftLoop", "SoftStudyConfig", "SoftCase", "run_cases", "tracking_loop", "sampled_loop", "noise_sequence",
           "tip_forces", "convergence_time", "tracking_records", "shape_trace",
           "scenario_figure"]
