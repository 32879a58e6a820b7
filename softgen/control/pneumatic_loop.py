"""Blocks of a chapter-10 controller and a McKibben plant, and their closed loop.

One sample: read q, q̇ and the stiffness σ = −KΦ_q p of the pressures acting now,
run the controller step (:mod:`softgen.control.pneumatic`), hold its pressure
command over the sample, integrate the plant. :func:`closed_loop` wires the blocks
into a :class:`~softgen.blocks.ClosedLoop`, whose ``loop_fun(steps)`` repeats the
sample inside one generated function (DESIGN section 1: "whole loops in C where it
pays"); the loop is no longer composed by hand here.

Plants:
``"ideal"``  pressures equal the command at once (section 10.2's assumption), clipped
    to [0, p_max]; x = (q, q̇, p_applied).
``"valve"``  first-order regulators ṗ = (sat(p_c) − p)/T_p (section 10.4);
    x = (q, q̇, p).
Either way x has 4n entries, so traces have one layout.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.symbolic.actuated import rk4_steps, valve_plant_fun
from softgen.symbolic.rigid import FUNCTION_OPTS
from softgen.control.pneumatic import KINDS, PneumaticArm

PLANTS = ("ideal", "valve")


def applied_pressures(act, p_cmd):
    """What the regulators deliver of a command: clipped to [0, p_max] (no upper clip
    for muscles without a ``pressure_max``)."""
    p = ca.fmax(p_cmd, 0)
    pmax = np.repeat(act.pressure_max, 2)
    return ca.fmin(p, ca.DM(pmax)) if np.all(np.isfinite(pmax)) else p


def _ideal_plant(arm: PneumaticArm, substeps: int) -> ca.Function:
    n, dyn, act = arm.n, arm.dyn, arm.act
    m = dyn.nominal
    x, pc, h = ca.SX.sym("x", 4 * n), ca.SX.sym("p_c", 2 * n), ca.SX.sym("h")
    p = applied_pressures(act, pc)
    xs, ps = ca.SX.sym("xs", 2 * n), ca.SX.sym("ps", 2 * n)
    qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(m.q, ps)),
                        ca.vertcat(m.q, m.qd), xs)
    rhs = ca.Function("rhs", [xs, ps], [ca.vertcat(xs[n:], qdd)])
    xn = rk4_steps(rhs, x[:2 * n], p, h, substeps)
    return ca.Function("ideal_plant", [x, pc, h], [ca.vertcat(xn, p)])


def closed_loop(arm: PneumaticArm, kind: str, dt: float, *, plant: str = "ideal",
                substeps: int = 1, name: str | None = None) -> ClosedLoop:
    """Controller ``kind`` on the McKibben arm, as a diagram of the library blocks.

    :func:`controller_block` reads the plant's q, q̇, σ and the external input ``ref``
    (6n per sample: q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d); its pressures ``p`` drive
    :func:`plant_block` (``plant``: ``"ideal"`` or ``"valve"``), which holds them over
    the sample. ``step_fun()`` / ``loop_fun(steps)`` give the generated C of one sample /
    ``steps`` samples; :func:`softgen.runtime.simulate` runs it.
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    return ClosedLoop(name or f"{arm.name}_{kind}_{plant}",
                      [controller_block(arm, kind, dt),
                       plant_block(arm, dt, plant=plant, substeps=substeps)],
                      [("ctrl.p", "plant.p_cmd")], externals={"ref": 6 * arm.n})


# -- blocks ------------------------------------------------------------------------------

def controller_block(arm: PneumaticArm, kind: str, dt: float, *, name: str = "ctrl") -> Block:
    """Controller ``kind`` as a block: reads q, q̇, σ and ``ref``; emits the pressures ``p``.

    State (ν, Π̂) for Theorem 5 and Corollary 2, Π̂ otherwise; gains are parameters
    (``lam``, ``kd``, ``kpi``, and ``ksigma``, ``kinv`` where the law has them).
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    f = arm.step_fun(kind)
    parts = [("Pi_hat", arm.n_params)]
    if kind in ("theorem5", "corollary2"):
        parts = [("nu", arm.n_nu)] + parts
    params = [g for g in ("lam", "kd", "kpi", "ksigma", "kinv") if g in f.name_in()]
    return Block.wrap(name, f, dt=dt, state={"z": "z_next"}, state_parts={"z": parts},
                      params=params, constants={"dt": dt}, doc=f"chapter-10 controller {kind}",
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative"},
                      meta={"kind": kind})


def plant_block(arm: PneumaticArm, dt: float, *, plant: str = "ideal", substeps: int = 1,
                name: str = "plant") -> Block:
    """The McKibben arm over one sample, command ``p_cmd`` held.

    State (q, q̇, p); outputs the same and the stiffness σ = −KΦ_q p of the pressures
    acting at the sample. ``plant``: ``"ideal"`` (p = clipped command at once) or
    ``"valve"`` (first-order regulators with time constants ``T_p``, a parameter).
    """
    if plant not in PLANTS:
        raise ValueError(f"plant: expected one of {', '.join(PLANTS)}, got {plant!r}")
    n = arm.n
    f = valve_plant_fun(arm.dyn, arm.act, substeps=substeps) if plant == "valve" \
        else _ideal_plant(arm, substeps)

    def body(x, u, p):
        xv = ca.vertcat(x["q"], x["qd"], x["p"])
        xn = f(xv, u["p_cmd"], p["T_p"], dt) if plant == "valve" else f(xv, u["p_cmd"], dt)
        return ({"q": xn[:n], "qd": xn[n:2 * n], "p": xn[2 * n:]},
                {"q": x["q"], "qd": x["qd"], "p": x["p"],
                 "sigma": arm.act.stiffness(x["q"], x["p"])})

    return Block.define(name, dt=dt, state=[("q", n, "rad"), ("qd", n, "rad/s"),
                                            ("p", 2 * n, "Pa")],
                        inputs=[("p_cmd", 2 * n, "Pa")],
                        outputs=[("q", n, "rad"), ("qd", n, "rad/s"), ("p", 2 * n, "Pa"),
                                 ("sigma", n, "N m/rad")],
                        params=[("T_p", 2 * n, "s")] if plant == "valve" else [],
                        p0={"T_p": 0.05} if plant == "valve" else None,
                        body=body, doc=f"McKibben arm, {plant} pressures",
                        meta={"model": arm.name})


def uncertain_plant_block(arm: PneumaticArm, dt: float, *, substeps: int = 1,
                          name: str = "plant") -> Block:
    """The McKibben arm of :func:`plant_block` (ideal pressures) with its true values as
    parameters, so that one generated loop serves every sample of a robustness study.

    Parameters: ``pi`` the base inertial parameters π of the plant (the dynamics are
    Y(q, q̇, q̇, q̈) π plus the known terms, so B(q) = ∂(Yπ)/∂q̈ and the bias is Yπ at
    q̈ = 0: eq. 10.9's structure, derived, not transcribed); ``R``, ``Kg`` (n) pulley
    radii and muscle gains; ``ln``, ``lm`` (2n, muscles a, b of each joint in turn)
    nominal and minimum muscle lengths. At the model's values (``p0``) the block equals
    :func:`plant_block` (``tests/test_pneumatic_control.py`` checks the trajectories).
    """
    n, dyn = arm.n, arm.dyn
    m = dyn.nominal
    k = len(dyn.base.names)
    q, qd, pc = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("p", 2 * n)
    pi, R, Kg = ca.SX.sym("pi", k), ca.SX.sym("R", n), ca.SX.sym("Kg", n)
    ln, lm = ca.SX.sym("ln", 2 * n), ca.SX.sym("lm", 2 * n)
    qdd = ca.SX.sym("qdd", n)
    tau_model = dyn.base.Y @ pi
    if dyn.base.constant is not None:
        tau_model = tau_model + dyn.base.constant
    tau_model = ca.substitute(tau_model, ca.vertcat(m.q, m.qd, m.qd_r, m.qdd_r),
                              ca.vertcat(q, qd, qd, qdd))
    B = ca.jacobian(tau_model, qdd)
    bias = ca.substitute(tau_model, qdd, ca.DM.zeros(n))
    act = arm.act.with_values(R=R, Kg=Kg, ln_a=ln[0::2], ln_b=ln[1::2], lm_a=lm[0::2],
                              lm_b=lm[1::2])
    values = [pi, R, Kg, ln, lm]
    rhs = ca.Function("rhs", [ca.vertcat(q, qd), pc, *values],
                      [ca.vertcat(qd, ca.solve(B, act.torque(q, pc) - bias))])
    stiff = ca.Function("stiffness", [q, pc, *values], [act.stiffness(q, pc)])

    def body(x, u, p):
        vals = [p[nm] for nm in ("pi", "R", "Kg", "ln", "lm")]
        applied = applied_pressures(arm.act, u["p_cmd"])
        xn = rk4_steps(lambda xx, pp: rhs(xx, pp, *vals), ca.vertcat(x["q"], x["qd"]),
                       applied, dt, substeps)
        return ({"q": xn[:n], "qd": xn[n:], "p": applied},
                {"q": x["q"], "qd": x["qd"], "p": x["p"],
                 "sigma": stiff(x["q"], x["p"], *vals)})

    a = arm.act
    p0 = {"pi": dyn.parameter_nominal, "R": a.R, "Kg": a.Kg,
          "ln": np.ravel(np.column_stack([a.ln_a, a.ln_b])),
          "lm": np.ravel(np.column_stack([a.lm_a, a.lm_b]))}
    return Block.define(name, dt=dt, state=[("q", n, "rad"), ("qd", n, "rad/s"),
                                            ("p", 2 * n, "Pa")],
                        inputs=[("p_cmd", 2 * n, "Pa")],
                        outputs=[("q", n, "rad"), ("qd", n, "rad/s"), ("p", 2 * n, "Pa"),
                                 ("sigma", n, "N m/rad")],
                        params=[("pi", k), ("R", n, "m"), ("Kg", n), ("ln", 2 * n, "m"),
                                ("lm", 2 * n, "m")],
                        p0=p0, body=body, rules={"R": "positive", "Kg": "positive",
                                                 "ln": "positive", "lm": "positive"},
                        doc="McKibben arm, ideal pressures, true values as parameters",
                        meta={"model": arm.name})


# -- continuous-time controllers inside the plant's Runge-Kutta step ----------------------------

def valve_rhs_fun(robot) -> ca.Function:
    """``<model>_valve_rhs``: (x, p_c, T_p) -> ẋ of the valve plant (section 10.4).

    The right-hand side of :func:`valve_plant_fun`: eq. 2.5 with nominal π and K and
    ṗ = (sat(p_c) − p)/T_p, p_c clipped to [0, p_max]; so that a controller can be
    evaluated at every Runge-Kutta stage (:func:`rk4_stage_step`).
    """
    n, dyn, act = robot.n, robot.dyn, robot.act
    m = dyn.nominal
    x, pc, tp = ca.SX.sym("x", 4 * n), ca.SX.sym("p_c", 2 * n), ca.SX.sym("T_p", 2 * n)
    q, qd, p = x[:n], x[n:2 * n], x[2 * n:]
    qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(m.q, p)),
                        ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))
    sat = applied_pressures(act, pc)
    return ca.Function(f"{robot.name}_valve_rhs", [x, pc, tp],
                       [ca.vertcat(qd, qdd, (sat - p) / tp)], ["x", "p_c", "T_p"],
                       ["x_dot"], FUNCTION_OPTS)


def rk4_stage_step(rhs, s, ref_stages, dt: float):
    """One classical RK4 step of ṡ = rhs(s, r) with r read at the stage times.

    ``ref_stages`` stacks r(t_k), r(t_k + dt/2), r(t_k + dt)
    (:func:`stage_reference_block`). A controller evaluated inside ``rhs`` is a
    continuous-time law (as in the thesis's Simulink models), not a sampled one.
    """
    nr = ref_stages.numel() // 3
    r0, rh, r1 = ref_stages[:nr], ref_stages[nr:2 * nr], ref_stages[2 * nr:]
    k1 = rhs(s, r0)
    k2 = rhs(s + dt / 2 * k1, rh)
    k3 = rhs(s + dt / 2 * k2, rh)
    k4 = rhs(s + dt * k3, r1)
    return s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def stage_reference_block(ref: Block, dt: float, *, name: str | None = None) -> Block:
    """``ref`` (a stateless block reading ``t``) plus its ``ref`` at the RK4 stage times.

    Outputs every output of ``ref`` at t_k and ``ref_stages`` = (ref(t_k),
    ref(t_k + dt/2), ref(t_k + dt)), what a block built on :func:`rk4_stage_step`
    reads.
    """
    if ref.state.size or ref.params.size or ref.inputs.names != ("t",) or "ref" not in ref.outputs:
        raise ValueError(f"block {ref.name}: expected a stateless, parameter-free block reading "
                         "only t and emitting ref")
    nr = ref.outputs.signal("ref").size
    empty = ca.DM(0, 1)

    def at(t):
        return ref.outputs.split(ca.SX(ref.step(empty, t, empty)[1]))

    def body(x, u, p):
        y = at(u["t"])
        y["ref_stages"] = ca.vertcat(y["ref"], at(u["t"] + dt / 2)["ref"], at(u["t"] + dt)["ref"])
        return {}, y

    return Block.define(name or ref.name, dt=dt, inputs={"t": 1},
                        outputs=[*ref.outputs.signals, ("ref_stages", 3 * nr)], body=body,
                        doc=f"{ref.doc}, also at the RK4 stage times")


def theorem5_continuous_block(arm: PneumaticArm, dt: float, *, name: str = "loop") -> Block:
    """Theorem 5 as a continuous-time law on the valve plant, one RK4 step per sample.

    The combined system s = (q, q̇, p, ν, Π̂), ṡ = (valve plant under p_c = p of
    Theorem 5, ν̇ of eq. 10.1 (NOTES item 4), dΠ̂/dt of eq. 10.2), σ read from the
    plant's pressures, is integrated over each sample by :func:`rk4_stage_step`: the
    block is controller and plant at once, as a Simulink model of both would be.
    Reads ``ref_stages`` (:func:`stage_reference_block`); parameters ``lam``, ``kd``,
    ``kpi``, ``ksigma``, ``kinv`` (Theorem 5) and ``T_p`` (valves). Outputs the state
    at the sample, σ, and ``p_cmd``, the command at t_k (before clipping).
    """
    n, k = arm.n, arm.n_params
    s, ref = ca.SX.sym("s", 5 * n + k), ca.SX.sym("ref", 6 * n)
    g = {nm: ca.SX.sym(nm, size) for nm, size in
         (("lam", n), ("kd", n), ("kpi", k), ("ksigma", n), ("kinv", n), ("T_p", 2 * n))}
    q, qd, p = s[:n], s[n:2 * n], s[2 * n:4 * n]
    p_cmd, _, nu_dot, Pi_dot = arm.theorem5_rates(
        q, qd, arm.act.stiffness(q, p), s[4 * n:5 * n], s[5 * n:], ref,
        *(g[nm] for nm in ("lam", "kd", "kpi", "ksigma", "kinv")))
    rhs = ca.Function("rhs", [s, ref, *g.values()],
                      [ca.vertcat(valve_rhs_fun(arm)(s[:4 * n], p_cmd, g["T_p"]), nu_dot, Pi_dot),
                       p_cmd])
    state = [("q", n, "rad"), ("qd", n, "rad/s"), ("p", 2 * n, "Pa"), ("nu", n, ""),
             ("Pi_hat", k, "")]

    def body(x, u, p):
        sv = ca.vertcat(*(x[nm] for nm, *_ in state))
        gains = [p[nm] for nm in g]
        s_next = rk4_stage_step(lambda s_, r: rhs(s_, r, *gains)[0], sv, u["ref_stages"], dt)
        parts = dict(zip([nm for nm, *_ in state],
                         ca.vertsplit(s_next, np.cumsum([0] + [m for _, m, _ in state]).tolist())))
        return parts, {**{nm: x[nm] for nm, *_ in state},
                       "sigma": arm.act.stiffness(x["q"], x["p"]),
                       "p_cmd": rhs(sv, u["ref_stages"][:6 * n], *gains)[1]}

    return Block.define(name, dt=dt, state=state, inputs=[("ref_stages", 18 * n)],
                        outputs=[*state, ("sigma", n, "N m/rad"), ("p_cmd", 2 * n, "Pa")],
                        params=[("lam", n), ("kd", n), ("kpi", k), ("ksigma", n), ("kinv", n),
                                ("T_p", 2 * n, "s")],
                        p0={"T_p": 0.05}, body=body,
                        rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative",
                               "T_p": "positive"},
                        doc="Theorem 5 and valve plant, continuous time, RK4 per sample",
                        meta={"model": arm.name})


def preset_nu(arm: PneumaticArm, Pi_hat: np.ndarray, q: np.ndarray, ref: np.ndarray,
              *, lam, kd, dt: float) -> np.ndarray:
    """ν that gives σ_d of ``ref`` at rest at ``q`` by the actuator model with Π̂ (the
    "initially inflated" preset of section 10.2: the open-loop stiffness step, K_π = 0)."""
    n = arm.n
    out = arm.step_fun("open_loop")(Pi_hat, q, np.zeros(n), ref, lam, kd,
                                    np.zeros(arm.n_params), 1 / arm.act.K, dt)
    return np.array(out[3]).ravel()


# -- decoupling of position and stiffness (chapter 10) ------------------------------------------

def decoupling_windows(own, other, *, settle: float, end: float) -> list[tuple[float, float, float]]:
    """``(t0, t1, step)``: intervals in which only the ``own`` references move.

    ``own`` and ``other`` are lists of :class:`~softgen.control.references.SmoothSteps`
    (e.g. positions and stiffnesses). Each step of ``own`` opens a window that lasts to
    the next change of any reference (or ``end``); steps before ``settle`` (an adaptation
    transient) or within one rise time of a step of ``other`` are left out.
    """
    other_times = {t for s in other for t in s.times[1:]}
    changes = sorted({t for s in [*own, *other] for t in s.times[1:]})
    return [(float(t0), float(min([u for u in changes if u > t0] + [end])), abs(b - a))
            for s in own for t0, a, b in zip(s.times[1:], s.values, s.values[1:])
            if t0 >= settle and all(abs(t0 - u) >= s.rise for u in other_times)]


def decoupling_index(t, err, windows) -> np.ndarray:
    """Per joint, max over ``windows`` of the change of ``err`` (samples × n) since the
    window's start, over the window's step: e.g. the stiffness error per radian of
    position step while only positions move. The change, not the error itself, so that a
    constant offset is charged only for what the other references' steps add."""
    t, err = np.asarray(t), np.asarray(err)
    worst = np.zeros(err.shape[1])
    for t0, t1, step in windows:
        mask = (t >= t0) & (t < t1)
        if mask.any() and step > 0:
            dev = np.abs(err[mask] - err[np.searchsorted(t, t0)])
            worst = np.maximum(worst, dev.max(axis=0) / step)
    return worst
