"""softgen's generated τ of whole trees (fixed or floating base) against Pinocchio's
``rnea`` compiled from its headers, side by side on the thread's CPU clock (issue 35).

Pinocchio is optional (``pip install pin``: its ``cmeel.prefix`` has the headers, the
URDF parser and the libraries). For each URDF file (vendor trees: Talos, ANYmal, ...):

1. softgen loads it whole (``load_model(path, floating=...)``) and generates τ, the
   bundle's ``inverse_dynamics`` (q, q̇, q̇_r, q̈_r; called at q̇_r = q̇) and its classical
   inverse dynamics ``rnea`` (q, v, a), at the flags of ``softgen generate``
   (:data:`softgen.codegen.build.CFLAGS`; ``--cflags`` adds flags to both sides alike)
   and at the level a bundle compiles each at (-O1 from
   :data:`softgen.codegen.generate.LARGE_FUNCTION` CasADi instructions on, else -O3;
   a floating bundle's ``rnea`` always -O3; ``--level O3``: all at -O3);
2. Pinocchio's URDF parser (its Python bindings, a free-flyer root for a floating base)
   reads the same file; its model (joint types, placements, inertias, damping) is
   written out and rebuilt joint by joint in the C++ harness (the pip wheel ships no
   urdfdom headers to compile the parser), softgen's coordinates are mapped onto
   Pinocchio's by joint name, and the harness checks that both give the
   same τ (+ D v: Pinocchio's ``rnea`` leaves joint damping out), then times ``rnea``
   and softgen's functions interleaved in rounds (the first dropped), each loop on
   ``CLOCK_THREAD_CPUTIME_ID``, and prints median [min-max] ns per call and the ratio
   Pinocchio ÷ softgen (above 1: softgen faster).

softgen's C is written as a bundle writes it: CasADi's, with the recursion's τ and
``rnea`` in the order of :meth:`~softgen.symbolic.rigid.RigidDynamics.codegen_order`
(:mod:`softgen.codegen.schedule`); ``--casadi-order`` keeps CasADi's order, to compare.

``--callgrind`` also runs the harness under valgrind's callgrind, a few calls of each
model, and prints each function's instructions per call (inclusive: libm's sin and cos
count), a figure the machine's load does not move.

A mimic joint is an independent joint to Pinocchio's parser: files with mimic joints are
refused here (compare like for like: talos_reduced, not talos_full_v2).

    .venv/bin/python benchmarks/tree_pinocchio.py --floating \\
        $SOFTGEN_VENDOR_URDFS/talos_reduced.urdf $SOFTGEN_VENDOR_URDFS/anymal_c.urdf

Give ``uptime`` beside the figures: CPU time does not count time preempted, but a loaded
machine still shares caches.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from softgen.app.peers import _CPP_HEAD, pinocchio_prefix, renamed
from softgen.codegen.build import CFLAGS
from softgen.codegen.generate import LARGE_FUNCTION
from softgen.codegen.schedule import apply_orders

#: softgen's compiler flags without -shared (the harness links an object file).
SOFTGEN_CFLAGS = [f for f in CFLAGS if f != "-shared"]
from softgen.modelfile.load import load_model
from softgen.symbolic.rigid import RigidDynamics

_HARNESS = r"""
// One line per joint: type parent R(9) p(3) axis(3) mass com(3) I_com(6) damping; the
// model as Pinocchio's own URDF parser built it (its Python bindings wrote the file).
static Model build_tree(const char *path, Eigen::Vector3d &g) {
  std::ifstream in(path);
  int n; in >> n >> g[0] >> g[1] >> g[2];
  Model m;
  m.gravity.linear() = g;
  std::vector<double> damping;
  for (int i = 0; i < n; ++i) {
    std::string type; int parent; double r[9], x[3], a[3], mass, c[3], I[6];
    in >> type >> parent;
    for (auto &v : r) in >> v;
    for (auto &v : x) in >> v;
    for (auto &v : a) in >> v;
    in >> mass >> c[0] >> c[1] >> c[2];
    for (auto &v : I) in >> v;
    int nv = type == "FreeFlyer" ? 6 : 1;
    for (int k = 0; k < nv; ++k) { double d; in >> d; damping.push_back(d); }
    Eigen::Matrix3d R; R << r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8];
    SE3 X(R, Eigen::Vector3d(x[0], x[1], x[2]));
    Eigen::Vector3d axis(a[0], a[1], a[2]);
    std::string name = "j" + std::to_string(i);
    JointIndex j;
    if (type == "FreeFlyer") j = m.addJoint(parent, JointModelFreeFlyer(), X, name);
    else if (type == "RX") j = m.addJoint(parent, JointModelRX(), X, name);
    else if (type == "RY") j = m.addJoint(parent, JointModelRY(), X, name);
    else if (type == "RZ") j = m.addJoint(parent, JointModelRZ(), X, name);
    else if (type == "PX") j = m.addJoint(parent, JointModelPX(), X, name);
    else if (type == "PY") j = m.addJoint(parent, JointModelPY(), X, name);
    else if (type == "PZ") j = m.addJoint(parent, JointModelPZ(), X, name);
    else if (type == "RevoluteUnaligned") j = m.addJoint(parent, JointModelRevoluteUnaligned(axis), X, name);
    else j = m.addJoint(parent, JointModelPrismaticUnaligned(axis), X, name);
    Eigen::Matrix3d Ic; Ic << I[0], I[1], I[2], I[1], I[3], I[4], I[2], I[4], I[5];
    m.appendBodyToJoint(j, Inertia(mass, Eigen::Vector3d(c[0], c[1], c[2]), Ic), SE3::Identity());
  }
  m.damping = Eigen::Map<Eigen::VectorXd>(damping.data(), damping.size());
  return m;
}

// Out of line, so that callgrind counts each call's instructions under one name (the
// CasADi functions are their own symbols already; their sin/cos are counted inside them).
__attribute__((noinline)) static void call_rnea(const Model &m, Data &d, const Eigen::VectorXd &q,
                                                const Eigen::VectorXd &v, const Eigen::VectorXd &a) {
  rnea(m, d, q, v, a);
}

static void bench_tree(const char *tag, const char *desc, int floating, const char *map,
                       casadi_fn tau, work_fn tau_w, casadi_fn id3, work_fn id3_w,
                       long calls, int repeats) {
  Eigen::Vector3d g;
  Model m = build_tree(desc, g);
  Data d(m);
  // map: nq nv, then our q -> Pinocchio's q index, our v -> Pinocchio's v index.
  std::ifstream in(map);
  int nq, nv; in >> nq >> nv;
  std::vector<int> iq(nq), iv(nv);
  for (auto &k : iq) in >> k;
  for (auto &k : iv) in >> k;
  Eigen::VectorXd q(nq), v(nv), a(nv), out(nv), out3(nv);
  srand(1);
  q.setRandom(); v.setRandom(); a.setRandom();
  if (floating) q.segment<4>(3).normalize();
  Eigen::VectorXd qp(m.nq), vp(m.nv), ap(m.nv);
  for (int k = 0; k < nq; ++k) qp[iq[k]] = q[k];
  for (int k = 0; k < nv; ++k) { vp[iv[k]] = v[k]; ap[iv[k]] = a[k]; }
  CFun ftau(tau, tau_w, {q.data(), v.data(), v.data(), a.data()}, out.data());
  CFun fid3(id3, id3_w, {q.data(), v.data(), a.data()}, out3.data());
  ftau(); fid3();
  call_rnea(m, d, qp, vp, ap);
  Eigen::VectorXd ref = d.tau + m.damping.cwiseProduct(vp), ours(nv);
  for (int k = 0; k < nv; ++k) ours[k] = ref[iv[k]];
  double s = std::max(1.0, ours.cwiseAbs().maxCoeff());
  double err = (ours - out).cwiseAbs().maxCoeff() / s, err3 = (ours - out3).cwiseAbs().maxCoeff() / s;
  std::vector<double> t_rnea, t_tau, t_id3;
  for (int r = 0; r < repeats + 1; ++r) {     // the first round warms up and is dropped
    double a1 = time_ns([&] { call_rnea(m, d, qp, vp, ap); sink += d.tau[0]; }, calls);
    double a2 = time_ns([&] { ftau(); sink += out[0]; }, calls);
    double a3 = time_ns([&] { fid3(); sink += out3[0]; }, calls);
    if (r == 0) continue;
    t_rnea.push_back(a1); t_tau.push_back(a2); t_id3.push_back(a3);
  }
  printf("%s %d %.3e %.3e", tag, nv, err, err3);
  stats(t_rnea); stats(t_tau); stats(t_id3);
  printf("\n");
  fflush(stdout);
}
"""


def pinocchio_description(path: Path, floating: bool) -> tuple[str, object]:
    """Pinocchio's model of the URDF file (its Python parser), as the lines the harness
    rebuilds it from, and the model."""
    import pinocchio as pin
    pm = (pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if floating
          else pin.buildModelFromUrdf(str(path)))
    g = pm.gravity.linear
    lines = [f"{pm.njoints - 1} " + " ".join(repr(float(x)) for x in g)]
    for j in range(1, pm.njoints):
        jm = pm.joints[j]
        kind = jm.shortname().replace("JointModel", "")
        if kind not in ("FreeFlyer", "RX", "RY", "RZ", "PX", "PY", "PZ", "RevoluteUnaligned",
                        "PrismaticUnaligned"):
            raise SystemExit(f"{path.name}: joint {pm.names[j]} is {kind} in Pinocchio (a "
                             "continuous joint: cos, sin); not comparable here")
        axis = (np.asarray(jm.extract().axis) if "Unaligned" in kind else np.zeros(3))
        X, inert = pm.jointPlacements[j], pm.inertias[j]
        Ic = inert.inertia
        d = pm.damping[jm.idx_v:jm.idx_v + jm.nv]
        vals = [*X.rotation.ravel(), *X.translation, *axis, inert.mass, *inert.lever,
                Ic[0, 0], Ic[0, 1], Ic[0, 2], Ic[1, 1], Ic[1, 2], Ic[2, 2], *d]
        lines.append(f"{kind} {pm.parents[j]} " + " ".join(repr(float(x)) for x in vals))
    return "\n".join(lines) + "\n", pm


def coordinate_map(pm, model, name: str) -> tuple[list[int], list[int]]:
    """Pinocchio's q and v index of each of softgen's coordinates, by joint name."""
    if model.mimics:
        raise SystemExit(f"{name}: mimic joints are independent joints to Pinocchio's "
                         "parser; compare a file without them")
    iq, iv = (list(range(7)), list(range(6))) if model.floating else ([], [])
    for link in model.links:
        j = pm.joints[pm.getJointId(link.joint_name)]
        iq.append(j.idx_q)
        iv.append(j.idx_v)
    if pm.nq != model.nq or pm.nv != model.nv:
        raise SystemExit(f"{name}: Pinocchio has nq={pm.nq}, nv={pm.nv}; softgen "
                         f"{model.nq}, {model.nv}")
    return iq, iv


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("urdf", nargs="+", type=Path)
    ap.add_argument("--floating", action="store_true")
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--pin-prefix", type=Path, default=None)
    ap.add_argument("--keep", type=Path, default=None, help="work in this directory and keep "
                    "it (the harness takes minutes of g++)")
    ap.add_argument("--callgrind", action="store_true", help="also count each function's "
                    "instructions per call under valgrind's callgrind (robust to the load)")
    ap.add_argument("--level", choices=("bundle", "O3"), default="bundle",
                    help="compile each function at the level its bundle does (-O1 from "
                    "LARGE_FUNCTION CasADi instructions on; default) or all at -O3")
    ap.add_argument("--casadi-order", action="store_true", help="softgen's C in CasADi's "
                    "order (before issue 35's softgen.codegen.schedule), for comparison")
    ap.add_argument("--cflags", default="", help="extra flags for both compilers alike, e.g. "
                    "'-march=native' (default: none, as softgen builds bundles)")
    args = ap.parse_args(argv)
    prefix = (args.pin_prefix or pinocchio_prefix())
    if prefix is None:
        raise SystemExit("Pinocchio is not installed (pip install pin)")
    prefix = prefix.resolve()
    with tempfile.TemporaryDirectory(prefix="softgen-tree-pin-") as tmp_:
        tmp = Path(tmp_) if args.keep is None else args.keep.resolve()
        tmp.mkdir(parents=True, exist_ok=True)
        # One C file per compiler level: a bundle compiles each function at -O3, or at
        # -O1 from LARGE_FUNCTION CasADi instructions on (softgen.bundles.bundle);
        # --level O3 compiles all at -O3.
        gens = {lv: ca.CodeGenerator(f"softgen_fns{suffix}.c", {"with_header": True})
                for lv, suffix in (("-O3", ""), ("-O1", "_o1"))}
        used: set[str] = set()
        orders: dict[str, dict] = {"-O3": {}, "-O1": {}}

        def add(fn, name, keep_o3=False, order=None):
            lv = "-O1" if args.level == "bundle" and not keep_o3 and \
                fn.n_instructions() >= LARGE_FUNCTION else "-O3"
            used.add(lv)
            f = renamed(fn, name)
            gens[lv].add(f)
            if order is not None and not args.casadi_order:
                orders[lv][name] = (f, order)
            return lv
        calls = []
        for k, path in enumerate(args.urdf):
            tag = f"m{k}"
            t0 = time.perf_counter()
            model = load_model(path, floating=args.floating)
            dyn = RigidDynamics(model)
            tau = dyn.inverse_dynamics_fun()
            id3 = dyn.rnea_fun()
            print(f"# {tag} = {path.name} ({'floating' if model.floating else 'fixed'}, nv "
                  f"{model.nv}): derived in {time.perf_counter() - t0:.1f} s; CasADi "
                  f"instructions: inverse_dynamics {tau.n_instructions()}, (q, v, a) "
                  f"{id3.n_instructions()}; compiled at "
                  f"{add(tau, f'tau_{tag}', order=dyn.codegen_order(tau))} and "
                  f"{add(id3, f'id3_{tag}', keep_o3=model.floating, order=dyn.codegen_order(id3))}",
                  flush=True)
            desc, pm = pinocchio_description(path, model.floating)
            (tmp / f"{tag}.txt").write_text(desc)
            iq, iv = coordinate_map(pm, model, path.name)
            (tmp / f"{tag}.map").write_text(f"{model.nq} {model.nv}\n{' '.join(map(str, iq))}\n"
                                            f"{' '.join(map(str, iv))}\n")
            calls.append(f'  if (only < 0 || only == {k}) bench_tree("{tag}", '
                         f'"{tmp / (tag + ".txt")}", {int(model.floating)}, '
                         f'"{tmp / (tag + ".map")}", tau_{tag}, tau_{tag}_work, id3_{tag}, '
                         f"id3_{tag}_work, calls, repeats);")
        for lv, g in gens.items():
            g.generate(str(tmp) + "/")
            c = tmp / f"softgen_fns{'' if lv == '-O3' else '_o1'}.c"
            # As a bundle writes it: the recursion's C in the order of codegen_order.
            c.write_bytes(apply_orders(c.read_bytes(), orders[lv]))
        with open(tmp / "softgen_fns.h", "a") as fh:      # the harness includes this one
            fh.write('\n#include "softgen_fns_o1.h"\n')
        cpp = tmp / "harness.cpp"
        # harness [calls [repeats [model]]]: the defaults, or a few calls of one model
        # (under callgrind).
        text = (_CPP_HEAD + _HARNESS + "\nint main(int argc, char **argv) {\n"
                + f"  long calls = argc > 1 ? atol(argv[1]) : {args.calls};\n"
                + f"  int repeats = argc > 2 ? atoi(argv[2]) : {args.repeats};\n"
                + "  int only = argc > 3 ? atoi(argv[3]) : -1;\n" + "\n".join(calls)
                + "\n  return 0;\n}\n")
        t0 = time.perf_counter()
        extra = args.cflags.split()
        # softgen's C at the flags of `softgen generate` (softgen.codegen.build.CFLAGS).
        objs = []
        for lv, suffix in (("-O3", ""), ("-O1", "_o1")):
            objs.append(str(tmp / f"softgen_fns{suffix}.o"))
            subprocess.run(["gcc", lv, *SOFTGEN_CFLAGS[1:], *extra, "-c", "-o", objs[-1],
                            str(tmp / f"softgen_fns{suffix}.c")], check=True)
        print(f"# gcc of softgen's C: {time.perf_counter() - t0:.1f} s", flush=True)
        defs = ["-DBOOST_MPL_LIMIT_LIST_SIZE=30", "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30",
                "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DBOOST_FUSION_INVOKE_MAX_ARITY=12"]
        t0 = time.perf_counter()
        text += f"// flags: {' '.join(extra)}\n"
        if not (cpp.exists() and cpp.read_text() == text and (tmp / "harness.o").exists()):
            cpp.write_text(text)        # with --keep, compiled again only when it changed
            subprocess.run(["g++", "-O3", "-DNDEBUG", "-std=c++17", *extra, *defs,
                            f"-I{prefix}/include", f"-I{prefix}/include/eigen3", f"-I{tmp}",
                            "-c", "-o", str(tmp / "harness.o"), str(cpp)], check=True)
        subprocess.run(["g++", "-o", str(tmp / "harness"), str(tmp / "harness.o"),
                        *objs, f"-L{prefix}/lib", "-lpinocchio_default",
                        f"-Wl,-rpath,{prefix}/lib", "-lm"], check=True)
        print(f"# g++ -O3 of the Pinocchio harness: {time.perf_counter() - t0:.1f} s",
              flush=True)
        run = subprocess.run([str(tmp / "harness")], capture_output=True, text=True)
        if run.returncode != 0:
            raise SystemExit(f"harness failed ({run.returncode}): {run.stderr[-2000:]}")
        out = run.stdout
        counted = ([callgrind_counts(tmp, k, f"m{k}") for k in range(len(args.urdf))]
                   if args.callgrind else [])
    print(f"{'model':<6} {'nv':>3} {'|τ-rnea|':>9} {'|id-rnea|':>9}  {'Pinocchio rnea ns':>22}  "
          f"{'softgen τ ns':>22} {'÷':>5}  {'softgen (q,v,a) ns':>22} {'÷':>5}")
    for line in out.splitlines():
        f = line.split()
        v = np.array(f[4:], dtype=float).reshape(3, 3)
        cell = lambda r: f"{r[0]:.1f} [{r[1]:.0f}-{r[2]:.0f}]"  # noqa: E731
        print(f"{f[0]:<6} {f[1]:>3} {float(f[2]):9.1e} {float(f[3]):9.1e}  {cell(v[0]):>22}  "
              f"{cell(v[1]):>22} {v[0, 0] / v[1, 0]:5.2f}  {cell(v[2]):>22} "
              f"{v[0, 0] / v[2, 0]:5.2f}")
    for k, c in enumerate(counted):
        if c is None:
            continue
        print(f"callgrind m{k}: instructions per call (libm's sin/cos included): Pinocchio "
              f"rnea {c['rnea']:,.0f}, softgen τ {c['tau']:,.0f} (÷ {c['rnea'] / c['tau']:.2f}), "
              f"softgen (q,v,a) {c['id3']:,.0f} (÷ {c['rnea'] / c['id3']:.2f})")
    return 0


#: Calls of each function per model in the callgrind run: the check, then 2 rounds of 30.
_CG_CALLS, _CG_REPEATS = 30, 1


def callgrind_counts(tmp: Path, k: int, tag: str) -> dict[str, float] | None:
    """Instructions per call of Pinocchio's rnea and softgen's two functions of model k,
    counted by callgrind (``valgrind --tool=callgrind``; inclusive: callees such as libm's
    sin and cos count), which does not depend on the machine's load."""
    out = tmp / f"callgrind.{tag}.out"
    run = subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                          str(tmp / "harness"), str(_CG_CALLS), str(_CG_REPEATS), str(k)],
                         capture_output=True, text=True)
    if run.returncode != 0:
        # e.g. SIGILL: valgrind does not know every instruction of -march=native builds.
        print(f"# callgrind {tag}: failed ({run.returncode}): {run.stderr.strip()[-300:]}")
        return None
    ann = subprocess.run(["callgrind_annotate", "--inclusive=yes", str(out)],
                         check=True, capture_output=True, text=True).stdout
    n = 1 + (_CG_REPEATS + 1) * _CG_CALLS
    got = {}
    for key, sym in (("rnea", "call_rnea"), ("tau", f"tau_{tag}"), ("id3", f"id3_{tag}")):
        m = re.search(rf"^\s*([\d,]+) .*[:\s]{sym}\b", ann, re.MULTILINE)
        if m is None:
            raise SystemExit(f"callgrind: no count for {sym} in {out}")
        got[key] = int(m.group(1).replace(",", "")) / n
    return got


if __name__ == "__main__":
    raise SystemExit(main())
