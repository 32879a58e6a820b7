"""ch10-pneumatic-adaptive: Theorem 5 on the two-link McKibben arm (section 10.2, Fig. 10.2-10.3).

Plant: Table 7.1 arm with the Table 10.1 muscles (``models/planar_2link_mckibben``),
pressures applied as commanded (the section's assumption), clipped to [0, 8 bar].
Controller: Theorem 5 (eq. 10.1-10.4 with NOTES section 2 item 4), K_d = 18, λ = 15,
K_π = 35, Π̂(0) = 0.9 Π; exact Φ and K, as the section assumes.

Choices the thesis leaves open, stated here:

- K_σ: not printed. K_σ = r/K_1 with r = ``stiffness_rate`` 1/s, so the stiffness error
  decays as exp(−r t) (K⁻¹σ̇ = u_σ, eq. 10.6).
- Sample time: the controller integrates ν and Π̂ by forward Euler at ``dt`` = 1 ms
  (the thesis ran Simulink, continuous in effect). The run is repeated at dt/2 and
  the largest change of the rms errors is reported (``dt_halving_max_rms_change``).
- References: the section gives phases, not values. Smoothed steps (C³, septic, rise
  ``rise`` s; instantaneous steps make s and τ_* jump and the thesis itself notes the
  stiffness transients they cause): phase 1 [0, 190) s position steps at σ_d = 2;
  phase 2 [190, 250) s stiffness steps at constant position; phase 3 [250, 350) s both.
- Preset (the thesis's "initially inflated" phase): ``preset`` s at rest with K_π = 0,
  starting from the ν that gives σ = 2 N m/rad by the actuator model.

The same run with the open-loop stiffness controller of Tonietti and Bicchi (K_π, K_d,
λ equal) is the reference for the coupling indices.
"""
from __future__ import annotations

import time

import numpy as np

from ..control.feasibility import check_pressures
from ..control.pneumatic import pneumatic_arm
from ..control.pneumatic_loop import closed_loop_fun
from ..control.references import SmoothSteps
from ..model import load_model
from .estimation_common import load_functions
from .pneumatic_common import coupling, parameter_ratio, phase_rms
from .registry import Experiment, absent, finding, graded, not_checked, num, times

PHASES = ((0.0, 190.0), (190.0, 250.0), (250.0, 350.0))

#: (times, values) of the smoothed steps: q1, q2 (rad), sigma1, sigma2 (N m/rad).
SCHEDULE = {
    "q1": ((0, 10, 50, 90, 130, 260, 320), (0.0, 0.1, 0.2, 0.3, 0.15, 0.3, 0.1)),
    "q2": ((0, 30, 70, 110, 150, 290), (0.0, 0.1, 0.2, 0.3, 0.15, 0.0)),
    "s1": ((0, 195, 220, 260, 320), (2.0, 3.0, 4.0, 3.0, 4.0)),
    "s2": ((0, 205, 230, 290, 320), (2.0, 2.5, 3.0, 2.0, 2.5)),
}

CONFIG = {
    "model": "planar_2link_mckibben",
    "controller": "theorem5",
    "dt": 1e-3,
    "chunk": 1000,
    "preset": 5.0,
    "duration": 350.0,
    "rise": 2.0,
    "lam": 15.0,
    "kd": 18.0,
    "kpi": 35.0,
    "stiffness_rate": 2.0,
    "sigma_preset": 2.0,
    "pi_hat0_ratio": 0.9,
    "adaptation_settle": 40.0,
    "compare_open_loop": True,
    "check_dt_halving": True,
    "compare_model_acceleration": True,
}


def references(t: np.ndarray, rise: float) -> np.ndarray:
    """(6n × len(t)): q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d of the schedule."""
    q = [SmoothSteps(*SCHEDULE[k], rise).check()(t) for k in ("q1", "q2")]
    s = [SmoothSteps(*SCHEDULE[k], rise).check()(t) for k in ("s1", "s2")]
    rows = [q[j][d] for d in range(4) for j in range(2)]
    rows += [s[j][0] for j in range(2)] + [s[j][1] for j in range(2)]
    return np.array(rows)


def _windows(kind: str, rise: float, settle: float) -> list[tuple[float, float, float]]:
    """Intervals in which only ``kind`` ("q" or "s") references move, with step sizes."""
    own, other = (("q1", "q2"), ("s1", "s2")) if kind == "q" else (("s1", "s2"), ("q1", "q2"))
    other_times = sorted({t for k in other for t in SCHEDULE[k][0][1:]})
    changes = sorted({t for k in own + other for t in SCHEDULE[k][0][1:]})
    out = []
    for key in own:
        times, values = SCHEDULE[key]
        for t0, a, b in zip(times[1:], values[:-1], values[1:]):
            if t0 < settle or any(abs(t0 - u) < rise for u in other_times):
                continue
            t1 = min([c for c in changes if c > t0] + [PHASES[-1][1]])
            out.append((float(t0), float(t1), abs(b - a)))
    return out


def simulate(arm, fns: dict, kind: str, c: dict, dt: float) -> dict[str, np.ndarray]:
    """Preset, then the three phases, in chunks of one generated loop call."""
    n, K1 = arm.n, arm.K1
    chunk = int(c["chunk"])
    loop = fns[f"{arm.step_fun(kind).name()}_loop_ideal"]
    Pi = arm.Pi_nominal
    lam, kd = np.full(n, c["lam"]), np.full(n, c["kd"])
    ksigma, kinv = np.full(n, c["stiffness_rate"] / K1), 1 / arm.act.K
    tp = np.ones(2 * n)                              # unused by the ideal plant
    pi0 = c["pi_hat0_ratio"] * Pi
    # Preset inflation: the ν (and pressures) the actuator model gives σ_preset at rest.
    ol = fns[f"{arm.name}_open_loop_stiffness"]
    ref0 = references(np.array([0.0]), c["rise"])[:, 0]
    ref0[4 * n:5 * n] = c["sigma_preset"]
    _, p0, _, nu0 = ol(pi0, np.zeros(n), np.zeros(n), ref0, lam, kd, np.zeros(arm.n_params),
                       kinv, dt)
    x = np.concatenate([np.zeros(2 * n), p0])
    z = np.concatenate([nu0, pi0]) if kind == "theorem5" else pi0.copy()
    n_pre = int(round(c["preset"] / dt / chunk)) * chunk
    n_run = int(round(c["duration"] / dt / chunk)) * chunk
    t = (np.arange(n_pre + n_run) - n_pre) * dt
    X, Z, P, S = [], [], [], []
    for start in range(0, t.size, chunk):
        tt = t[start:start + chunk]
        R = references(np.maximum(tt, 0.0), c["rise"])
        kpi = np.full(arm.n_params, c["kpi"] if tt[0] >= 0 else 0.0)
        xs, zs, ps, ss = loop(x, z, R, lam, kd, kpi, ksigma, kinv, tp, dt)
        x, z = xs[:, -1].copy(), zs[:, -1].copy()
        X.append(xs)
        Z.append(zs)
        P.append(ps)
        S.append(ss)
        if not np.all(np.isfinite(x)):
            raise FloatingPointError(f"{kind}: state not finite at t = {tt[-1]:.3f} s")
    keep = t >= 0
    X, Z, P, S = (np.hstack(a)[:, keep] for a in (X, Z, P, S))
    t = t[keep]
    R = references(t, c["rise"])
    nz = 0 if kind != "theorem5" else n
    return {"t": t, "q": X[:n].T, "qd": X[n:2 * n].T, "p": X[2 * n:].T, "p_cmd": P.T,
            "sigma": S.T, "q_d": R[:n].T, "sigma_d": R[4 * n:5 * n].T,
            "nu": Z[:nz].T, "Pi_hat": Z[nz:].T}


def _metrics(tr: dict, Pi: np.ndarray, c: dict, prefix: str = "") -> dict[str, float]:
    t = tr["t"]
    m = {}
    m.update(phase_rms(t, tr["q"] - tr["q_d"], PHASES, f"{prefix}position_rms_error"))
    m.update(phase_rms(t, tr["sigma"] - tr["sigma_d"], PHASES,
                       f"{prefix}stiffness_rms_error"))
    m.update(coupling(t, tr["sigma"] - tr["sigma_d"],
                      _windows("q", c["rise"], c["adaptation_settle"]),
                      f"{prefix}position_to_stiffness_coupling"))
    m.update(coupling(t, tr["q"] - tr["q_d"], _windows("s", c["rise"], c["adaptation_settle"]),
                      f"{prefix}stiffness_to_position_coupling"))
    m[f"{prefix}parameter_estimate_max_ratio"] = parameter_ratio(tr["Pi_hat"], Pi)
    return m


def run(config: dict, out) -> dict:
    c = config
    arm = pneumatic_arm(load_model(c["model"]))
    kinds = ["theorem5"] + (["open_loop"] if c["compare_open_loop"] else [])
    fns = [(closed_loop_fun(arm, k, plant="ideal", steps=int(c["chunk"])), f"{k} closed loop")
           for k in kinds]
    fns.append((arm.step_fun("open_loop"), "open-loop stiffness step (preset)"))
    fns = load_functions(arm.name, fns, out, c)
    t0 = time.perf_counter()
    tr = simulate(arm, fns, "theorem5", c, c["dt"])
    wall = time.perf_counter() - t0
    pmax = arm.act.pressure_max
    viol = check_pressures(tr["t"], tr["p_cmd"], pmax, label="ch10-pneumatic-adaptive")
    m = _metrics(tr, arm.Pi_nominal, c)
    m["pressure_violations"] = float(len(viol))
    # Preset plus the three phases, controller and plant in generated C loops.
    m["simulated_seconds_per_wall_second"] = (c["preset"] + c["duration"]) / wall
    m["pressure_min_pa"] = float(tr["p_cmd"].min())
    m["pressure_max_pa"] = float(tr["p_cmd"].max())
    np.savez_compressed(out / "traces.npz", **tr)
    if c["compare_open_loop"]:
        ol = simulate(arm, fns, "open_loop", c, c["dt"])
        m.update({k: v for k, v in _metrics(ol, arm.Pi_nominal, c, "open_loop_").items()
                  if "coupling" in k or "position_rms" in k})
    if c["check_dt_halving"]:
        m["dt_halving_max_rms_change"] = _dt_check(arm, c, out, m)
    if c["compare_model_acceleration"]:
        # Theorem 5 with the q̈ path of d/dt(Φ^†τ_*) closed by the adapted model.
        arm_a = pneumatic_arm(arm.model, acceleration="model")
        fa = load_functions(arm.name, [
            (closed_loop_fun(arm_a, "theorem5", plant="ideal", steps=int(c["chunk"])),
             "Theorem 5 (model acceleration) closed loop"),
            (arm.step_fun("open_loop"), "open-loop step (preset)")], out / "model_acceleration", c)
        ma = simulate(arm_a, fa, "theorem5", c, c["dt"])
        m.update({k: v for k, v in _metrics(ma, arm.Pi_nominal, c, "model_acceleration_").items()
                  if "coupling" in k or "stiffness_rms" in k})
    _figures(tr, arm, out)
    return m


def _dt_check(arm, c: dict, out, m: dict) -> float:
    """Largest |change| of the rms-error metrics when the sample time is halved."""
    c2 = {**c, "dt": c["dt"] / 2, "compare_open_loop": False}
    fns = load_functions(arm.name,
                         [(closed_loop_fun(arm, "theorem5", plant="ideal",
                                           steps=int(c2["chunk"])), "Theorem 5 closed loop"),
                          (arm.step_fun("open_loop"), "open-loop step (preset)")],
                         out / "half_dt", c2)
    tr = simulate(arm, fns, "theorem5", c2, c2["dt"])
    m2 = _metrics(tr, arm.Pi_nominal, c2)
    return max(abs(m2[k] - m[k]) for k in m2 if "rms_error" in k)


def _figures(tr: dict, arm, out) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = tr["t"]
    fig, ax = plt.subplots(4, 2, figsize=(11, 10), sharex=True)
    for j in range(2):
        ax[0, j].plot(t, tr["q_d"][:, j], "k--", lw=1, label="q_d")
        ax[0, j].plot(t, tr["q"][:, j], lw=1, label="q")
        ax[0, j].set_ylabel(f"q{j + 1} [rad]")
        ax[1, j].plot(t, tr["sigma_d"][:, j], "k--", lw=1, label="σ_d")
        ax[1, j].plot(t, tr["sigma"][:, j], lw=1, label="σ")
        ax[1, j].set_ylabel(f"σ{j + 1} [N m/rad]")
        ax[2, j].plot(t, tr["p_cmd"][:, 2 * j] / 1e5, lw=1, label="p_a")
        ax[2, j].plot(t, tr["p_cmd"][:, 2 * j + 1] / 1e5, lw=1, label="p_b")
        ax[2, j].set_ylabel("pressure [bar]")
        ax[3, j].plot(t, tr["nu"][:, j], lw=1)
        ax[3, j].set_ylabel(f"ν{j + 1}")
        ax[3, j].set_xlabel("t [s]")
        for a in ax[:3, j]:
            a.legend(loc="upper left", fontsize=7)
        for t0, _ in PHASES[1:]:
            for a in ax[:, j]:
                a.axvline(t0, color="0.7", lw=0.8)
    fig.suptitle("Theorem 5 on the two-link McKibben arm (cf. Fig. 10.2)")
    fig.tight_layout()
    fig.savefig(out / "fig10_2_tracking.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t, tr["Pi_hat"] / arm.Pi_nominal, lw=1)
    ax.legend(arm.parameter_names, fontsize=7)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("Π̂ / Π")
    ax.set_title("Parameter estimates (cf. Fig. 10.3)")
    fig.tight_layout()
    fig.savefig(out / "fig10_3_parameters.png", dpi=110)
    plt.close(fig)


def findings(m: dict) -> list[dict]:
    """The claims of section 10.2 (Fig. 10.2-10.3) checked against the metrics ``m``.

    Thresholds, stated again in each evidence text: rms errors (second half of each
    phase) below 1e-3 rad and 1e-2 N m/rad; coupling indices below what lets a 0.1 rad
    position step move σ by 1e-2 N m/rad, or a 1 N m/rad stiffness step move q by
    1e-3 rad (the tracking tolerances); ‖Π̂‖/‖Π‖ below 10; no pressure violation.
    """
    pos_tol, stiff_tol = 1e-3, 1e-2          # rad, N m/rad
    p2s_tol, s2p_tol = stiff_tol / 0.1, pos_tol / 1.0
    ratio_tol = 10.0
    joints, phases = (1, 2), (1, 2, 3)
    out = []

    claim = ("Fig. 10.2 (section 10.2): position and stiffness references are tracked with "
             "errors that go to zero after adaptation.")
    pos = {(i, k): f"position_rms_error_joint{i}_phase{k}" for i in joints for k in phases}
    sti = {(i, k): f"stiffness_rms_error_joint{i}_phase{k}" for i in joints for k in phases}
    if lost := absent(m, [*pos.values(), *sti.values()]):
        out.append(not_checked(claim, lost))
    else:
        pi, pk = max(pos, key=lambda ik: m[pos[ik]])
        si, sk = max(sti, key=lambda ik: m[sti[ik]])
        p_worst, s_worst = m[pos[pi, pk]], m[sti[si, sk]]
        out.append(finding(claim, graded([p_worst < pos_tol, s_worst < stiff_tol]),
                           f"Largest rms error over the second half of a phase: position "
                           f"{num(p_worst)} rad (joint {pi}, phase {pk}), stiffness "
                           f"{num(s_worst)} N m/rad (joint {si}, phase {sk}); thresholds "
                           f"< {pos_tol:g} rad and < {stiff_tol:g} N m/rad."))

    claim = ("Fig. 10.2 (section 10.2): position commands have almost no influence on the "
             "stiffness, and stiffness commands almost none on the position.")
    p2s = {i: f"position_to_stiffness_coupling_joint{i}" for i in joints}
    s2p = {i: f"stiffness_to_position_coupling_joint{i}" for i in joints}
    if lost := absent(m, [*p2s.values(), *s2p.values()]):
        out.append(not_checked(claim, lost))
    else:
        def quote(d: dict, unit: str) -> str:
            # Against the open-loop stiffness controller when the run has it (full runs).
            parts = []
            for i, key in d.items():
                ol = m.get(f"open_loop_{key}")
                rel = "" if ol is None else f"; {times(m[key], ol)} open loop"
                parts.append(f"{num(m[key])} {unit} (joint {i}{rel})")
            return ", ".join(parts)

        ok = [all(m[k] < p2s_tol for k in p2s.values()), all(m[k] < s2p_tol for k in s2p.values())]
        has_ol = not absent(m, [f"open_loop_{k}" for k in [*p2s.values(), *s2p.values()]])
        out.append(finding(
            claim, graded(ok),
            f"Stiffness deviation per rad of position step {quote(p2s, 'N m/rad')}; position "
            f"deviation per N m/rad of stiffness step {quote(s2p, 'rad')}"
            + ("" if has_ol else " (open-loop stiffness controller not run here)")
            + f"; thresholds < {p2s_tol:g} N m/rad per rad and < {s2p_tol:g} rad per "
            "N m/rad."))

    claim = "Fig. 10.3 (section 10.2): the parameter estimates stay bounded."
    if lost := absent(m, ["parameter_estimate_max_ratio"]):
        out.append(not_checked(claim, lost))
    else:
        r = m["parameter_estimate_max_ratio"]
        out.append(finding(claim, graded([r < ratio_tol]),
                           f"Largest ‖Π̂(t)‖/‖Π‖ {num(r)}; threshold < {ratio_tol:g}."))

    claim = "Section 10.2: the commanded pressures are feasible (within [0, p_max])."
    if lost := absent(m, ["pressure_violations"]):
        out.append(not_checked(claim, lost))
    else:
        v = m["pressure_violations"]
        span = (f"; commanded pressures ranged over [{num(m['pressure_min_pa'])}, "
                f"{num(m['pressure_max_pa'])}] Pa"
                if not absent(m, ["pressure_min_pa", "pressure_max_pa"]) else "")
        out.append(finding(claim, graded([v == 0]),
                           f"{v:g} episode(s) of a commanded pressure outside [0, p_max]"
                           f"{span}; required: 0."))
    return out


EXPERIMENT = Experiment(
    id="ch10-pneumatic-adaptive",
    title="Decoupled adaptive position and stiffness control of a two-link McKibben arm",
    section="10.2, Fig. 10.2-10.3",
    run=run,
    config=CONFIG,
    quick={"compare_open_loop": False, "check_dt_halving": False,
           "compare_model_acceleration": False},
    findings=findings,
    discussion=(
        "The thesis prints no numbers for this simulation, only Fig. 10.2-10.3. Read "
        "`position_rms_error_joint{i}_phase{k}` and `stiffness_rms_error_joint{i}_phase{k}` "
        "(second half of each phase) for convergence after adaptation, and the coupling "
        "indices for the decoupling: stiffness deviation per radian of position step while "
        "only positions move, and position deviation per N m/rad of stiffness step while "
        "only stiffnesses move. The open-loop stiffness controller (`open_loop_*`) runs on "
        "the same plant with the exact actuator model, where open-loop stiffness is exact "
        "by construction; its stiffness coupling is therefore the floor, and the Theorem 5 "
        "coupling is the price of the omitted q̈ path of d/dt(Φ^†τ_*) (module docstring of "
        "`softgen.control.pneumatic`), which the stiffness loop rejects; "
        "`model_acceleration_*` is the same run with that path closed by the adapted "
        "model's q̈ (`acceleration=\"model\"`). "
        "`parameter_estimate_max_ratio` shows the estimates stay bounded (Fig. 10.3); they "
        "need not converge to Π. `dt_halving_max_rms_change` checks the 1 ms Euler "
        "discretisation of the controller."),
)
