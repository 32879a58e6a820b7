"""``ch6-electric-invasive``: section 6.2.3, Fig. 6.5-6.6, Table 6.1.

The two-link arm of Table 7.1 with a qbmove VSA per joint (``planar_2link``:
b = 3e-6 kg m², d = 1e-6 N m s, a/k per joint as NOTES section 2 item 7) under
open-loop sinusoidal motor torques of 0.15 N m at 0.25, 0.06, 0.17 and 0.08 Hz
(τ_11, τ_12, τ_21, τ_22), T = 10⁻³ s. One Theorem 2 observer (L = 2) per motor and
one RLS per motor on (φ, φ³, φ⁵, φ⁷), Π̂(0) = 0, P(0) = 10⁸ I₄; plant and estimator
run in one diagram (:mod:`softgen.plants.qbmove`).

The thesis does not say how long it ran nor over which interval Table 6.1 is
computed; we run 60 s and compute the indices after the first 10 %. MSREP in
percent (Table 6.1 labels its column [%]). Torque entries: the joint's total
flexibility torque from the RLS models; stiffness: σ̂_a + σ̂_b.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimation.indices import mse, msrep
from ..model import load_model
from ..plants.qbmove import polynomial_fit_stiffness
from ..symbolic.actuators import QbmoveSprings
from .estimation_common import estimator, figures, qbmove_run, variant_records
from .registry import Config, Experiment, Metrics, finding, num, times


@dataclass(frozen=True)
class ElectricInvasiveConfig(Config):
    model: str = "planar_2link"
    duration: float = 60.0
    dt: float = 1e-3
    substeps: int = 10              # RK4 at 0.1 ms: the motor-spring modes reach ~600 rad/s
    torque_amplitude: float = 0.15  # N m
    torque_frequency: tuple[float, ...] = (0.25, 0.06, 0.17, 0.08)  # Hz: τ_11, τ_12, τ_21, τ_22
    powers: tuple[int, ...] = (1, 3, 5, 7)
    p0: float = 1e8
    delay: int = 2
    metric_window: tuple[float, float] | None = None


THESIS = {"stiffness_mse_joint1": 1.84e-7, "stiffness_mse_joint2": 1.92e-7,
          "stiffness_msrep_joint1": 3.34e-7, "stiffness_msrep_joint2": 3.38e-7,
          "torque_mse_joint1": 1.49e-11, "torque_mse_joint2": 1.62e-11,
          "torque_msrep_joint1": 2.85e-9, "torque_msrep_joint2": 2.84e-9}


def run(c: ElectricInvasiveConfig, out) -> Metrics:
    model = load_model(c.model)
    n = model.dof
    est = estimator(model, "electric", c)
    K = int(round(c.duration / c.dt)) + 1
    t = np.arange(K) * c.dt
    # Plant input order: τ_a of each joint, then τ_b; the thesis's τ_ij is joint i, motor j.
    f = np.array(c.torque_frequency).reshape(n, 2)
    U = c.torque_amplitude * np.sin(2 * np.pi * np.outer(t, np.concatenate([f[:, 0], f[:, 1]])))
    tr, truth = qbmove_run("ch6_electric_invasive", model, c, {"est": est.block("est")}, K=K,
                           inputs={"tau_motor": U}, x0={}, servo=False)
    m, res, mask = variant_records(tr, truth, est, "est", c.metric_window, truth.tau_e)
    for i in range(n):
        m.add("observer_torque_mse", mse(truth.tau_e[mask, i], res.tau_uio[mask, i]),
              "(N m)^2", joint=i + 1)
    phi = np.hstack([tr["plant.q"] - tr["plant.qa"], tr["plant.q"] - tr["plant.qb"]])
    m.add("max_abs_deflection", np.abs(phi).max(), "rad")
    # Two measured limits on the accuracy: the least-squares fit of the odd polynomial
    # to the *true* spring torques (the RLS model class), and the fastest
    # motor-against-spring mode sqrt(σ_j/b_j) met, beside the Nyquist rate π/T.
    fit = polynomial_fit_stiffness(phi[mask], truth.spring_torque[mask], c.powers)
    for i in range(n):
        m.add("polynomial_fit_stiffness_msrep", msrep(truth.sigma[mask, i], fit[:, i]), "%",
              joint=i + 1)
    sp = QbmoveSprings(model)
    m.add("motor_mode_max_rad_s", np.sqrt(truth.spring_stiffness / np.concatenate(
        [sp.b_a, sp.b_b])).max(), "rad/s")
    m.add("nyquist_rad_s", np.pi / c.dt, "rad/s")
    m.add("metric_window_start", t[mask][0], "s")
    m.add("metric_window_end", t[mask][-1], "s")
    np.savez_compressed(out / "traces.npz", t=t, tau_motor=U, tau_e=truth.tau_e,
                        sigma=truth.sigma, sigma_hat=res.sigma_hat, tau_hat=res.tau_hat,
                        tau_uio=res.tau_uio, **{f"x_{s}": tr[f"plant.{s}"] for s in
                                                ("q", "qd", "qa", "qad", "qb", "qbd")},
                        **{f"theta_{r}": v for r, v in res.theta.items()})
    figures(out, "", tr, truth.sigma, truth.tau_e, res, est, "electric, invasive")
    return m


def findings(m: dict) -> list[dict]:
    """Table 6.1: stiffness MSE per joint within 10× of the thesis's."""
    ok = [m[f"stiffness_mse_joint{j}"] < 10 * THESIS[f"stiffness_mse_joint{j}"] for j in (1, 2)]
    return [finding(
        "Table 6.1: stiffness MSE 1.8e-7 / 1.9e-7 (joints 1/2) under open-loop torques",
        "reproduced" if all(ok) else "partly reproduced" if any(ok) else "not reproduced",
        f"stiffness MSE {num(m['stiffness_mse_joint1'])} / {num(m['stiffness_mse_joint2'])} "
        f"({times(m['stiffness_mse_joint1'], 1.84e-7)} / "
        f"{times(m['stiffness_mse_joint2'], 1.92e-7)} the thesis's; threshold 10×); largest "
        f"deflection {num(m['max_abs_deflection'])} rad, fastest motor mode "
        f"{num(m['motor_mode_max_rad_s'])} rad/s against Nyquist {num(m['nyquist_rad_s'])}")]


EXPERIMENT = Experiment(
    id="ch6-electric-invasive",
    title="Invasive stiffness estimation, two-link arm with qbmove VSAs (Theorem 2 + RLS)",
    section="6.2.3, Fig. 6.5-6.6, Table 6.1",
    run=run,
    config=ElectricInvasiveConfig(),
    quick={"duration": 20.0},
    thesis=THESIS,
    findings=findings,
    discussion="""
**Reading.** Our errors are orders of magnitude above Table 6.1. Two measurements in
this run locate the cause. `polynomial_fit_stiffness_msrep_joint*` (the odd
polynomial fitted by least squares to the true spring torques) is small, so the RLS
model class is not the limit. `motor_mode_max_rad_s` against `nyquist_rad_s` is: with
the thesis's motor inertia b = 3e-6 kg m² and damping d = 1e-6 N m s, each motor
oscillates against its exponentially stiffening spring at hundreds to thousands of
rad/s, barely damped, and the open-loop torques of section 6.2.3 keep exciting
these modes (see the torque traces). The observer's Euler model is a finite
difference that is accurate only for ωT ≪ 1, so its torque reconstruction
(`observer_torque_mse_joint*`) carries these errors into the RLS. The thesis's
figures show no such oscillation; its numbers are reproducible only on a plant
without these modes (compare the Euler-plant diagnostic of ch6-pneumatic-invasive).
""",
)
