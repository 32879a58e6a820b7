"""``softgen check``: predict whether a sampled soft-body loop is stable at given gains"""
from __future__ import annotations

from softgen.cli._chain import add_chain_arguments, chain_model

HELP = "predict from the linearised sampled loop whether Theorem 10 at --dt is stable"


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL", help="a soft model (name or .toml file)")
    p.add_argument("--dt", type=float, default=1e-3, help="sample time, s (default 1e-3)")
    p.add_argument("--kd", type=float, nargs="+", default=[1.0],
                   help="K_d = kd I (several values: one verdict each)")
    p.add_argument("--lam", type=float, nargs="+", default=[5.0],
                   help="Lambda = lam I (several values: one verdict each)")
    p.add_argument("--law", nargs="+", default=["zoh", "implicit"],
                   help="zoh (tau held, softgen.control.soft), implicit "
                        "(softgen.control.soft_sampled) and/or identified (its predictor "
                        "identified online, softgen.control.soft_identified); default zoh "
                        "implicit")
    p.add_argument("--d-scale", type=float, default=1.0,
                   help="scale of the implicit step's predictor damping (a wrong model)")
    p.add_argument("--plant-scale", nargs="+", default=None, metavar="NAME=FACTOR",
                   help="the plant off the model file: factors on its masses, stiffnesses "
                        "and dampings (e.g. mass=10 damping=2.5 stiffness=0.3)")
    add_chain_arguments(p)


def run(args) -> int:
    # Imported here, not at the top: the CLI imports every verb to build its parser, and
    # this one pulls CasADi and the symbolic layer.
    from softgen.app.check import check_model
    verdicts = check_model(chain_model(args, args.model, "check"), args.dt, args.kd, args.lam,
                           args.law, args.d_scale, args.plant_scale)
    for v in verdicts:
        print(v.line())
    return 0 if all(v.stable for v in verdicts) else 1
