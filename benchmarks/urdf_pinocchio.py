"""softgen against Pinocchio on the same URDF files: inverse dynamics, regressor, timings.

Pinocchio is not a dependency. Run in a scratch environment that has it, with softgen
from the checkout on the path:

    python3 -m venv /tmp/pinvenv
    /tmp/pinvenv/bin/pip install pin cmeel-eigen casadi==3.8.2 numpy scipy matplotlib
    PYTHONPATH=$PWD /tmp/pinvenv/bin/python benchmarks/urdf_pinocchio.py \\
        [URDF ...] [--states 1000] [--cpp --pin-prefix \\
        /tmp/pinvenv/lib/python3.11/site-packages/cmeel.prefix]

Default files: the 3-joint test arm ``tests/data/arm3.urdf`` (offsets, tilted and
unnormalised axes, full tensors in rotated inertial frames, a continuous and a prismatic
joint, fixed joints in the middle and at the tip) and the shipped Panda
``models/panda.urdf``. For each file:

1. Pinocchio reads it with ``pin.buildModelFromUrdf`` (its own URDF parser, which also
   merges fixed links into their parent body), softgen with ``load_model``; softgen's
   bundle is generated (the shipped one for a shipped model) and compiled.
2. At seeded random states (q, v, a), ``pin.rnea`` + D v against softgen's generated
   ``inverse_dynamics(q, v, v, a)`` (D: the URDF's ``<dynamics damping>``, which
   Pinocchio stores but ``rnea`` leaves out), and both regressors: softgen's
   ``regressor(q, v, v, a) @ pi`` and Pinocchio's ``computeJointTorqueRegressor`` times
   its dynamic parameters (``Inertia.toDynamicParameters`` of each body) + D v. All
   four must agree; the largest absolute differences (N m or N) are printed.
   A continuous joint is an unbounded joint in Pinocchio (q as cos, sin): mapped here.
3. Timings from Python, per call, best of 7 repeats of 20,000 calls: Pinocchio's
   bindings (``rnea``, ``computeJointTorqueRegressor``; boost.python call + C++)
   against softgen's compiled library through its fixed-buffer fast path
   (``f.inputs[k][:] = ...; f.call()``: one ctypes call + the generated C, -O3).
4. With ``--cpp``, the C++ harness of ``pinocchio_chains.py`` on the same models: both
   libraries called from C++ at -O3, no Python in the loop. That harness builds
   Pinocchio's model from softgen's merged chain (a continuous joint becomes a bounded
   revolute joint there), and checks its rnea against softgen's τ first.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import timeit
from pathlib import Path

import numpy as np
import pinocchio as pin

from softgen.bundles.bundle import generate, load_bundle
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = [ROOT / "tests" / "data" / "arm3.urdf", ROOT / "models" / "panda.urdf"]


def pin_configuration(pm, q: np.ndarray) -> np.ndarray:
    """Pinocchio's q from one angle or displacement per joint (cos, sin for unbounded)."""
    out = []
    for j, jm in enumerate(pm.joints[1:]):
        out += [np.cos(q[j]), np.sin(q[j])] if jm.nq == 2 else [q[j]]
    return np.array(out)


def check_order(pm, model) -> None:
    """Pinocchio's joints in softgen's chain order: each softgen link hangs on joint i."""
    for i, link in enumerate(model.links, start=1):
        frame = pm.frames[pm.getFrameId(link.name)]
        if frame.parentJoint != i:
            raise SystemExit(f"{model.name}: link {link.name} is on Pinocchio joint "
                             f"{frame.parentJoint}, softgen joint {i}")


def compare(path: Path, states: int, tmp: Path):
    model = load_model(path)
    pm = pin.buildModelFromUrdf(str(path))
    pd = pm.createData()
    n = model.dof
    if pm.nv != n:
        raise SystemExit(f"{path}: Pinocchio has {pm.nv} velocities, softgen {n} joints")
    check_order(pm, model)
    shipped = path.resolve().parent == MODELS_DIR.resolve()
    arm = load_bundle(model.name if shipped else generate(path, tmp), backend="c")
    D = np.array(pm.damping)
    pi_pin = np.concatenate([pm.inertias[j].toDynamicParameters() for j in range(1, n + 1)])
    prismatic = np.array([lk.joint == "prismatic" for lk in model.links])
    rng = np.random.default_rng(17)
    err = {"tau": 0.0, "Ypi_sg": 0.0, "Ypi_pin": 0.0, "Ysg_vs_Ypin": 0.0}
    tau_max = 0.0
    for _ in range(states):
        q, v, a = (rng.uniform(-np.pi, np.pi, n), rng.uniform(-2, 2, n), rng.uniform(-5, 5, n))
        q[prismatic] = rng.uniform(-0.1, 0.1, int(prismatic.sum()))
        qp = pin_configuration(pm, q)
        tau_pin = pin.rnea(pm, pd, qp, v, a) + D * v
        tau_sg = arm.inverse_dynamics(q, v, v, a)
        ypi_sg = arm.regressor(q, v, v, a) @ arm.parameter_nominal
        ypi_pin = pin.computeJointTorqueRegressor(pm, pd, qp, v, a) @ pi_pin + D * v
        tau_max = max(tau_max, np.abs(tau_pin).max())
        for k, e in (("tau", tau_sg - tau_pin), ("Ypi_sg", ypi_sg - tau_sg),
                     ("Ypi_pin", ypi_pin - tau_pin), ("Ysg_vs_Ypin", ypi_sg - ypi_pin)):
            err[k] = max(err[k], float(np.abs(e).max()))
    return model, pm, pd, arm, err, tau_max


def timings(model, pm, pd, arm) -> dict[str, float]:
    """ns per call from Python, best of 7 repeats (see the module docstring)."""
    n = model.dof
    rng = np.random.default_rng(1)
    q, v, a = (rng.uniform(-1, 1, n) for _ in range(3))
    qp = pin_configuration(pm, q)
    number = 20_000

    def best(fn):
        return min(timeit.repeat(fn, number=number, repeat=7)) / number * 1e9

    out = {"pin.rnea": best(lambda: pin.rnea(pm, pd, qp, v, a)),
           "pin.regressor": best(lambda: pin.computeJointTorqueRegressor(pm, pd, qp, v, a))}
    for key, name, ins in (("softgen tau", "inverse_dynamics", (q, v, v, a)),
                           ("softgen Y", "regressor", (q, v, v, a)),
                           ("softgen Ypi", "regressor_times",
                            (q, v, v, a, arm.parameter_nominal))):
        f = getattr(arm, name) if hasattr(arm, name) else arm[f"{model.name}_{name}"]
        for k, x in enumerate(ins):
            f.inputs[k][:] = x
        out[key] = best(f.call)
    out["softgen tau (checked call)"] = best(lambda: arm.inverse_dynamics(q, v, v, a))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("urdf", nargs="*", type=Path, default=DEFAULT)
    ap.add_argument("--states", type=int, default=1000, help="random states compared")
    ap.add_argument("--cpp", action="store_true", help="also the C++ harness (minutes of g++)")
    ap.add_argument("--pin-prefix", type=Path, help="cmeel.prefix of `pip install pin` (--cpp)")
    args = ap.parse_args(argv)
    if args.cpp and args.pin_prefix is None:
        ap.error("--cpp needs --pin-prefix")
    print(f"pinocchio {pin.__version__}; {args.states} seeded random states per model; "
          "errors are max |difference| over every joint and state")
    models = []
    with tempfile.TemporaryDirectory(prefix="softgen-urdf-pin-") as tmp:
        for path in args.urdf:
            model, pm, pd, arm, err, tau_max = compare(path, args.states, Path(tmp))
            models.append((model.name, model))
            print(f"\n{path.name}: {model.name}, {model.dof} joints "
                  f"({', '.join(lk.joint for lk in model.links)}), "
                  f"{len(arm.parameter_nominal)} base parameters; max |tau| {tau_max:.3g}")
            print(f"  |tau_softgen - (rnea + D v)|            {err['tau']:.2e}")
            print(f"  |Y pi - tau| softgen                    {err['Ypi_sg']:.2e}")
            print(f"  |Y_pin pi_pin + D v - (rnea + D v)|     {err['Ypi_pin']:.2e}")
            print(f"  |Y pi (softgen) - Y_pin pi_pin (pin)|   {err['Ysg_vs_Ypin']:.2e}")
            ok = all(e <= 1e-10 for e in err.values())
            print(f"  {'PASS' if ok else 'FAIL'} (1e-10)")
            print("  ns per call from Python:")
            for k, t in timings(model, pm, pd, arm).items():
                print(f"    {k:<28} {t:9.0f}")
    if args.cpp:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from pinocchio_chains import harness
        print("\nC++ (pinocchio_chains.py harness: -O3, interleaved, median ns per call; "
              "ratios Pinocchio / softgen)")
        print("\n".join(harness(models, args.pin_prefix, 20000, 7)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
