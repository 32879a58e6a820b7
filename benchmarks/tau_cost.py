"""Cost of the generated inverse dynamics τ of URDF arms: instructions and time per call.

For every model (a shipped name or a path, default the shipped Panda), the τ that
``softgen generate`` builds (``RigidDynamics(model).inverse_dynamics_fun()``, route
"auto") is

1. counted: CasADi instructions (``Function.n_instructions()``, what ``softgen info``
   prints; inputs, outputs and constants included) and, with ``--callgrind``, machine
   instructions per call at -O3 from ``valgrind --tool=callgrind``: the Ir of a loop of
   2K calls minus that of K calls, divided by K (start-up and harness cancel);
2. timed: thread CPU time per call in a plain C loop at -O3 (CPU time rather than
   wall time: on a shared machine the time a process spends preempted is not the
   function's cost), the median of ``--repeats`` repeats in one process, and of those
   the median over ``--rounds`` rounds that run every function's process in turn (so
   that functions compared see the same machine load).

No Pinocchio needed (``pinocchio_chains.py --arm --urdf FILE`` gives the ratio to it).
Run from a checkout. To compare with another revision, emit its functions with its
``softgen`` first on ``PYTHONPATH``, then time both in the same interleaved rounds:

    PYTHONPATH=/path/to/old/checkout .venv/bin/python benchmarks/tau_cost.py \
        panda ur5.urdf --tag before --emit /tmp/tau_before
    .venv/bin/python benchmarks/tau_cost.py panda ur5.urdf --tag after \
        --also /tmp/tau_before --callgrind
"""
from __future__ import annotations

import argparse
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import casadi as ca

from softgen.modelfile.load import load_model
from softgen.symbolic.rigid import RigidDynamics

_LOOP = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "%(h)s"
static double cpu_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e9 + t.tv_nsec;
}
static int cmp(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}
/* argv: calls per repeat, repeats (0: run the calls once, untimed, for callgrind). */
int main(int argc, char **argv) {
  long calls = atol(argv[1]);
  int repeats = atoi(argv[2]);
  casadi_real x[4][64], out[64];
  for (int k = 0; k < 4; ++k) for (int i = 0; i < 64; ++i) x[k][i] = 0.1 * (i + 1) - 0.3 * k;
  const casadi_real *arg[8] = {x[0], x[1], x[2], x[3]};
  casadi_real *res[2] = {out};
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  %(f)s_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  casadi_int *iw = malloc(sizeof(casadi_int) * (sz_iw + 1));
  casadi_real *w = malloc(sizeof(casadi_real) * (sz_w + 1));
  volatile double sink = 0;
  double t[1000];
  if (repeats > 1000) repeats = 1000;
  for (int r = 0; r <= repeats; ++r) {          /* r = 0 warms up and is dropped */
    double t0 = cpu_ns();
    for (long c = 0; c < calls; ++c) { x[0][0] += 1e-9; %(f)s(arg, res, iw, w, 0); sink += out[0]; }
    if (r > 0) t[r - 1] = (cpu_ns() - t0) / calls;
    if (repeats == 0) break;
  }
  if (repeats > 0) { qsort(t, repeats, sizeof(double), cmp); printf("%%.1f\n", t[repeats / 2]); }
  return 0;
}
"""


def _loop(tmp: Path, name: str, src: Path) -> Path:
    """The harness of ``name``, compiled at -O3 with the generated C ``src``."""
    exe = tmp / f"loop_{name}"
    (tmp / f"loop_{name}.c").write_text(_LOOP % {"f": name, "h": src.with_suffix(".h")})
    subprocess.run(["gcc", "-O3", "-Werror=implicit-function-declaration", "-o", str(exe),
                    str(tmp / f"loop_{name}.c"), str(src), "-lm"], check=True)
    return exe


def ns_per_call(exe: Path, calls: int, repeats: int) -> float:
    """Median over ``repeats`` of the thread CPU time per call, in ns."""
    out = subprocess.run([str(exe), str(calls), str(repeats)], check=True,
                         capture_output=True, text=True)
    return float(out.stdout.strip())


def callgrind_ir(exe: Path, k: int = 2000) -> float:
    """Machine instructions per call (-O3), by callgrind: Ir(2K calls) − Ir(K calls), / K."""
    ir = []
    for calls in (k, 2 * k):
        out = exe.parent / f"cg_{exe.name}_{calls}.out"
        subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                        str(exe), str(calls), "0"], check=True, capture_output=True)
        summary = [ln for ln in out.read_text().splitlines() if ln.startswith("summary:")]
        ir.append(int(summary[0].split()[1]))
    return (ir[1] - ir[0]) / k


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="*", default=["panda"])
    ap.add_argument("--calls", type=int, default=20_000, help="calls per timed repeat")
    ap.add_argument("--repeats", type=int, default=11, help="timed repeats per round")
    ap.add_argument("--rounds", type=int, default=9,
                    help="rounds; each runs every function once, in turn")
    ap.add_argument("--callgrind", action="store_true")
    ap.add_argument("--tag", default="", help="suffix of the function names (e.g. before)")
    ap.add_argument("--emit", type=Path, help="also keep the generated tau.c/.h and the "
                    "counts in this directory (for --also of a later run)")
    ap.add_argument("--also", type=Path, nargs="*", default=[],
                    help="directories written by --emit of other revisions: their "
                         "functions are timed in the same rounds, interleaved")
    args = ap.parse_args(argv)
    if args.callgrind and not shutil.which("valgrind"):
        raise SystemExit("--callgrind: valgrind is not on PATH")

    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text()
                .splitlines() if ln.startswith("model name")), platform.processor())
    print(f"# {cpu}; gcc -O3; thread CPU time per call, median over {args.rounds} "
          f"interleaved rounds of the median of {args.repeats} repeats of {args.calls} calls")
    suffix = f"_{args.tag}" if args.tag else ""
    with tempfile.TemporaryDirectory(prefix="softgen-tau-") as tmp:
        tmp = Path(tmp)
        out = args.emit or tmp
        out.mkdir(parents=True, exist_ok=True)
        gen = ca.CodeGenerator("tau.c", {"with_header": True})
        rows = []
        for spec in args.models:
            model = load_model(Path(spec) if spec.endswith((".urdf", ".toml")) else spec)
            f = RigidDynamics(model).inverse_dynamics_fun()
            name = f"tau_{model.name}{suffix}"
            ins = f.sx_in()
            gen.add(ca.Function(name, ins, f.call(ins), f.name_in(), f.name_out(),
                                {"cse": True}))
            rows.append((name, int(f.n_instructions())))
        gen.generate(str(out) + "/")
        (out / "counts.txt").write_text("".join(f"{n} {k}\n" for n, k in rows))
        sources = [(rows, out / "tau.c")]
        for d in args.also:
            other = [(ln.split()[0], int(ln.split()[1]))
                     for ln in (d / "counts.txt").read_text().splitlines()]
            sources.append((other, d / "tau.c"))
        table = [(name, n, _loop(tmp, name, src)) for rws, src in sources for name, n in rws]
        times: dict[str, list[float]] = {name: [] for name, _, _ in table}
        for _ in range(args.rounds):
            for name, _, exe in table:
                times[name].append(ns_per_call(exe, args.calls, args.repeats))
        print(f"{'function':<24} {'CasADi instr':>12} {'Ir/call':>9} {'ns/call':>8}")
        for name, n, exe in sorted(table):
            ir = f"{callgrind_ir(exe):9.0f}" if args.callgrind else f"{'-':>9}"
            ns = sorted(times[name])[len(times[name]) // 2]
            print(f"{name:<24} {n:12d} {ir} {ns:8.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
