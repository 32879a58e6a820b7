"""Plants of robots driven by antagonistic actuators: rigid links + actuator model.

Pneumatic (eq. 2.5, with instantaneous pressure regulators, as the thesis assumes):
x = (q, q̇), input the pressures p; B q̈ + C q̇ + G (+ D q̇ + K q) = K Φ(q) p.

Electric (eq. 2.6 / 2.10): x = (q, q̇, q_a, q̇_a, q_b, q̇_b), input the motor torques
(τ_a, τ_b);
    B q̈ + C q̇ + G (+ D q̇) = −τ_e,     b_j q̈_j + d_j q̇_j − τ^e_j(q − q_j) = τ_j.
The springs may differ from the nominal model by a factor per spring
(``spring_scale``), to emulate the 20 % mismatch of section 6.2.4.1.

Any spring drive with motors (SEA or antagonistic pair of declared laws, eq. 2.6-2.7):
x = (q, q̇, θ, θ̇), :func:`spring_motor_plant_fun`, through
:class:`~softgen.symbolic.actuation.Actuation`.

Each plant is one generated step: ``substeps`` classical RK4 steps over one sample
with the input held (zero-order hold).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.symbolic.actuation import Actuation
from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics


def rk4_steps(rhs, x, u, h, substeps: int):
    dt = h / substeps
    for _ in range(substeps):
        k1 = rhs(x, u)
        k2 = rhs(x + dt / 2 * k1, u)
        k3 = rhs(x + dt / 2 * k2, u)
        k4 = rhs(x + dt * k3, u)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def euler_steps(rhs, x, u, h, substeps: int):
    dt = h / substeps
    for _ in range(substeps):
        x = x + dt * rhs(x, u)
    return x


def pneumatic_plant_fun(dyn: RigidDynamics, act: McKibbenPairs, *, substeps: int,
                        integrator: str = "rk4") -> ca.Function:
    """``<model>_pneumatic_plant``: one sample of length h of eq. 2.5, pressures held.

    ``integrator="euler"`` integrates with explicit Euler instead of RK4: with one
    substep it is exactly the discrete model the thesis's observer is designed for
    (a diagnostic of where estimation errors come from, not a plant to trust).
    """
    if integrator not in ("rk4", "euler"):
        raise ValueError(f"integrator: expected 'rk4' or 'euler', got {integrator!r}")
    step = rk4_steps if integrator == "rk4" else euler_steps
    n = dyn.model.dof
    x, p, h = ca.SX.sym("x", 2 * n), ca.SX.sym("p", 2 * n), ca.SX.sym("h")

    xs, ps = ca.SX.sym("xs", 2 * n), ca.SX.sym("ps", 2 * n)
    qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(dyn.nominal.q, ps)),
                        ca.vertcat(dyn.nominal.q, dyn.nominal.qd), xs)
    rhs = ca.Function("rhs", [xs, ps], [ca.vertcat(xs[n:], qdd)])
    return ca.Function(f"{dyn.name}_pneumatic_plant", [x, p, h],
                       [step(rhs, x, p, h, substeps)], ["x", "p", "h"], ["x_next"],
                       FUNCTION_OPTS)


def electric_plant_fun(dyn: RigidDynamics, springs: QbmoveSprings, *, substeps: int,
                       link_damping: bool = False) -> ca.Function:
    """``<model>_electric_plant``: one sample of eq. 2.6, motor torques held.

    Inputs: x (6n: q, q̇, q_a, q̇_a, q_b, q̇_b), u (2n: τ_a, τ_b), spring_scale (2n:
    factor on k of each agonist then antagonist spring; 1 = nominal), h (sample time).
    With ``link_damping`` an input ``link_damping`` (n, N m s/rad) adds a viscous
    torque −β q̇ on each link, beyond the model's own D q̇ (an emulated arm's bearings).
    """
    n = dyn.model.dof
    m = dyn.nominal
    x, u, h = ca.SX.sym("x", 6 * n), ca.SX.sym("u", 2 * n), ca.SX.sym("h")
    scale = ca.SX.sym("spring_scale", 2 * n)

    xs, us, sc = ca.SX.sym("xs", 6 * n), ca.SX.sym("us", 2 * n), ca.SX.sym("sc", 2 * n)
    beta = ca.SX.sym("link_damping", n)
    q, qd, qa, qad, qb, qbd = (xs[i * n:(i + 1) * n] for i in range(6))
    ta = springs.spring_torque(q - qa, "a", sc[:n])
    tb = springs.spring_torque(q - qb, "b", sc[n:])
    tau = -(ta + tb) - beta * qd if link_damping else -(ta + tb)
    qdd = ca.substitute(dyn.forward_dynamics_expr(tau), ca.vertcat(m.q, m.qd),
                        ca.vertcat(q, qd))
    qadd = (us[:n] + ta - springs.d_a * qad) / springs.b_a
    qbdd = (us[n:] + tb - springs.d_b * qbd) / springs.b_b
    extra = [beta] if link_damping else []
    rhs = ca.Function("rhs", [xs, us, sc, *extra],
                      [ca.vertcat(qd, qdd, qad, qadd, qbd, qbdd)])
    ins, names = [x, u, scale, *extra, h], ["x", "u", "spring_scale"] + ["link_damping"] * \
        link_damping + ["h"]

    def f(xx, uu):
        return rhs(xx, uu, scale, *extra)

    return ca.Function(f"{dyn.name}_electric_plant", ins, [rk4_steps(f, x, u, h, substeps)],
                       names, ["x_next"], FUNCTION_OPTS)


def spring_motor_plant_fun(dyn: RigidDynamics, act: Actuation, b, d, *, substeps: int,
                           name: str) -> ca.Function:
    """``<model>_<name>``: one sample of eq. 2.6 for springs of any declared law.

    Every actuator variable of ``act`` (:class:`~softgen.symbolic.actuation.Actuation`)
    must be a motor position θ driving its joint through a spring (an SEA, or each side
    of an antagonistic spring pair): x = (q, q̇, θ, θ̇), θ in the order of
    ``act.variables`` (joint by joint, side a then b), input the motor torques u held
    over the sample, and

        B q̈ + C q̇ + G (+ K q + D q̇) = τ(q, θ),      b θ̈ + d θ̇ − τ_e(q − θ) = u,

    τ(q, θ) = −Σ τ_e of each joint's springs (eq. 2.7) and τ_e the spring's torque on its
    motor (eq. 2.6), both from the declared laws by :class:`Actuation`. ``b``, ``d``:
    motor inertia and damping per variable. ``substeps`` classical RK4 steps.
    (:func:`electric_plant_fun` is the same physics written for k sinh(aφ) springs with
    the a-side motors first; it is kept as it is for the chapter-11 models.)
    """
    n, m = dyn.model.dof, act.m
    b, d = ca.DM(np.asarray(b, float).ravel()), ca.DM(np.asarray(d, float).ravel())
    xs, us = ca.SX.sym("xs", 2 * n + 2 * m), ca.SX.sym("us", m)
    q, qd, th, thd = xs[:n], xs[n:2 * n], xs[2 * n:2 * n + m], xs[2 * n + m:]
    mn = dyn.nominal
    qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(q, th)),
                        ca.vertcat(mn.q, mn.qd), ca.vertcat(q, qd))
    thdd = (us - d * thd + act.motor_torque(q, th)) / b
    rhs = ca.Function("rhs", [xs, us], [ca.vertcat(qd, qdd, thd, thdd)])
    x, u, h = ca.SX.sym("x", 2 * n + 2 * m), ca.SX.sym("u", m), ca.SX.sym("h")
    return ca.Function(f"{dyn.name}_{name}", [x, u, h], [rk4_steps(rhs, x, u, h, substeps)],
                       ["x", "u", "h"], ["x_next"], FUNCTION_OPTS)


def servo_plant_fun(dyn: RigidDynamics, springs: QbmoveSprings, *, substeps: int,
                    bandwidth: float, damping_ratio: float = 1.0) -> ca.Function:
    """``<model>_servo_plant``: eq. 2.6 with each motor under its own position servo.

    The qbmove motors are position-controlled by their own electronics, faster
    than the estimator's sample rate. Inside the sample, each motor torque is
    τ_j = b_j (ω² (q_j,ref − q_j) − 2ζω q̇_j) − τ^e_j,nominal(φ_j): a continuous PD
    of bandwidth ω with compensation of the *nominal* spring, while the plant's
    springs are scaled by ``spring_scale`` (the model mismatch). References are held
    over the sample. Outputs the state at the end of the sample and the motor
    torques at its start (what a current sensor sampled then reads).
    """
    n = dyn.model.dof
    m = dyn.nominal
    w, z = float(bandwidth), float(damping_ratio)
    x, ref, h = ca.SX.sym("x", 6 * n), ca.SX.sym("q_ref", 2 * n), ca.SX.sym("h")
    scale = ca.SX.sym("spring_scale", 2 * n)
    xs, rs, sc = ca.SX.sym("xs", 6 * n), ca.SX.sym("rs", 2 * n), ca.SX.sym("sc", 2 * n)

    def parts(xx, rr, ss):
        q, qd, qa, qad, qb, qbd = (xx[i * n:(i + 1) * n] for i in range(6))
        ta = springs.spring_torque(q - qa, "a", ss[:n])
        tb = springs.spring_torque(q - qb, "b", ss[n:])
        ua = springs.b_a * (w * w * (rr[:n] - qa) - 2 * z * w * qad) \
            - springs.spring_torque(q - qa, "a")
        ub = springs.b_b * (w * w * (rr[n:] - qb) - 2 * z * w * qbd) \
            - springs.spring_torque(q - qb, "b")
        return q, qd, qa, qad, qb, qbd, ta, tb, ua, ub

    q, qd, qa, qad, qb, qbd, ta, tb, ua, ub = parts(xs, rs, sc)
    qdd = ca.substitute(dyn.forward_dynamics_expr(-(ta + tb)), ca.vertcat(m.q, m.qd),
                        ca.vertcat(q, qd))
    qadd = (ua + ta - springs.d_a * qad) / springs.b_a
    qbdd = (ub + tb - springs.d_b * qbd) / springs.b_b
    rhs = ca.Function("rhs", [xs, rs, sc], [ca.vertcat(qd, qdd, qad, qadd, qbd, qbdd)])
    x_next = rk4_steps(lambda xx, uu: rhs(xx, uu, scale), x, ref, h, substeps)
    *_, ua0, ub0 = parts(x, ref, scale)
    return ca.Function(f"{dyn.name}_servo_plant", [x, ref, scale, h],
                       [x_next, ca.vertcat(ua0, ub0)], ["x", "q_ref", "spring_scale", "h"],
                       ["x_next", "tau_motor"], FUNCTION_OPTS)


def valve_plant_fun(dyn: RigidDynamics, act: McKibbenPairs, *, substeps: int) -> ca.Function:
    """``<model>_valve_plant``: eq. 2.5 with first-order pressure regulators.

    x = (q, q̇, p) (4n). Each muscle's pressure follows its command through
    ṗ = (sat(p_c) − p) / T_p, the valve model of section 10.4 (the thesis gives no
    time constant; ``T_p`` is an input, 2n values). The command is saturated to
    [0, p_max] of the model file: a valve can neither pull a vacuum nor exceed its
    supply, so an infeasible command is clipped here and reported by
    :func:`softgen.control.feasibility.check_pressures`, never turned into NaN.
    Inputs ``x, p_c, T_p, h``; output ``x_next``.
    """
    n = dyn.model.dof
    m = dyn.nominal
    x, pc, tp, h = (ca.SX.sym("x", 4 * n), ca.SX.sym("p_c", 2 * n), ca.SX.sym("T_p", 2 * n),
                    ca.SX.sym("h"))
    pmax = ca.DM(np.repeat(act.pressure_max, 2))
    xs, us = ca.SX.sym("xs", 4 * n), ca.SX.sym("us", 2 * n)
    q, qd, p = xs[:n], xs[n:2 * n], xs[2 * n:]
    qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(m.q, p)),
                        ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))
    sat = ca.fmin(ca.fmax(us, 0), pmax) if np.all(np.isfinite(act.pressure_max)) \
        else ca.fmax(us, 0)
    ts = ca.SX.sym("ts", 2 * n)
    rhs = ca.Function("rhs", [xs, us, ts], [ca.vertcat(qd, qdd, (sat - p) / ts)])
    return ca.Function(f"{dyn.name}_valve_plant", [x, pc, tp, h],
                       [rk4_steps(lambda xx, uu: rhs(xx, uu, tp), x, pc, h, substeps)], ["x", "p_c", "T_p", "h"],
                       ["x_next"], FUNCTION_OPTS)


# -- the plants as diagram blocks -------------------------------------------------------------

def _plant_block(f: ca.Function, name: str, dt: float, n: int, parts: list[str], ins: list,
                 *, extra_out: list | None = None, params: list | None = None,
                 p0: dict | None = None, doc: str = ""):
    """A block around one of the plant steps above: state ``parts`` (n each), emitted at
    the sample; ``ins`` [(input name, size, function input)]; ``params`` likewise."""
    from softgen.blocks import Block
    params = params or []
    extra_out = extra_out or []

    def body(x, u, p):
        args = {fi: u[nm] for nm, _, fi in ins}
        args.update({fi: p[nm] for nm, _, fi in params})
        res = f.call({"x": ca.vertcat(*[x[s] for s in parts]), "h": dt, **args})
        xn = res["x_next"]
        y = {s: x[s] for s in parts}
        y.update({nm: res[fo] for nm, _, fo in extra_out})
        return {s: xn[i * n:(i + 1) * n] for i, s in enumerate(parts)}, y

    return Block.define(name, dt=dt, state=[(s, n) for s in parts],
                        inputs=[(nm, sz) for nm, sz, _ in ins],
                        outputs=[(s, n) for s in parts] + [(nm, sz) for nm, sz, _ in extra_out],
                        params=[(nm, sz) for nm, sz, _ in params], p0=p0, body=body,
                        doc=doc or f.name(), rules={nm: "nonnegative" for nm, *_ in params})


QBMOVE_STATE = ["q", "qd", "qa", "qad", "qb", "qbd"]


def electric_plant_block(dyn: RigidDynamics, springs: QbmoveSprings, dt: float, *,
                         substeps: int, name: str = "plant", spring_scale=1.0,
                         link_damping=None):
    """:func:`electric_plant_fun` as a block (eq. 2.6, motor torques held over a sample).

    State and outputs (at the sample): ``q, qd, qa, qad, qb, qbd`` (n each); input
    ``tau_motor`` (τ_a of every joint, then τ_b); parameter ``spring_scale`` (2n) and,
    if ``link_damping`` is given (N m s/rad), parameter ``link_damping`` (n).
    """
    n, damped = dyn.model.dof, link_damping is not None
    params = [("spring_scale", 2 * n, "spring_scale")]
    p0 = {"spring_scale": spring_scale}
    if damped:
        params.append(("link_damping", n, "link_damping"))
        p0["link_damping"] = link_damping
    b = _plant_block(electric_plant_fun(dyn, springs, substeps=substeps, link_damping=damped),
                     name, dt, n, QBMOVE_STATE, [("tau_motor", 2 * n, "u")], params=params,
                     p0=p0)
    return b


def servo_plant_block(dyn: RigidDynamics, springs: QbmoveSprings, dt: float, *,
                      substeps: int, bandwidth: float, name: str = "plant", spring_scale=1.0):
    """:func:`servo_plant_fun` as a block: input ``q_ref`` (2n motor position
    references), outputs the state at the sample and ``tau_motor``, the servo's motor
    torques at the sample (what a current sensor sampled then reads)."""
    n = dyn.model.dof
    return _plant_block(servo_plant_fun(dyn, springs, substeps=substeps, bandwidth=bandwidth),
                        name, dt, n, QBMOVE_STATE, [("q_ref", 2 * n, "q_ref")],
                        extra_out=[("tau_motor", 2 * n, "tau_motor")],
                        params=[("spring_scale", 2 * n, "spring_scale")],
                        p0={"spring_scale": spring_scale})


def pneumatic_plant_block(dyn: RigidDynamics, act: McKibbenPairs, dt: float, *,
                          substeps: int, integrator: str = "rk4", name: str = "plant"):
    """:func:`pneumatic_plant_fun` as a block: state and outputs ``q, qd``; input ``p``
    (2n pressures, Pa, held over the sample)."""
    n = dyn.model.dof
    return _plant_block(pneumatic_plant_fun(dyn, act, substeps=substeps, integrator=integrator),
                        name, dt, n, ["q", "qd"], [("p", 2 * n, "p")])
