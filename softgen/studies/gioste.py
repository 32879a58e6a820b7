"""Runs on the emulated GioSte (section 10.3): gains, start, scenario, trace reads.

The hardware emulation and its closed loop are :mod:`softgen.plants.gioste`; this
module sets up and runs it: :func:`controller_gains` (a :class:`Theorem5Gains` with
K̂ calibrated on the maps), :func:`initial_state` (the arm at rest under the first
command), :func:`scenario` / :func:`run` (one :class:`~softgen.studies.Scenario`
through the one driver, returned as a :class:`~softgen.runtime.simulate.Trace` padded
to the reference's length), and the reads of such a trace that the chapter-10 indices
need (errors counted after an emergency stop, oscillation, feasibility).
"""
from __future__ import annotations

import warnings

import casadi as ca
import numpy as np

from softgen.control.feasibility import PressureViolation, PressureWarning, check_pressures
from softgen.control.pneumatic import pneumatic_arm
from softgen.modelfile.model import RobotModel
from softgen.modelfile.load import load_model
from softgen.plants.gioste import (STOP_SIGNALS, V_MAX, GiosteEmulation, HardwareConfig,
                                   delay_samples, emergency_stop, equilibrium, fitted_model,
                                   kpi_vector, loop_diagram, reference_layout)
from softgen.runtime.simulate import Trace
from softgen.studies.gains import Theorem5Gains, thesis_to_physical
from softgen.studies.scenario import Scenario

#: Signals a run records: the stop's, and what metrics and figures read.
RECORD = (*STOP_SIGNALS, "ref.sigma_d", "stiff.sigma", "plant.sigma_physical", "ctrl.nu",
          "ctrl.Pi_hat", "valves.V", "valves.V_raw")


def controller_gains(emu: GiosteEmulation, kd, lam, kpi: float, sigma_range, *,
                     stiffness_rate: float, per_g2: bool = True) -> Theorem5Gains:
    """Theorem 5's gains on GioSte: the printed K_d, Λ per joint and K_π (by
    :func:`~softgen.plants.gioste.kpi_vector`) in physical units
    (:func:`~softgen.studies.gains.thesis_to_physical`, the fitted muscles' K_g R), and K̂
    calibrated over ``sigma_range`` (:meth:`GiosteEmulation.calibrated_gain`) in
    K_σ = rate/K̂ and K̂⁻¹."""
    khat = emu.calibrated_gain(sigma_range)
    vec = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (emu.n,)).copy()  # noqa: E731
    kd_phys, kpi_phys = thesis_to_physical(emu.arm.act.muscle_gain, vec(kd),
                                           kpi_vector(emu.arm, kpi, per_g2=per_g2))
    return Theorem5Gains.from_stiffness_rate(stiffness_rate, lam=vec(lam), kd=kd_phys,
                                             kpi=kpi_phys, khat=khat)


def initial_state(emu: GiosteEmulation, kind: str, ref0: np.ndarray, gains: Theorem5Gains, *,
                  Pi_hat0: np.ndarray, dt: float) -> dict:
    """``x0`` of :func:`~softgen.plants.gioste.loop_diagram`: the arm at rest under the
    first command.

    The controller's first command is the preset of section 10.2
    (:meth:`~softgen.control.pneumatic.PneumaticArm.preset`) at q = q_d(0); the muscles
    are at those pressures (inflated beforehand), the delay line full of them, and the
    arm rests where they hold it (:func:`~softgen.plants.gioste.equilibrium`).
    """
    n = emu.n
    q0, zero = ref0[reference_layout(n).slice("q_d")].copy(), np.zeros(n)
    p0, nu0 = emu.arm.preset(Pi_hat0, q0, ref0, lam=gains.lam, kd=gains.kd, kinv=gains.kinv,
                             dt=dt)
    V0, tgt0, _ = (np.array(v).ravel() for v in emu.interface_fun()(p0))
    q_start = equilibrium(emu, tgt0, q0)
    d = delay_samples(emu.hw, dt)
    x0 = {"plant.q": q_start, "plant.qd": zero, "plant.p": tgt0, "stiff.V_prev": V0,
          "vel.q_prev": np.floor(q_start / emu.encoder_step + 0.5) * emu.encoder_step,
          "vel.v_prev": zero, "ctrl.Pi_hat": Pi_hat0}
    if d:
        x0["delay.p_target_line"] = np.tile(tgt0, d)
    if kind in ("theorem5", "corollary2"):
        x0["ctrl.nu"] = nu0
    return x0


def static_net_stiffness(emu: GiosteEmulation, kind: str, ref0: np.ndarray,
                         gains: Theorem5Gains, *, Pi_hat0: np.ndarray, dt: float = 1e-3,
                         h: float = 1e-4) -> np.ndarray:
    """−∂(τ − G)/∂q of the arm under the controller's first command law, state frozen.

    The controller's pressures at (q, q̇ = 0) with ν (the preset's) and Π̂ held (K_π = 0)
    are applied as steady pressures; the emulated arm's torque minus gravity is
    differentiated in q by central differences of step ``h``. In the controller's own
    model this is −∂(K Φ p − G)/∂q with K Φ p = τ_*: the null-space pressures cancel the
    muscles' stiffness exactly. A negative value means the arm falls away from the start
    faster than the (weak) feedback can act.
    """
    n, kappa = emu.n, emu.arm.n_params
    zero = np.zeros(n)
    r0 = reference_layout(n).split(ref0)
    _, nu0 = emu.arm.preset(Pi_hat0, r0["q_d"], ref0, lam=gains.lam, kd=gains.kd,
                            kinv=gains.kinv, dt=dt)
    ctrl = emu.arm.step_fun(kind)
    args = {"z": np.concatenate([nu0, Pi_hat0]), "qd": zero, "sigma": r0["sigma_d"],
            "ref": ref0, "lam": gains.lam, "kd": gains.kd, "kpi": np.zeros(kappa),
            "ksigma": gains.ksigma, "kinv": gains.kinv, "dt": dt}
    q = ca.SX.sym("q", n)
    p = ctrl.call({**{k: args[k] for k in ctrl.name_in() if k != "q"}, "q": q})["p"]
    net = ca.Function("net", [q], [emu.residual_fun()(q, emu.interface_fun()(p)[1])[0]])
    out = np.empty(n)
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        out[j] = -(float(net(r0["q_d"] + e)[j]) - float(net(r0["q_d"] - e)[j])) / (2 * h)
    return out


def scenario(emu: GiosteEmulation, kind: str, ref: np.ndarray, gains: Theorem5Gains, *,
             dt: float, divergence: float, Pi_hat0: np.ndarray, chunk: int = 5000,
             record=RECORD) -> Scenario:
    """Controller ``kind`` on the emulated arm along ``ref`` (K × 6n, row k at t = k dt),
    from :func:`initial_state`, with :func:`~softgen.plants.gioste.emergency_stop` at
    ``divergence`` rad (a non-finite value stops the run too). One compiled loop per
    controller and ``dt`` serves every reference (``ext.ref``)."""
    if (kind, dt) not in emu.diagrams:
        emu.diagrams[kind, dt] = loop_diagram(emu, kind, dt)
    d = emu.diagrams[kind, dt]
    return Scenario(f"gioste {kind}", d, steps=ref.shape[0],
                    x0=initial_state(emu, kind, ref[0], gains, Pi_hat0=Pi_hat0, dt=dt),
                    params=gains.params(d.params.names), externals={"ref": ref},
                    stop=[emergency_stop(divergence)], record=record, on_nonfinite="stop",
                    chunk=chunk)


def run(emu: GiosteEmulation, kind: str, ref: np.ndarray, gains: Theorem5Gains, *, dt: float,
        divergence: float, Pi_hat0: np.ndarray, chunk: int = 5000, record=RECORD) -> Trace:
    """:func:`scenario` run, its trace padded to the reference's K samples: every signal
    NaN after an emergency stop, ``ref.q_d``/``ref.sigma_d`` the references given."""
    tr = scenario(emu, kind, ref, gains, dt=dt, divergence=divergence, Pi_hat0=Pi_hat0,
                  chunk=chunk, record=record).run()
    K, lay = ref.shape[0], reference_layout(emu.n)
    s = {}
    for name in record:
        s[name] = np.full((K, tr[name].shape[1]), np.nan)
        s[name][:tr.t.size] = tr[name]
    s["ref.q_d"], s["ref.sigma_d"] = ref[:, lay.slice("q_d")], ref[:, lay.slice("sigma_d")]
    return Trace(np.arange(K) * dt, s, tr.final_state, tr.next_k, tr.stopped_at,
                 tr.stop_reason, tr.wall_seconds, {**tr.meta, "dt": dt})


def stop_time(tr: Trace) -> float:
    """The emergency stop's time, or the run's last sample when it never tripped."""
    return float(tr.stopped_at if tr.stopped_at is not None else tr.t[-1])


def position_error(tr: Trace, bound: float) -> np.ndarray:
    """q − q_d; after a stop counted as ``bound`` (a stopped run has failed, and its error
    is at least the threshold: every index stays finite and ordered)."""
    e = tr["plant.q"] - tr["ref.q_d"]
    e[~tr.valid] = bound
    return e


def stiffness_error(tr: Trace, which: str = "stiff.sigma") -> np.ndarray:
    """σ − σ_d; after a stop −σ_d (the valves vented, the map gives σ = 0)."""
    sd, keep = tr["ref.sigma_d"], tr.valid
    e = tr[which] - sd
    e[~keep] = -sd[~keep]
    return e


def oscillation(tr: Trace, window: float, bound: float) -> float:
    """Half peak-to-peak of q − q_d over the last ``window`` s, linear trend removed (a
    slow convergence or a drift is not an oscillation); the worst joint."""
    m = tr.t >= tr.t[-1] - window
    e, tt = position_error(tr, bound)[m], tr.t[m] - tr.t[m].mean()
    A = np.column_stack([np.ones_like(tt), tt])
    e = e - A @ np.linalg.lstsq(A, e, rcond=None)[0]
    return float(np.max((e.max(axis=0) - e.min(axis=0)) / 2))


def concatenate(traces: list[Trace], gap: float) -> Trace:
    """Traces laid end to end, trace k shifted by k·``gap`` in time."""
    return Trace(np.concatenate([r.t + k * gap for k, r in enumerate(traces)]),
                 {k: np.concatenate([r[k] for r in traces]) for k in traces[0].signals},
                 {}, 0, None, None, sum(r.wall_seconds for r in traces))


def compact(tr: Trace, every: int) -> dict[str, np.ndarray]:
    """A trace up to its stop, every ``every``-th sample, float32 (for ``traces.npz``)."""
    keep = slice(0, int(tr.valid.sum()), every)
    return {k.replace(".", "_"): np.asarray(v[keep], np.float32)
            for k, v in {"t": tr.t, **tr.signals}.items()}


def save_traces(path, traces: dict[str, dict[str, np.ndarray]]) -> None:
    """``{run: compact(trace)}`` to one ``.npz`` (``<run>_t``, ``<run>_<block>_<signal>``)."""
    np.savez_compressed(path, **{f"{n}_{k}": v for n, a in traces.items() for k, v in a.items()})


def feasibility(emu: GiosteEmulation, t, p_cmd, V_raw, label: str, *, warn: bool = True
                ) -> tuple[list[PressureViolation], float]:
    """Pressure episodes outside [0, p(6 V)] and the fraction of samples with a clipped volt.

    :func:`~softgen.control.feasibility.check_pressures` finds each episode with joint,
    muscle and time; with ``warn``, one :class:`PressureWarning` per run names the first
    and counts the others. The bound per joint is the lower of its valves' 6 V pressures.
    """
    viol = check_pressures(t, p_cmd, emu.p_max, label=label, warn=False)
    if warn and viol:
        more = f" (and {len(viol) - 1} more episodes)" if len(viol) > 1 else ""
        warnings.warn(viol[0].message(label) + more, PressureWarning, stacklevel=2)
    clipped = np.any((V_raw < 0.0) | (V_raw > V_MAX) | ~np.isfinite(V_raw), axis=1)
    return viol, float(clipped.mean()) if clipped.size else 0.0


def feasibility_summary(emu: GiosteEmulation, runs: dict[str, Trace]) -> tuple[int, float]:
    """Over ``{label: trace}``: episodes of commanded pressure outside [0, p(6 V)]
    (:func:`feasibility`, warned once per run) and the fraction of samples before the
    stops with a clipped voltage."""
    episodes, clipped, samples = 0, 0.0, 0
    for label, r in runs.items():
        keep = r.valid
        viol, frac = feasibility(emu, r.t[keep], r["ctrl.p"][keep], r["valves.V_raw"][keep],
                                 label)
        episodes += len(viol)
        clipped += frac * int(keep.sum())
        samples += int(keep.sum())
    return episodes, clipped / max(samples, 1)


class Bench:
    """A controller model on its emulated GioSte, with the settings its runs share.

    ``muscles``: "fitted" identifies the controller's McKibben pairs from the maps
    (:func:`~softgen.plants.gioste.fitted_model`), "table10.1" keeps the model file's;
    ``actuator`` as in :class:`GiosteEmulation`. ``config`` is kept for the caller.
    """

    def __init__(self, model: str | RobotModel, hw: HardwareConfig | None = None, *,
                 muscles: str = "fitted", actuator: str = "identified", dt: float = 1e-3,
                 divergence: float = 0.5, stiffness_rate: float = 1.0, per_g2: bool = True,
                 chunk: int = 5000, config=None):
        if muscles not in ("fitted", "table10.1"):
            raise ValueError(f"muscles: expected 'fitted' or 'table10.1', got {muscles!r}")
        base = load_model(model) if isinstance(model, str) else model
        hw = hw or HardwareConfig()
        self.arm = pneumatic_arm(fitted_model(base, origin=hw.map_origin)
                                 if muscles == "fitted" else base)
        self.emu = GiosteEmulation(self.arm, hw, actuator=actuator)
        self.dt, self.divergence, self.chunk, self.c = dt, divergence, chunk, config
        self.stiffness_rate, self.per_g2 = stiffness_rate, per_g2

    def gains(self, kd, lam, kpi, sigma_range, *, per_g2: bool | None = None) -> Theorem5Gains:
        """:func:`controller_gains` with the bench's K_σ rate and K_π reading."""
        return controller_gains(self.emu, kd, lam, kpi, sigma_range,
                                stiffness_rate=self.stiffness_rate,
                                per_g2=self.per_g2 if per_g2 is None else per_g2)

    def run(self, kind: str, ref: np.ndarray, gains: Theorem5Gains,
            dt: float | None = None) -> Trace:
        """:func:`run` from Π̂(0) = Π of the controller's model."""
        return run(self.emu, kind, ref, gains, dt=dt or self.dt, divergence=self.divergence,
                   Pi_hat0=self.arm.Pi_nominal, chunk=self.chunk)

    def net_stiffness(self, ref0: np.ndarray, gains: Theorem5Gains) -> np.ndarray:
        """:func:`static_net_stiffness` of Theorem 5's first command at ``ref0``."""
        return static_net_stiffness(self.emu, "theorem5", ref0, gains,
                                    Pi_hat0=self.arm.Pi_nominal)
