"""``softgen observer``: a delayed unknown-input observer for your own system (thesis ch. 5)"""
from __future__ import annotations

from pathlib import Path

from softgen.cli._chain import add_chain_arguments, chain_model
from softgen.core.errors import SoftgenError

HELP = "delayed unknown-input observer (eq. 5.4) for a system file or a model's linearisation"


def add_arguments(p) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--system", metavar="FILE",
                     help=".toml or .json with A, B, C, D (2-D arrays), optional time "
                          "(discrete | continuous), dt, discretization (euler | zoh), "
                          "unknown (0-based input columns; default all), name")
    src.add_argument("--model", metavar="MODEL",
                     help="linearise a rigid model's plant step (McKibben, qbmove or "
                          "torque-driven) about --q0/--actuator; unknown input: an external "
                          "torque on every joint")
    p.add_argument("--delay", type=int, default=None, metavar="L",
                   help="observer delay (default: the smallest that works)")
    p.add_argument("--out", metavar="DIR",
                   help="write <name>.c, <name>.h, manifest.json here (default: only check)")
    p.add_argument("--force", action="store_true", help="overwrite files in --out")
    p.add_argument("--q0", metavar="Q1,Q2,...", help="--model: joint positions (default 0)")
    p.add_argument("--actuator", metavar="V1,V2,...",
                   help="--model: McKibben pressures p1a,p1b,... in Pa (default half of "
                        "pressure_max) or qbmove motor positions qa1..,qb1.. (default q0)")
    p.add_argument("--dt", type=float, help="--model: sample time (default 0.01 s)")
    p.add_argument("--integrator", choices=("euler", "rk4"),
                   help="--model: one Euler (the thesis's discretisation) or RK4 step")
    add_chain_arguments(p)


def run(args) -> int:
    # Imported here: CasADi and the symbolic layer take a second to import, which
    # `softgen --help` should not pay.
    from softgen.app.observer import (check_system, linearise_model, no_observer_line,
                                      read_system, write_observer)
    if args.system is not None:
        model_only = [o for o in ("q0", "actuator", "dt", "integrator", "root", "tip")
                      if getattr(args, o) is not None]
        if model_only:
            raise SoftgenError(f"observer: --{model_only[0]} is for --model, not --system")
        system = read_system(args.system)
    else:
        system = linearise_model(chain_model(args, args.model, "observer"), q0=args.q0, actuator=args.actuator,
                                 dt=1e-2 if args.dt is None else args.dt,
                                 integrator=args.integrator or "euler")
    n, p = system.A.shape[0], system.C.shape[0]
    delay = args.delay
    if delay is None:
        first = check_system(system, 0)
        delay = first.smallest if first.smallest is not None else 0
    chk = check_system(system, delay)
    print(f"observer: {system.source}: n = {n} states, m = {len(system.unknown)} unknown + "
          f"{len(system.known)} known inputs, p = {p} outputs, delay L = {delay}")
    for c in chk.conditions:
        print(f"  {c.line()}")
    if not chk.exists:
        raise SoftgenError(no_observer_line(system, chk))
    if args.out is None:
        print(f"observer: a delayed UIO with delay {delay} exists (add --out DIR to write it)")
        return 0
    out, _ = write_observer(system, delay, Path(args.out), force=args.force)
    print(f"observer: wrote {out / (system.name + '.c')}, {system.name}.h, manifest.json")
    return 0
