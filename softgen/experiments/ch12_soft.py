"""Chapter 12: Theorem 10 (adaptive control of soft-bodied robots) on three robots (§12.2).

``ch12-planar-pcc`` (Fig. 12.2-12.3), ``ch12-affine-pendulum`` (Fig. 12.4-12.5) and
``ch12-3d-pcc`` (Fig. 12.6-12.7), with the numbers of NOTES §1. Every physical
parameter is unknown to the controller (π̂(0) = 0, §12.2). Loops and records come from
:mod:`softgen.studies.soft`; the one driver runs them.

- Planar and 3D PCC: Theorem 10 acts in continuous time inside the plant's ODE, one
  ROS2 step per 1 ms sample (:func:`softgen.control.soft.closed_loop_block`), as the
  thesis's Simulink runs must have. A τ held over 1 ms (zero-order hold) diverges within
  a few samples on these models, not because of their light modes but because on the
  damping-dominated modes the held K_d σ and D̂ q̇ feed back the last sample's velocity
  (stable only while |D̂ − K_d| < D; :mod:`softgen.control.soft`). The linearly implicit
  sampled law of :mod:`softgen.control.soft_sampled` runs at 1 ms from π̂ = 0 within
  1.01× of this loop's rms error (``ext-sampled-soft``).
- Affine pendulum (distributed mass): the sampled law (τ held over 1 ms) and the
  plant, the controller reading the noisy measurement.
- Noise: seeded Gaussian, σ = 0.032 (rad or m) on the configuration (``noise_reason``),
  fed to the diagram as the external input ``noise``. Disturbance: the same force on
  every segment tip from the catalogue's time. Errors are e = q_d − q of the true state.

Choices where the thesis prints no value are fields of the configs, with the reason in
the field beside them. Metric names: no suffix = the first scenario (ideal sensing, no
disturbance, higher gains); ``_disturbed`` = noise + disturbance + initial error; other
variants add their own suffix.

Beyond the thesis, ``_forces`` variants run Theorem 10 with force columns (adapted
constant tip forces, :mod:`softgen.control.soft`; K_f and the declared tips are config
fields) on the disturbed cases, with ``force_estimate_<name>_final`` records; ``_clean``
variants (no noise, no force) separate what the force, the noise and the run's length
each contribute.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

from softgen.control.soft import reference_block
from softgen.experiments.registry import Experiment, Metrics
from softgen.modelfile.load import load_model
from softgen.studies.gains import PLANAR_PCC_HIGHER_GAINS, PLANAR_PCC_REFERENCE
from softgen.studies.soft import SoftStudyConfig, run_cases, sampled_loop, tracking_loop
# The claims and their thresholds live with the checks they use; re-exported here as the
# experiments' documented findings and constants (ch12.findings_planar, ch12.BOUNDED, ...).
from softgen.studies.soft_claims import (BOUNDED, CONVERGED, DRIFT, FLOOR_FACTOR,  # noqa: F401
                                         NOISE_FACTOR, ROBUST,
                                         CAPTIONS_3D, CAPTIONS_PENDULUM, CAPTIONS_PLANAR,
                                         DISCUSSION, NOT_IN_THESIS, findings_3d,
                                         findings_pendulum, findings_planar, records_of)
from softgen.symbolic.pcc import LinearRoute, SoftDynamics

PI = math.pi


@dataclass(frozen=True)
class PlanarConfig(SoftStudyConfig):
    model: str = "pcc_planar_4seg"
    dt: float = 1e-3
    duration: float = 50.0
    amplitude: tuple[float, ...] = PLANAR_PCC_REFERENCE["amplitude"]     # M, rad
    phase: tuple[float, ...] = PLANAR_PCC_REFERENCE["phase"]             # φ, rad
    omega: float = PLANAR_PCC_REFERENCE["omega"]                         # rad/s
    higher: tuple[float, float, float] = PLANAR_PCC_HIGHER_GAINS         # Λ, K_d, K_π
    lower: tuple[float, float, float] = (2.0, 0.5, 1.0)
    gains_reason: str = (
        "not printed (Fig. 12.2 says 'lower and higher'). Λ and K_d differ, K_π is shared. "
        "Upper limit measured: with π̂ integrated explicitly against the light modes, the "
        "1 ms ROS2 step of the loop diverged within 10 ms for K_π = 1.5 or 2 (Λ = 5, "
        "K_d = 1) and for Λ = 10 (K_d = 1 or 2, K_π = 1)")
    noise_std: float = 0.032
    noise_seed: int = 1201
    force: float = 0.5                                                   # N per tip
    force_direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    force_reason: str = ("not printed; +x is horizontal, across gravity (the arm hangs "
                         "along -y): the largest bending moment on the hanging arm")
    t_disturbance: float = 25.0
    initial_error: tuple[float, ...] = (1.0, -1.0, 1.0, -1.0)            # rad
    # Force columns (beyond the thesis): variant _disturbed_forces, () to skip it.
    force_columns: tuple = ("tips",)
    kf: float = 1.0                                                      # K_f = k_f I
    force_columns_reason: str = (
        "the scenario puts the same force on every tip, so one shared world force "
        "(2 parameters, x and y) is declared on all tips ('tips'); its value is unknown. "
        "k_f = 1: of 0.1, 1, 10, 100 on the disturbed case (50 s, one noise draw) the rms "
        "error was 0.0209, 0.0092, 0.0081, 0.0105 rad and f̂_x at the end 0.080, 0.43, "
        "0.67, 1.25 N against 0.5 N: 1 estimates best, 10 tracks marginally better")


@dataclass(frozen=True)
class PendulumConfig(SoftStudyConfig):
    model: str = "soft_pendulum"
    dt: float = 1e-3
    duration: float = 250.0
    k_stiff: float = 4.0                                                 # N m/rad
    gains: tuple[float, float, float] = (0.3, 0.05, 0.01)                # Fig. 12.4
    gains_disturbed_soft: tuple[float, float, float] = (0.2, 0.05, 0.01)  # Fig. 12.5, k = 1
    gains_disturbed_stiff: tuple[float, float, float] = (0.1, 0.1, 0.05)  # Fig. 12.5, k = 4
    initial_error: tuple[float, ...] = (PI / 4, -PI / 4)                 # rad, both figures
    duration_reason: str = ("not printed; twice the disturbance time, so the disturbed "
                            "half is as long as the undisturbed one")
    noise_std: float = 0.032
    noise_seed: int = 1202
    force: float = 5e-3                                                  # N at the tip
    force_direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    force_reason: str = ("not printed; +x is horizontal: at the upright straight pose a "
                         "vertical force acts along the backbone and has no moment")
    t_disturbance: float = 125.0
    # k = 1, Fig. 12.5 gains, noise alone and force alone (suffixes _noise_only and
    # _force_only), and neither (_clean, below): what the soft pendulum's _disturbed
    # error at the end of the run is made of. Not the force alone: with neither noise nor
    # force these gains leave 0.135 rad at 250 s (0.0028 rad at 500 s, 1.2e-6 rad at
    # 1000 s; below 0.05 rad from t = 309 s): the run is short for them (measured, full
    # runs; the finding reports the current numbers).
    separate_causes: bool = True
    shape_window: float = 0.0            # the whole run: the way up
    # k = 1, Fig. 12.5 gains, neither noise nor force (suffix _clean), at ``duration``
    # and at ``clean_long_duration`` (suffix _clean_long, 0: skip): whether the run is
    # long enough for the soft pendulum to settle at all (issue 22 item 6). 500 s: it
    # settles by then (below 0.05 rad from t = 309 s), at half the cost of 1000 s.
    clean_long_duration: float = 500.0                                   # s
    # Force columns (beyond the thesis): _disturbed_forces and _disturbed_forces_k4, and
    # with separate_causes _clean_forces (columns, no force, no noise) and
    # _force_only_long_forces (columns, the force alone, clean_long_duration). () to skip.
    force_columns: tuple = ("tip",)
    kf: float = 1.0                                                      # K_f = k_f I
    force_columns_reason: str = (
        "the disturbance acts at the tip (the only segment), x and y unknown. k_f = 1: of "
        "k_f = 0.1 and 1 on the soft disturbed case (250 s, one noise draw) the rms error "
        "was 0.052 and 0.0076 rad")


@dataclass(frozen=True)
class Soft3DConfig(SoftStudyConfig):
    model: str = "pcc_3d_4seg"
    dt: float = 1e-3
    duration: float = 100.0
    # References per segment i: Δx = 0.2 sin(t + φ_i), Δy = 0.2 sin(t + φ_i + π/2),
    # δL = 0.05 sin(t + φ_i), φ = (0, π/2, π/3, π) as in §12.2.1.
    amplitude: tuple[float, ...] = (0.2, 0.2, 0.05) * 4                  # m
    phase: tuple[float, ...] = tuple(p + d for p in (0.0, PI / 2, PI / 3, PI)
                                     for d in (0.0, PI / 2, 0.0))
    omega: float = 1.0
    reference_reason: str = (
        "amplitudes not printed ('sinusoidal references'): 0.2 m of Δ (0.2 rad of bending "
        "at radius 1) on a circle per segment and 5 % elongation; the phases and ω of "
        "§12.2.1, so that the segments do not move in unison")
    gains: tuple[float, float, float] = (7.0, 13.0, 2.0)                 # Λ, K_d, K_π
    noise_std: float = 0.032                                             # m
    noise_seed: int = 1203
    force: float = 5.0                                                   # N per tip
    force_direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    force_reason: str = (
        "not printed; -z (along gravity, a 5 N payload on every tip, half a segment's "
        "weight). The lateral variant (+x, suffix _disturbed_lateral) is run too")
    lateral_variant: bool = True
    # Force columns (beyond the thesis): _disturbed_forces (and _disturbed_lateral_forces
    # with lateral_variant, plus the noise-free lateral pair _lateral_clean and
    # _lateral_clean_forces that separates the noise from the force). () to skip.
    force_columns: tuple = ("tips",)
    kf: float = 0.1                                                      # K_f = k_f I
    force_columns_reason: str = (
        "the scenario puts the same force on every tip: one shared world force (3 "
        "parameters) on all tips ('tips'). k_f = 0.1: of 0.1, 0.3, 1, 10 the smallest "
        "noisy lateral rms error (0.021, 0.027, 0.038, 0.106 m, 100 s runs, one noise draw "
        "each); without noise 0.3, 1, 3 gave 0.0020, 0.0024, 0.0025 m")
    t_disturbance: float = 50.0
    initial_error: tuple[float, ...] = (0.05,) * 6 + (-0.05,) * 6       # m
    convergence_band: float = 0.02       # m
    shapes: int = 7
    full_run_cost: str = (
        "measured on 2 shared cores: 24.1 s wall for the full run on a cold build cache "
        "(derivation ~4 s, C compilation of the 47k-instruction diagram, 3 scenarios of "
        "100 s at 78x real time), beside the other two experiments. With the force-column "
        "variants (8 scenarios on two diagrams): 67.7 s and 33.6 s wall in two full runs "
        "(build cache state not controlled)")

    def validate(self) -> None:
        if not self.metric_window < self.t_disturbance < self.duration:
            raise ValueError(f"t_disturbance: expected within (metric_window, duration), got "
                             f"{self.t_disturbance}")


def _not_speed(r) -> bool:
    """Keep a variant run's records but its speed (the experiment's is the first run's)."""
    return r.quantity != "simulated_seconds_per_wall_second"


def _figures(prefix: str, rows) -> dict[str, str]:
    return {row[0]: f"{prefix}{row[0]}.png" for row in rows}


def run_planar(c: PlanarConfig, out: Path) -> Metrics:
    dyn = SoftDynamics(load_model(c.model))
    lin = LinearRoute(dyn)
    ref = reference_block("ref", c.dt, c.amplitude, c.omega, c.phase)
    loop = tracking_loop("ch12_planar_pcc", dyn, ref, c.dt, lin)
    zero, d = (0.0,) * dyn.model.dof, c.force_direction
    # _noise_only: the disturbed case without its force, on its noise draw (index 2): what
    # a noisy case is graded against (issue 32).
    sc = c.cases(dyn.model.n_segments, [
        ("", c.higher, False, 0.0, d, zero), ("_lower_gains", c.lower, False, 0.0, d, zero),
        ("_disturbed", c.higher, True, c.force, d, c.initial_error),
        ("_noise_only", c.higher, True, 0.0, d, c.initial_error, 2)])
    figs = {"": "fig12_2_higher_gains.png", "_lower_gains": "fig12_2_lower_gains.png",
            "_disturbed": "fig12_3_disturbed.png", "_noise_only": "fig12_3_noise_only.png"}
    m = run_cases(loop, sc, c, out, "ch12-planar-pcc", figs, "rad")
    if c.force_columns:
        loop_f = tracking_loop("ch12_planar_pcc_forces", dyn, ref, c.dt, lin,
                               forces=c.force_columns)
        # Noise index 2: the noise of _disturbed, so that the pair differs only in columns.
        rows = [("_disturbed_forces", c.higher + (c.kf,), True, c.force, d, c.initial_error,
                 2)]
        m.extend(run_cases(loop_f, c.cases(dyn.model.n_segments, rows), c, out,
                           "ch12-planar-pcc", _figures("fig12_3", rows), "rad"), keep=_not_speed)
    return m


def run_pendulum(c: PendulumConfig, out: Path) -> Metrics:
    soft = load_model(c.model)
    stiff = dataclasses.replace(soft, nominal={**soft.nominal, "k1": c.k_stiff})
    m, d, e0 = Metrics(), c.force_direction, c.initial_error
    for model, tag, g_dist in ((soft, "", c.gains_disturbed_soft),
                               (stiff, "_k4", c.gains_disturbed_stiff)):
        dyn = SoftDynamics(model)
        lin = LinearRoute(dyn)
        ref = reference_block("ref", c.dt, (0.0, 0.0), 0.0)       # upright: q_d = 0
        loop = sampled_loop(f"ch12_affine_pendulum{tag}", dyn, ref, c.dt, lin)
        # _noise_only: the disturbed case without its force on its noise draw (index 1),
        # what it is graded against (issue 32), for both stiffnesses.
        rows = [(tag, c.gains, False, 0.0, d, e0), (f"_disturbed{tag}", g_dist, True, c.force, d, e0),
                (f"_noise_only{tag}", g_dist, True, 0.0, d, e0, 1)]
        k = f"{model.nominal['k1']:g}"
        figs = {tag: f"fig12_4_k{k}.png", f"_disturbed{tag}": f"fig12_5_k{k}.png",
                f"_noise_only{tag}": f"fig12_5_k{k}_noise_only.png"}
        if c.separate_causes and not tag:     # _clean: neither (issue 22 item 6)
            rows += [("_force_only", g_dist, False, c.force, d, e0),
                     ("_clean", g_dist, False, 0.0, d, e0)]
            figs.update({s: f"fig12_5_k1{s}.png" for s in ("_force_only", "_clean")})
        mk = run_cases(loop, c.cases(1, rows), c, out, "ch12-affine-pendulum", figs, "rad")
        m.extend(mk, keep=lambda r: r.quantity != "simulated_seconds_per_wall_second"
                 or not tag)
        if c.separate_causes and c.clean_long_duration and not tag:
            # The same without noise, with and without the force, run longer.
            rows = [("_clean_long", g_dist, False, 0.0, d, e0),
                    ("_force_only_long", g_dist, False, c.force, d, e0)]
            m.extend(run_cases(loop, c.cases(1, rows),
                               dataclasses.replace(c, duration=c.clean_long_duration), out,
                               "ch12-affine-pendulum", _figures("fig12_5_k1", rows), "rad"),
                     keep=_not_speed)
        if c.force_columns:
            loop_f = sampled_loop(f"ch12_affine_pendulum_forces{tag}", dyn, ref, c.dt,
                                  lin, forces=c.force_columns)
            g_f = g_dist + (c.kf,)
            rows = [(f"_disturbed_forces{tag}", g_f, True, c.force, d, e0, 1)]   # its noise
            if c.separate_causes and not tag:
                rows.append(("_clean_forces", g_f, False, 0.0, d, e0))
            m.extend(run_cases(loop_f, c.cases(1, rows), c, out, "ch12-affine-pendulum",
                               _figures(f"fig12_5_k{k}", rows), "rad"), keep=_not_speed)
            if c.separate_causes and c.clean_long_duration and not tag:
                # The force alone, long: what the columns reject once settling is over.
                rows = [("_force_only_long_forces", g_f, False, c.force, d, e0)]
                m.extend(run_cases(loop_f, c.cases(1, rows),
                                   dataclasses.replace(c, duration=c.clean_long_duration),
                                   out, "ch12-affine-pendulum", _figures("fig12_5_k1", rows),
                                   "rad"), keep=_not_speed)
    return m


def run_3d(c: Soft3DConfig, out: Path) -> Metrics:
    dyn = SoftDynamics(load_model(c.model))
    lin = LinearRoute(dyn)
    ref = reference_block("ref", c.dt, c.amplitude, c.omega, c.phase, unit="m")
    loop = tracking_loop("ch12_3d_pcc", dyn, ref, c.dt, lin)
    zero, d, e0 = (0.0,) * dyn.model.dof, c.force_direction, c.initial_error
    lat, ns = (1.0, 0.0, 0.0), dyn.model.n_segments
    # Every noisy case on one noise draw (index 1) with its noise-only run: a noisy case is
    # graded against the noise alone on the same draw (issue 32).
    rows = [("", c.gains, False, 0.0, d, zero), ("_disturbed", c.gains, True, c.force, d, e0),
            ("_noise_only", c.gains, True, 0.0, d, e0, 1)]
    figs = {"": "fig12_6_ideal.png", "_disturbed": "fig12_7_disturbed.png",
            "_noise_only": "fig12_7_noise_only.png"}
    if c.lateral_variant:
        rows.append(("_disturbed_lateral", c.gains, True, c.force, lat, e0, 1))
        figs["_disturbed_lateral"] = "fig12_7_disturbed_lateral.png"
        if c.force_columns:      # what the force leaves without noise (no columns)
            rows.append(("_lateral_clean", c.gains, False, c.force, lat, e0))
            figs.update(_figures("fig12_7", rows[-1:]))
    m = run_cases(loop, c.cases(ns, rows), c, out, "ch12-3d-pcc", figs, "m")
    if c.force_columns:
        loop_f = tracking_loop("ch12_3d_pcc_forces", dyn, ref, c.dt, lin,
                               forces=c.force_columns)
        g_f = c.gains + (c.kf,)
        # The noise draw of every noisy case (index 1): paired comparisons.
        rows = [("_disturbed_forces", g_f, True, c.force, d, e0, 1)]
        if c.lateral_variant:
            rows += [("_disturbed_lateral_forces", g_f, True, c.force, lat, e0, 1),
                     ("_lateral_clean_forces", g_f, False, c.force, lat, e0)]
        m.extend(run_cases(loop_f, c.cases(ns, rows), c, out, "ch12-3d-pcc",
                           _figures("fig12_7", rows), "m"), keep=_not_speed)
    return m


# --------------------------------------------------------------------------- findings

EXPERIMENT_PLANAR = Experiment(
    cost=7.1,  # CPU s, fresh-clone main job of 2026-12-06, load ~1
    id="ch12-planar-pcc", title="Theorem 10 on a planar 4-segment PCC soft arm",
    section="12.2.1, Fig. 12.2-12.3", run=run_planar, config=PlanarConfig().check(),
    quick={"duration": 20.0, "t_disturbance": 10.0}, findings=findings_planar,
    discussion=DISCUSSION, not_in_thesis=NOT_IN_THESIS, captions=CAPTIONS_PLANAR)
EXPERIMENT_PENDULUM = Experiment(
    cost=18.8,  # CPU s, fresh-clone main job of 2026-12-06, load ~1
    id="ch12-affine-pendulum", title="Theorem 10 regulating a soft inverted pendulum with "
    "affine curvature", section="12.2.2, Fig. 12.4-12.5", run=run_pendulum,
    config=PendulumConfig().check(),
    quick={"duration": 60.0, "t_disturbance": 30.0, "separate_causes": False},
    findings=findings_pendulum, discussion=DISCUSSION, not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS_PENDULUM)
EXPERIMENT_3D = Experiment(
    cost=21.0,  # CPU s, fresh-clone main job of 2026-12-06, load ~1
    id="ch12-3d-pcc", title="Theorem 10 on a 3D 4-segment PCC soft arm",
    section="12.2.3, Fig. 12.6-12.7", run=run_3d, config=Soft3DConfig().check(),
    quick={"duration": 20.0, "t_disturbance": 12.0, "lateral_variant": False},
    findings=findings_3d, discussion=DISCUSSION, not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS_3D)
