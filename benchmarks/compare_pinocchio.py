"""Cross-check and time softgen against Pinocchio (optional; Pinocchio is not a dependency).

Run in an environment that has both (``pip install pin`` beside softgen):

    python benchmarks/compare_pinocchio.py [MODEL ...]

For each planar model, builds the same chain in Pinocchio (revolute joints about z,
link frames placed as softgen places them), then

1. checks Pinocchio's RNEA τ(q, v, a) against softgen's generated inverse dynamics
   with q̇_r = q̇, q̈_r = q̈ (an independent rigid-body library as the reference), and
   Pinocchio's joint-torque regressor against softgen's regressor through their
   parameter vectors;
2. times, from Python, ``pinocchio.computeJointTorqueRegressor`` and
   ``pinocchio.rnea`` against softgen's generated regressor and inverse dynamics
   (buffer path and checked call path).
"""
from __future__ import annotations

import sys
import timeit

import numpy as np
import pinocchio as pin

from softgen.modelfile.load import load_model
from softgen.bundles.bundle import load_bundle


def pinocchio_model(model):
    if model.kind != "planar" or any(lk.joint != "revolute" for lk in model.links):
        raise SystemExit(f"{model.name}: only planar revolute chains are translated")
    if any(lk.inertia_about != "com" for lk in model.links):
        raise SystemExit(f"{model.name}: lumped (inertia about the joint) models have no "
                         "rigid-body equivalent in Pinocchio")
    p = model.nominal
    pm = pin.Model()
    pm.gravity.linear = np.array([0.0, -p["g"], 0.0])
    parent = 0
    # softgen's planar base frame is rotated by base_angle about z.
    base = pin.SE3(pin.rpy.rpyToMatrix(*model.base_rpy), np.zeros(3))
    for i in range(1, model.dof + 1):
        offset = np.zeros(3) if i == 1 else np.array([p[f"l{i - 1}"], 0.0, 0.0])
        placement = base if i == 1 else pin.SE3(np.eye(3), offset)
        jid = pm.addJoint(parent, pin.JointModelRZ(), placement, f"j{i}")
        com = np.array([p.get(f"c{i}", p.get(f"c{i}x", 0.0)), p.get(f"c{i}y", 0.0), 0.0])
        inertia = np.diag([1e-9, 1e-9, p[f"I{i}"]])   # only Izz acts in the plane
        pm.appendBodyToJoint(jid, pin.Inertia(p[f"m{i}"], com, inertia), pin.SE3.Identity())
        parent = jid
    return pm


def main(names):
    for name in names or ["planar_2link"]:
        model = load_model(name)
        pm = pinocchio_model(model)
        pd = pm.createData()
        arm = load_bundle(name)
        n = model.dof
        rng = np.random.default_rng(0)
        worst_tau = worst_y = 0.0
        pi_pin = np.concatenate([pm.inertias[j].toDynamicParameters() for j in range(1, n + 1)])
        for _ in range(100):
            q, v, a = (rng.uniform(-3, 3, n) for _ in range(3))
            tau_pin = pin.rnea(pm, pd, q, v, a)
            tau_sg = arm.inverse_dynamics(q, v, v, a)
            worst_tau = max(worst_tau, np.max(np.abs(tau_pin - tau_sg)))
            Y_pin = pin.computeJointTorqueRegressor(pm, pd, q, v, a)
            Y_sg = arm.regressor(q, v, v, a)
            worst_y = max(worst_y, np.max(np.abs(Y_pin @ pi_pin - Y_sg @ arm.parameter_nominal)))
        print(f"{name}: max |rnea - softgen| = {worst_tau:.2e} N m, "
              f"max |Y_pin pi_pin - Y pi| = {worst_y:.2e} N m over 100 random states")

        q, v, a = (rng.uniform(-1, 1, n) for _ in range(3))
        number, repeat = 50_000, 7

        def best(fn):
            return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e9

        Y = arm.regressor
        for buf, x in zip(Y.inputs, (q, v, v, a)):
            buf[:] = x
        ID = arm.inverse_dynamics
        for buf, x in zip(ID.inputs, (q, v, v, a)):
            buf[:] = x
        rows = [
            ("pinocchio.computeJointTorqueRegressor",
             best(lambda: pin.computeJointTorqueRegressor(pm, pd, q, v, a))),
            ("softgen regressor, buffer path", best(Y.call)),
            ("softgen regressor, f(q, qd, qd_r, qdd_r)", best(lambda: Y(q, v, v, a))),
            ("pinocchio.rnea", best(lambda: pin.rnea(pm, pd, q, v, a))),
            ("softgen inverse_dynamics, buffer path", best(ID.call)),
        ]
        print(f"{name}: per-call latency from Python (best of {repeat} x {number})")
        for label, ns in rows:
            print(f"  {label:<45} {ns:9.1f} ns")


if __name__ == "__main__":
    main(sys.argv[1:])
