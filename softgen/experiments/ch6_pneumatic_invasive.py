"""``ch6-pneumatic-invasive``: section 6.1.3, Fig. 6.2-6.3.

The one-link pendulum of section 6.1 driven by its McKibben pair
(``models/pendulum_1link.toml``) tracks q_d = 0.3 sin(πt/10) and σ_d = 5 + sin(πt/6).
As the issue allows, the pressures come from an exact-model allocation
(:mod:`softgen.plants.pneumatic`), not from the thesis's controller. The invasive
estimator (Theorem 1 observer with L = 2, RLS on p_a(1, q, q²), p_b(1, q, q²),
Π̂(0) = 0, P(0) = 10⁹ I₆, T = 10⁻² s) runs in the same diagram on the sampled position
and the commanded pressures.

Truth: τ_e = KΦ(q)p and σ = −KΦ_q(q)p at the same samples. The thesis does not give
the interval of its indices; ours are over t ≥ 10 % of the run (config
``metric_window``). MSREP is read as percent (NOTES section 2 item 9). The torque
entries use the RLS model τ̂ = ΦΠ̂; the observer's own reconstruction is reported as
``observer_torque_*``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.estimation.estimators import EstimatorConfig, StiffnessEstimator
from softgen.studies.indices import error_records, estimation_figure, mse, msrep, window_mask
from softgen.estimation.offline import estimation_result, recorded
from softgen.modelfile.load import load_model
from softgen.plants.pneumatic import pendulum_diagram, sinusoid_reference_block
from softgen.studies.figures_pneumatic import pendulum_tracking as tracking_figure
from softgen.runtime.simulate import simulate, save_traces
from softgen.symbolic.actuators import McKibbenPairs
from softgen.symbolic.rigid import RigidDynamics
from softgen.experiments.registry import (Config, Experiment, Metrics, banded, finding,
                                          graded, not_checked, num, times)


@dataclass(frozen=True)
class PneumaticInvasiveConfig(Config):
    model: str = "pendulum_1link"
    duration: float = 60.0              # s
    dt: float = 1e-2                    # T
    substeps: int = 10                  # RK4 steps of the plant per sample
    q_amplitude: float = 0.3
    q_omega: float = np.pi / 10
    sigma_offset: float = 5.0
    sigma_amplitude: float = 1.0
    sigma_omega: float = np.pi / 6
    kp: float = 100.0                   # PD of the allocation's computed torque
    kd: float = 20.0
    powers: tuple[int, ...] = (0, 1, 2)  # κ = 2
    p0: float = 1e9
    delay: int = 2
    discretization: str = "euler"
    metric_window: tuple[float, float] | None = None   # None: after the first 10 %
    plant_integrator: str = "rk4"
    # Diagnostics (why our errors exceed the thesis's): the same run at T/2 and T/4,
    # and on an explicit-Euler plant at T, the observer's own discrete model.
    diagnostics: bool = True


THESIS = {"torque_mse_joint1": 1.7e-14, "stiffness_mse_joint1": 1.2e-5,
          "torque_msrep_joint1": 1.6e-8, "stiffness_msrep_joint1": 0.45}
# Section 6.1.3 does not say whether its flexibility-torque estimate is the observer's
# (UIO) or the RLS model's: both readings get the printed number.
THESIS.update({f"observer_{k}": v for k, v in THESIS.items() if k.startswith("torque_")})
# On a plant integrated by explicit Euler at T the observer runs on its own discrete model,
# the setting the finding compares with the printed table: it gets the printed numbers too.
THESIS.update({f"diagnostic_euler_plant_{k}": THESIS[k] for k in (
    "stiffness_mse_joint1", "torque_mse_joint1", "observer_torque_mse_joint1")})
NOT_IN_THESIS = {
    "diagnostic_T_*": "the indices again at T/2 and T/4: a discretisation check the thesis "
                      "does not run",
    "observer_error_*": "our fit of the observer error's mechanism (issue 13)",
    "position_rms_error": "section 6.1.3 prints estimation indices only (Fig. 6.3 shows "
                          "the tracking)",
    "estimator_seconds_per_step": "our timing",
    "metric_window_*": "the window the indices cover (the thesis does not state it)",
}
CAPTIONS = {
    "estimation.png": "True and estimated stiffness and flexibility torque of the pneumatic "
                      "pendulum (Theorem 1 observer + RLS), and their errors; mirrors Fig. 6.3.",
    "tracking.png": "Position and stiffness against their references with the muscle "
                    "pressures during the same run; mirrors Fig. 6.2.",
}


def run(c: PneumaticInvasiveConfig, out) -> Metrics:
    m = _run(c, out, figures=True)
    if c.diagnostics:
        base = c.replace(diagnostics=False)
        for tag, over in (("T_half", {"dt": c.dt / 2}), ("T_quarter", {"dt": c.dt / 4}),
                          ("euler_plant", {"plant_integrator": "euler", "substeps": 1})):
            m.extend(_run(base.replace(**over), out, figures=False), prefix=f"diagnostic_{tag}_",
                     keep=lambda r: r.quantity in ("stiffness_mse", "torque_mse",
                                                   "observer_torque_mse"))
    return m


def _run(c: PneumaticInvasiveConfig, out, *, figures: bool) -> Metrics:
    model = load_model(c.model)
    dyn, act = RigidDynamics(model), McKibbenPairs(model)
    est = StiffnessEstimator(model, EstimatorConfig(
        "pneumatic", dt=c.dt, delay=c.delay, powers=c.powers, p0=c.p0,
        discretization=c.discretization))
    ref = sinusoid_reference_block(
        "ref", [{"amplitude": c.q_amplitude, "omega": c.q_omega}],
        [{"offset": c.sigma_offset, "amplitude": c.sigma_amplitude, "omega": c.sigma_omega}])
    d = pendulum_diagram(f"ch6_pneumatic_{c.plant_integrator}_{c.substeps}", dyn, act, c.dt,
                         ref=ref, kp=c.kp, kd=c.kd, substeps=c.substeps,
                         integrator=c.plant_integrator, estimator=est.block("est"))
    K = int(round(c.duration / c.dt)) + 1
    tr = simulate(d, steps=K, x0={"plant.q": 0.0, "plant.qd": c.q_amplitude * c.q_omega},
                  record=["ref.q_d", "ref.sigma_d", "plant.q", "plant.qd", "ctrl.p", *recorded()],
                  label="ch6-pneumatic-invasive")
    q, p = tr["plant.q"], tr["ctrl.p"]
    if np.any(p < 0):
        raise FloatingPointError(f"ch6-pneumatic-invasive: a pressure went negative "
                                 f"(min {p.min():.3g} Pa)")
    tau, sigma = (np.array(v).T for v in act.functions()[0][0].map(K)(q.T, p.T))
    res = estimation_result(est, tr)
    t = tr.t
    mask = window_mask(t, c.metric_window, res)
    m = error_records(Metrics(), sigma, tau, res, mask)
    m.add("observer_torque_mse", mse(tau[mask, 0], res.tau_uio[mask, 0]), "(N m)^2", joint=1)
    m.add("observer_torque_msrep", msrep(tau[mask, 0], res.tau_uio[mask, 0]), "%", joint=1)
    m.add("position_rms_error", np.sqrt(np.mean((q[mask, 0] - tr["ref.q_d"][mask, 0]) ** 2)),
          "rad")
    # Measured decomposition of the observer's torque error e = τ̂_UIO − τ_e (issue 13):
    # least squares on the torque rate τ̇ (the second difference's lag) and σ q̇ (the
    # muscle torque drifting while the pressures are held over a sample), in units of
    # −T/2, and the rms of each fitted term.
    e = res.tau_uio[mask, 0] - tau[mask, 0]
    terms = np.column_stack([np.gradient(tau[:, 0], c.dt)[mask],
                             (sigma[:, 0] * tr["plant.qd"][:, 0])[mask]])
    coef, *_ = np.linalg.lstsq(terms, e, rcond=None)
    for name, k in (("tau_rate", 0), ("sigma_qd", 1)):
        m.add(f"observer_error_{name}_coef", coef[k] / (-c.dt / 2), "-T/2")
        m.add(f"observer_error_{name}_rms", np.sqrt(np.mean((coef[k] * terms[:, k]) ** 2)), "N m")
    m.add("observer_error_fit_r2", 1 - np.sum((e - terms @ coef) ** 2) / np.sum(e ** 2), "1")
    m.add("estimator_seconds_per_step", tr.wall_seconds / K, "s")
    m.add("metric_window_start", t[mask][0], "s")
    m.add("metric_window_end", t[mask][-1], "s")
    if figures:
        save_traces(out / "traces.npz", t=t, q=q[:, 0], p=p, tau_true=tau,
                            sigma_true=sigma, sigma_hat=res.sigma_hat, tau_hat=res.tau_hat,
                            tau_uio=res.tau_uio, theta=res.theta["joint1"])
        estimation_figure(out / "estimation.png", t, sigma, tau, res,
                          title="pneumatic, invasive",
                          names={"joint1": est.parameter_names("joint1")})
        tracking_figure(out / "tracking.png", t, q, tr["ref.q_d"], sigma, tr["ref.sigma_d"], p)
    return m


#: k of the band [1/k, k] section 6.1.3's indices are graded in: a simulation whose every
#: number is printed but the window of its indices; 3× in a mean square is 1.7× in the rms
#: error (halving T moves our MSE 3.5×: ``diagnostic_T_half_*``).
BAND = 3.0


def _indices(m: Metrics, claim: str, keys: list[str], kind: str, note: str) -> dict:
    flat = dict(m.items())
    if lost := [k for k in keys if k not in flat]:
        return not_checked(claim, lost, kind=kind, band=BAND)
    ok, ev = banded(flat, THESIS, keys, BAND)
    return finding(claim, graded(ok), ev + note, kind=kind, metrics=keys, band=BAND)


def findings(m: Metrics, c: Config | None = None) -> list[dict]:
    """Section 6.1.3's indices in the band [1/3, 3], on the continuous plant (the thesis's
    setting) and on the Euler plant (the observer's own discrete model, a variant)."""
    obs = m.find("observer_torque_mse", joint=1)
    out = [
        _indices(m, "Fig. 6.2-6.3 (section 6.1.3): stiffness estimated with MSE 1.2e-5 and "
                    "MSREP 0.45 %", ["stiffness_mse_joint1", "stiffness_msrep_joint1"],
                 "thesis", "; the printed pair disagrees with itself: at σ ≈ 5 N m/rad an MSE "
                           "of 1.2e-5 is an MSREP near 5e-5 %"),
        _indices(m, "Section 6.1.3: flexibility torque estimated with MSE 1.7e-14 and MSREP "
                    "1.6e-8 %", ["torque_mse_joint1", "torque_msrep_joint1"], "thesis",
                 " (the RLS model's torque" + (f"; the observer's own: MSE {num(obs.value)})"
                                               if obs is not None else ")"))]
    if m.find("stiffness_mse", joint=1, prefix="diagnostic_euler_plant_") is not None:
        cont = [m.value("stiffness_mse", joint=1, prefix=f"diagnostic_{t}_")
                for t in ("T_half", "T_quarter")]
        out.append(_indices(
            m, "Section 6.1.3 on the thesis's discrete model (plant integrated by explicit "
               "Euler at T, the observer's own model): stiffness and torque MSE 1.2e-5 and "
               "1.7e-14", ["diagnostic_euler_plant_stiffness_mse_joint1",
                           "diagnostic_euler_plant_torque_mse_joint1"], "variant",
            f"; on the continuous plant at T, T/2, T/4: {num(m.value('stiffness_mse', joint=1))}"
            f", {num(cont[0])}, {num(cont[1])} (O(T²)): the printed stiffness MSE lies between "
            "the two plants' and matches neither"))
    claim = ("Mechanism (issue 13): the observer's torque error is e ≈ −(T/2) τ̇ − (T/2) σ q̇, "
             "the σ q̇ term larger")
    names = ("fit_r2", "sigma_qd_rms", "tau_rate_rms", "tau_rate_coef", "sigma_qd_coef")
    if lost := [f"observer_error_{q}" for q in names if m.find(f"observer_error_{q}") is None]:
        return out + [not_checked(claim, lost, kind="diagnostic")]
    v = {q: m.value(f"observer_error_{q}") for q in names}
    out.append(finding(
        claim, "reproduced" if v["fit_r2"] > 0.9 and
        v["sigma_qd_rms"] > v["tau_rate_rms"] else "not reproduced",
        f"least squares on this run: coefficients {num(v['tau_rate_coef'])} and "
        f"{num(v['sigma_qd_coef'])} × (−T/2), R² {num(v['fit_r2'])}; rms of the σ q̇ term "
        f"{num(v['sigma_qd_rms'])} N m, {times(v['sigma_qd_rms'], v['tau_rate_rms'])} the "
        f"τ̇ term's {num(v['tau_rate_rms'])}", kind="diagnostic",
        metrics=[f"observer_error_{q}" for q in ("fit_r2", "sigma_qd_rms", "tau_rate_rms")]))
    return out


EXPERIMENT = Experiment(
    not_in_thesis=NOT_IN_THESIS, captions=CAPTIONS,
    id="ch6-pneumatic-invasive",
    title="Invasive stiffness estimation, pneumatic pendulum (Theorem 1 + RLS)",
    section="6.1.3, Fig. 6.2-6.3",
    run=run,
    config=PneumaticInvasiveConfig(),
    quick={"duration": 30.0},
    thesis=THESIS,
    findings=findings,
    discussion="""
**Reading.** Our stiffness MSREP is of the thesis's order; our MSEs are far above its
numbers. The thesis's observer is designed on the Euler-discretised model, so on a
continuous plant its torque reconstruction errs by O(T): the `diagnostic_T_half_*` and
`diagnostic_T_quarter_*` MSEs fall about 4x per halving of T. The error decomposition
measured on this run (`observer_error_*`) gives its mechanism: e ≈ a τ̇ + b σ q̇ with
a, b close to −T/2 and the σ q̇ term (the muscle torque drifting with q while the
pressures are held over a sample) larger than the τ̇ term (the lag of the second
difference). On a plant integrated by explicit Euler at T, the thesis's own discrete
model (`diagnostic_euler_plant_*`), the observer is exact to round-off and the MSEs
fall far *below* the printed ones: the printed stiffness MSE lies between the two
plants' and is reproduced by neither (graded in a two-sided band, issue 32). With
σ ≈ 5 N m/rad its stiffness MSE of 1.2e-5 means an MSREP near 5e-5 %, not the printed
0.45: the two printed numbers disagree with each other.
""",

)
