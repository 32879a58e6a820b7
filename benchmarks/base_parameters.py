"""CPU time and peak memory of the base-parameter derivation on long chains.

For every chain length n (default 10 20 30 40) and chain kind, one fresh Python
process builds the model, ``RigidDynamics(model, route="recursive")`` and its
``base`` (base regressor Y and base parameters π(p)), with every inertial parameter
uncertain (masses, centres of mass, inertias: the models' default):

* ``planar``: :func:`softgen.app.chains.chain_model` (n identical revolute links);
* ``spatial``: :func:`softgen.app.chains.spatial_chain_model` (revolute joints about z
  and y in turn, every fifth prismatic; full inertias and off-axis centres of mass);
* ``planar-lengths``: ``chain_model`` with the lengths uncertain too ("every parameter
  uncertain": masses, lengths, centres of mass, inertias); lengths move the joints, so
  the base parameters are products of masses and lengths (thesis eq. 10.9);
* ``spatial-all``: ``spatial_chain_model`` with the joint placements uncertain too.

Reported per point: CPU seconds of the derivation (``time.process_time``, all
threads of the process, so BLAS threads count), peak resident memory of the whole
process (``resource.getrusage(RUSAGE_SELF).ru_maxrss``, which includes the ~50 MB of
the interpreter and CasADi), the number of base parameters, of monomials
before reduction and which path ran. ``--check`` then verifies, outside the
timing, that Y(x) π equals the nominal inverse dynamics τ(x) to 1e-9 (relative to
max(1, |τ|)) at seeded random states.

    .venv/bin/python benchmarks/base_parameters.py [--n 10 20 30 40] \\
        [--kind planar spatial] [--check] [--timeout 900]

A point that exceeds ``--timeout`` seconds of wall time is reported as such.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

_CHILD = r"""
import json, resource, sys, time
import numpy as np
t_start = time.process_time()
from softgen.app.chains import chain_model, spatial_chain_model
from softgen.symbolic.rigid import RigidDynamics
kind, n, check = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"
t0 = time.process_time()
if kind.startswith("spatial"):
    model = spatial_chain_model(n)
    if kind == "spatial-all":
        import dataclasses
        model = dataclasses.replace(model, uncertain=tuple(k for k in model.nominal
                                                           if k != "g"))
else:
    model = chain_model(n)
    if kind == "planar-lengths":
        import dataclasses
        model = dataclasses.replace(model, uncertain=tuple(
            k for k in model.nominal if k[0] in "mlcI" and k != "g"))
dyn = RigidDynamics(model, route="recursive", base_method=sys.argv[4])
t1 = time.process_time()
base = dyn.base
nominal = dyn.parameter_nominal
t2 = time.process_time()
out = {"kind": kind, "n": n, "uncertain": len(model.uncertain),
       "setup_s": t1 - t0, "base_s": t2 - t1,
       "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
       "base_count": len(base.names), "monomials": base.full_rank,
       "path": dyn.route_detail.get("base_parameters")}
if check:
    rng = np.random.default_rng(0)
    Yp = dyn.regressor_times_fun()
    tau = dyn.inverse_dynamics_fun()
    worst = 0.0
    for _ in range(5):
        x = [rng.uniform(-np.pi, np.pi, model.dof) for _ in range(4)]
        a = np.array(Yp(*x, nominal)).ravel()
        b = np.array(tau(*x)).ravel()
        worst = max(worst, float(np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b)))))
    out["check_rel_err"] = worst
print("RESULT " + json.dumps(out))
"""


def run_point(kind: str, n: int, check: bool, timeout: float, base_method: str = "auto"
              ) -> dict:
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-c", _CHILD, kind, str(n), "1" if check else "0",
                               base_method],
                              capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"kind": kind, "n": n, "error": f"over {timeout:.0f} s wall"}
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            row = json.loads(line[7:])
            row["wall_s"] = time.perf_counter() - t0
            return row
    tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
    return {"kind": kind, "n": n, "error": tail[:200]}


def fmt(row: dict) -> str:
    if "error" in row:
        return f"| {row['kind']} | {row['n']} | - | - | - | - | - | {row['error']} |"
    chk = f"{row['check_rel_err']:.1e}" if "check_rel_err" in row else "-"
    return (f"| {row['kind']} | {row['n']} | {row['uncertain']} | {row['base_s']:.2f} | "
            f"{row['peak_rss_mb']:.0f} | {row['base_count']} | {row['monomials']} | "
            f"{row['path']}; check {chk} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[10, 20, 30, 40])
    ap.add_argument("--kind", nargs="+", default=["planar-lengths", "spatial-all", "planar", "spatial"],
                    choices=["planar", "spatial", "planar-lengths", "spatial-all"])
    ap.add_argument("--check", action="store_true", help="verify Y pi = tau (not timed)")
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--json", action="store_true", help="one JSON object per point")
    ap.add_argument("--base-method", default="auto",
                    help="RigidDynamics(base_method=...): auto, numeric, regrouped, symbolic")
    args = ap.parse_args(argv)
    if not args.json:
        print("| chain | n | uncertain | base CPU s | peak RSS MB | base params | monomials | "
              "path |")
        print("|---|---|---|---|---|---|---|---|")
    for kind in args.kind:
        for n in args.n:
            row = run_point(kind, n, args.check, args.timeout, args.base_method)
            print(json.dumps(row) if args.json else fmt(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
