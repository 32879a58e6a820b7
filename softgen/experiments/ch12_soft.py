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
from softgen.experiments.registry import (Config, Experiment, Metrics, finding, graded,
                                          not_checked, num)
from softgen.modelfile.load import load_model
from softgen.studies.soft import SoftStudyConfig, run_cases, sampled_loop, tracking_loop
# Thresholds re-exported: they are the findings' documented constants (ch12.BOUNDED, ...).
from softgen.studies.soft_claims import (BOUNDED, CONVERGED, DRIFT, ROBUST,  # noqa: F401
                                         bounded_claim, columns_claim, converges_claim,
                                         records_of)
from softgen.symbolic.pcc import LinearRoute, SoftDynamics

PI = math.pi


@dataclass(frozen=True)
class PlanarConfig(SoftStudyConfig):
    model: str = "pcc_planar_4seg"
    dt: float = 1e-3
    duration: float = 50.0
    amplitude: tuple[float, ...] = (PI / 8, PI / 6, PI / 3, PI / 2)     # M, rad
    phase: tuple[float, ...] = (0.0, PI / 2, PI / 3, PI)                 # φ, rad
    omega: float = 1.0                                                   # rad/s
    higher: tuple[float, float, float] = (5.0, 1.0, 1.0)                 # Λ, K_d, K_π
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
    sc = c.cases(dyn.model.n_segments, [
        ("", c.higher, False, 0.0, d, zero), ("_lower_gains", c.lower, False, 0.0, d, zero),
        ("_disturbed", c.higher, True, c.force, d, c.initial_error)])
    figs = {"": "fig12_2_higher_gains.png", "_lower_gains": "fig12_2_lower_gains.png",
            "_disturbed": "fig12_3_disturbed.png"}
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
        rows = [(tag, c.gains, False, 0.0, d, e0), (f"_disturbed{tag}", g_dist, True, c.force, d, e0)]
        k = f"{model.nominal['k1']:g}"
        figs = {tag: f"fig12_4_k{k}.png", f"_disturbed{tag}": f"fig12_5_k{k}.png"}
        if c.separate_causes and not tag:     # _clean: neither (issue 22 item 6)
            rows += [("_noise_only", g_dist, True, 0.0, d, e0),
                     ("_force_only", g_dist, False, c.force, d, e0),
                     ("_clean", g_dist, False, 0.0, d, e0)]
            figs.update({s: f"fig12_5_k1{s}.png" for s in ("_noise_only", "_force_only",
                                                           "_clean")})
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
    rows = [("", c.gains, False, 0.0, d, zero), ("_disturbed", c.gains, True, c.force, d, e0)]
    figs = {"": "fig12_6_ideal.png", "_disturbed": "fig12_7_disturbed.png"}
    if c.lateral_variant:
        rows.append(("_disturbed_lateral", c.gains, True, c.force, lat, e0))
        figs["_disturbed_lateral"] = "fig12_7_disturbed_lateral.png"
        if c.force_columns:      # what the noise and the force each leave (no columns)
            rows += [("_lateral_clean", c.gains, False, c.force, lat, e0),
                     ("_noise_only", c.gains, True, 0.0, d, e0)]
            figs.update(_figures("fig12_7", rows[-2:]))
    m = run_cases(loop, c.cases(ns, rows), c, out, "ch12-3d-pcc", figs, "m")
    if c.force_columns:
        loop_f = tracking_loop("ch12_3d_pcc_forces", dyn, ref, c.dt, lin,
                               forces=c.force_columns)
        g_f = c.gains + (c.kf,)
        # Noise indices of _disturbed (1) and _disturbed_lateral (2): paired comparisons.
        rows = [("_disturbed_forces", g_f, True, c.force, d, e0, 1)]
        if c.lateral_variant:
            rows += [("_disturbed_lateral_forces", g_f, True, c.force, lat, e0, 2),
                     ("_lateral_clean_forces", g_f, False, c.force, lat, e0)]
        m.extend(run_cases(loop_f, c.cases(ns, rows), c, out, "ch12-3d-pcc",
                           _figures("fig12_7", rows), "m"), keep=_not_speed)
    return m


# --------------------------------------------------------------------------- findings

def findings_planar(m: Metrics, c: Config | None = None) -> list[dict]:
    """Fig. 12.2-12.3 claims; thresholds in CONVERGED, ROBUST, BOUNDED."""
    out = [converges_claim(m, "Fig. 12.2: Theorem 10 makes the planar PCC arm track the "
                         "sinusoidal references with all parameters unknown.",
                      ["", "lower_gains"], CONVERGED["planar"], "rad")]
    claim = ("Fig. 12.2: higher control gains give a faster tracking convergence and a more "
             "precise tracking since the beginning.")
    tc, e0 = (records_of(m, q, ["", "lower_gains"]) for q in ("convergence_time",
                                                        "position_rms_error_initial"))
    if lost := [x for r in (tc, e0) if isinstance(r, list) for x in r]:
        out.append(not_checked(claim, lost))
    else:
        out.append(finding(claim, graded([tc[""] < tc["lower_gains"],
                                          e0[""] < e0["lower_gains"]]),
                           f"time after which ‖q_d − q‖ stays below 0.05 rad: {num(tc[''])} s "
                           f"(higher) vs {num(tc['lower_gains'])} s (lower); rms over the "
                           f"first 5 s {num(e0[''])} vs {num(e0['lower_gains'])} rad; "
                           "reproduced when the higher gains are smaller on both."))
    out.append(bounded_claim(m, "Fig. 12.2-12.3: the parameter estimates behave and remain "
                           "bounded.", ["", "lower_gains", "disturbed"]))
    out.append(converges_claim(m, "Fig. 12.3: the approach is robust to a persistent 0.5 N force "
                             "on each segment from t = 25 s, measurement noise (σ = 0.032 rad) "
                             "and an initial error of (1, −1, 1, −1) rad.",
                          ["disturbed"], ROBUST["planar"], "rad"))
    if m.find("position_rms_error", suffix="disturbed_forces") is not None:
        out.append(columns_claim(m, "Beyond the thesis (issue 22): with force columns (one "
                                    "adapted world force shared by the tips) the disturbed "
                                    "case tracks at least as well.",
                                 [("disturbed", "disturbed_forces")], ["disturbed_forces"],
                                 ROBUST["planar"], "rad"))
    return out


def findings_pendulum(m: Metrics, c: Config | None = None) -> list[dict]:
    """Fig. 12.4-12.5 claims; thresholds in CONVERGED, ROBUST, BOUNDED."""
    out = [
        converges_claim(m, "Fig. 12.4: the controller stabilises the soft inverted pendulum "
                      "upright, with lower (k = 1) and higher (k = 4) stiffness.",
                   ["", "k4"], CONVERGED["pendulum"], "rad"),
        bounded_claim(m, "§12.2.2: the parameter estimates remain bounded.",
                 ["", "k4", "disturbed", "disturbed_k4"]),
        converges_claim(m, "Fig. 12.5: upright regulation with noise (σ = 0.032 rad) and a "
                      "5e-3 N disturbance from t = 125 s, both stiffnesses.",
                   ["disturbed", "disturbed_k4"], ROBUST["pendulum"], "rad"),
    ]
    causes = records_of(m, "position_rms_error", ["noise_only", "force_only"])
    if isinstance(causes, dict) and out[-1]["verdict"] != "not checked":
        out[-1]["evidence"] += (f" Soft pendulum (k = 1, same gains) with the noise alone "
                                f"{num(causes['noise_only'])} rad, with the force alone "
                                f"{num(causes['force_only'])} rad.")
        out[-1]["evidence"] += _pendulum_causes(m, c)
    if m.find("position_rms_error", suffix="disturbed_forces") is not None:
        f = columns_claim(m, "Beyond the thesis (issue 22): with force columns (an adapted "
                             "tip force) the disturbed soft pendulum (k = 1, Fig. 12.5 gains) "
                             "stays within 0.02 rad.",
                          [("disturbed", "disturbed_forces"),
                           ("disturbed_k4", "disturbed_forces_k4")], ["disturbed_forces"],
                          0.02, "rad")
        both = records_of(m, "position_rms_error", ["clean", "clean_forces"])
        if isinstance(both, dict) and f["verdict"] != "not checked":
            # The columns adapt from t = 0, not only once the force is on: how much of the
            # gain is the force and how much faster settling, from the runs without force.
            f["evidence"] += (f" Without noise or force: {num(both['clean'])} rad without, "
                              f"{num(both['clean_forces'])} rad with the columns"
                              + (", so part of the gain at the end of the run is faster "
                                 "settling, not the force." if both["clean_forces"]
                                 < both["clean"] else "."))
        long = records_of(m, "position_rms_error", ["force_only_long", "force_only_long_forces"])
        if isinstance(long, dict) and f["verdict"] != "not checked":
            f["evidence"] += (f" The force alone without noise, long run: "
                              f"{num(long['force_only_long'])} rad without, "
                              f"{num(long['force_only_long_forces'])} rad with the columns.")
        out.append(f)
    return out


def _pendulum_causes(m: Metrics, c: Config | None) -> str:
    """What the soft pendulum's disturbed error at the end of the run is made of, from the
    runs with neither noise nor force (issue 22 item 6: the run is short for these gains)."""
    v = records_of(m, "position_rms_error", ["noise_only", "force_only", "clean", "clean_long",
                                       "force_only_long"])
    if isinstance(v, list):
        return ""
    t = f"{c.duration:g} s" if c is not None else "the run"
    t_long = f"{c.clean_long_duration:g} s" if c is not None else "the long run"
    settled = v["clean_long"] < CONVERGED["pendulum"]
    return (f" With neither noise nor force it is {num(v['clean'])} rad after {t} and "
            f"{num(v['clean_long'])} rad after {t_long}; with the force alone "
            f"{num(v['force_only_long'])} rad after {t_long}. "
            + ("So the run is too short for these gains to settle: the error without noise "
               "or force is still above the threshold at the end of the run, " if
               v["clean"] >= CONVERGED["pendulum"] and settled else "")
            + (f"the noise adds {num(v['noise_only'] - v['clean'])} rad to it and the "
               f"force {num(v['force_only'] - v['clean'])} rad"
               + (", and the force's part remains when the run is longer."
                  if v["force_only_long"] >= CONVERGED["pendulum"] else "."))
            )


def findings_3d(m: Metrics, c: Config | None = None) -> list[dict]:
    """Fig. 12.6-12.7 claims; thresholds in CONVERGED, ROBUST, BOUNDED."""
    lateral = m.find("position_rms_error", suffix="disturbed_lateral") is not None
    out = [
        converges_claim(m, "Fig. 12.6: Theorem 10 (Λ = 7, K_d = 13, K_π = 2) makes the 3D PCC arm "
                      "track sinusoidal references with all parameters unknown.",
                   [""], CONVERGED["3d"], "m"),
        bounded_claim(m, "§12.2.3: the parameter estimates remain bounded.",
                 ["", "disturbed"] + ["disturbed_lateral"] * lateral),
        converges_claim(m, "Fig. 12.7: tracking survives noise (σ = 0.032 m), a 5 N force on "
                      "each segment tip from t = 50 s and an initial error of ±0.05 m.",
                   ["disturbed"], ROBUST["3d"], "m")]
    if lateral:
        out.append(converges_claim(m, "Fig. 12.7 with the force across gravity (+x) instead of "
                                 "along it (the direction is not printed).",
                              ["disturbed_lateral"], ROBUST["3d"], "m"))
    if m.find("position_rms_error", suffix="disturbed_lateral_forces") is not None:
        f = columns_claim(m, "Beyond the thesis (issue 22): with force columns (one adapted "
                             "world force shared by the tips) the lateral-force case stays "
                             "within 0.01 m.",
                          [("disturbed_lateral", "disturbed_lateral_forces"),
                           ("lateral_clean", "lateral_clean_forces"),
                           ("disturbed", "disturbed_forces")],
                          ["disturbed_lateral_forces", "lateral_clean_forces"], 0.01, "m")
        floor = records_of(m, "position_rms_error", ["noise_only"])
        if isinstance(floor, dict) and f["verdict"] != "not checked":
            f["evidence"] += (f" lateral_clean*: without noise; with the noise alone (no "
                              f"force, no columns) {num(floor['noise_only'])} m"
                              + (", above the threshold: the noise sets the floor of the "
                                 "noisy cases." if floor["noise_only"] >= 0.01 else "."))
        out.append(f)
    elif m.find("position_rms_error", suffix="disturbed_forces") is not None:
        out.append(columns_claim(m, "Beyond the thesis (issue 22): with force columns the "
                                    "disturbed case tracks as well.",
                                 [("disturbed", "disturbed_forces")], ["disturbed_forces"],
                                 ROBUST["3d"], "m"))
    return out


_DISCUSSION = (
    "The thesis prints no numbers for these runs, only figures. `position_rms_error*` is the "
    "rms of ‖q_d − q‖ over the last 10 s, `position_max_error_final*` its maximum there, "
    "`convergence_time*` the time after which ‖q_d − q‖ stays inside the band of the config, "
    "`parameter_estimate_max_norm*` the largest ‖π̂(t)‖ and `input_max_abs*` the largest "
    "actuator input. The regressor has the base parameters of the automatic factorisation "
    "(31 planar, 4 pendulum, 38 in 3D) instead of the thesis's 173 / 4 / 60.")

#: Section 12.2 shows Fig. 12.2-12.7 and prints no number for these simulations.
NOT_IN_THESIS = {"*": "section 12.2 shows Fig. 12.2-12.7 only, no numbers"}
_PANELS = ("configuration variables against their references, tracking errors, parameter "
           "estimates, commanded inputs and the shape")
CAPTIONS_PLANAR = {
    "fig12_2_higher_gains.png": f"Planar 4-segment PCC arm, higher gains: {_PANELS}; mirrors "
                                "Fig. 12.2 (higher-gain row).",
    "fig12_2_lower_gains.png": f"Planar 4-segment PCC arm, lower gains: {_PANELS}; mirrors "
                               "Fig. 12.2 (lower-gain row).",
    "fig12_3_disturbed.png": f"Planar arm with noise (σ = 0.032 rad), 0.5 N per segment and an "
                             f"initial error of (1, −1, 1, −1) rad: {_PANELS}; mirrors Fig. 12.3.",
    "fig12_3_*.png": "The Fig. 12.3 case again with force columns in the regressor (an adapted "
                     "world force, beyond the thesis); layout of Fig. 12.3.",
}
CAPTIONS_PENDULUM = {
    "fig12_4_k1.png": f"Soft inverted pendulum (affine curvature, k = 1 N m/rad) regulated "
                      f"upright: {_PANELS}; mirrors Fig. 12.4 (low stiffness).",
    "fig12_4_k4.png": f"Stiffer pendulum (k = 4 N m/rad) regulated upright: {_PANELS}; mirrors "
                      "Fig. 12.4 (medium stiffness).",
    "fig12_5_k1.png": f"Pendulum k = 1 with noise (σ = 0.032 rad) and a 5e-3 N disturbance: "
                      f"{_PANELS}; mirrors Fig. 12.5 (soft pendulum).",
    "fig12_5_k4.png": f"Pendulum k = 4 with noise and disturbance: {_PANELS}; mirrors Fig. 12.5 "
                      "(stiff pendulum).",
    "fig12_5_k1_noise_only.png": "Fig. 12.5's soft case with the noise only (separating the "
                                 "causes, issue 22); layout of Fig. 12.5.",
    "fig12_5_k1_force_only.png": "Fig. 12.5's soft case with the force only (issue 22); layout "
                                 "of Fig. 12.5.",
    "fig12_5_k1_clean.png": "Fig. 12.5's soft case with the disturbed gains and neither noise "
                            "nor force (issue 22); layout of Fig. 12.5.",
    "fig12_5_k1_clean_long.png": "Fig. 12.5's soft case with neither noise nor force, run "
                                 "for clean_long_duration instead of 250 s: whether the run "
                                 "is too short (issue 22); layout of Fig. 12.5.",
    "fig12_5_k1_force_only_long.png": "Fig. 12.5's soft case with the force alone, run for "
                                      "clean_long_duration (issue 22); layout of Fig. 12.5.",
    "fig12_5_*forces*.png": "A Fig. 12.5 case again with force columns in the regressor (an "
                            "adapted tip force, beyond the thesis); layout of Fig. 12.5.",
}
CAPTIONS_3D = {
    "fig12_6_ideal.png": f"3D 4-segment PCC arm tracking sinusoidal references without "
                         f"disturbance: {_PANELS}; mirrors Fig. 12.6.",
    "fig12_7_disturbed.png": f"3D arm with noise (σ = 0.032 m), 5 N per segment and an initial "
                             f"error of ±0.05 m: {_PANELS}; mirrors Fig. 12.7.",
    "fig12_7_*.png": "A Fig. 12.7 variant named by its file (lateral force, force columns, "
                     "noise or force alone; beyond the thesis); layout of Fig. 12.7.",
}

EXPERIMENT_PLANAR = Experiment(
    id="ch12-planar-pcc", title="Theorem 10 on a planar 4-segment PCC soft arm",
    section="12.2.1, Fig. 12.2-12.3", run=run_planar, config=PlanarConfig().check(),
    quick={"duration": 20.0, "t_disturbance": 10.0}, findings=findings_planar,
    discussion=_DISCUSSION, not_in_thesis=NOT_IN_THESIS, captions=CAPTIONS_PLANAR)
EXPERIMENT_PENDULUM = Experiment(
    cost=33.0,  # CPU s, fresh-clone profile of 2026-12-02 (Experiment.cost)
    id="ch12-affine-pendulum", title="Theorem 10 regulating a soft inverted pendulum with "
    "affine curvature", section="12.2.2, Fig. 12.4-12.5", run=run_pendulum,
    config=PendulumConfig().check(),
    quick={"duration": 60.0, "t_disturbance": 30.0, "separate_causes": False},
    findings=findings_pendulum, discussion=_DISCUSSION, not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS_PENDULUM)
EXPERIMENT_3D = Experiment(
    cost=48.0,  # CPU s, fresh-clone profile of 2026-12-02 (Experiment.cost)
    id="ch12-3d-pcc", title="Theorem 10 on a 3D 4-segment PCC soft arm",
    section="12.2.3, Fig. 12.6-12.7", run=run_3d, config=Soft3DConfig().check(),
    quick={"duration": 20.0, "t_disturbance": 12.0, "lateral_variant": False},
    findings=findings_3d, discussion=_DISCUSSION, not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS_3D)
