"""``ch6-pneumatic-invasive``: section 6.1.3, Fig. 6.2-6.3.

The one-link pendulum of section 6.1 driven by its McKibben pair
(``models/pendulum_1link.toml``) tracks q_d = 0.3 sin(πt/10) and σ_d = 5 + sin(πt/6).
As the issue allows, the pressures come from an exact-model allocation (computed
torque on the link with PD feedback, then the pressures realising that torque and
σ_d at the measured q), not from the thesis's controller. The invasive estimator
(Theorem 1 observer with L = 2, RLS on p_a(1, q, q²), p_b(1, q, q²), Π̂(0) = 0,
P(0) = 10⁹ I₆, T = 10⁻² s) runs on the sampled position and commanded pressures.

Truth: τ_e = KΦ(q)p and σ = −KΦ_q(q)p at the same samples. The thesis does not give
the interval of its indices; ours are over t ≥ 10 % of the run (config
``metric_window``). MSREP is read as percent (NOTES section 2 item 9): 100 ·
mean(((χ − χ̂)/χ)²). The torque entries use the RLS model τ̂ = ΦΠ̂; the observer's
own reconstruction is reported as ``observer_torque_*``.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from ..estimation.estimators import EstimatorConfig, StiffnessEstimator
from ..estimation.offline import run_offline
from ..model import load_model
from ..symbolic.actuated import pneumatic_plant_fun
from ..symbolic.actuators import McKibbenPairs
from ..symbolic.rigid import FUNCTION_OPTS, RigidDynamics
from .estimation_common import error_metrics, estimation_figures, load_functions, mse, msrep
from .registry import Experiment

CONFIG = {
    "model": "pendulum_1link",
    "duration": 60.0,            # s
    "dt": 1e-2,                  # T
    "substeps": 10,              # RK4 steps of the plant per sample
    "q_d": {"amplitude": 0.3, "omega": np.pi / 10},
    "sigma_d": {"offset": 5.0, "amplitude": 1.0, "omega": np.pi / 6},
    "kp": 100.0, "kd": 20.0,     # PD of the allocation's computed torque
    "powers": [0, 1, 2],         # κ = 2
    "p0": 1e9,
    "delay": 2,
    "discretization": "euler",
    "metric_window": None,       # None: after the first 10 % of the run
    "plant_integrator": "rk4",
    # Diagnostics (why our errors exceed the thesis's): the same run at T/2 and T/4,
    # and on an explicit-Euler plant at T, the observer's own discrete model.
    "diagnostics": True,
}

THESIS = {"torque_mse_joint1": 1.7e-14, "stiffness_mse_joint1": 1.2e-5,
          "torque_msrep_joint1": 1.6e-8, "stiffness_msrep_joint1": 0.45}


def allocation_control_fun(dyn: RigidDynamics, act: McKibbenPairs) -> ca.Function:
    """Computed torque with PD at the measured state, then the exact-model pressures."""
    m = dyn.nominal
    n = dyn.model.dof
    q_d, qd_d, qdd_d, sigma_d = (ca.SX.sym(s, n) for s in ("q_d", "qd_d", "qdd_d", "sigma_d"))
    kp, kd = ca.SX.sym("kp"), ca.SX.sym("kd")
    acc = qdd_d + kd * (qd_d - m.qd) + kp * (q_d - m.q)
    tau = ca.substitute(m.slotine_li(dyn.route), ca.vertcat(m.qd_r, m.qdd_r),
                        ca.vertcat(m.qd, acc))
    p = act.allocation(m.q, tau, sigma_d)
    return ca.Function(f"{dyn.name}_allocation_control",
                       [m.q, m.qd, q_d, qd_d, qdd_d, sigma_d, kp, kd], [p],
                       ["q", "qd", "q_d", "qd_d", "qdd_d", "sigma_d", "kp", "kd"], ["p"],
                       FUNCTION_OPTS)


def run(config: dict, out: Path) -> dict:
    metrics = _run(config, out, figures=True)
    if config.get("diagnostics"):
        base = {**config, "diagnostics": False}
        for tag, over in (("T_half", {"dt": config["dt"] / 2}),
                          ("T_quarter", {"dt": config["dt"] / 4}),
                          ("euler_plant", {"plant_integrator": "euler", "substeps": 1})):
            sub = out / f"diagnostic_{tag}"
            sub.mkdir(exist_ok=True)
            m = _run({**base, **over}, sub, figures=False)
            for key in ("stiffness_mse_joint1", "torque_mse_joint1",
                        "observer_torque_mse_joint1"):
                metrics[f"diagnostic_{tag}_{key}"] = m[key]
    return metrics


def _run(config: dict, out: Path, *, figures: bool) -> dict:
    model = load_model(config["model"])
    dyn, act = RigidDynamics(model), McKibbenPairs(model)
    est = StiffnessEstimator(model, EstimatorConfig(
        "pneumatic", dt=config["dt"], delay=config["delay"], powers=tuple(config["powers"]),
        p0=config["p0"], discretization=config["discretization"]))
    fns = load_functions(model.name, [
        (pneumatic_plant_fun(dyn, act, substeps=config["substeps"],
                             integrator=config["plant_integrator"]), "plant, one sample"),
        (allocation_control_fun(dyn, act), "computed torque + exact pressure allocation"),
        (act.functions()[0][0], "torque and stiffness of the pair"),
        (est.step_fun(), "invasive pneumatic estimator step (Theorem 1 + RLS)"),
    ], out, config)
    plant = fns[f"{model.name}_pneumatic_plant"]
    ctrl = fns[f"{model.name}_allocation_control"]
    truth = fns[f"{model.name}_mckibben_torque"]

    dt = config["dt"]
    K = int(round(config["duration"] / dt)) + 1
    t = np.arange(K) * dt
    A, w = config["q_d"]["amplitude"], config["q_d"]["omega"]
    qd_ref = np.stack([A * np.sin(w * t), A * w * np.cos(w * t), -A * w * w * np.sin(w * t)])
    s = config["sigma_d"]
    sigma_ref = s["offset"] + s["amplitude"] * np.sin(s["omega"] * t)

    x = np.array([qd_ref[0, 0], qd_ref[1, 0]])
    X = np.empty((K, 2))
    Pr = np.empty((K, 2))
    tau_true, sigma_true = np.empty(K), np.empty(K)
    ci, pi_ = ctrl.inputs, plant.inputs
    ci[6][0], ci[7][0] = config["kp"], config["kd"]
    pi_[2][0] = dt
    for k in range(K):
        X[k] = x
        ci[0][0], ci[1][0] = x[0], x[1]
        ci[2][0], ci[3][0], ci[4][0], ci[5][0] = qd_ref[0, k], qd_ref[1, k], qd_ref[2, k], \
            sigma_ref[k]
        ctrl.call()
        Pr[k] = ctrl.outputs[0]
        truth.inputs[0][0] = x[0]
        truth.inputs[1][:] = Pr[k]
        truth.call()
        tau_true[k], sigma_true[k] = truth.outputs[0][0], truth.outputs[1][0]
        pi_[0][:], pi_[1][:] = x, Pr[k]
        plant.call()
        x[:] = plant.outputs[0]
    if not np.all(np.isfinite(X)) or np.any(Pr < 0):
        raise FloatingPointError("ch6-pneumatic-invasive: plant diverged or a pressure went "
                                 f"negative (min {Pr.min():.3g} Pa)")

    Y = np.column_stack([X[:, 0], Pr])
    res = run_offline(est, Y, step=fns[est.step_fun().name()])
    metrics, interval = error_metrics(t, sigma_true[:, None], tau_true[:, None], res,
                                      config["metric_window"])
    mask = (t >= interval[0]) & (t <= interval[1])
    metrics["observer_torque_mse_joint1"] = mse(tau_true[mask], res.tau_uio[mask, 0])
    metrics["observer_torque_msrep_joint1"] = msrep(tau_true[mask], res.tau_uio[mask, 0])
    metrics["position_rms_error"] = float(np.sqrt(np.mean((X[mask, 0] - qd_ref[0, mask]) ** 2)))
    metrics["estimator_seconds_per_step"] = res.seconds_per_step
    metrics["metric_window_start"], metrics["metric_window_end"] = interval
    np.savez_compressed(out / "traces.npz", t=t, q=X[:, 0], qd=X[:, 1], p=Pr,
                        tau_true=tau_true, sigma_true=sigma_true, sigma_hat=res.sigma_hat,
                        tau_hat=res.tau_hat, tau_uio=res.tau_uio, theta=res.theta["joint1"])
    if figures:
        estimation_figures(out, t, sigma_true[:, None], tau_true[:, None], res,
                           title="pneumatic, invasive",
                           names={"joint1": est.parameter_names("joint1")})
        _tracking_figure(out, t, X, qd_ref, sigma_ref, sigma_true, Pr)
    return metrics


def _tracking_figure(out, t, X, qd_ref, sigma_ref, sigma_true, Pr) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    ax[0].plot(t, qd_ref[0], "k", label="q_d")
    ax[0].plot(t, X[:, 0], "--", label="q")
    ax[0].set_ylabel("q [rad]")
    ax[0].legend()
    ax[1].plot(t, sigma_ref, "k", label="sigma_d")
    ax[1].plot(t, sigma_true, "--", label="sigma")
    ax[1].set_ylabel("sigma [N m/rad]")
    ax[1].legend()
    ax[2].plot(t, Pr[:, 0] / 1e5, label="p_a")
    ax[2].plot(t, Pr[:, 1] / 1e5, label="p_b")
    ax[2].set_ylabel("pressure [bar]")
    ax[2].set_xlabel("t [s]")
    ax[2].legend()
    fig.tight_layout()
    fig.savefig(Path(out) / "tracking.png", dpi=100)
    plt.close(fig)


EXPERIMENT = Experiment(
    id="ch6-pneumatic-invasive",
    title="Invasive stiffness estimation, pneumatic pendulum (Theorem 1 + RLS)",
    section="6.1.3, Fig. 6.2-6.3",
    run=run,
    config=CONFIG,
    quick={"duration": 30.0},
    thesis=THESIS,
    discussion="""
**Reading.** Our stiffness MSREP is of the thesis's order; our MSEs are far above its
numbers. The diagnostics say why. The thesis's observer is designed on the
Euler-discretised model, so its input estimate is a second difference of q: on a
continuous plant it errs by O(T), and the `diagnostic_T_half_*` and
`diagnostic_T_quarter_*` MSEs fall about 4x per halving of T (O(T²) in MSE). On a
plant integrated by explicit Euler at T, i.e. the observer's own model
(`diagnostic_euler_plant_*`), the observer is exact to round-off and the torque and
stiffness MSEs drop to the thesis's order: its printed numbers are what this
estimator gives on its own discrete model, not on a continuous plant. The thesis's
MSE and MSREP for stiffness also disagree with each other: with σ ≈ 5 N m/rad an
MSE of 1.2e-5 means a mean squared relative error near 5e-7, i.e. 5e-5 %, not 0.45.
""",
)
