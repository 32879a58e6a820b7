"""Issue 32, item 2: a sampled Theorem 10 whose predictor learns the plant (the study).

The study that led to the library law :mod:`softgen.control.soft_identified` (the
options ``--full-balance --forget 0.999 --mean-velocity`` with each sample's rows
weighted 1/‖Φ‖² and the adaptation gated for the first 20 samples, which this script
does not have: ``ext-sampled-soft`` runs the library law and states its count). The
fixed-predictor sampled step
(:func:`softgen.control.soft_sampled.sampled_theorem10_fun`) predicts the plant's answer
within a sample with the model file's B, D, K and takes the plant to be in balance with
the force it applied last sample (``u_prev``); ``ext-sampled-soft`` measured with it that from
π̂ = 0 it tracks within 2x the continuous loop on 16 of the 29 grid plants that have a
continuous reference (mass ×0.1-×10, stiffness ×0.3-×3, damping ×0.01-×2.5). The same
diagrams and plants as that experiment, with the step changed one option at a time:

``--predictor fixed:M,K,D``
    The predictor at fixed factors of the model file. The grid's lower corner
    ``fixed:0.1,0.3,0.01`` is stable on every grid plant by the linearised check
    (``softgen check --plant-scale``), but the law is timid (it predicts a larger answer
    than the plant gives) and π̂ drifts: 1.19-319x the continuous loop.

``--predictor identified`` (default)
    The three factors s = (mass, stiffness, damping) identified online by recursive
    least squares from the implicit-Euler balance of the sample just ended,

        s_m (B Δq̇/h + C q̇ + G) + s_k K q + s_d D q̇ = u_{k−1}     (linear in s),

    with the measured (q_k, q̇_k), Δq̇ = q̇_k − q̇_{k−1} and the force applied over that
    sample (nothing is learnt at the first sample); s is clipped to
    :data:`~softgen.control.soft_sampled.UNCERTAINTY`. ``--forget``: RLS forgetting
    factor; ``--s0``, ``--prior``: the initial factors and their weight.

``--full-balance``
    The predictor's balance from its model, B Δq̇ = h (u − C q̇ − G − K (q + h q̇⁺) − D q̇⁺)
    with the identified s, instead of ``u_prev``. ``--warmup N``: the lower corner with
    ``u_prev`` for the first N samples.

``--mean-velocity``
    The adaptation reads the sample's mean velocity (q_k − q_{k−1})/h instead of the
    measured q̇ (the fast modes of a lightly damped plant alias into Yᵀσ at 1 ms).

``--implicit-adaptation``, ``--kpi-scale F``, ``--trace``
    The torque uses π̂ after the sample's update (its gain h Y K_π Yᵀ inside J); K_π of
    both loops times F (0: no adaptation); |q_d − q|, |π̂|, |τ| of both loops along the run.

Measured 2026-12-05 (load 1-3, each row one run of the four cases, ~1 min; ratio:
sampled over continuous rms over the last 10 s; tracks: ratio ≤ 2, over the 29 grid
plants whose continuous loop stays finite; python benchmarks/sampled_predictor.py
planar,3d,pendulum,user_3seg OPTIONS):

==========================================================  ======  ======================
OPTIONS                                                     tracks  fails
==========================================================  ======  ======================
``--predictor fixed:1,1,1`` (the shipped step, as the        16/29   12 with mass ×0.1 or
report's ``ext-sampled-soft``: the same 13 fail)                    damping ×0.01, one other
``--predictor fixed:0.1,0.3,0.01`` (the lower corner)        13/29   timid: 2.25-319x
(none)                                                      19/29   damping ×0.01 only
``--mean-velocity``                                         18/29   damping ×0.01, one ×2.5
``--full-balance --forget 1``                               22/29   damping ×0.01 only
``--full-balance --forget 1 --mean-velocity``               24/29   stiffness ×3 (4 of
                                                                    them with damping ×0.01)
the same with ``--learn-first-sample``                      25/29   the four stiffness ×3,
                                                                    damping ×0.01 plants
==========================================================  ======  ======================

The causes, each tested by a run on ``planar --plant 0.1,0.3,0.01`` (the continuous
loop 0.00244 rad): without adaptation (``--kpi-scale 0``) the sampled and continuous
loops agree (0.0875 vs 0.0791 rad, 1.11x), so the sampled step itself is sound and the
adaptation fails; with ``u_prev`` the first sample's torque kicks the light, lightly
damped plant 0.082 rad off the reference (continuous: 0.0003) and |π̂| reaches 14 in
10 ms (true |π| 2.0), the balance with the last force not holding on its 39 rad/s,
ζ = 0.065 mode; ``--full-balance`` removes the kick (8.1x); ``--mean-velocity`` on top
gives 1.00x. Left: the stiff, lightly damped plants (stiffness ×3, damping ×0.01), whose
first samples still kick them while the factors are being learnt: which plants fail
depends on those first samples (``--learn-first-sample``, ``--s0``/``--prior`` and
``--warmup N`` move it; none made all track), and moving the result into the library
step, its generated C and the linearised check.

Run: ``python benchmarks/sampled_predictor.py planar,3d,pendulum,user_3seg --full-balance
--forget 1 --mean-velocity`` (``--plant M,K,D`` for one plant). Prints, per plant, both
loops' rms tracking error over the last 10 s, their ratio and the identified factors at
0.01, 0.1, 1, 10 s and the end.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import casadi as ca
import numpy as np

import softgen.experiments.ext_sampled_soft as E
from softgen.blocks import Block
from softgen.control.soft import _chain_applies, _inv3, _projector, apply_pinv
from softgen.control.soft_sampled import UNCERTAINTY, ModelScale, _law, scaled_plant_block
from softgen.modelfile.load import load_model
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic.pcc_chain import chain_terms, inertia_from_blocks
from softgen.symbolic.rigid import FUNCTION_OPTS

GROUPS = ("mass", "stiffness", "damping")
STATE = {"pi_hat": "pi_hat_next", "u_prev": "u_next", "qd_prev": "qd_prev_next",
         "q_prev": "q_prev_next", "s_hat": "s_next", "R": "R_next", "started": "started_next"}


def identified_step(dyn: SoftDynamics, lin: LinearRoute, *, forget: float,
                    mean_velocity: bool, fixed: ModelScale | None,
                    implicit_adaptation: bool = False, full_balance: bool = False,
                    warmup: int = 0, learn_first_sample: bool = False) -> ca.Function:
    """The linearly implicit sampled Theorem 10 (as the library's step) with the
    predictor's factors a state identified by RLS (or ``fixed``); the switches are the
    command line's options of the same names (module docstring)."""
    b = dyn.nominal
    n, r = dyn.model.dof, lin.r
    chain = _chain_applies(b)
    pi_hat, kpi = ca.SX.sym("pi_hat", r), ca.SX.sym("kpi", r)
    u_prev, qd_prev, q_prev = (ca.SX.sym(s, n) for s in ("u_prev", "qd_prev", "q_prev"))
    s_hat, R, started = ca.SX.sym("s_hat", 3), ca.SX.sym("R", 3, 3), ca.SX.sym("started")
    q, qd, q_d, qd_d, qdd_d, lam, kd = (ca.SX.sym(s, n) for s in
                                        ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd"))
    h = ca.SX.sym("dt")
    tau0, sigma, yt_s = _law(dyn, lin, pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, chain)
    if mean_velocity:
        _, _, yt_s = _law(dyn, lin, pi_hat, q, (q - q_prev) / h, q_d, qd_d, qdd_d, lam, kd,
                          chain)
    pi_next = pi_hat + h * kpi * yt_s
    if implicit_adaptation:
        # The torque uses the estimate after this sample's update, π̂ + h K_π Yᵀσ(q̇),
        # so J below holds the adaptation's instantaneous gain h Y K_π Yᵀ on σ.
        tau0, sigma, _ = _law(dyn, lin, pi_next, q, qd, q_d, qd_d, qdd_d, lam, kd, chain)
    J_q = ca.jacobian(kd * sigma, q)
    J = ca.jacobian(tau0, qd) + h * J_q
    sub = lambda e: ca.substitute(e, b.q, q)        # noqa: E731
    if chain:
        ct = chain_terms(b, q, ca.SX.zeros(n))
        B = inertia_from_blocks(ct.J, [m for m, _ in b.mass_points])
        blocks = ct.A
    else:
        B = sub(b.inertia_pm())
        blocks = [sub(A) for A in b.actuation_blocks()]
    K, D = sub(b._quadratic_form("k")), sub(b._quadratic_form("d"))
    # The regression of the sample just ended: every mass term of the model (B, C, G) is
    # proportional to the mass factor, K q to the stiffness one, D q̇ to the damping one.
    rigid = b.slotine_li_pm() - b.spring() - b.damping()
    mass_term = ca.substitute(rigid, ca.vertcat(b.q, b.qd, b.qd_r, b.qdd_r),
                              ca.vertcat(q, qd, qd, (qd - qd_prev) / h))
    Phi = ca.horzcat(mass_term, ca.mtimes(K, q), ca.mtimes(D, qd))
    # Before the first sample no force was applied: nothing to learn from (started = 0).
    if not learn_first_sample:
        Phi = ca.if_else(started > 0.5, 1.0, 0.0) * Phi
    R_next = forget * R + ca.mtimes(Phi.T, Phi)
    s_ls = s_hat + ca.solve(R_next + 1e-30 * ca.SX.eye(3),
                            ca.mtimes(Phi.T, u_prev - ca.mtimes(Phi, s_hat)))
    s_next = ca.vertcat(*[ca.fmin(ca.fmax(s_ls[i], UNCERTAINTY[g][0]), UNCERTAINTY[g][1])
                          for i, g in enumerate(GROUPS)])
    s = ca.DM(fixed.array()) if fixed is not None else s_next
    P = _projector(blocks)
    M = s[0] * B + h * s[2] * D + h * h * s[1] * K
    tau_e = tau0 + h * ca.mtimes(J_q, qd)
    u_last = u_prev
    if full_balance:
        # The force the plant's model says it is in balance with now (implicit Euler of
        # B q̈ + C q̇ + G + K q + D q̇ = u): the predictor's own model, not u_prev.
        bias = ca.substitute(rigid, ca.vertcat(b.q, b.qd, b.qd_r, b.qdd_r),
                             ca.vertcat(q, qd, qd, ca.SX.zeros(n)))
        u_model = s[0] * bias + s[1] * ca.mtimes(K, q + h * qd) + s[2] * ca.mtimes(D, qd)
        # Until ``warmup`` samples have taught the factors, the timid predictor: the lower
        # corner with the measured balance (u_prev).
        lower = [UNCERTAINTY[g][0] for g in GROUPS]
        learnt = started >= warmup
        M = ca.if_else(learnt, M, lower[0] * B + h * lower[2] * D + h * h * lower[1] * K)
        u_last = ca.if_else(learnt, u_model, u_last)
    w = ca.solve(M - h * ca.mtimes(P, J), ca.mtimes(P, tau_e) - u_last)
    tau_star = tau_e + h * ca.mtimes(J, w)
    tau = ca.vertcat(*[ca.mtimes(_inv3(A_i), tau_star[3 * i:3 * i + 3])
                       for i, A_i in enumerate(blocks)]) if chain else \
        apply_pinv(blocks, tau_star)
    names_in = ["pi_hat", "u_prev", "qd_prev", "q_prev", "s_hat", "R", "q", "qd", "q_d",
                "qd_d", "qdd_d", "lam", "kd", "kpi", "dt", "started"]
    return ca.Function(f"{dyn.name}_t10_identified_predictor",
                       [pi_hat, u_prev, qd_prev, q_prev, s_hat, R, q, qd, q_d, qd_d, qdd_d,
                        lam, kd, kpi, h, started],
                       [pi_next, ca.mtimes(P, tau_star), qd, q, s_next,
                        R_next, started + 1, tau, sigma],
                       names_in, [STATE[k] for k in STATE] + ["tau", "sigma"], FUNCTION_OPTS)


@dataclasses.dataclass(frozen=True)
class StudyLoop(E.SoftLoop):
    @property
    def record(self) -> tuple[str, ...]:
        return super().record + ("ctrl.s_hat",)

    def x0(self, q0, qd0) -> dict:
        return {**super().x0(q0, qd0), "ctrl.q_prev": q0, "ctrl.qd_prev": qd0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", help="comma-separated case tags of ext-sampled-soft")
    ap.add_argument("--predictor", default="identified", help="identified or fixed:M,K,D")
    ap.add_argument("--plant", help="one plant M,K,D (default: the model and the grid)")
    ap.add_argument("--forget", type=float, default=0.999)
    ap.add_argument("--mean-velocity", action="store_true")
    ap.add_argument("--implicit-adaptation", action="store_true",
                    help="the torque uses pi_hat after this sample's update (in J)")
    ap.add_argument("--full-balance", action="store_true",
                    help="the predictor's force balance from its model (s), not u_prev")
    ap.add_argument("--s0", default="lower",
                    help="initial factors: lower (the uncertainty's lower corner) or M,K,D")
    ap.add_argument("--prior", type=float, default=0.0,
                    help="weight of the initial factors (the RLS information matrix at t = 0)")
    ap.add_argument("--learn-first-sample", action="store_true",
                    help="the RLS also reads the first sample (u_prev = 0, nothing applied)")
    ap.add_argument("--warmup", type=int, default=0,
                    help="with --full-balance: samples of the timid predictor first")
    ap.add_argument("--trace", action="store_true",
                    help="print |q_d - q| and |pi_hat| of both loops along the run")
    ap.add_argument("--kpi-scale", type=float, default=1.0,
                    help="K_pi of both loops times this (0: no adaptation, pi_hat = 0)")
    a = ap.parse_args()
    fixed = None if a.predictor == "identified" else \
        ModelScale(*map(float, a.predictor.removeprefix("fixed:").split(",")))
    c = E.SampledConfig()
    lower = np.array([UNCERTAINTY[g][0] for g in GROUPS]) if a.s0 == "lower" else \
        np.array([float(x) for x in a.s0.split(",")])
    for case in E._default_cases():
        if case.tag not in a.cases.split(","):
            continue
        case = dataclasses.replace(case, gains=(*case.gains[:2], case.gains[2] * a.kpi_scale))
        src = E._CHECKOUT / case.model if case.model.endswith(".toml") else case.model
        dyn = SoftDynamics(load_model(src))
        lin, n = LinearRoute(dyn), dyn.model.dof
        ref = E.reference_block("ref", c.dt, case.amplitude, case.omega, case.phase,
                                unit=case.unit)
        f = identified_step(dyn, lin, forget=a.forget, mean_velocity=a.mean_velocity,
                            fixed=fixed, implicit_adaptation=a.implicit_adaptation,
                            full_balance=a.full_balance, warmup=a.warmup,
                            learn_first_sample=a.learn_first_sample)
        ctrl = Block.wrap("ctrl", f, dt=c.dt, state=STATE, params=["lam", "kd", "kpi"],
                          constants={"dt": c.dt},
                          x0={"s_hat": lower, "R": a.prior * np.eye(3).ravel()},
                          doc="sampled Theorem 10, predictor identified online (study)")
        d = E.ClosedLoop(f"study_{case.tag}_predictor",
                         [ref, E.tip_force_block("dist", dyn.model.n_segments), ctrl,
                          scaled_plant_block(dyn, c.dt)],
                         [("plant.q_meas", "ctrl.q"), ("plant.qd_meas", "ctrl.qd")],
                         externals={"noise": 2 * n})
        loops = {"sampled": StudyLoop(d, dyn, "plant", "ctrl", lin.r),
                 "continuous": E.continuous_soft_loop(f"study_{case.tag}_cont", dyn, ref,
                                                      c.dt, lin, case.substeps)}
        grid = [(1.0, 1.0, 1.0), *c.grid] if a.plant is None else \
            [tuple(map(float, a.plant.split(",")))]
        for g in grid:
            dur = case.duration if g == (1.0, 1.0, 1.0) else min(case.duration,
                                                                   c.grid_duration)
            t0, got, s_at = time.time(), {}, ""
            for kind, loop in loops.items():
                tr = E._run_loop(loop, kind, case, c, f"study {kind}", ModelScale(*g), dur)
                e = np.linalg.norm(tr["ref.q_d"] - tr[f"{loop.plant}.q"], axis=1)
                last = tr.t >= dur - c.metric_window
                got[kind] = float(np.sqrt(np.mean(e[last] ** 2))) \
                    if tr.stopped_at is None else float("nan")
                if a.trace:
                    for x in (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.3, 1, 3, 10, dur):
                        i = min(int(np.searchsorted(tr.t, x)), len(tr.t) - 1)
                        print(f"  {kind:10s} t {tr.t[i]:7.3f} s: |e| {e[i]:.3g}, |pi_hat| "
                              f"{np.linalg.norm(tr[f'{loop.ctrl}.pi_hat'][i]):.3g}, |tau| "
                              f"{np.linalg.norm(tr[f'{loop.ctrl}.tau'][i]):.3g}")
                if kind == "sampled":
                    sh = tr["ctrl.s_hat"]
                    at = [int(np.searchsorted(tr.t, x)) for x in (0.01, 0.1, 1, 10) if x < dur]
                    s_at = " ".join(np.array2string(sh[min(i, len(sh) - 1)], precision=3)
                                    for i in [*at, -1])
            ratio = E._ratio(got["sampled"], got["continuous"])
            print(f"{case.tag} plant {ModelScale(*g).text()}: sampled {got['sampled']:.4g}, "
                  f"continuous {got['continuous']:.4g} {case.unit}, ratio {ratio:.3g} "
                  f"({time.time() - t0:.0f} s); s_hat {s_at}", flush=True)


if __name__ == "__main__":
    main()
