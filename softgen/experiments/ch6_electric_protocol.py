"""``ch6-electric-protocol``: section 6.2.4.2, Fig. 6.10-6.12, Tables 6.2-6.3.

The thesis ran this protocol on qbmove hardware; we run it on an emulation of that
hardware (NOTES section 1, :mod:`softgen.plants.qbmove`): plant, sensors and the
invasive electric estimator (Theorem 2 observer per motor, L = 2, one RLS per motor on
(φ, φ³, φ⁵, φ⁷), Π̂(0) = 0, P(0) = 10⁸ I₄) in one diagram. T = 5·10⁻³ s; encoders of
8192 counts/rev; motor torque read with noise of std 10⁻³ N m; springs off the
datasheet model the allocation uses by 17 % RMSRE (section 6.2.4.1 measured about 20 %):
1.25 × wearing linearly to 1.15 × over the protocol, with a Dahl hysteresis of 0.02 N m
and reversal slope 2 N m/rad per spring (issue 32; the earlier emulation's uniform 1.2 ×
is the ``uniform`` probe, :class:`~softgen.plants.qbmove.SpringError`); motor servos
of 1000 rad/s (at 300 rad/s the motors missed their references by 0.1 rad rms on
3 × 40 s runs); plant RK4 with 20 substeps (20 → 40 changed the true stiffness by
1.4·10⁻⁶ N m/rad).

Three phases of 200 s: q_d = 0.53 + 0.2 sin(πt/4) and σ_d = 5 + 2.5 sin(πt/8); then
σ_d = 5; then q_d = 0.53 (continuous at the boundaries; the 2-DoF ``planar_2link`` run
gives both joints these references). 1-DoF (``qbmove_1dof``) without the update stop
(Table 6.2 "with drift", ``dof1_drift_*``) and with it (``dof1_stop_*``) on the same
measurements; 2-DoF with it (Table 6.3, unprefixed keys).

**Update stop**: :class:`~softgen.estimation.rls.ExcitationGate` on each motor's
measured deflection, W = 2 s (it separated the phases best among 1, 2, 4, 8 s: phase-1/3
5th percentile over phase-2 95th percentile 5.8 against 2.5-4.0), s_min = 5·10⁻³ rad
(geometric mean of the phase-2 95th percentile and the phase-1 minimum, 16 times the
quantisation noise of a measured deflection); ``*deflection_std*_phase{k}`` report it.

**What makes the unstopped estimate drift, measured** (issue 32; ``dof1_probe_<name>_*``):
the 1-DoF protocol again, each probe changing one thing, with and without the stop
(stiffness MSE per phase against the plant's backbone springs). ``uniform``: the earlier
emulation (springs a static 1.2 × the datasheet, unbiased readings); ``wear``: that
spring wearing (``spring_scale`` to ``spring_scale_end``), no hysteresis; ``hysteresis``:
the Dahl element alone on a static 1.2 × spring; ``friction``: each motor's Coulomb
friction ``probe_motor_friction`` in the current reading; ``forgetting``: the RLS with
λ = ``probe_forgetting`` < 1 (eq. 5.5 prints λ = 1); ``offset``: a motor-torque reading
offset growing over phase 2 to ``offset_probe`` (a deliberately large stand-in for a
sensor's thermal drift). The headline runs on the default emulation: wear and hysteresis
together (:class:`~softgen.plants.qbmove.SpringError`).

Indices over t ≥ 10 % of the run, MSREP in percent; truth from the plant's springs and,
as the thesis did, from the datasheet's (``*vs_nominal_*``). Tables 6.2-6.3's
stiffness MSE/MSREP ratios (≈ σ² at σ ≈ 5) make their MSREP a plain fraction, held in
``THESIS`` × 100 so that ours / thesis divides percent by percent (issue 32); their
torque ratios imply one spring's torque: hence ``*spring_torque_*`` per spring.

Grading (issue 32): the protocol is the thesis's, run on the emulated hardware (kind
"thesis"); Tables 6.2-6.3's indices in the band [1/10, 10]: hardware numbers from one
physical run, whose spring error, friction and sensing the emulation has only in kind.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.studies.indices import mse, msrep
from softgen.experiments.registry import (Config, Experiment, Metrics, banded, finding,
                                          graded, in_band, not_checked, num)
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import save_traces
from softgen.studies.estimation import (ProtocolConfig, estimator, figures, protocol_run,
                                        spring_rmsre, variant_records)


@dataclass(frozen=True)
class ElectricProtocolConfig(ProtocolConfig):
    # per phase: (q_d is the sinusoid, sigma_d is the sinusoid); else their offsets
    phases: tuple[tuple[bool, bool], ...] = ((True, True), (True, False), (False, True))
    q_d: tuple[float, float, float] = (0.53, 0.2, np.pi / 4)     # offset, amplitude, omega
    sigma_d: tuple[float, float, float] = (5.0, 2.5, np.pi / 8)
    torque_noise: float = 1e-3
    offset_probe: float = 0.03    # N m, torque-reading offset of the offset probe (0: none)
    probe_motor_friction: float = 0.005   # N m, Coulomb friction of the friction probe
    probe_forgetting: float = 0.9998      # λ of the forgetting probe (0.9995: P overflows at 394 s)
    probes: bool = True           # the drift probes (module docstring)


#: Tables 6.2-6.3 as printed; their MSREP columns are fractions (module docstring).
_PRINTED = {
    "dof1_drift_stiffness_mse_joint1": 0.5304, "dof1_drift_stiffness_msrep_joint1": 0.0187,
    "dof1_drift_torque_mse_joint1": 8.8e-6, "dof1_drift_torque_msrep_joint1": 3.3e-5,
    "dof1_stop_stiffness_mse_joint1": 0.0258, "dof1_stop_stiffness_msrep_joint1": 0.001,
    "dof1_stop_torque_mse_joint1": 1.1e-6, "dof1_stop_torque_msrep_joint1": 2.7e-6,
    "stiffness_mse_joint1": 0.048, "stiffness_msrep_joint1": 0.002,
    "torque_mse_joint1": 9e-4, "torque_msrep_joint1": 0.002,
    "stiffness_mse_joint2": 0.033, "stiffness_msrep_joint2": 0.001,
    "torque_mse_joint2": 1.1e-5, "torque_msrep_joint2": 4e-5,
}
#: In our units (issue 32: one unit per quantity): MSREP in percent, the fractions × 100.
THESIS = {k: (100 * v if "_msrep_" in k else v) for k, v in _PRINTED.items()}
# The same printed numbers beside the readings the module docstring names as the thesis's:
# stiffness against the datasheet springs (``vs_nominal``), torque of one spring.
THESIS.update({k.replace("stiffness_", "vs_nominal_stiffness_", 1): v
               for k, v in list(THESIS.items()) if "_stiffness_" in f"_{k}"})
THESIS.update({k.replace("torque_", "spring_torque_", 1): v
               for k, v in list(THESIS.items()) if "_torque_" in f"_{k}"})
NOT_IN_THESIS = {
    "dof1_probe_*": "our drift probes: the 1-DoF protocol again with one thing changed "
                    "(module docstring); the thesis ran no such probe",
    "*spring_torque_rmsre": "the emulated springs' error against the datasheet (section "
                            "6.2.4.1 measured about 20 % on hardware, no number per run)",
    "probe_*": "the settings of our drift probes",
    "*deflection_std*": "our excitation measure for the update stop (module docstring)",
    "*achieved_over_desired_stiffness*": "our check of the emulated stiffness allocation",
    "*update_fraction_phase*": "our share of samples with the RLS updating",
    "*stiffness_mse_joint*_phase*": "per-phase split of the MSE; Tables 6.2-6.3 print the "
                                    "whole protocol",
    "*estimator_seconds_per_step": "our timing",
    "metric_window_*": "the window the indices cover",
    "offset_probe": "the torque-reading offset of our drift probe (dof1_probe_offset_*)",
}
CAPTIONS = {
    "dof1_protocol.png": "One-DoF emulated qbmove through the three phases: position, "
                         "stiffness, deflections, excitation against the stop threshold and "
                         "when each RLS updates; mirrors Fig. 6.10.",
    "dof2_protocol.png": "Two-DoF emulated setup through the three phases (as dof1_protocol); "
                         "mirrors Fig. 6.12.",
    "dof1_drift_estimation.png": "One-DoF: true and estimated stiffness and torque without the "
                                 "update stop; mirrors Fig. 6.10 (with drift).",
    "dof1_stop_estimation.png": "One-DoF: true and estimated stiffness and torque with the "
                                "update stop; mirrors Fig. 6.11 (without drift).",
    "dof2_estimation.png": "Two-DoF: true and estimated stiffness and torque of both joints "
                           "with the update stop; mirrors Fig. 6.12.",
}


def run(c: ElectricProtocolConfig, out) -> Metrics:
    m, traces = Metrics(), {}
    for dof, name in enumerate(c.models[:1 + c.two_dof], start=1):
        model = load_model(name)
        n, pre = model.dof, "dof1_" if dof == 1 else ""
        ests = {"stop": estimator(model, "electric", c)}
        if dof == 1:
            ests = {"drift": estimator(model, "electric", c, gated=False), **ests}
        r = protocol_run(c, model, f"ch6_protocol_{model.name}", (c.sigma_d,) * n,
                         {k: e.block(k) for k, e in ests.items()})
        r.records(m, prefix=pre)
        for tag, est in ests.items():
            mv, res, mask = variant_records(r.tr, r.truth, est, tag, c.metric_window,
                                            r.truth.tau_e, r.phase)
            # Per spring: each motor's RLS model Σ_p π̂_p φ_j^p at the measured
            # deflection against the plant's spring torque, pooled over the two sides.
            for i in range(n):
                e, tt = [], []
                for s, col in (("a", i), ("b", i + n)):
                    reg = np.stack([r.phi[:, col] ** p for p in c.powers], axis=1)
                    e.append(np.sum(reg * res.theta[f"joint{i + 1}{s}"], axis=1)[mask])
                    tt.append(r.truth.spring_torque[mask, col])
                e, tt = np.concatenate(e), np.concatenate(tt)
                mv.add("spring_torque_mse", mse(tt, e), "(N m)^2", joint=i + 1)
                mv.add("spring_torque_msrep", msrep(tt, e), "%", joint=i + 1)
            m.extend(mv, prefix=f"{pre}{tag}_" if dof == 1 else "")
            traces.update({f"dof{dof}_{tag}_sigma_hat": res.sigma_hat,
                           f"dof{dof}_{tag}_updating": res.updating})
            figures(out, f"{pre}{tag}_" if dof == 1 else "dof2_", r.tr, r.truth.sigma,
                    r.truth.tau_e, res, est,
                    f"{dof}-DoF, {'no update stop' if tag == 'drift' else 'stop'}")
        if dof == 1 and c.probes:
            drift_probes_run(c, model, m)
        traces.update({f"dof{dof}_q": r.tr["plant.q"], f"dof{dof}_sigma": r.truth.sigma,
                       f"dof{dof}_sigma_nominal": r.truth.sigma_nominal})
        r.figure(out / f"dof{dof}_protocol.png",
                 {k: traces[f"dof{dof}_{k}_updating"] for k in ests})
    m.add("metric_window_start", r.t[mask][0], "s")
    m.add("metric_window_end", r.t[mask][-1], "s")
    save_traces(out / "traces.npz", t=r.t, **traces)
    return m


#: The drift probes (module docstring): name -> config overrides, RLS λ, reading offset.
def _probes(c: ElectricProtocolConfig) -> dict[str, tuple[dict, float, bool]]:
    static = dict(spring_scale_end=c.spring_scale, hysteresis=0.0, hysteresis_slope=0.0)
    return {
        "uniform": (dict(static, spring_scale=1.2, spring_scale_end=1.2), 1.0, False),
        "wear": (dict(hysteresis=0.0, hysteresis_slope=0.0), 1.0, False),
        "hysteresis": (dict(spring_scale=1.2, spring_scale_end=1.2), 1.0, False),
        "friction": (dict(static, spring_scale=1.2, spring_scale_end=1.2,
                          motor_friction=c.probe_motor_friction), 1.0, False),
        "forgetting": (dict(static, spring_scale=1.2, spring_scale_end=1.2),
                       c.probe_forgetting, False),
        "offset": (dict(static, spring_scale=1.2, spring_scale_end=1.2), 1.0,
                   bool(c.offset_probe)),
    }


def drift_probes_run(c: ElectricProtocolConfig, model, m: Metrics) -> None:
    """The 1-DoF protocol once per probe of :func:`_probes`, the estimator with and without
    the stop: stiffness MSE per phase and update fractions as
    ``dof1_probe_<name>_{drift,stop}_*``."""
    t = c.samples()
    for name, (over, lam, offset) in _probes(c).items():
        cp = c.replace(**over)
        ests = {"drift": estimator(model, "electric", cp, gated=False, forgetting=lam),
                "stop": estimator(model, "electric", cp, forgetting=lam)}
        bias = None
        if offset:
            ramp = c.offset_probe * np.clip((t - c.phase_duration) / c.phase_duration, 0, 1)
            bias = np.repeat(ramp[:, None], 2 * model.dof, axis=1)
        r = protocol_run(cp, model, f"ch6_protocol_probe_{name}_{model.name}",
                         (cp.sigma_d,) * model.dof,
                         {k: e.block(k) for k, e in ests.items()}, torque_bias=bias)
        for tag, est in ests.items():
            mv = variant_records(r.tr, r.truth, est, tag, c.metric_window, r.truth.tau_e,
                                 r.phase)[0]
            m.extend(mv, prefix=f"dof1_probe_{name}_{tag}_", keep=lambda x: x.quantity in (
                "stiffness_mse", "update_fraction"))
        m.add("spring_torque_rmsre", spring_rmsre(r.truth), "1", prefix=f"dof1_probe_{name}_")
    m.add("offset_probe", c.offset_probe, "N m")
    m.add("probe_motor_friction", c.probe_motor_friction, "N m")
    m.add("probe_forgetting", c.probe_forgetting, "1")


#: k of the band [1/k, k] Tables 6.2-6.3 are graded in (module docstring).
BAND = 10.0


def _table(m: Metrics, claim: str, keys: list[str]) -> dict:
    flat = dict(m.items())
    if lost := [k for k in keys if k not in flat]:
        return not_checked(claim, lost, kind="thesis", band=BAND)
    ok, ev = banded(flat, THESIS, keys, BAND)
    return finding(claim, graded(ok), ev + " (against the emulated plant's springs; MSREP "
                   "in %, the tables' fractions × 100)", kind="thesis", metrics=keys, band=BAND)


def findings(m: Metrics, c: Config | None = None) -> list[dict]:
    """Table 6.2: the update stop removes a drift; Tables 6.2-6.3's indices in the band."""
    d, s = (_phases(m, f"dof1_{tag}_") for tag in ("drift", "stop"))
    drift = _drifts(d)
    whole = {t: m.value("stiffness_mse", joint=1, prefix=f"dof1_{t}_") for t in ("drift", "stop")}
    keys = [f"dof1_{t}_stiffness_mse_joint1" for t in ("drift", "stop")]
    in_b = [in_band(whole[t], THESIS[f"dof1_{t}_stiffness_mse_joint1"], BAND)
            for t in ("drift", "stop")]
    out = [finding(
        "Table 6.2: without the update stop the stiffness estimate drifts in the "
        "constant-stiffness phase (MSE 0.53 against 0.026 with it)",
        graded([drift and s[1] < d[1], *in_b]),
        "stiffness MSE per phase without the stop " + ", ".join(num(x) for x in d)
        + "; with it " + ", ".join(num(x) for x in s) + "; update fraction in phase 2 "
        f"{num(m.value('update_fraction', phase=2, prefix='dof1_stop_'))} (a drift: phase 2 "
        f"or 3 above 3× phase 1). Whole run: {num(whole['drift'])} without the stop, "
        f"{num(whole['stop'])} with it, against 0.53 and 0.026 "
        f"({', '.join(num(whole[t] / THESIS[k]) + '×' for t, k in zip(('drift', 'stop'), keys))}"
        f"; band [1/{BAND:g}, {BAND:g}]). Against the datasheet springs MSE "
        f"{num(m.value('vs_nominal_stiffness_mse', joint=1, prefix='dof1_stop_'))}",
        kind="thesis", band=BAND,
        metrics=[*keys, *(f"dof1_{t}_stiffness_mse_joint1_phase{k}" for t in ("drift", "stop")
                          for k in (1, 2, 3))])]
    out.append(_table(m, "Table 6.2: 1-DoF stiffness and torque indices with the update stop",
                      [f"dof1_stop_{q}_{i}_joint1" for q in ("stiffness", "torque")
                       for i in ("mse", "msrep")]))
    if m.find("stiffness_mse", joint=2) is not None:
        out.append(_table(m, "Table 6.3: 2-DoF stiffness and torque indices with the update "
                             "stop", [f"{q}_{i}_joint{j}" for q in ("stiffness", "torque")
                                      for i in ("mse", "msrep") for j in (1, 2)]))
    out += drift_probes(m)
    return out


def _phases(m: Metrics, prefix: str) -> list[float]:
    return [m.value("stiffness_mse", joint=1, phase=k, prefix=prefix) for k in (1, 2, 3)]


def _drifts(v: list[float]) -> bool:
    """The drift rule of the findings: phase 2 or 3 above 3 × phase 1."""
    return v[1] > 3 * v[0] or v[2] > 3 * v[0]


def drift_probes(m: Metrics) -> list[dict]:
    """Issue 32: what was tried to reproduce Table 6.2's drift, one diagnostic per probe
    (does the unstopped estimate drift, and does the stop prevent it), and which did."""
    names = [n for n in ("uniform", "wear", "hysteresis", "friction", "forgetting", "offset")
             if m.find("stiffness_mse", joint=1, phase=1, prefix=f"dof1_probe_{n}_drift_")]
    if not names:
        return []
    what = {"uniform": "springs a static 1.2 × the datasheet, unbiased readings (the earlier "
                       "emulation)",
            "wear": "the springs wearing over the protocol, no hysteresis",
            "hysteresis": "a Dahl hysteresis on static 1.2 × springs",
            "friction": "motor Coulomb friction in the current reading",
            "forgetting": "the RLS with a forgetting factor λ < 1",
            "offset": "a torque-reading offset growing over phase 2"}
    out, reproduced = [], []
    for n in names:
        d, s_ = _phases(m, f"dof1_probe_{n}_drift_"), _phases(m, f"dof1_probe_{n}_stop_")
        ok = _drifts(d) and max(s_[1:]) < max(d[1:])
        if ok:
            reproduced.append(n)
        keys = [f"dof1_probe_{n}_{t}_stiffness_mse_joint1_phase{k}" for t in ("drift", "stop")
                for k in (1, 2, 3)]
        out.append(finding(
            f"Probe ({n}): with {what[n]} the unstopped estimate drifts and the stop prevents "
            "it", "reproduced" if ok else "not reproduced",
            "stiffness MSE per phase without the stop " + ", ".join(num(x) for x in d)
            + "; with it " + ", ".join(num(x) for x in s_) + " (drift: phase 2 or 3 above 3× "
            "phase 1; prevented: the stop's worst later phase below the unstopped one); "
            f"spring RMSRE against the datasheet "
            f"{num(m.value('spring_torque_rmsre', prefix=f'dof1_probe_{n}_'))}",
            kind="diagnostic", metrics=keys))
    head = _phases(m, "dof1_drift_"), _phases(m, "dof1_stop_")
    drifted = {n: _drifts(_phases(m, f"dof1_probe_{n}_drift_")) for n in names}
    # The statement the probes test: hysteresis and a forgetting RLS give a drift the stop
    # prevents; a static spring error, motor friction, a reading offset give none.
    expect = {"hysteresis": True, "forgetting": True, "uniform": False, "friction": False,
              "offset": False}
    ok = [(n in reproduced) == want for n, want in expect.items() if n in names]
    worse = [n for n in names if drifted[n] and n not in reproduced]
    out.append(finding(
        "Cause of Table 6.2's drift (issue 32): the drift that the update stop prevents "
        "needs a spring that lags its deflection (hysteresis) or an RLS that forgets "
        "(λ < 1); a static spring error, motor friction in the current reading or a "
        "reading offset give none", graded(ok),
        "probes that drift and are stopped: " + (", ".join(reproduced) or "none")
        + "; that drift but the stop does not prevent: " + (", ".join(worse) or "none")
        + "; no drift: " + (", ".join(n for n in names if not drifted[n]) or "none")
        + " (per-phase numbers in the probes' rows). The headline emulation (wear and "
          "hysteresis together): MSE per phase " + ", ".join(num(x) for x in head[0])
        + " without the stop, " + ", ".join(num(x) for x in head[1]) + " with it",
        kind="diagnostic",
        metrics=[f"dof1_probe_{n}_{t}_stiffness_mse_joint1_phase{k}" for n in names
                 for t in ("drift", "stop") for k in (1, 2, 3)]))
    return out


EXPERIMENT = Experiment(
    cost=21.9,  # CPU s, fresh-clone main job of 2026-12-06, load ~1
    id="ch6-electric-protocol",
    title="Invasive electric estimator on emulated qbmove hardware: three-phase protocol "
          "with and without the RLS update stop",
    section="6.2.4.2, Fig. 6.10-6.12, Tables 6.2-6.3",
    run=run,
    config=ElectricProtocolConfig(),
    quick={"phase_duration": 40.0},
    thesis=THESIS,
    not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS,
    findings=findings,
)
