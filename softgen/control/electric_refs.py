"""References of the chapter-11 simulations (section 11.2), with their derivatives.

The cascades of :mod:`softgen.control.electric` read, per joint, q_d and four time
derivatives and σ_d and three (:data:`~softgen.control.electric.REFERENCE_BLOCKS`):
the motor references' second derivative goes through q̈_d and σ̇_d of eq. 11.4 twice.
Sinusoids have them in closed form; nothing here is differentiated numerically.
"""
from __future__ import annotations

import numpy as np

from softgen.control.electric import REFERENCE_BLOCKS

#: Section 11.2: q_d = 1 + 0.5 sin(πt/10) on both joints; σ_1d = 8 + 3 sin(πt/8),
#: σ_2d = 4 + sin(πt/8). Per block: (offset, amplitude, ω) per joint.
THESIS_Q = ((1.0, 0.5, np.pi / 10), (1.0, 0.5, np.pi / 10))
THESIS_SIGMA = ((8.0, 3.0, np.pi / 8), (4.0, 1.0, np.pi / 8))


def _sinusoid_derivatives(t: np.ndarray, offset: float, amplitude: float, omega: float,
                          order: int) -> list[np.ndarray]:
    """offset + A sin(ωt) and its first ``order`` derivatives: A ω^k sin(ωt + kπ/2)."""
    out = [offset + amplitude * np.sin(omega * t)]
    for k in range(1, order + 1):
        out.append(amplitude * omega ** k * np.sin(omega * t + k * np.pi / 2))
    return out


def sinusoid_references(t, q_spec=THESIS_Q, sigma_spec=THESIS_SIGMA) -> np.ndarray:
    """Reference columns (9n × K) for the sample times ``t`` (K,), rows in the order of
    :data:`REFERENCE_BLOCKS`; ``q_spec``/``sigma_spec`` give (offset, amplitude, ω)
    per joint (default: section 11.2)."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    n = len(q_spec)
    if len(sigma_spec) != n:
        raise ValueError(f"sigma_spec: expected {n} joints like q_spec, got {len(sigma_spec)}")
    q = [_sinusoid_derivatives(t, *q_spec[i], 4) for i in range(n)]
    s = [_sinusoid_derivatives(t, *sigma_spec[i], 3) for i in range(n)]
    rows = [np.stack([q[i][k] for i in range(n)]) for k in range(5)]
    rows += [np.stack([s[i][k] for i in range(n)]) for k in range(4)]
    assert len(rows) == len(REFERENCE_BLOCKS)
    return np.concatenate(rows, axis=0)


#: Gains of section 11.2 (NOTES section 1, ch11-electric-pd / -adaptive). The adaptive
#: "k_p, k_d" are read as (Λ, k) (module docstring of :mod:`softgen.control.electric`);
#: k_π of the motors per joint (1a, 2a, 1b, 2b) for both b and d.
THESIS_GAINS = {
    "pd": dict(kp_m=50, kd_m=25, kp=25, kd=10, ksigma=150, delta=70),
    "pd_integral": dict(kp_m=50, kd_m=25, kp=0.05, kd=0.75, ksigma=30, ki=15, delta=70),
    "adaptive": dict(lam_m=0.1, k_m=0.1, kpi_m=[6e-4, 1e-3, 1e-4, 1e-4] * 2, lam=0.1, k=0.5,
                     kpi=0.2, ksigma=20, delta=145),
    "adaptive_integral": dict(lam_m=0.1, k_m=0.1, kpi_m=[6e-4, 1e-3, 1e-4, 1e-4] * 2,
                              lam=0.1, k=0.1, kpi=7, ksigma=20, ki=25, delta=145),
}


def thesis_run(arm, variant: str, *, duration: float = 40.0, dt: float = 1e-3,
               loop=None, steps: int = 1000, initial: str = "zero", **gains) -> dict:
    """Section 11.2's run of one cascade and its metrics (a measurement helper).

    ``arm`` is an :class:`~softgen.control.electric.ElectricArm` (its derivative route
    is used); ``gains`` override :data:`THESIS_GAINS` (a filter route needs
    ``omega_f``); ``loop`` is :func:`~softgen.control.electric.electric_closed_loop_fun`
    with ``steps`` samples (or its compiled version; default: built here and evaluated
    by CasADi). ``initial``: ``"zero"`` (π̂(0) = 0, as the thesis) or ``"nominal"``.
    The plant starts on the references (:func:`initial_plant_state`, quasi-steady
    stiffness without integral, :func:`integral_start` with). Metrics over the second
    half: position, stiffness and motor rms errors, signed mean stiffness error, and
    the largest |motor torque| over the run; ``None`` when the run did not stay finite.
    """
    from softgen.control.electric import (electric_closed_loop_fun, initial_plant_state, integral_start,
                           near_singular_events, run_closed_loop)
    import time

    g = {**THESIS_GAINS[variant], **gains}
    n = arm.n
    K = int(round(duration / dt))
    K -= K % steps
    ref = sinusoid_references(dt * np.arange(K))
    rf = lambda t: sinusoid_references(t)[:, 0]   # noqa: E731
    integ = variant.endswith("_integral")
    x0 = initial_plant_state(arm, rf, **({} if integ else dict(ksigma=g["ksigma"],
                                                                 delta=g["delta"])))
    nominal = initial == "nominal"
    z0 = arm.initial_state(
        variant, x0, xi0=integral_start(arm, x0, g["delta"], g["ki"]) if integ else None,
        pi_hat0=arm.parameter_nominal if nominal else None,
        pi_m_hat0=arm.motor_parameter_nominal if nominal else None)
    loop = loop or electric_closed_loop_fun(arm, variant, steps=steps)
    t0 = time.perf_counter()
    tr = run_closed_loop(arm, variant, loop, x0=x0, z0=z0, ref=ref, gains=g, dt=dt)
    wall = time.perf_counter() - t0
    half = slice(K // 2, None)
    finite = bool(np.all(np.isfinite(tr["x"])))

    def rms(e):
        return np.sqrt(np.mean(e[half] ** 2, axis=0)).tolist() if finite else None

    e_q = tr["x"][:, :n] - ref[:n].T
    e_s = tr["sigma"] - ref[5 * n:6 * n].T
    e_m = np.concatenate([tr["x"][:, 2 * n:3 * n], tr["x"][:, 4 * n:5 * n]], axis=1) \
        - tr["q_m_ref"]
    out = {"finite": finite, "simulated_seconds_per_wall_second": duration / wall,
           "position_rms_error": rms(e_q), "stiffness_rms_error": rms(e_s),
           "stiffness_mean_error": e_s[half].mean(0).tolist() if finite else None,
           "motor_rms_error": rms(e_m),
           "motor_torque_max_abs": float(np.abs(tr["tau_m"]).max()) if finite else None,
           "near_singular": near_singular_events(tr["t"], tr["det"], g["delta"])}
    if not finite:
        bad = np.flatnonzero(~np.all(np.isfinite(tr["x"]), axis=1))
        out["first_nonfinite_time"] = float(tr["t"][bad[0]])
    return out


def cascade_figure(path, tr, title: str) -> None:
    """Fig. 11.2-11.5's quantities of one run: link angles, stiffness, motor angles with
    their references and motor torques per joint (``tr``: a trace of the blocks of
    :mod:`softgen.control.electric` named ``ref``, ``ctrl``, ``plant``); adaptive runs add
    π̂/π and b̂/b."""
    from matplotlib.figure import Figure
    t, n = tr.t, tr["plant.q"].shape[1]
    adaptive = "ctrl.pi_hat" in tr.signals
    fig = Figure(figsize=(11, 12 if adaptive else 10))
    ax = fig.subplots(5 if adaptive else 4, 2, sharex=True)
    qm = np.hstack([tr["plant.qa"], tr["plant.qb"]])
    for i in range(n):
        ax[0, i].plot(t, tr["ref.q_d"][:, i], "k--", lw=1, label="q_d")
        ax[0, i].plot(t, tr["plant.q"][:, i], lw=1, label="q")
        ax[0, i].set_ylabel(f"q{i + 1} [rad]")
        ax[1, i].plot(t, tr["ref.sigma_d"][:, i], "k--", lw=1, label="σ_d")
        ax[1, i].plot(t, tr["plant.sigma"][:, i], lw=1, label="σ")
        ax[1, i].set_ylabel(f"σ{i + 1} [N m/rad]")
        for s, col in (("a", i), ("b", n + i)):
            ax[2, i].plot(t, tr["ctrl.q_m_ref"][:, col], "k--", lw=0.8)
            ax[2, i].plot(t, qm[:, col], lw=1, label=f"q{i + 1}{s}")
            ax[3, i].plot(t, tr["ctrl.tau_m"][:, col], lw=1, label=f"τ{i + 1}{s}")
        ax[2, i].set_ylabel("motor angle [rad] (-- ref)")
        ax[3, i].set_ylabel("motor torque [N m]")
        for a in ax[:4, i]:
            a.legend(loc="upper right", fontsize=7)
    if adaptive:
        pi, pm = tr.meta["parameter_nominal"], tr.meta["motor_parameter_nominal"]
        ax[4, 0].plot(t, tr["ctrl.pi_hat"] / pi, lw=1)
        ax[4, 0].set_ylabel("π̂ / π (link)")
        ax[4, 1].plot(t, tr["ctrl.pi_m_hat"][:, :2 * n] / pm[:2 * n], lw=1)
        ax[4, 1].set_ylabel("b̂ / b (motors)")
    for a in ax[-1]:
        a.set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
