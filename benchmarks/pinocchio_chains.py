"""softgen's generated C against Pinocchio's C++ on the same chains, timed interleaved.

Pinocchio is not a dependency. Install it in a scratch environment, e.g.

    python3 -m venv /tmp/pinvenv && /tmp/pinvenv/bin/pip install pin cmeel-eigen

and point this script at its headers and libraries (the ``cmeel.prefix`` directory):

    .venv/bin/python benchmarks/pinocchio_chains.py \\
        --pin-prefix /tmp/pinvenv/lib/python3.11/site-packages/cmeel.prefix \\
        --n 2 5 10 20 40 80 --arm

For every chain (softgen.app.chains.chain_model(n); with ``--arm`` also the shipped
7-DoF Panda, ``models/panda.urdf``, and with ``--urdf FILE ...`` any URDF arm, e.g.
the UR5 of example-robot-data), it writes one C file with softgen's
functions as ``softgen generate`` builds them (``RigidDynamics(model)`` with
route="auto": τ = inverse_dynamics, Yᵀ s and Y π̂ over the base parameters), a text
description of the chain (joint type, axis, placement, mass, centre of mass,
inertia) from which the C++ harness builds the Pinocchio model, and one C++
harness that

1. checks Pinocchio's ``rnea(q, v, a)`` against softgen's τ at q̇_r = q̇, q̈_r = q̈;
2. times ``rnea`` and ``computeJointTorqueRegressor`` against softgen's τ, Yᵀ s and
   Y π̂, repeats interleaved, median ns of thread CPU time per call (CPU time, so that
   time preempted on a shared machine does not count). Both sides are compiled with
   ``-O3`` (softgen's C with gcc, the harness with g++ -O3 -DNDEBUG).

Prints one table; ratios are Pinocchio ÷ softgen (above 1: softgen faster).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from softgen.app.chains import chain_model
from softgen.modelfile.load import load_model
from softgen.symbolic.mechanics import rpy
from softgen.symbolic.rigid import RigidDynamics

def describe(model) -> str:
    """One line per joint: type axis(3) xyz(3) rot(9) mass com(3) inertia-about-com(6)
    damping (viscous; Pinocchio's ``rnea`` leaves it out, the harness adds D v)."""
    p = model.nominal
    res = lambda v: float(model.resolve(v, p))  # noqa: E731
    R0 = rpy(*model.base_rpy)
    g = p["g"] * np.asarray(model.gravity_direction)
    lines = [f"{model.dof} " + " ".join(repr(float(x)) for x in g)]
    for i, link in enumerate(model.links):
        if link.inertia_about != "com":
            raise SystemExit(f"{model.name}: lumped inertia has no Pinocchio equivalent")
        xyz = np.array([res(v) for v in link.origin_xyz])
        rot = rpy(*link.origin_rpy)
        if i == 0:              # the base frame's rotation folds into the first placement
            xyz, rot = R0 @ xyz, R0 @ rot
        com = [res(v) for v in link.com]
        inertia = [res(v) for v in link.inertia]
        damping = res(link.damping) if link.damping is not None else 0.0
        vals = (list(link.axis) + list(xyz) + list(rot.ravel()) + [res(link.mass)] + com
                + inertia + [damping])
        # The joint type is read as an integer: write it as one.
        lines.append(f"{0 if link.joint == 'revolute' else 1} "
                     + " ".join(repr(float(v)) for v in vals))
    return "\n".join(lines) + "\n"


def renamed(f: ca.Function, name: str) -> ca.Function:
    ins = f.sx_in()
    return ca.Function(name, ins, f.call(ins), f.name_in(), f.name_out(), {"cse": True})


_CPP_HEAD = r"""
#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <pinocchio/algorithm/regressor.hpp>
#include <ctime>
#include <cstdio>
#include <fstream>
#include <vector>
#include <algorithm>
extern "C" {
#include "softgen_fns.h"
}
using namespace pinocchio;
typedef int (*casadi_fn)(const casadi_real**, casadi_real**, casadi_int*, casadi_real*, int);
typedef int (*work_fn)(casadi_int*, casadi_int*, casadi_int*, casadi_int*);
static volatile double sink;

static Model build(const char *path) {
  std::ifstream in(path);
  int n; double g[3];
  in >> n >> g[0] >> g[1] >> g[2];
  Model m;
  m.gravity.linear() << g[0], g[1], g[2];
  JointIndex parent = 0;
  std::vector<double> damping(n);
  for (int i = 0; i < n; ++i) {
    int type; double a[3], x[3], r[9], mass, c[3], I[6];
    in >> type >> a[0] >> a[1] >> a[2] >> x[0] >> x[1] >> x[2];
    for (int k = 0; k < 9; ++k) in >> r[k];
    in >> mass >> c[0] >> c[1] >> c[2];
    for (int k = 0; k < 6; ++k) in >> I[k];
    in >> damping[i];
    Eigen::Matrix3d R; R << r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8];
    SE3 placement(R, Eigen::Vector3d(x[0], x[1], x[2]));
    Eigen::Vector3d axis(a[0], a[1], a[2]);
    JointIndex j;
    std::string name = "j" + std::to_string(i);
    // Pinocchio's specialised joints where the axis is a coordinate axis (its fast path).
    if (type == 0 && axis == Eigen::Vector3d::UnitZ()) j = m.addJoint(parent, JointModelRZ(), placement, name);
    else if (type == 0 && axis == Eigen::Vector3d::UnitX()) j = m.addJoint(parent, JointModelRX(), placement, name);
    else if (type == 0 && axis == Eigen::Vector3d::UnitY()) j = m.addJoint(parent, JointModelRY(), placement, name);
    else if (type == 0) j = m.addJoint(parent, JointModelRevoluteUnaligned(axis), placement, name);
    else if (axis == Eigen::Vector3d::UnitX()) j = m.addJoint(parent, JointModelPX(), placement, name);
    else j = m.addJoint(parent, JointModelPrismaticUnaligned(axis), placement, name);
    Eigen::Matrix3d Ic; Ic << I[0], I[3], I[4], I[3], I[1], I[5], I[4], I[5], I[2];
    m.appendBodyToJoint(j, Inertia(mass, Eigen::Vector3d(c[0], c[1], c[2]), Ic), SE3::Identity());
    parent = j;
  }
  m.damping = Eigen::Map<Eigen::VectorXd>(damping.data(), n);
  return m;
}

struct CFun {
  casadi_fn f; std::vector<const casadi_real*> arg; std::vector<casadi_real*> res;
  std::vector<casadi_int> iw; std::vector<casadi_real> w;
  CFun(casadi_fn f_, work_fn wk, std::vector<const casadi_real*> in, casadi_real *out) : f(f_) {
    casadi_int a, r, i, ww; wk(&a, &r, &i, &ww);
    arg.assign(std::max<casadi_int>(a, in.size()), nullptr);
    res.assign(std::max<casadi_int>(r, 1), nullptr);
    for (size_t k = 0; k < in.size(); ++k) arg[k] = in[k];
    res[0] = out; iw.resize(i + 1); w.resize(ww + 1);
  }
  inline void operator()() { f(arg.data(), res.data(), iw.data(), w.data(), 0); }
};

// CPU time of this thread, not wall time: on a shared machine, time spent preempted by
// other processes is not the function's cost.
static double cpu_ns() {
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e9 + t.tv_nsec;
}

template <class F> static double time_ns(F &&fn, long calls) {
  double t0 = cpu_ns();
  for (long c = 0; c < calls; ++c) fn();
  return (cpu_ns() - t0) / calls;
}

static double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

static void bench(const char *tag, const char *desc, casadi_fn tau, work_fn tau_w,
                  casadi_fn yts, work_fn yts_w, casadi_fn ypi, work_fn ypi_w, int n_pi,
                  long calls, int repeats) {
  Model m = build(desc);
  Data d(m);
  int n = m.nv;
  Eigen::VectorXd q = Eigen::VectorXd::Random(n), v = Eigen::VectorXd::Random(n),
                  a = Eigen::VectorXd::Random(n), s = Eigen::VectorXd::Random(n),
                  pi = Eigen::VectorXd::Random(n_pi), out(n), outp(n_pi), outy(n);
  CFun ftau(tau, tau_w, {q.data(), v.data(), v.data(), a.data()}, out.data());
  CFun fyts(yts, yts_w, {q.data(), v.data(), v.data(), a.data(), s.data()}, outp.data());
  CFun fypi(ypi, ypi_w, {q.data(), v.data(), v.data(), a.data(), pi.data()}, outy.data());
  ftau();
  rnea(m, d, q, v, a);
  Eigen::VectorXd tau_d = d.tau + m.damping.cwiseProduct(v);
  double err = (tau_d - out).cwiseAbs().maxCoeff() / std::max(1.0, tau_d.cwiseAbs().maxCoeff());
  std::vector<double> t_rnea, t_tau, t_reg, t_yts, t_ypi;
  long rc = std::max(1L, calls / (n > 20 ? 4 : 1));
  for (int r = 0; r < repeats + 1; ++r) {     // the first round warms up and is dropped
    double a1 = time_ns([&] { rnea(m, d, q, v, a); sink += d.tau[0]; }, calls);
    double a2 = time_ns([&] { ftau(); sink += out[0]; }, calls);
    double a3 = time_ns([&] { computeJointTorqueRegressor(m, d, q, v, a); sink += d.jointTorqueRegressor(0, 0); }, rc);
    double a4 = time_ns([&] { fyts(); sink += outp[0]; }, calls);
    double a5 = time_ns([&] { fypi(); sink += outy[0]; }, calls);
    if (r == 0) continue;
    t_rnea.push_back(a1); t_tau.push_back(a2); t_reg.push_back(a3); t_yts.push_back(a4);
    t_ypi.push_back(a5);
  }
  printf("%s %d %.3e %.1f %.1f %.1f %.1f %.1f\n", tag, n, err, median(t_rnea), median(t_tau),
         median(t_reg), median(t_yts), median(t_ypi));
  fflush(stdout);
}
"""


def harness(models, prefix: Path, calls: int, repeats: int) -> list[str]:
    """Compile and run the C++ harness on ``models`` ((tag, RobotModel) pairs).

    One table row per model: Pinocchio ``rnea`` / ``computeJointTorqueRegressor``
    against softgen's τ, Yᵀ s and Y π̂, median ns per call (also used by
    ``urdf_pinocchio.py``). ``prefix`` is the ``cmeel.prefix`` of ``pip install pin``.
    """
    prefix = prefix.resolve()
    with tempfile.TemporaryDirectory(prefix="softgen-pin-") as tmp:
        tmp = Path(tmp)
        gen = ca.CodeGenerator("softgen_fns.c", {"with_header": True})
        calls_cpp = []
        for tag, model in models:
            t0 = time.perf_counter()
            dyn = RigidDynamics(model)
            fns = {"tau": dyn.inverse_dynamics_fun(), "yts": dyn.regressor_transpose_times_fun(),
                   "ypi": dyn.regressor_times_fun()}
            derive = time.perf_counter() - t0
            for k, f in fns.items():
                gen.add(renamed(f, f"{k}_{tag}"))
            (tmp / f"{tag}.txt").write_text(describe(model))
            print(f"# {tag}: derived in {derive:.2f} s, route {dyn.route_detail.get('tau')}, "
                  f"Yts by {dyn.route_detail.get('regressor_transpose_times')}, "
                  f"instructions tau {fns['tau'].n_instructions()}, "
                  f"Yts {fns['yts'].n_instructions()}, Ypi {fns['ypi'].n_instructions()}, "
                  f"{len(dyn.parameter_names)} base parameters", flush=True)
            calls_cpp.append(
                f'  bench("{tag}", "{tmp / (tag + ".txt")}", tau_{tag}, tau_{tag}_work, '
                f"yts_{tag}, yts_{tag}_work, ypi_{tag}, ypi_{tag}_work, "
                f"{len(dyn.parameter_names)}, {calls}, {repeats});")
        gen.generate(str(tmp) + "/")
        cpp = tmp / "harness.cpp"
        cpp.write_text(_CPP_HEAD + "\nint main() {\n" + "\n".join(calls_cpp)
                       + "\n  return 0;\n}\n")
        t0 = time.perf_counter()
        subprocess.run(["gcc", "-O3", "-fPIC", "-c", "-o", str(tmp / "softgen_fns.o"),
                        str(tmp / "softgen_fns.c")], check=True)
        print(f"# gcc -O3 of softgen's C: {time.perf_counter() - t0:.1f} s", flush=True)
        t0 = time.perf_counter()
        # Pinocchio's own interface definitions (its CMake config); no explicit template
        # instantiation, so its algorithms are compiled here at -O3 and inlined.
        defs = ["-DBOOST_MPL_LIMIT_LIST_SIZE=30", "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30",
                "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DBOOST_FUSION_INVOKE_MAX_ARITY=12"]
        subprocess.run(["g++", "-O3", "-DNDEBUG", "-std=c++17", *defs, f"-I{prefix}/include",
                        f"-I{prefix}/include/eigen3", f"-I{tmp}", "-o", str(tmp / "harness"),
                        str(cpp), str(tmp / "softgen_fns.o"), f"-L{prefix}/lib",
                        "-lpinocchio_default", f"-Wl,-rpath,{prefix}/lib", "-lm"],
                       check=True)
        print(f"# g++ -O3 of the Pinocchio harness: {time.perf_counter() - t0:.1f} s",
              flush=True)
        proc = subprocess.run([str(tmp / "harness")], check=True, capture_output=True,
                              text=True)
    head = (f"{'model':<8} {'n':>3} {'|tau-rnea|':>10} {'rnea ns':>9} {'tau ns':>8} "
            f"{'ratio':>6} {'regr ns':>9} {'Yts ns':>8} {'ratio':>6} {'Ypi ns':>8} {'ratio':>6}")
    rows = [head]
    for line in proc.stdout.splitlines():
        tag, n, err, rn, ta, rg, yt, yp = line.split()
        rn, ta, rg, yt, yp = map(float, (rn, ta, rg, yt, yp))
        rows.append(f"{tag:<8} {n:>3} {float(err):10.1e} {rn:9.1f} {ta:8.1f} {rn / ta:6.2f} "
                    f"{rg:9.1f} {yt:8.1f} {rg / yt:6.2f} {yp:8.1f} {rg / yp:6.2f}")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pin-prefix", required=True, type=Path,
                    help="cmeel.prefix directory of a scratch `pip install pin cmeel-eigen`")
    ap.add_argument("--n", type=int, nargs="+", default=[2, 5, 10, 20, 40, 80])
    ap.add_argument("--arm", action="store_true",
                    help="also the shipped 7-DoF Panda (models/panda.urdf)")
    ap.add_argument("--urdf", type=Path, nargs="*", default=[],
                    help="more URDF files (tagged by their file stem), e.g. a UR5")
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)

    models = [(f"chain{n}", chain_model(n)) for n in args.n]
    if args.arm:
        models.append(("panda", load_model("panda")))
    models += [(path.stem.replace("-", "_"), load_model(path)) for path in args.urdf]
    print("\n".join(harness(models, args.pin_prefix, args.calls, args.repeats)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
