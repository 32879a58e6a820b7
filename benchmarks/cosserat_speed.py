"""Speed of the Cosserat pipeline in generated C (issue 33, Done-when 4), CPU clock.

Sections (``--only NAME`` runs one):

``control``  the 3-segment 3D tendon rod (6 strains per segment, 4 tendons,
             ``tests/data/rod_tendon_6strain.toml``): the task-space adaptive step and
             one sample of the closed loop (references + controller + plant, ROS2 and
             linearly implicit Euler), µs per call; real-time factor = 1 ms / loop step.
``scaling``  CasADi instructions and µs per call of the forward dynamics at 4, 8 and 16
             segments: a 3D PCS rod (6 strains) and the 3D PCC arm (``pcc_3d_4seg``'s
             segment). The rod as one straight-line SX function ("SX") and as the looped
             function (:mod:`softgen.symbolic.tree_loop`, the rod's
             ``forward_dynamics_fun``); the PCC by the routes the PCC bundles use, the O(n)
             passes over the segments (:mod:`softgen.symbolic.pcc_chain`): looped
             (``pcc_chain.forward_dynamics_fun``, the bundles' ``forward_dynamics``) and
             straight-line (:func:`softgen.control.soft.plant_qdd`, the bundles' plant),
             beside the issue-25 block solve (``plant_qdd(route="blocks")``, O(n²)) and
             the tree route (:mod:`softgen.symbolic.pcc_tree`, SX and looped). A looped
             function's C calls one function per distinct block of segments
             (instructions: what its C runs, the called functions' CasADi instructions
             summed over the calls). Every size's functions are compiled first, then timed
             round-robin in one process (7 rounds, the median per function), so the 16/4
             ratios are read under one load; the ratios are printed.
``jsrm``     a planar PCS forward dynamics (3 segments, bend/shear/axial, 5 Gauss points:
             ``tests/test_cosserat_jsrm.py``'s rod) in softgen's generated C against jsrm's
             ``forward_dynamics`` under ``jax.jit`` on the CPU (``block_until_ready``
             per call), side by side in one run. Needs jax and jsrm (skipped otherwise).

Times are the median over repeats of the thread CPU time per call
(``CLOCK_THREAD_CPUTIME_ID``; JAX: the process CPU time around each call, which includes
its dispatch, ``time.process_time``: every thread of the process, XLA's too), at -O3, inputs from a realistic state (not random), with the load average
printed beside them. Run on an idle machine for final figures:

    .venv/bin/python benchmarks/cosserat_speed.py [--only control|scaling|jsrm]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

_HARNESS = r"""
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
%(data)s
int main(int argc, char **argv) {
  long calls = atol(argv[1]);
  int repeats = atoi(argv[2]);
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  %(f)s_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  const casadi_real **arg = malloc(sizeof(casadi_real *) * (sz_arg + 1));
  casadi_real **res = malloc(sizeof(casadi_real *) * (sz_res + 1));
  casadi_int *iw = malloc(sizeof(casadi_int) * (sz_iw + 1));
  casadi_real *w = malloc(sizeof(casadi_real) * (sz_w + 1));
%(bind)s
  volatile double sink = 0;
  double t[1000];
  if (repeats > 1000) repeats = 1000;
  for (int r = 0; r <= repeats; ++r) {
    double t0 = cpu_ns();
    for (long c = 0; c < calls; ++c) { %(f)s(arg, res, iw, w, 0); sink += res[0][0]; }
    if (r > 0) t[r - 1] = (cpu_ns() - t0) / calls;
  }
  qsort(t, repeats, sizeof(double), cmp);
  printf("%%.1f\n", t[repeats / 2]);
  return 0;
}
"""


def time_c(f: ca.Function, inputs: list, *, calls: int = 2000, repeats: int = 7,
           opt: str = "-O3") -> float:
    """Median thread-CPU ns per call of the generated C of ``f`` at ``inputs``."""
    with tempfile.TemporaryDirectory(prefix="cosserat-speed-") as tmp:
        tmp = Path(tmp)
        cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": True})
        cg.add(f)
        cg.generate(str(tmp) + "/")
        data, bind = [], []
        for i, v in enumerate(inputs):
            v = np.atleast_1d(np.asarray(v, dtype=float)).ravel(order="F")
            data.append(f"static casadi_real in{i}[] = {{{', '.join(repr(float(x)) for x in v)}"
                        f"{', ' if len(v) else ''}0}};")
            bind.append(f"  arg[{i}] = in{i};")
        for k in range(f.n_out()):
            n = f.nnz_out(k)
            data.append(f"static casadi_real out{k}[{max(n, 1)}];")
            bind.append(f"  res[{k}] = out{k};")
        src = tmp / "harness.c"
        src.write_text(_HARNESS % {"h": tmp / f"{f.name()}.h", "f": f.name(),
                                   "data": "\n".join(data), "bind": "\n".join(bind)})
        exe = tmp / "harness"
        subprocess.run(["gcc", opt, "-o", str(exe), str(src), str(tmp / f"{f.name()}.c"), "-lm"],
                       check=True, capture_output=True)
        out = subprocess.run([str(exe), str(calls), str(repeats)], check=True,
                             capture_output=True, text=True)
        return float(out.stdout.strip())


_MANY = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#define casadi_real double
#define casadi_int long long int
static double cpu_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e9 + t.tv_nsec;
}
static int cmp(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}
typedef int (*fn_t)(const casadi_real **, casadi_real **, casadi_int *, casadi_real *, int);
typedef int (*work_t)(casadi_int *, casadi_int *, casadi_int *, casadi_int *);
%(decl)s
int main(int argc, char **argv) {
  long calls = atol(argv[1]);
  int repeats = atoi(argv[2]);
  if (repeats > 1000) repeats = 1000;
  enum { NF = %(nf)d };
  fn_t fn[NF] = {%(fns)s};
  work_t wk[NF] = {%(wks)s};
  const casadi_real **arg[NF]; casadi_real **res[NF]; casadi_int *iw[NF]; casadi_real *w[NF];
  static double t[NF][1000];
  volatile double sink = 0;
  for (int k = 0; k < NF; ++k) {
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    wk[k](&sz_arg, &sz_res, &sz_iw, &sz_w);
    arg[k] = malloc(sizeof(casadi_real *) * (sz_arg + 1));
    res[k] = malloc(sizeof(casadi_real *) * (sz_res + 1));
    iw[k] = malloc(sizeof(casadi_int) * (sz_iw + 1));
    w[k] = malloc(sizeof(casadi_real) * (sz_w + 1));
  }
%(bind)s
  for (int r = 0; r <= repeats; ++r)      /* round-robin: every function in every round */
    for (int k = 0; k < NF; ++k) {
      double t0 = cpu_ns();
      for (long c = 0; c < calls; ++c) { fn[k](arg[k], res[k], iw[k], w[k], 0); sink += res[k][0][0]; }
      if (r > 0) t[k][r - 1] = (cpu_ns() - t0) / calls;
    }
  for (int k = 0; k < NF; ++k) {
    qsort(t[k], repeats, sizeof(double), cmp);
    printf("%%.1f\n", t[k][repeats / 2]);
  }
  return 0;
}
"""


def time_c_many(items: list, *, calls: int = 2000, repeats: int = 7,
                opt: str = "-O3") -> list[float]:
    """Median thread-CPU ns per call of the generated C of each (f, inputs) of ``items``,
    all in one process, timed round-robin (every function once per round), so that
    their ratios are read under the same load. Names must be distinct."""
    with tempfile.TemporaryDirectory(prefix="cosserat-speed-") as tmp:
        tmp = Path(tmp)
        decl, bind, objs = [], [], []
        for k, (f, inputs) in enumerate(items):
            nm = f.name()
            cg = ca.CodeGenerator(f"{nm}.c", {"with_header": True})
            cg.add(f)
            cg.generate(str(tmp) + "/")
            obj = tmp / f"{nm}.o"
            subprocess.run(["gcc", opt, "-c", "-o", str(obj), str(tmp / f"{nm}.c")],
                           check=True, capture_output=True)
            objs.append(str(obj))
            decl.append(f"int {nm}(const casadi_real **, casadi_real **, casadi_int *, "
                        f"casadi_real *, int);\nint {nm}_work(casadi_int *, casadi_int *, "
                        "casadi_int *, casadi_int *);")
            for i, v in enumerate(inputs):
                v = np.atleast_1d(np.asarray(v, dtype=float)).ravel(order="F")
                decl.append(f"static casadi_real in{k}_{i}[] = {{"
                            f"{', '.join(repr(float(x)) for x in v)}{', ' if len(v) else ''}0}};")
                bind.append(f"  arg[{k}][{i}] = in{k}_{i};")
            for o in range(f.n_out()):
                decl.append(f"static casadi_real out{k}_{o}[{max(f.nnz_out(o), 1)}];")
                bind.append(f"  res[{k}][{o}] = out{k}_{o};")
        names = [f.name() for f, _ in items]
        src = tmp / "harness.c"
        src.write_text(_MANY % {"decl": "\n".join(decl), "bind": "\n".join(bind),
                                "nf": len(items), "fns": ", ".join(names),
                                "wks": ", ".join(f"{n}_work" for n in names)})
        exe = tmp / "harness"
        subprocess.run(["gcc", "-O2", "-o", str(exe), str(src), *objs, "-lm"], check=True,
                       capture_output=True)
        out = subprocess.run([str(exe), str(calls), str(repeats)], check=True,
                             capture_output=True, text=True)
        return [float(x) for x in out.stdout.split()]


def load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.2f} {b:.2f} {c:.2f}"


# --------------------------------------------------------------------------- sections

def control() -> None:
    from softgen.blocks import ClosedLoop
    from softgen.control import cosserat as C
    from softgen.modelfile.load import load_model
    from softgen.runtime.simulate import simulate
    from softgen.symbolic.cosserat_dynamics import CosseratDynamics
    m = load_model(ROOT / "tests" / "data" / "rod_tendon_6strain.toml")
    d = CosseratDynamics(m)
    print(f"## control: {m.name}, {m.dof} DoF, {m.n_inputs} tendons ({load()})")
    loop = C.closed_loop(d)
    tr = simulate(loop, steps=500, externals={"w": np.zeros((500, 6))})
    q, qd = tr["plant.q"][-1], tr["plant.qd"][-1]
    pi = tr["ctrl.pi_hat"][-1]
    g = C.GAINS
    step = C.tip_adaptive_fun(d)
    xd = tr["ref.x_d"][-1]
    ins = [pi, q, qd, xd, tr["ref.xd_d"][-1], tr["ref.xdd_d"][-1], g.lam, g.kd,
           g.kpi_vector(d), g.u_min, 1e-3]
    t_ctrl = time_c(step, ins)
    print(f"controller step: {step.n_instructions()} instructions, {t_ctrl / 1000:.1f} µs")
    for method in C.PLANT_METHODS:
        dg = ClosedLoop(f"loop_{method}", [C.reference_block("ref", 1e-3),
                                           C.controller_block(d, 1e-3),
                                           C.plant_block(d, 1e-3, method=method)],
                        externals=[("w", 6, "N")])
        f = dg.step_fun()
        x = np.concatenate([pi, q, qd])
        p0 = np.concatenate([b.p0 for b in dg.blocks.values()])
        t_loop = time_c(f, [x, p0, 500.0, np.zeros(6)])
        print(f"loop step ({method} plant): {t_loop / 1000:.1f} µs per 1 ms sample, "
              f"{1e6 / t_loop:.0f}x real time")


def _rod(ns: int):
    from softgen.modelfile.load import load_model
    seg = ("[[segments]]\nlength = 0.1\nradius = 0.01\ndensity = 1100\nyoungs_modulus = 1e6\n"
           "damping = 1000\nstrains = [\"torsion\", \"bend_y\", \"bend_z\", \"stretch\", "
           "\"shear_y\", \"shear_z\"]\n")
    p = Path(tempfile.mkdtemp()) / f"rod{ns}.toml"
    p.write_text("[model]\nname = \"rod\"\nkind = \"cosserat\"\n" + seg * ns)
    return load_model(p)


def _pcc(ns: int):
    from softgen.modelfile.load import load_model
    text = (ROOT / "models" / "pcc_3d_4seg.toml").read_text()
    head, rest = text.split("[[segments]]", 1)
    seg = "[[segments]]" + rest.split("[[segments]]")[0]
    p = Path(tempfile.mkdtemp()) / f"pcc{ns}.toml"
    p.write_text(head + seg * ns)
    return load_model(p)


def executed_instructions(f: ca.Function) -> int:
    """CasADi instructions one evaluation of ``f`` runs: an SX function's count; for an MX
    function (the looped routes), its own instructions plus, per call, the called
    function's (recursively)."""
    if f.is_a("SXFunction"):
        return f.n_instructions()
    return sum(executed_instructions(f.instruction_MX(i).which_function())
               if f.instruction_id(i) == ca.OP_CALL else 1 for i in range(f.n_instructions()))


def scaling() -> None:
    from softgen.control.soft import plant_qdd
    from softgen.symbolic import pcc_chain
    from softgen.symbolic.cosserat_dynamics import CosseratDynamics
    from softgen.symbolic.pcc import SoftDynamics
    from softgen.symbolic.pcc_tree import forward_dynamics, forward_dynamics_function, pcc_tree
    os.environ.setdefault("SOFTGEN_MAX_EXPRESSION_SIZE", "100000000")
    rng = np.random.default_rng(0)
    rows = []               # (model, route, segments, instructions, function, inputs)
    for ns in (4, 8, 16):
        d = CosseratDynamics(_rod(ns))
        x = [rng.normal(size=d.model.dof) * 0.1, rng.normal(size=d.model.dof)]
        f = ca.Function(f"fd_rod_sx{ns}", [d.q, d.qd],
                        [d.forward_dynamics_expr(ca.DM.zeros(0))], {"cse": True})
        rows.append(("Cosserat PCS, 6 strains", "SX", ns, f.n_instructions(), f, x))
        f = d.forward_dynamics_fun()
        f = ca.Function(f"fd_rod_loop{ns}", [f.mx_in(0), f.mx_in(1)],
                        [f(f.mx_in(0), f.mx_in(1), ca.DM.zeros(0), ca.DM.zeros(6))])
        rows.append(("Cosserat PCS, 6 strains", "looped", ns, executed_instructions(f), f, x))
    for ns in (4, 8, 16):
        m = _pcc(ns)
        dyn = SoftDynamics(m)
        b = dyn.nominal
        tau, fx = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * ns)
        x = [rng.normal(size=m.dof) * 0.1, rng.normal(size=m.dof), np.zeros(b.n_inputs),
             np.zeros(3 * ns)]
        f = pcc_chain.forward_dynamics_fun(dyn)
        f = ca.Function(f"fd_pcc_passes_loop{ns}", f.mx_in(), f.call(f.mx_in()))
        rows.append(("PCC 3D", "O(n) passes, looped (bundles' forward_dynamics)", ns,
                     executed_instructions(f), f, x[:3]))
        f = ca.Function(f"fd_pcc_passes_sx{ns}", [b.q, b.qd, tau, fx], [plant_qdd(b, tau, fx)],
                        {"cse": True})
        rows.append(("PCC 3D", "O(n) passes, SX (bundles' plant)", ns, f.n_instructions(),
                     f, x))
        f = ca.Function(f"fd_pcc_blocks{ns}", [b.q, b.qd, tau, fx],
                        [plant_qdd(b, tau, fx, route="blocks")], {"cse": True})
        rows.append(("PCC 3D", "blocks (issue 25)", ns, f.n_instructions(), f, x))
        pt = pcc_tree(b)
        f = ca.Function(f"fd_pcc_tree_sx{ns}", [b.q, b.qd, tau, fx],
                        [forward_dynamics(b, pt, tau, fx)], {"cse": True})
        rows.append(("PCC 3D", "tree, SX", ns, f.n_instructions(), f, x))
        f = forward_dynamics_function(b, pt, f"fd_pcc_tree_loop{ns}")
        rows.append(("PCC 3D", "tree, looped", ns, executed_instructions(f), f, x))
    before = load()
    times = time_c_many([(r[4], r[5]) for r in rows])
    print(f"## scaling: forward dynamics, instructions and µs per call (before the timing "
          f"{before}; after it {load()})")
    print("| model | route | segments | instructions | µs |")
    print("|---|---|---:|---:|---:|")
    for r, t in zip(rows, times):
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {t / 1000:.2f} |")
    print("\n16 segments over 4, same run:")
    by = {(r[0], r[1], r[2]): (r[3], t) for r, t in zip(rows, times)}
    for (model, route, ns), (ins16, t16) in by.items():
        if ns == 16:
            ins4, t4 = by[(model, route, 4)]
            print(f"- {model}, {route}: time {t16 / t4:.2f}x, instructions {ins16 / ins4:.2f}x")


def jsrm() -> None:
    try:
        import jax
        import jax.numpy as jnp
        from jsrm.systems.planar_pcs import PlanarPCS
    except ImportError as exc:
        print(f"## jsrm: skipped ({exc})")
        return
    import math
    import warnings
    jax.config.update("jax_enable_x64", True)
    from softgen.modelfile.load import load_model
    from softgen.symbolic.cosserat_dynamics import CosseratDynamics
    ns, L, R = 3, [0.1, 0.12, 0.08], [0.02, 0.015, 0.012]
    RHO, E = [1070.0, 1100.0, 1000.0], [1e4, 2e4, 3e4]
    G = [e / 3 for e in E]
    params = {"th0": jnp.array(0.3), "l": jnp.array(L), "r": jnp.array(R),
              "rho": jnp.array(RHO), "g": jnp.array([0.0, -9.81]), "E": jnp.array(E),
              "G": jnp.array(G), "D": 1e-3 * jnp.eye(3 * ns)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = PlanarPCS(num_segments=ns, params=params, order_gauss=5)
    segs = ""
    for i in range(ns):
        A, I = math.pi * R[i] ** 2, math.pi * R[i] ** 4 / 4
        segs += (f"[[segments]]\nlength = {L[i]!r}\nradius = {R[i]!r}\ndensity = {RHO[i]!r}\n"
                 f"EI = {E[i] * I!r}\nEA = {E[i] * A!r}\nGA = {4 / 3 * A * G[i]!r}\n"
                 "strains = [\"bend_z\", \"stretch\", \"shear_y\"]\nquadrature = 5\n")
    p = Path(tempfile.mkdtemp()) / "pp.toml"
    p.write_text("[model]\nname = \"pp\"\nkind = \"cosserat\"\nbase_rpy_deg = [0, 0, 107.19]\n"
                 "[gravity]\nvector = [0.0, -9.81, 0.0]\n" + segs)
    d = CosseratDynamics(load_model(p))
    f = ca.Function("pp_fd", [d.q, d.qd], [d.forward_dynamics_expr(ca.DM.zeros(0))],
                    {"cse": True})
    rng = np.random.default_rng(1)
    q, qd = rng.normal(size=3 * ns) * 0.5, rng.normal(size=3 * ns)
    t_ours = time_c(f, [q, qd], calls=20000)
    fd = jax.jit(lambda y: robot.forward_dynamics(0.0, y, (jnp.zeros(3 * ns),)))
    y = jnp.array(np.concatenate([q, qd]))
    fd(y).block_until_ready()                    # compile
    times = []
    for _ in range(7):
        t0 = time.process_time()         # every thread of the process: XLA's too
        for _ in range(200):
            fd(y).block_until_ready()
        times.append((time.process_time() - t0) / 200)
    t_jsrm = float(np.median(times)) * 1e9
    print(f"## jsrm: planar PCS, 3 segments, 9 DoF, forward dynamics ({load()})")
    print(f"softgen C: {f.n_instructions()} instructions, {t_ours / 1000:.2f} µs per call")
    print(f"jsrm jax.jit CPU: {t_jsrm / 1000:.1f} µs per call (process CPU time, with "
          f"dispatch); ratio {t_jsrm / t_ours:.0f}x")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("control", "scaling", "jsrm"))
    args = ap.parse_args(argv)
    for name, fn in (("control", control), ("scaling", scaling), ("jsrm", jsrm)):
        if args.only in (None, name):
            fn()
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
