"""Issue 32, item 2 (open): a sampled Theorem 10 whose predictor learns the plant.

A study, not a library law: the shipped sampled step
(:func:`softgen.control.soft_sampled.sampled_theorem10_fun`) predicts the plant's answer
within a sample with the model file's B, D, K, and ``ext-sampled-soft`` measures that it
tracks from π̂ = 0 within 2x the continuous loop on only part of the uncertainty grid
(mass ×0.1-×10, stiffness ×0.3-×3, damping ×0.01-×2.5). Two predictors are tried here
on the same diagrams and plants as that experiment:

``--predictor fixed:M,K,D``
    The predictor at fixed factors of the model file, e.g. the grid's lower corner
    ``fixed:0.1,0.3,0.01``: the linearised check (``softgen check --plant-scale``) then
    finds every grid plant stable, but the law is timid (it predicts a larger answer than
    the plant gives) and π̂ drifts while the force lags: measured, 2026-12-05, planar
    ratios 1.3-319 on the grid (see the closing note of that session).

``--predictor identified``
    The predictor's three factors s = (mass, stiffness, damping) identified online by
    recursive least squares from the implicit-Euler balance of the sample just ended,

        s_m (B Δq̇/h + C q̇ + G) + s_k K q + s_d D q̇ = u_{k−1}     (linear in s),

    with the measured (q_k, q̇_k), Δq̇ = q̇_k − q̇_{k−1} and the generalized force the
    law applied over that sample (its state ``u_prev``); s is clipped to the declared
    uncertainty (:data:`~softgen.control.soft_sampled.UNCERTAINTY`) and starts at its
    lower corner. ``--mean-velocity``: the adaptation reads the sample's mean velocity
    (q_k − q_{k−1})/h instead of the measured q̇ (an anti-alias for the fast modes).

Run: ``python benchmarks/sampled_predictor.py planar --predictor identified``
(cases: planar, 3d, pendulum, user_3seg, as ``ext-sampled-soft``; ``--plant M,K,D``
for one plant). Prints, per plant, both loops' rms tracking error over the last 10 s,
their ratio and the identified factors at 0.01, 0.1, 1, 10 s and the end.
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
         "q_prev": "q_prev_next", "s_hat": "s_next", "R": "R_next"}


def identified_step(dyn: SoftDynamics, lin: LinearRoute, *, forget: float,
                    mean_velocity: bool, fixed: ModelScale | None) -> ca.Function:
    """The linearly implicit sampled Theorem 10 (as the library's step) with the
    predictor's factors a state identified by RLS (or ``fixed``)."""
    b = dyn.nominal
    n, r = dyn.model.dof, lin.r
    chain = _chain_applies(b)
    pi_hat, kpi = ca.SX.sym("pi_hat", r), ca.SX.sym("kpi", r)
    u_prev, qd_prev, q_prev = (ca.SX.sym(s, n) for s in ("u_prev", "qd_prev", "q_prev"))
    s_hat, R = ca.SX.sym("s_hat", 3), ca.SX.sym("R", 3, 3)
    q, qd, q_d, qd_d, qdd_d, lam, kd = (ca.SX.sym(s, n) for s in
                                        ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd"))
    h = ca.SX.sym("dt")
    tau0, sigma, yt_s = _law(dyn, lin, pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, chain)
    if mean_velocity:
        _, _, yt_s = _law(dyn, lin, pi_hat, q, (q - q_prev) / h, q_d, qd_d, qdd_d, lam, kd,
                          chain)
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
    R_next = forget * R + ca.mtimes(Phi.T, Phi)
    s_ls = s_hat + ca.solve(R_next + 1e-30 * ca.SX.eye(3),
                            ca.mtimes(Phi.T, u_prev - ca.mtimes(Phi, s_hat)))
    s_next = ca.vertcat(*[ca.fmin(ca.fmax(s_ls[i], UNCERTAINTY[g][0]), UNCERTAINTY[g][1])
                          for i, g in enumerate(GROUPS)])
    s = ca.DM(fixed.array()) if fixed is not None else s_next
    P = _projector(blocks)
    M = s[0] * B + h * s[2] * D + h * h * s[1] * K
    tau_e = tau0 + h * ca.mtimes(J_q, qd)
    w = ca.solve(M - h * ca.mtimes(P, J), ca.mtimes(P, tau_e) - u_prev)
    tau_star = tau_e + h * ca.mtimes(J, w)
    tau = ca.vertcat(*[ca.mtimes(_inv3(A_i), tau_star[3 * i:3 * i + 3])
                       for i, A_i in enumerate(blocks)]) if chain else \
        apply_pinv(blocks, tau_star)
    names_in = ["pi_hat", "u_prev", "qd_prev", "q_prev", "s_hat", "R", "q", "qd", "q_d",
                "qd_d", "qdd_d", "lam", "kd", "kpi", "dt"]
    return ca.Function(f"{dyn.name}_t10_identified_predictor",
                       [pi_hat, u_prev, qd_prev, q_prev, s_hat, R, q, qd, q_d, qd_d, qdd_d,
                        lam, kd, kpi, h],
                       [pi_hat + h * kpi * yt_s, ca.mtimes(P, tau_star), qd, q, s_next,
                        R_next, tau, sigma],
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
    a = ap.parse_args()
    fixed = None if a.predictor == "identified" else \
        ModelScale(*map(float, a.predictor.removeprefix("fixed:").split(",")))
    c = E.SampledConfig()
    lower = np.array([UNCERTAINTY[g][0] for g in GROUPS])
    for case in E._default_cases():
        if case.tag not in a.cases.split(","):
            continue
        src = E._CHECKOUT / case.model if case.model.endswith(".toml") else case.model
        dyn = SoftDynamics(load_model(src))
        lin, n = LinearRoute(dyn), dyn.model.dof
        ref = E.reference_block("ref", c.dt, case.amplitude, case.omega, case.phase,
                                unit=case.unit)
        f = identified_step(dyn, lin, forget=a.forget, mean_velocity=a.mean_velocity,
                            fixed=fixed)
        ctrl = Block.wrap("ctrl", f, dt=c.dt, state=STATE, params=["lam", "kd", "kpi"],
                          constants={"dt": c.dt}, x0={"s_hat": lower},
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
