"""Python call latency of the Panda's generated τ (issue 31 item 6): the bundle's
checked call ``f(q, qd, qd_r, qdd_r)`` (shapes and dtypes checked, fresh output; its
compiled entry, :mod:`softgen.runtime.fastcall`, and the Python entry it falls back on)
against Pinocchio's ``pin.rnea(model, data, q, v, a)`` from Python on the same URDF, timed
interleaved on the thread's CPU clock (best of rounds). Needs ``pip install pin``.

    .venv/bin/python benchmarks/checked_call.py [--rounds 15] [--number 20000]
"""
from __future__ import annotations

import argparse
import os
import time
import timeit
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--number", type=int, default=20000)
    args = ap.parse_args()
    import pinocchio as pin

    from softgen.bundles.bundle import load_bundle
    b = load_bundle("panda")
    tau = b["panda_inverse_dynamics"]
    model = pin.buildModelFromUrdf(str(ROOT / "models" / "panda.urdf"))
    data = model.createData()
    rng = np.random.default_rng(0)
    n = model.nv
    q, v, a = (rng.uniform(-1, 1, n) for _ in range(3))
    ours = np.asarray(tau(q, v, v, a)).ravel()
    theirs = pin.rnea(model, data, q, v, a)
    err = float(np.max(np.abs(ours - theirs)) / np.max(np.abs(theirs)))
    calls = {"softgen checked call": lambda: tau(q, v, v, a),
             "pin.rnea": lambda: pin.rnea(model, data, q, v, a)}
    if tau.fast_path == "c":     # the Python entry, which takes what the C entry does not
        calls["  its Python entry"] = lambda: tau._fast(q, v, v, a)
    best = {k: float("inf") for k in calls}
    for _ in range(args.rounds):
        for k, f in calls.items():
            t = timeit.timeit(f, number=args.number, timer=time.thread_time)
            best[k] = min(best[k], t / args.number * 1e9)
    print(f"panda tau, relative difference to pin.rnea: {err:.1e}; load {os.getloadavg()}; "
          f"entry {tau.fast_path!r}")
    for k, ns in best.items():
        print(f"  {k:<22} {ns:7.0f} ns per call (thread CPU clock, best of {args.rounds})")
    print(f"  ratio pin.rnea / softgen: {best['pin.rnea'] / best['softgen checked call']:.2f}")


if __name__ == "__main__":
    main()
