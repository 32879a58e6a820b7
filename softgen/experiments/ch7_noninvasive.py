"""``ch7-noninvasive-1dof`` and ``ch7-noninvasive-2dof``: section 7.3, Fig. 7.2-7.3.

Non-invasive estimation (Theorem 4): link positions only feed the observer
(triple integrator, L = 3), the rotatum comes from eq. 7.9 with the symbolic
model, and one RLS per joint fits (φ̇_a φ_a^j, φ̇_b φ_b^j). Motor positions give
the deflections; motor torques are not used.

1-DoF: ``pendulum_qbmove`` (m = 0.4 kg, l = 0.3 m, I = 0.015 kg m², β = 1e-7,
springs a1/k1 and a2/k2 of eq. 7.14), even powers (0, 2, 4) per side as in 7.3.
2-DoF: ``planar_2link`` (Table 7.1), powers 0…4 per side ("fifth-order expansion").

Section 7.3 gives neither references, sample time, P(0) nor run length: we track
sinusoidal position and stiffness references through the motors' servos (the
exact-model allocation of :mod:`electric_common`), T = 10⁻³ s, P(0) = 10⁸ I, 60 s,
indices after the first 10 %. The thesis reports no numbers for these runs
(figures only), so ``thesis`` is empty. Torque entries are for the rotatum τ̇_e.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..estimation.offline import run_offline
from . import electric_common as ec
from .estimation_common import error_metrics, estimation_figures
from .registry import Experiment

CONFIG_1DOF = {
    "model": "pendulum_qbmove",
    "duration": 60.0,
    "dt": 1e-3,
    "substeps": 10,
    "servo_bandwidth": 300.0,           # rad/s, the motors' own position loop
    "q_d": [{"offset": 0.0, "amplitude": 0.3, "omega": np.pi / 4}],
    "sigma_d": [{"offset": 5.0, "amplitude": 2.0, "omega": np.pi / 6}],
    "powers": [0, 2, 4],
    "p0": 1e8,
    "delay": 3,
    "metric_window": None,
}

CONFIG_2DOF = {
    **CONFIG_1DOF,
    "model": "planar_2link",
    "q_d": [{"offset": 0.3, "amplitude": 0.2, "omega": np.pi / 4},
            {"offset": 0.2, "amplitude": 0.2, "omega": np.pi / 5}],
    "sigma_d": [{"offset": 5.0, "amplitude": 2.0, "omega": np.pi / 6},
                {"offset": 3.0, "amplitude": 1.0, "omega": np.pi / 7}],
    "powers": [0, 1, 2, 3, 4],
}


DISCUSSION = """
**Reading.** The thesis prints figures, no numbers, for these simulations. The
rotatum τ̇_e changes sign every half period of the motion, so its MSREP is dominated
by the samples next to its zeros and says little; its MSE and the stiffness indices
are the informative ones. The rotatum carries a lightly damped link oscillation
(β is 1e-7 N m s in 7.3) that the estimate follows.
"""


def references(t, c):
    q = np.array([ec.sinusoid(t, **r) for r in c["q_d"]])           # (n, 3, K)
    s = np.array([ec.sinusoid(t, **r)[0] for r in c["sigma_d"]])    # (n, K)
    return q[:, 0], q[:, 1], q[:, 2], s


def run(config: dict, out: Path) -> dict:
    model, est, fns, t = ec.setup("noninvasive", config, out, servo=True)
    n, dt, K = model.dof, config["dt"], len(t)
    q_d, qd_d, qdd_d, sigma_d = references(t, config)
    refs = ec.motor_references(model, fns, q_d, qd_d, qdd_d, sigma_d)
    x0 = np.concatenate([q_d[:, 0], qd_d[:, 0], refs[0, :n], qd_d[:, 0], refs[0, n:],
                         qd_d[:, 0]])
    tr = ec.simulate(model, fns, dt=dt, K=K, x0=x0, inputs=refs,
                     spring_scale=np.ones(2 * n), servo=True)
    Y = ec.measure(tr, "noninvasive", n, config.get("sensors", {}), np.random.default_rng(0))
    res = run_offline(est, Y, step=fns[est.step_fun().name()])
    metrics, interval = error_metrics(t, tr.sigma, tr.rotatum, res, config["metric_window"])
    mask = (t >= interval[0]) & (t <= interval[1])
    for i in range(n):
        metrics[f"position_rms_error_joint{i + 1}"] = float(
            np.sqrt(np.mean((tr.x[mask, i] - q_d[i, mask]) ** 2)))
    metrics["estimator_seconds_per_step"] = res.seconds_per_step
    metrics["metric_window_start"], metrics["metric_window_end"] = interval
    np.savez_compressed(out / "traces.npz", t=t, x=tr.x, sigma=tr.sigma, rotatum=tr.rotatum,
                        sigma_hat=res.sigma_hat, rotatum_hat=res.tau_hat,
                        rotatum_uio=res.tau_uio, q_d=q_d, sigma_d=sigma_d,
                        **{f"theta_{r}": v for r, v in res.theta.items()})
    estimation_figures(out, t, tr.sigma, tr.rotatum, res, title="non-invasive",
                       torque_label="rotatum [N m/s]",
                       names={r: est.parameter_names(r) for r in est.rls_names})
    return metrics


EXPERIMENT_1DOF = Experiment(
    id="ch7-noninvasive-1dof",
    title="Non-invasive stiffness estimation, one-link qbmove robot (Theorem 3/4 + RLS)",
    section="7.3, Fig. 7.2",
    run=run, config=CONFIG_1DOF, quick={"duration": 20.0}, thesis={}, discussion=DISCUSSION,
)

EXPERIMENT_2DOF = Experiment(
    id="ch7-noninvasive-2dof",
    title="Non-invasive stiffness estimation, two-link arm with qbmove VSAs (Theorem 4 + RLS)",
    section="7.3, Fig. 7.3",
    run=run, config=CONFIG_2DOF, quick={"duration": 20.0}, thesis={}, discussion=DISCUSSION,
)
