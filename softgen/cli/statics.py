"""``softgen statics``: the static shape of a Cosserat (or hybrid) model under gravity,
tip loads, tendon tensions, chamber pressures and joint torques."""
from __future__ import annotations

import math

from softgen.core.errors import SoftgenError

HELP = "static shape of a Cosserat model under gravity, tip loads, tendons and pressures"


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL", help="a kind = \"cosserat\" model name or file")
    p.add_argument("--tip-force", nargs=3, type=float, metavar=("FX", "FY", "FZ"),
                   default=(0.0, 0.0, 0.0), help="force on the tip, world frame [N]")
    p.add_argument("--tip-torque", nargs=3, type=float, metavar=("MX", "MY", "MZ"),
                   default=(0.0, 0.0, 0.0), help="torque on the tip about its point, world "
                   "frame [N m]")
    p.add_argument("--tendon", action="append", default=[], metavar="NAME=T",
                   help="tendon tension [N], >= 0 (repeatable)")
    p.add_argument("--pressure", action="append", default=[], metavar="NAME=P",
                   help="chamber gauge pressure [Pa], >= 0 (repeatable)")
    p.add_argument("--torque", action="append", default=[], metavar="NAME=TAU",
                   help="torque of a rigid joint's actuator [N m] (repeatable)")
    p.add_argument("--json", metavar="OUT", help="write q, tip_position, tip_rotation "
                   "(3 x 3, rows) and the backbone to OUT")
    p.add_argument("--force", action="store_true", help="overwrite an existing --json file")
    p.add_argument("--per-segment", type=int, default=8, metavar="N",
                   help="backbone points per rod segment in --json (default 8)")


def _assignments(items: list[str], option: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = math.nan
        if not sep or not name or not math.isfinite(v):
            raise SoftgenError(f"{option} {item}: expected NAME=VALUE with a finite number")
        if name in out:
            raise SoftgenError(f"{option} {name}: given twice")
        out[name] = v
    return out


def run(args) -> int:
    from softgen.core.atomic import check_output_file
    from softgen.modelfile.limits import check_expression_size
    from softgen.app.statics import Loads, Statics, check_loads, write_json
    from softgen.modelfile.cosserat import CosseratModel
    from softgen.modelfile.load import load_model

    if args.per_segment < 1 or args.per_segment > 1000:
        raise SoftgenError(f"--per-segment: expected 1..1000, got {args.per_segment}")
    model = load_model(args.model)
    check_expression_size(model)      # before deriving (issue 36: 200 segments ran silent)
    if args.json:
        inputs = (model.path,) if model.path else ()
        check_output_file(args.json, "--json", force=args.force, inputs=inputs)
    if not isinstance(model, CosseratModel):
        raise SoftgenError(f"{model.path or model.name}: model.kind = {model.kind!r}: statics "
                           "needs a kind = \"cosserat\" model")
    inputs, kinds = {}, {}
    for option, items in (("--tendon", args.tendon), ("--pressure", args.pressure),
                          ("--torque", args.torque)):
        for k, v in _assignments(items, option).items():
            if k in inputs:
                raise SoftgenError(f"{option} {k}: given twice")
            inputs[k], kinds[k] = v, option
    loads = Loads(tip_force=tuple(args.tip_force), tip_torque=tuple(args.tip_torque),
                  inputs=inputs)
    check_loads(model, loads, kinds)
    result = Statics(model, per_segment=args.per_segment).solve(loads)
    p, R = result.tip_position, result.tip_rotation
    print(f"{model.name}: equilibrium after {result.continuation_steps} continuation step(s), "
          f"{result.newton_iterations} Newton iteration(s), residual {result.residual:.2e}")
    print(f"tip position [m]: {p[0]: .6f} {p[1]: .6f} {p[2]: .6f}")
    for i, row in enumerate(R):
        print(("tip rotation:     " if i == 0 else "                  ")
              + " ".join(f"{x: .6f}" for x in row))
    if args.json:
        write_json(result, args.json, force=args.force)
        print(f"wrote {args.json}")
    return 0
