"""Round three of the fault campaign (issue 36): the verbs and model classes added after
the second campaign, Cosserat rods (``kind = "cosserat"``, ``statics``), trees and
floating bases (``--floating``, ``floating = true``), ``bench``, ``export --set`` and
``identify`` of a floating base's log.

Loaded by ``benchmarks/fault_campaign.py`` after ``fault_attempts`` (its generators are
registered beside that module's, per verb). Nothing here touches a path outside the
attempt's sandbox: a device output is a FIFO made in the sandbox, never ``/dev/...``.
"""
from __future__ import annotations

import csv
import os
import random
import re
import signal
from pathlib import Path

from fault_attempts import mutate_toml, put, steps
from fault_campaign import ROOT, TESTS, Attempt, generator

MODELS = ROOT / "models"
ROD = (MODELS / "rod_tendon_3seg.toml").read_text()
ROD6 = (TESTS / "data" / "rod_tendon_6strain.toml").read_text()
#: A rod with a tendon and a chamber (tests/test_statics.py's).
ROD2 = """[model]
name = "rod2"
kind = "cosserat"
base_rpy_deg = [0, 90, 0]

[[segments]]
length = 0.2
radius = 0.01
density = 1100
youngs_modulus = 1e6
strains = ["bend_y", "bend_z", "stretch"]

[[actuators]]
type = "tendon"
name = "t"
offset = [0.008, 0.0]

[[actuators]]
type = "chamber"
name = "c"
area = 2e-5
offset = [0.0, 0.006]
"""
#: A hybrid chain: a rigid revolute joint, then a rod (a soft wrist on a rigid arm).
HYBRID = """[model]
name = "hybrid"
kind = "cosserat"

[[segments]]
name = "j"
joint = "revolute"
axis = [0, 0, 1]
mass = 1
com = [0.1, 0, 0]
inertia = [0.01, 0.01, 0.01, 0, 0, 0]

[[segments]]
length = 0.3
radius = 0.01
density = 1000
youngs_modulus = 1e6
strains = ["bend_y", "bend_z"]

[[actuators]]
type = "torque"
name = "m"
joint = "j"
"""
URDF = (TESTS / "data" / "arm3.urdf").read_text()


def _quad(floating: bool = True) -> str:
    import sys
    sys.path.insert(0, str(TESTS))
    from test_identify_floating import quadruped_toml
    return quadruped_toml(floating)


def _rod(n: int, text: str = ROD) -> str:
    """``text`` with its first segment repeated ``n`` times."""
    head, rest = text.split("[[segments]]", 1)
    segment = "[[segments]]" + rest.split("[[segments]]")[0].split("[[actuators]]")[0]
    actuators = text[text.index("[[actuators]]"):] if "[[actuators]]" in text else ""
    return head + "".join(segment.replace('"s1"', f'"s{i}"') for i in range(n)) + actuators


def _named_urdf(name: str) -> str:
    return re.sub(r'<robot name="[^"]*"', f'<robot name="{name}"', URDF, count=1)


def _fifo(name: str):
    def step(d: Path) -> None:
        os.mkfifo(d / name)
    return step


# -- statics ----------------------------------------------------------------------------

@generator("statics")
def statics_attempts(rng: random.Random, ctx):
    rod, rod2 = put("rod.toml", ROD), put("rod2.toml", ROD2)
    ok = (("s.json", "json"),)
    yield Attempt("statics", "shipped rod, no load", ["statics", "rod_tendon_3seg"])
    yield Attempt("statics", "tendons", ["statics", "rod.toml", "--tendon", "t1=0.5",
                                         "--tendon", "t2=0.2", "--json", "s.json"], rod,
                  outputs=ok)
    yield Attempt("statics", "tendon and chamber", ["statics", "rod2.toml", "--tendon", "t=1",
                                                    "--pressure", "c=2e4", "--json", "s.json"],
                  rod2, outputs=ok)
    yield Attempt("statics", "6 strains, tip force", ["statics", "r6.toml", "--tip-force",
                                                      "0.1", "0", "0", "--json", "s.json"],
                  put("r6.toml", ROD6), outputs=ok, timeout=120)
    yield Attempt("statics", "hybrid, joint torque", ["statics", "h.toml", "--torque", "m=0.01",
                                                      "--json", "s.json"],
                  put("h.toml", HYBRID), outputs=ok)
    # Outputs: the model itself, a directory, a FIFO, a missing directory, an existing file.
    yield Attempt("statics", "--json is the model, --force",
                  ["statics", "rod.toml", "--json", "./rod.toml", "--force"], rod)
    yield Attempt("statics", "--json is the model", ["statics", "rod.toml", "--json",
                                                     "rod.toml"], rod)
    yield Attempt("statics", "--json a directory", ["statics", "rod.toml", "--json", "d",
                                                    "--force"], steps(rod, put("d/x", "mine")))
    yield Attempt("statics", "--json a FIFO", ["statics", "rod.toml", "--json", "f", "--force"],
                  steps(rod, _fifo("f")), timeout=30)
    yield Attempt("statics", "--json in a missing directory",
                  ["statics", "rod.toml", "--json", "no/s.json"], rod)
    yield Attempt("statics", "--json exists", ["statics", "rod.toml", "--json", "s.json"],
                  steps(rod, put("s.json", "mine")))
    yield Attempt("statics", "--json exists, --force", ["statics", "rod.toml", "--json",
                                                        "s.json", "--force"],
                  steps(rod, put("s.json", "mine")), may_change=("s.json",), outputs=ok)
    yield Attempt("statics", "--json on a full disk", ["statics", "rod.toml", "--json",
                                                       "disk/s.json"], rod, disk=100,
                  outputs=(("disk/s.json", "json"),))
    # Loads.
    loads = [["--tendon", "t1=-1"], ["--tendon", "t9=1"], ["--tendon", "t1=nan"],
             ["--tendon", "t1"], ["--tendon", "t1=1", "--tendon", "t1=2"],
             ["--tendon", "t1=1e30"], ["--tip-force", "1e300", "0", "0"],
             ["--tip-force", "1", "2"], ["--tip-force", "inf", "0", "0"],
             ["--tip-torque", "0", "0", "50"], ["--pressure", "t1=1"], ["--torque", "t1=1"],
             ["--per-segment", "0"], ["--per-segment", "1000000"], ["--per-segment", "1000"],
             ["--tendon", "t1=" + "9" * 400], ["--tendon", "=1"], ["--tendon", "t1=1e-320"],
             ["--tip-force", "0", "0", "-1000"]]
    for extra in loads:
        yield Attempt("statics", "load " + " ".join(extra)[:50], ["statics", "rod.toml", *extra,
                                                                   "--json", "s.json"], rod,
                      outputs=ok, timeout=120)
    # Models: sizes, wrong kinds, broken values.
    yield Attempt("statics", "200-segment rod", ["statics", "r.toml"], put("r.toml", _rod(200)),
                  timeout=60)
    yield Attempt("statics", "40-segment rod", ["statics", "r.toml"], put("r.toml", _rod(40)),
                  timeout=120)
    yield Attempt("statics", "a rigid model", ["statics", "planar_2link"])
    yield Attempt("statics", "a JSON file", ["statics", "m.json"], put("m.json", '{"a": 1}'))
    yield Attempt("statics", "a URDF", ["statics", "a.urdf"], put("a.urdf", URDF))
    for key, values in {"youngs_modulus": ["1e300", "1e12", "0", "-1", "1e-30"],
                        "radius": ["0", "-0.01", "10", "1e-9"],
                        "length": ["0", "1e6", "-0.1"], "density": ["0", "1e9"],
                        "damping": ["-1", "1e12"],
                        "strains": ['[]', '["twist", "twist"]', '["warp"]', '"bend_y"']}.items():
        for v in values:
            text = re.sub(rf"^{key} = .*$", f"{key} = {v}", ROD, count=1, flags=re.M)
            yield Attempt("statics", f"rod {key} = {v}", ["statics", "r.toml", "--tendon",
                                                          "t1=0.2", "--json", "s.json"],
                          put("r.toml", text), outputs=ok, timeout=120)
    for i in range(20):
        yield Attempt("statics", f"mutated rod #{i}", ["statics", "m.toml", "--json", "s.json"],
                      put("m.toml", mutate_toml(rng.choice([ROD, ROD2, HYBRID]), rng)),
                      outputs=ok, timeout=120)
    for sig in (signal.SIGINT, signal.SIGTERM):
        yield Attempt("statics", f"{signal.Signals(sig).name} while solving",
                      ["statics", "r6.toml", "--tip-force", "0.5", "0", "0", "--json", "s.json"],
                      put("r6.toml", ROD6), signal=(sig, rng.uniform(1.0, 3.0)),
                      outputs=ok)


@generator("info")
def info_rod_attempts(rng, ctx):
    for name, text in {"rod": ROD, "rod2": ROD2, "hybrid": HYBRID, "rod 6 strains": ROD6,
                       "quadruped": _quad(), "fixed quadruped": _quad(False)}.items():
        yield Attempt("info", f"{name}", ["info", "m.toml"], put("m.toml", text), timeout=120)
    for i in range(12):
        yield Attempt("info", f"mutated rod #{i}", ["info", "m.toml"],
                      put("m.toml", mutate_toml(rng.choice([ROD, ROD2, HYBRID]), rng)),
                      timeout=120)
    for i in range(10):
        yield Attempt("info", f"mutated floating tree #{i}", ["info", "m.toml"],
                      put("m.toml", mutate_toml(_quad(), rng)), timeout=120)
    yield Attempt("info", "URDF --floating", ["info", "a.urdf", "--floating"],
                  put("a.urdf", URDF), timeout=120)


# -- floating bases ----------------------------------------------------------------------

def _massless(text: str) -> str:
    text = re.sub(r"^mass = .*$", "mass = 0.0", text, flags=re.M)
    return re.sub(r"^inertia = .*$", "inertia = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]", text,
                  flags=re.M)


@generator("generate")
def generate_floating_attempts(rng, ctx):
    for n in (8, 64, 65, 300):
        name = "a" * n
        yield Attempt("generate", f"--floating, a {n}-character name, no directory",
                      ["generate", "a.urdf", "--floating", "--out", "g", "--no-build"],
                      put("a.urdf", _named_urdf(name)),
                      outputs=((f"g/{name}", "bundle"),) if n <= 64 else (), timeout=120)
    yield Attempt("generate", "--floating --root --tip", ["generate", "a.urdf", "--floating",
                                                          "--tip", "nope", "--out", "g"],
                  put("a.urdf", URDF))
    yield Attempt("generate", "floating quadruped", ["generate", "q.toml", "--out", "g",
                                                     "--no-build"], put("q.toml", _quad()),
                  outputs=(("g/quad", "bundle"),), timeout=150)
    yield Attempt("generate", "massless floating base",
                  ["generate", "q.toml", "--out", "g", "--no-build"],
                  put("q.toml", _massless(_quad())), outputs=(("g/quad", "bundle"),),
                  timeout=150)
    base_only = re.sub(r"(\[base\][^\[]*?)mass = [0-9.]+", r"\1mass = 0.0", _quad(), count=1,
                       flags=re.S)
    yield Attempt("generate", "floating base of mass 0 (legs massive)",
                  ["generate", "q.toml", "--out", "g", "--no-build"], put("q.toml", base_only),
                  outputs=(("g/quad", "bundle"),), timeout=150)
    yield Attempt("generate", "floating base mass -1",
                  ["generate", "q.toml", "--out", "g", "--no-build"],
                  put("q.toml", _quad().replace("mass = 8.0", "mass = -1.0", 1)))
    yield Attempt("generate", "rod, no build", ["generate", "r.toml", "--out", "g",
                                                "--no-build"], put("r.toml", ROD),
                  outputs=(("g/rod_tendon_3seg", "bundle"),), timeout=150)
    yield Attempt("generate", "200-segment rod", ["generate", "r.toml", "--out", "g"],
                  put("r.toml", _rod(200)), timeout=60)
    for i in range(6):
        yield Attempt("generate", f"mutated rod #{i}", ["generate", "m.toml", "--out", "g",
                                                        "--no-build"],
                      put("m.toml", mutate_toml(ROD, rng)),
                      outputs=(("g/rod_tendon_3seg", "bundle"),), timeout=150)


@generator("check")
def check_new_attempts(rng, ctx):
    yield Attempt("check", "a Cosserat rod", ["check", "r.toml"], put("r.toml", ROD),
                  timeout=120)
    yield Attempt("check", "a floating tree", ["check", "q.toml"], put("q.toml", _quad()),
                  timeout=120)
    yield Attempt("check", "URDF --floating", ["check", "a.urdf", "--floating"],
                  put("a.urdf", URDF))


@generator("observer")
def observer_new_attempts(rng, ctx):
    yield Attempt("observer", "--model a Cosserat rod", ["observer", "--model", "r.toml"],
                  put("r.toml", ROD), timeout=120)
    yield Attempt("observer", "--model a floating tree", ["observer", "--model", "q.toml"],
                  put("q.toml", _quad()), timeout=120)


# -- bench ----------------------------------------------------------------------------------

@generator("bench")
def bench_new_attempts(rng, ctx):
    for calls in ("-3", "10000000000", "x", "1"):
        yield Attempt("bench", f"--calls {calls}", ["bench", "pendulum_1link", "--calls", calls],
                      timeout=150)
    yield Attempt("bench", "--json a directory", ["bench", "pendulum_1link", "--calls", "10",
                                                  "--json", "d"], put("d/x", "mine"))
    yield Attempt("bench", "--json is the model", ["bench", "m.toml", "--calls", "10",
                                                   "--json", "m.toml"],
                  put("m.toml", (MODELS / "pendulum_1link.toml").read_text()
                      .replace('"pendulum_1link"', '"pend_copy"')), timeout=150)
    yield Attempt("bench", "--json in a missing directory",
                  ["bench", "pendulum_1link", "--calls", "10", "--json", "no/b.json"])
    yield Attempt("bench", "--flags junk", ["bench", "pendulum_1link", "--flags", "O3; rm"])
    yield Attempt("bench", "--flags empty", ["bench", "pendulum_1link", "--flags", ""])
    # A whole bench of a rod or a floating arm is minutes of compiles and timed loops
    # (heartbeat lines meanwhile): interrupted after a while, it must end cleanly, with
    # what was measured in --json.
    yield Attempt("bench", "a Cosserat rod, SIGINT after 40 s",
                  ["bench", "r.toml", "--calls", "100", "--json", "b.json"], put("r.toml", ROD),
                  signal=(signal.SIGINT, 40.0), outputs=(("b.json", "json"),), timeout=150)
    yield Attempt("bench", "URDF --floating, SIGTERM after 30 s",
                  ["bench", "a.urdf", "--floating", "--calls", "100", "--json", "b.json"],
                  put("a.urdf", URDF), signal=(signal.SIGTERM, 30.0),
                  outputs=(("b.json", "json"),), timeout=150)
    yield Attempt("bench", "--peers --root", ["bench", "--peers", "--root", "x"])
    yield Attempt("bench", "two models --floating", ["bench", "a", "b", "--floating"])
    yield Attempt("bench", "SIGINT while timing", ["bench", "pendulum_1link", "--calls", "100000",
                                                   "--json", "b.json"],
                  signal=(signal.SIGINT, rng.uniform(3.0, 6.0)), timeout=150)


# -- export --set ---------------------------------------------------------------------------

SET_VALUES = ["0", "-1", "1e9", "1e-12", "nan", "inf", "x", "()", "(1,)", "True", "[1, 2]",
              "100000000", "1e308", "-0.0", "None"]
SET_KEYS = {"planar_2link": ["lam", "kd", "kpi", "amplitude", "frequency", "dt", "zzz"],
            "arm_2link_pneumatic": ["substeps", "rise", "stiffness_rate", "pi_hat0_ratio",
                                    "q_times", "sigma_values", "stiffness_headroom", "dt"],
            "arm_2link_electric": ["stiffness_margin", "mode_ratio", "dt"],
            "pcc_planar_4seg": ["lam", "omega", "amplitude", "initial_error", "dt"]}


@generator("export")
def export_set_attempts(rng, ctx):
    for _ in range(30):
        model = rng.choice(sorted(SET_KEYS))
        key, value = rng.choice(SET_KEYS[model]), rng.choice(SET_VALUES)
        yield Attempt("export", f"{model} --set {key}={value}",
                      ["export", model, "--out", "p", "--set", f"{key}={value}"],
                      outputs=((("p", "export"),)), timeout=150)
    yield Attempt("export", "--set with no =", ["export", "planar_2link", "--out", "p", "--set",
                                                "lam"])
    yield Attempt("export", "--set twice", ["export", "planar_2link", "--out", "p", "--set",
                                            "lam=3", "--set", "lam=4"],
                  outputs=(("p", "export"),), timeout=150)
    yield Attempt("export", "a Cosserat rod", ["export", "r.toml", "--out", "p"],
                  put("r.toml", ROD), outputs=(("p", "export"),), timeout=150)
    yield Attempt("export", "a floating quadruped", ["export", "q.toml", "--out", "p"],
                  put("q.toml", _quad()), outputs=(("p", "export"),), timeout=150)
    yield Attempt("export", "URDF --floating, long name", ["export", "a.urdf", "--floating",
                                                           "--out", "p"],
                  put("a.urdf", _named_urdf("b" * 64)), outputs=(("p", "export"),),
                  timeout=150)


# -- identify of a floating base ---------------------------------------------------------

def _floating_log(edit=None, wrench: bool = True):
    """A setup writing q.toml (the quadruped) and log.csv (its simulated log, possibly
    edited: ``edit(header, rows) -> (header, rows)``)."""
    def step(d: Path) -> None:
        import sys
        sys.path.insert(0, str(TESTS))
        from test_identify_floating import _write_log
        from softgen.modelfile.load import load_model
        (d / "q.toml").write_text(_quad())
        model = load_model(d / "q.toml")
        log = _write_log(d / "log.csv", model, T=6.0, wrench=wrench)
        if edit is not None:
            rows = list(csv.reader(log.open()))
            header, body = edit(rows[0], rows[1:])
            with log.open("w", newline="") as fh:
                csv.writer(fh).writerows([header] + body)
    return step


def _col(name: str, f):
    def edit(header, rows):
        i = header.index(name)
        for r in rows:
            r[i] = f(r[i])
        return header, rows
    return edit


@generator("identify")
def identify_floating_attempts(rng, ctx):
    base = ["identify", "q.toml", "--log", "log.csv", "--out", "o.toml"]
    ok = (("o.toml", "model"),)
    yield Attempt("identify", "floating: simulated log", base, _floating_log(), outputs=ok,
                  timeout=150)
    variants = {
        "no base columns": lambda h, r: ([c for c in h if not c.startswith("base_")],
                                         [[v for c, v in zip(h, x) if not c.startswith("base_")]
                                          for x in r]),
        "zero quaternion": lambda h, r: (h, [[("0" if c in ("base_qx", "base_qy", "base_qz",
                                                            "base_qw") else v)
                                              for c, v in zip(h, x)] for x in r]),
        "base_x nan": _col("base_x", lambda v: "nan"),
        "base_x 1e300": _col("base_x", lambda v: "1e300"),
        "tau3 zero": _col("tau3", lambda v: "0"),
        "q2 still": _col("q2", lambda v: "0.1"),
        "q in degrees": lambda h, r: (h, [[(str(float(v) * 57.3) if c.startswith("q") else v)
                                           for c, v in zip(h, x)] for x in r]),
        "time in ms": _col("t", lambda v: str(float(v) * 1000)),
        "wrench x1000": lambda h, r: (h, [[(str(float(v) * 1000) if c.startswith("base_f")
                                            else v) for c, v in zip(h, x)] for x in r]),
        "30 rows": lambda h, r: (h, r[:30]),
    }
    for name, edit in variants.items():
        yield Attempt("identify", f"floating: {name}", base, _floating_log(edit), outputs=ok,
                      timeout=150)
    yield Attempt("identify", "floating: contact-free (no wrench)", base,
                  _floating_log(wrench=False), outputs=ok, timeout=150)
    yield Attempt("identify", "URDF --floating, a fixed chain's log",
                  ["identify", "a.urdf", "--floating", "--log", "id.csv", "--out", "o.toml"],
                  steps(put("a.urdf", URDF), put("id.csv", ctx.id_log)), outputs=ok,
                  timeout=150)
    yield Attempt("identify", "floating --excite", ["identify", "q.toml", "--excite", "--out",
                                                    "t.csv"], put("q.toml", _quad()))
    yield Attempt("identify", "a Cosserat rod's log", ["identify", "r.toml", "--log", "id.csv",
                                                       "--out", "o.toml"],
                  steps(put("r.toml", ROD), put("id.csv", ctx.id_log)), outputs=ok,
                  timeout=150)
