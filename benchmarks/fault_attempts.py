"""The attempts of the fault campaign, verb by verb (``benchmarks/fault_campaign.py`` runs
and judges them; its docstring says what counts as clean).

A verb's attempts come from generators ``f(rng, ctx) -> Iterable[Attempt]`` registered with
``@generator("verb")``; ``ctx`` (:class:`Context`) holds valid inputs made once per
campaign (model, log, system and trace files) to copy and damage. A new verb: add a
generator here, or in a module of its own passed with ``--plugin``.
"""
from __future__ import annotations

import json
import math
import os
import random
import shutil
import signal
import subprocess
from collections.abc import Callable, Iterable
from pathlib import Path

from fault_campaign import PY, ROOT, TESTS, WRAPPER, Attempt, Run, generator

# -- shared inputs (made once per campaign) ----------------------------------------------

class Context:
    """Inputs every generator may copy into its sandboxes: valid model, log, system and
    trace files, made once in ``base``."""

    def __init__(self, base: Path):
        self.base = base
        base.mkdir(parents=True, exist_ok=True)
        self.arm = self._write("arm.toml", ARM)
        self.soft = self._write("soft.toml", SOFT)
        self.sea = self._write("sea.toml", (TESTS / "data" / "user_models" / "arm3_sea.toml")
                               .read_text())
        self.urdf = self._copy(ROOT / "tests" / "data" / "user_models" / "arm3_declared.urdf")
        self.system = self._write("plant.json", json.dumps(SYSTEM))
        from softgen.app.estimate import sample_log
        lines = sample_log().read_text().splitlines()
        self.est_lines = lines[:4001]
        self.est_log = self._write("est.csv", "\n".join(self.est_lines) + "\n")
        self.id_log = self._identification_log()
        self.trace = base / "traces.npz"
        import numpy as np
        from softgen.runtime.simulate import save_traces
        save_traces(self.trace, t=np.arange(100) * 0.01, q=np.sin(np.arange(100.0))[:, None])

    def _write(self, name: str, text: str) -> Path:
        p = self.base / name
        p.write_text(text)
        return p

    def _copy(self, src: Path) -> Path:
        p = self.base / src.name
        shutil.copy(src, p)
        return p

    def _identification_log(self) -> Path:
        import numpy as np
        from softgen.modelfile.load import load_model
        from softgen.studies.excitation import IdentificationRegressor, optimise_excitation
        reg = IdentificationRegressor(load_model("planar_2link"))
        ex = optimise_excitation(reg, harmonics=3, period=10.0, seed=1, maxiter=5, grid=40)
        t = np.arange(6000) * 2e-3
        q, qd, qdd = ex.trajectory.evaluate(t)
        tau = np.asarray(reg.dyn.inverse_dynamics_fun().map(t.size)(q.T, qd.T, qd.T, qdd.T)).T
        tau = tau + 0.1 * qd + np.random.default_rng(0).normal(scale=1e-3, size=tau.shape)
        self.id_arrays = (t, q, tau)
        return self._write("id.csv", table("t,q1,q2,tau1,tau2", np.column_stack([t, q, tau])))


def table(header: str, rows) -> str:
    return header + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n"


ARM = """[model]
name = "camp_arm"
kind = "planar"

[gravity]
g = 9.81

[[links]]
name = "a"
joint = "revolute"
length = 0.3
mass = 1.0
com = 0.15
inertia = 0.01

[[links]]
name = "b"
joint = "revolute"
length = 0.25
mass = 0.6
com = 0.1
inertia = 0.005

[parameters]
uncertain = ["mass", "com", "inertia"]
"""

SOFT = """[model]
name = "camp_soft"
kind = "pcc-planar"

[[segments]]
length = 0.1
mass = 0.01
stiffness = 1.0
damping = 0.1

[[segments]]
length = 0.1
mass = 0.01
stiffness = 1.0
damping = 0.1
"""

SYSTEM = {"A": [[1.0, 0.01], [0.0, 1.0]], "B": [[0.0], [0.01]], "C": [[1.0, 0.0]],
          "D": [[0.0]], "name": "camp_plant"}


def chain(n: int) -> str:
    links = "".join('[[links]]\njoint = "revolute"\nlength = 0.3\nmass = 1.0\ncom = 0.15\n'
                    'inertia = 0.01\n\n' for _ in range(n))
    return f'[model]\nname = "chain{n}"\nkind = "planar"\n\n{links}'


def pcc(n: int) -> str:
    segs = "".join('[[segments]]\nlength = 0.1\nmass = 0.01\nstiffness = 1.0\n'
                   'damping = 0.1\n\n' for _ in range(n))
    return f'[model]\nname = "pcc{n}"\nkind = "pcc-planar"\n\n{segs}'


def put(name: str, content: str | bytes | Path | Callable[[Path], None]):
    """A setup step writing ``name`` in the sandbox (text, bytes, a copy of a path)."""
    def step(d: Path) -> None:
        p = d / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, Path):
            shutil.copy(content, p)
        elif isinstance(content, bytes):
            p.write_bytes(content)
        elif callable(content):
            content(p)
        else:
            p.write_text(content)
    return step


def steps(*fs):
    def run(d: Path) -> None:
        for f in fs:
            if f is not None:
                f(d)
    return run


# -- mutations of valid files ---------------------------------------------------------------

JUNK_VALUES = ["-1", "0", "1e400", "nan", "inf", '"x"', "[]", "{}", "true", "9" * 400,
               "1e-320", "[1, 2, 3]", '"' + "a" * 5000 + '"', "-0.0", "1e308"]


def mutate_toml(text: str, rng: random.Random) -> str:
    """One random edit of a TOML model: a value replaced, a line dropped or duplicated,
    the file truncated, or bytes flipped."""
    lines = text.splitlines()
    kind = rng.choice(["value", "value", "value", "drop", "dup", "truncate", "flip", "key"])
    idx = [i for i, ln in enumerate(lines) if "=" in ln]
    i = rng.choice(idx)
    if kind == "value":
        key = lines[i].split("=")[0]
        lines[i] = f"{key}= {rng.choice(JUNK_VALUES)}"
    elif kind == "drop":
        del lines[i]
    elif kind == "dup":
        lines.insert(i, lines[i])
    elif kind == "key":
        lines.insert(i, f"{rng.choice(['zzz', 'mass2', 'links', 'Name'])} = 1")
    elif kind == "truncate":
        return text[:rng.randrange(len(text))]
    else:
        b = bytearray(text.encode())
        for _ in range(rng.randint(1, 5)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return b.decode("latin-1")
    return "\n".join(lines) + "\n"


HOSTILE_LAWS = [
    "k*phi**(2**64)", "k*(1+phi)**(10**10)", "k*phi**1e308", "k*phi**(8*9)",
    "k*sinh(phi)**(2*50)", "k*phi*exp(700)", "k*phi*exp(1000)", "k*phi*(0/0)",
    "k*phi*log(-1)", "k*phi/(1e-200*1e-200)", "__import__('os').system('true')",
    "k.__class__", "k*phi if phi else 0", "eval('1')", "(" * 200 + "phi" + ")" * 200,
    "k*phi" + "+phi" * 500, "lambda: 1", "k*phi*10**10**10", "k*phi**-(2**64)",
    "k*phi*1e12", "k*phi**(0.5*200)", "sin", "k*phi; import os", "k*phi\x00",
    "k*(phi**64)**64", "k*exp(exp(exp(phi)))", "k*phi/phi", "k*sqrt(phi)", "k*log(phi)",
    "k*phi**-1", "k*tan(phi+pi/2)", "k*phi*pi**40", "q1*k", "k*phi*[1][0]",
]


# -- the generators ---------------------------------------------------------------------------

def _help_and_junk(verb: str) -> list[Attempt]:
    # ``reproduce`` with no arguments is the main job (every experiment, minutes): it is
    # interrupted after a few seconds, which must end it cleanly.
    long = (signal.SIGINT, 6.0) if verb == "reproduce" else None
    return [Attempt(verb, "no arguments", [verb], signal=long),
            Attempt(verb, "--help", [verb, "--help"]),
            Attempt(verb, "unknown option", [verb, "--no-such-option", "1"]),
            Attempt(verb, "nonexistent path", [verb, "no/such/file.toml"]),
            Attempt(verb, "a directory as the argument", [verb, "."])]


@generator("list")
def list_attempts(rng, ctx):
    yield Attempt("list", "plain", ["list"])
    yield Attempt("list", "extra argument", ["list", "x"])


@generator("info")
def info_attempts(rng, ctx):
    yield from _help_and_junk("info")
    for name in ("planar_2link", "pcc_planar_4seg", "panda"):
        yield Attempt("info", f"shipped {name}", ["info", name])
    for i in range(70):
        text = mutate_toml(ARM if i % 2 else SOFT, rng)
        yield Attempt("info", f"mutated model #{i}", ["info", "m.toml"], put("m.toml", text))
    for law in HOSTILE_LAWS:
        text = ctx.sea.read_text().replace('law = "k*phi"', f"law = {json.dumps(law)}")
        yield Attempt("info", f"law {law[:30]!r}", ["info", "law.toml"], put("law.toml", text))
    bad = {"utf16": ARM.encode("utf-16"), "nul": b"\0" * 3000, "random": bytes(range(256)) * 8,
           "empty": b"", "deep arrays": ('[model]\nname="a"\nkind="planar"\nx = ' + "[" * 5000
                                          + "]" * 5000 + "\n").encode(),
           "deep tables": ('[model]\nname="a"\nkind="planar"\nx = ' + "{a=" * 3000 + "1"
                           + "}" * 3000 + "\n").encode(),
           "huge mass": ARM.replace("mass = 1.0", "mass = " + "9" * 500).encode()}
    for name, data in bad.items():
        yield Attempt("info", f"file: {name}", ["info", "bad.toml"], put("bad.toml", data))
    urdfs = {
        "xxe": '<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
               '<robot name="r">&x;</robot>',
        "laughs": '<?xml version="1.0"?><!DOCTYPE l [<!ENTITY a "aaaaaaaaaa">'
                  + "".join(f'<!ENTITY {chr(98 + i)} "' + f"&{chr(97 + i)};" * 10 + '">'
                            for i in range(8)) + ']><robot name="&i;"/>',
        "deep": '<robot name="r">' + "<a>" * 5000 + "</a>" * 5000 + "</robot>",
        "no links": '<robot name="r"></robot>', "not xml": "robot {",
        "loop": '<robot name="r"><link name="a"/><link name="b"/><joint name="j" '
                'type="revolute"><parent link="a"/><child link="b"/></joint><joint name="k" '
                'type="revolute"><parent link="b"/><child link="a"/></joint></robot>'}
    for name, text in urdfs.items():
        yield Attempt("info", f"urdf: {name}", ["info", "r.urdf"], put("r.urdf", text))
    yield Attempt("info", "60-link chain", ["info", "c.toml"], put("c.toml", chain(60)),
                  timeout=60)
    yield Attempt("info", "40-segment body", ["info", "p.toml"], put("p.toml", pcc(40)),
                  timeout=60)
    yield Attempt("info", "urdf chain --tip unknown", ["info", "a.urdf", "--tip", "nope"],
                  put("a.urdf", ctx.urdf))


def _bundle_outputs(name: str, out: str = "gen") -> tuple:
    return ((f"{out}/{name}", "bundle"),)


@generator("generate")
def generate_attempts(rng, ctx):
    yield from _help_and_junk("generate")
    yield Attempt("generate", "model file, no build", ["generate", "arm.toml", "--out", "gen",
                                                       "--no-build"], put("arm.toml", ARM),
                  outputs=_bundle_outputs("camp_arm"))
    yield Attempt("generate", "relative ./ path", ["generate", "./arm.toml", "--out", "./g/x",
                                                   "--no-build"], put("arm.toml", ARM),
                  outputs=_bundle_outputs("camp_arm", "g/x"))
    yield Attempt("generate", "--out a file", ["generate", "pendulum_1link", "--out", "f",
                                               "--no-build"], put("f", "mine"))
    yield Attempt("generate", "--out under a file", ["generate", "pendulum_1link", "--out",
                                                     "f/x", "--no-build"], put("f", "mine"))
    for budget in (0, 2000, 20_000, 60_000):
        yield Attempt("generate", f"full disk ({budget} B)",
                      ["generate", "arm.toml", "--out", "disk/gen", "--no-build", "--force"],
                      put("arm.toml", ARM), disk=budget,
                      outputs=_bundle_outputs("camp_arm", "disk/gen"))

    def earlier(d: Path) -> None:
        from softgen.bundles.bundle import generate
        (d / "arm.toml").write_text(ARM)
        generate(d / "arm.toml", d / "disk" / "gen")
        (d / "arm.toml").write_text(ARM.replace("mass = 1.0", "mass = 1.1"))
    for budget in (5000, 30_000, 80_000):
        yield Attempt("generate", f"--force over a bundle, full disk ({budget} B)",
                      ["generate", "arm.toml", "--out", "disk/gen", "--no-build", "--force"],
                      earlier, disk=budget, may_change=("disk/gen",),
                      outputs=_bundle_outputs("camp_arm", "disk/gen"))
    yield Attempt("generate", "full cache (compile)", ["generate", "pendulum_1link", "--out",
                                                       "gen", "--force"],
                  env={"SOFTGEN_CACHE_DIR": "{d}/disk/cache"}, disk=1000,
                  outputs=_bundle_outputs("pendulum_1link"))
    yield Attempt("generate", "compiler that fails", ["generate", "pendulum_1link", "--out",
                                                      "gen", "--force"],
                  put("cc", "#!/bin/sh\necho 'ld: final link failed: No space left on "
                            "device' >&2\nexit 1\n"), env={"CC": "{d}/cc"})
    yield Attempt("generate", "missing compiler", ["generate", "pendulum_1link", "--out",
                                                   "gen"], env={"CC": "/no/such/cc"})
    for i in range(16):
        yield Attempt("generate", f"mutated model #{i}",
                      ["generate", "m.toml", "--out", "gen", "--no-build"],
                      put("m.toml", mutate_toml(ARM, rng)), outputs=_bundle_outputs("camp_arm"))
    yield Attempt("generate", "60-link chain", ["generate", "c.toml", "--out", "gen",
                                                "--no-build"], put("c.toml", chain(60)))
    yield Attempt("generate", "--jobs 0", ["generate", "--all", "--jobs", "0"])
    yield Attempt("generate", "shipped name from a file",
                  ["generate", "p.toml", "--no-build"],
                  put("p.toml", ARM.replace("camp_arm", "planar_2link")))
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        yield Attempt("generate", f"{signal.Signals(sig).name} while deriving",
                      ["generate", "pcc_3d_4seg", "--out", "gen", "--force"],
                      signal=(sig, rng.uniform(1.5, 4.0)))
        yield Attempt("generate", f"{signal.Signals(sig).name} of two side by side",
                      ["generate", "pcc_3d_4seg", "pcc_planar_4seg", "--out", "gen", "--force",
                       "--jobs", "2"], signal=(sig, rng.uniform(3.0, 6.0)))


def _est(*extra, log="est.csv", out="e.csv"):
    return ["estimate", "pendulum_qbmove", "--log", log, "--method", "noninvasive",
            "--out", out, *extra]


def _implausible(run: Run) -> str | None:
    if run.status == 0 and "plausible" in run.stdout and "warning" not in run.stdout:
        return "status 0 and 'plausible' for an estimate that cannot be"
    return None


@generator("estimate")
def estimate_attempts(rng, ctx):
    yield from _help_and_junk("estimate")
    lines = ctx.est_lines
    head, rows = lines[0], lines[1:]
    log = put("est.csv", ctx.est_log)
    yield Attempt("estimate", "the sample log (4000 rows)", _est(), log,
                  outputs=(("e.csv", "csv"),))
    cols = head.split(",")

    def column_edit(f):
        out = [head]
        for k, r in enumerate(rows):
            cells = r.split(",")
            out.append(",".join(f(k, cells)))
        return "\n".join(out) + "\n"
    edits = {
        "time in ms": lambda k, c: [repr(float(c[0]) * 1000)] + c[1:],
        "time reversed": lambda k, c: [repr(-float(c[0]))] + c[1:],
        "irregular time": lambda k, c: [repr(float(c[0]) + (1e-3 if k == 50 else 0))] + c[1:],
        "a NaN cell": lambda k, c: c[:2] + (["nan"] if k == 70 else [c[2]]) + c[3:],
        "an empty cell": lambda k, c: c[:1] + ([""] if k == 9 else [c[1]]) + c[2:],
        "a text cell": lambda k, c: c[:3] + (["abc"] if k == 11 else [c[3]]) + c[4:],
        "all zero": lambda k, c: [c[0]] + ["0"] * (len(c) - 1),
        "constant": lambda k, c: [c[0]] + ["0.3"] * (len(c) - 1),
        "values 1e300": lambda k, c: [c[0]] + [repr(1e300 * (1 if k % 3 else -1))] * (len(c) - 1),
        "degrees": lambda k, c: [c[0]] + [repr(math.degrees(float(x))) for x in c[1:]],
        "columns swapped": lambda k, c: [c[0], c[2], c[1]] + c[3:],
        "ragged row": lambda k, c: c + (["1"] if k == 5 else []),
        "noise": lambda k, c: [c[0]] + [repr(rng.gauss(0, 1)) for _ in c[1:]],
    }
    for _ in range(20):          # one random cell made odd
        row, col = rng.randrange(len(rows)), rng.randrange(len(cols))
        cell = rng.choice(["", "nan", "1e999", "-inf", "x", "1e308", "0x10", " ", "1,5",
                           '"3"', "1e-320"])
        edits[f"cell {row},{col} = {cell!r}"] = (
            lambda k, c, row=row, col=col, cell=cell: [cell if (k, j) == (row, col) else v
                                                       for j, v in enumerate(c)])
    for name, f in edits.items():
        yield Attempt("estimate", f"log: {name}", _est(), put("est.csv", column_edit(f)),
                      outputs=(("e.csv", "csv"),),
                      judge=_implausible if name in ("noise", "constant", "all zero") else None)
    files = {"empty": b"", "header only": (head + "\n").encode(), "NUL": b"\0" * 4000,
             "binary": bytes(range(256)) * 20, "utf16": ctx.est_log.read_text().encode("utf-16"),
             "3 rows": ("\n".join(lines[:4]) + "\n").encode(),
             "one long line": ("t," + "1," * 300000 + "\n").encode(),
             "missing column": (b"t,q1\n0,1\n0.005,2\n")}
    for name, data in files.items():
        yield Attempt("estimate", f"file: {name}", _est(), put("est.csv", data))
    yield Attempt("estimate", "/dev/zero", _est(log="/dev/zero"), timeout=60)
    yield Attempt("estimate", "/dev/null", _est(log="/dev/null"))
    yield Attempt("estimate", "a directory as --log", _est(log="."))
    yield Attempt("estimate", "10 MB of one row repeated, low row limit", _est(),
                  put("est.csv", "\n".join([head] + rows * 40) + "\n"),
                  env={"SOFTGEN_MAX_LOG_ROWS": "50000"}, timeout=60)
    for p0 in ("1e-300", "1e-6", "1e300", "0", "-1", "nan"):
        yield Attempt("estimate", f"--p0 {p0}", _est("--p0", p0), log,
                      outputs=(("e.csv", "csv"),),
                      judge=_implausible if p0 in ("1e-300", "1e-6") else None)
        yield Attempt("estimate", f"--p0 {p0} --strict", _est("--p0", p0, "--strict"), log,
                      outputs=(("e.csv", "csv"),),
                      judge=_implausible if p0 in ("1e-300", "1e-6") else None)
    for opt, vals in (("--dt", ("0.005", "0.001", "1e-300", "100", "-1")),
                      ("--powers", ("1,3,5", "100000", "0,0", "a", "1,2,3,4,5,6,7,8,9")),
                      ("--lowpass", ("0", "1", "1000", "-1", "nan"))):
        for v in vals:
            yield Attempt("estimate", f"{opt} {v}", _est(opt, v), log,
                          outputs=(("e.csv", "csv"),))
    yield Attempt("estimate", "--out exists", _est(), steps(log, put("e.csv", "mine")))
    yield Attempt("estimate", "--out exists --force", _est("--force"),
                  steps(log, put("e.csv", "mine")), may_change=("e.csv",),
                  outputs=(("e.csv", "csv"),))
    yield Attempt("estimate", "--out is the log", _est("--force", out="est.csv"), log)
    yield Attempt("estimate", "--out a fifo --force", _est("--force", out="fifo"),
                  steps(log, lambda d: os.mkfifo(d / "fifo")))
    yield Attempt("estimate", "--out a directory", _est(out="."), log)
    yield Attempt("estimate", "--out in a missing directory", _est(out="no/dir/e.csv"), log)
    for budget in (0, 1000, 100_000):
        yield Attempt("estimate", f"full disk ({budget} B) with --force",
                      _est("--force", out="disk/e.csv"), steps(log, put("disk/e.csv", "old")),
                      disk=budget, may_change=("disk/e.csv",), outputs=(("disk/e.csv", "csv"),))
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        yield Attempt("estimate", f"{signal.Signals(sig).name} during the run",
                      _est("--force"), steps(log, put("e.csv", "old")), may_change=(),
                      may_change_on_success=("e.csv",), signal=(sig, rng.uniform(1.0, 3.0)))
    yield Attempt("estimate", "60-joint model", ["estimate", "c.toml", "--log", "est.csv"],
                  steps(log, put("c.toml", chain(60))))
    yield Attempt("estimate", "no estimator for the model", ["estimate", "planar_2link",
                                                            "--log", "est.csv"], log)


def _idlog(ctx, f=None, name="id.csv"):
    import numpy as np
    t, q, tau = ctx.id_arrays
    if f is not None:
        t, q, tau = f(t.copy(), q.copy(), tau.copy())
    return put(name, table("t,q1,q2,tau1,tau2", np.column_stack([t, q, tau])))


@generator("identify")
def identify_attempts(rng, ctx):
    import numpy as np
    yield from _help_and_junk("identify")
    ok = (("o.toml", "model"),)
    base = ["identify", "planar_2link", "--log", "id.csv", "--out", "o.toml"]
    variants = {
        "good": None, "time in ms": lambda t, q, u: (t * 1000, q, u),
        "degrees": lambda t, q, u: (t, np.degrees(q), u),
        "mN m": lambda t, q, u: (t, q, u * 1000), "kN m": lambda t, q, u: (t, q, u / 1000),
        "swapped": lambda t, q, u: (t, u, q), "tau zero": lambda t, q, u: (t, q, 0 * u),
        "q still": lambda t, q, u: (t, 0 * q + 0.2, u),
        "noise": lambda t, q, u: (t, np.random.default_rng(1).normal(size=q.shape),
                                  np.random.default_rng(2).normal(size=u.shape)),
        "short": lambda t, q, u: (t[:30], q[:30], u[:30]),
        "1 ms sampling pretended 1 s": lambda t, q, u: (t * 500, q, u),
        "tau sign flipped": lambda t, q, u: (t, q, -u),
        "one joint's tau scaled": lambda t, q, u: (t, q, u * np.array([1.0, 50.0])),
    }
    for _ in range(15):          # random unit factors on t, q and tau
        ft, fq, fu = (rng.choice([1.0, 1.0, 1e-3, 1e3, 57.3, 0.0174]) for _ in range(3))
        variants[f"scaled t x{ft:g}, q x{fq:g}, tau x{fu:g}"] = (
            lambda t, q, u, ft=ft, fq=fq, fu=fu: (t * ft, q * fq, u * fu))
    for name, f in variants.items():
        yield Attempt("identify", f"log: {name}", base, _idlog(ctx, f), outputs=ok)
    yield Attempt("identify", "log: /dev/zero", ["identify", "planar_2link", "--log",
                                                "/dev/zero", "--out", "o.toml"], timeout=60)
    yield Attempt("identify", "actuator data: /dev/zero", ["identify", "--actuator", "sinh",
                                                          "--log", "/dev/zero"], timeout=60)
    yield Attempt("identify", "--out exists", base, steps(_idlog(ctx), put("o.toml", "x")))
    yield Attempt("identify", "soft model", ["identify", "s.toml", "--log", "id.csv"],
                  steps(_idlog(ctx), put("s.toml", SOFT)))
    yield Attempt("identify", "60-link chain --excite", ["identify", "c.toml", "--excite",
                                                        "--out", "t.csv"],
                  put("c.toml", chain(60)), timeout=60)
    ex = ["identify", "planar_2link", "--excite", "--out", "t.csv", "--maxiter", "3"]
    opts = [("--dt", "100"), ("--dt", "0"), ("--dt", "1e-9"), ("--dt", "0.05"),
            ("--periods", "0"), ("--periods", "1000000"), ("--period", "1e9"),
            ("--period", "-1"), ("--period", "0.01"), ("--harmonics", "100000"),
            ("--harmonics", "1000"), ("--harmonics", "0"), ("--harmonics", "2"),
            ("--maxiter", "-5"), ("--maxiter", "0"), ("--seed", "-1"), ("--dt", "nan")]
    for o, v in opts:
        yield Attempt("identify", f"--excite {o} {v}", ex + [o, v], outputs=(("t.csv", "csv"),),
                      timeout=60)
    sinh = "q,qa,tau\n" + "".join(f"{x},{0.0},{0.02 * math.sinh(6.7 * x)}\n"
                                  for x in np.linspace(-0.3, 0.3, 50))
    for name, text in {"sinh ok": sinh, "sinh constant": "q,qa,tau\n" + "0,0,0\n" * 20,
                       "sinh nan": sinh.replace("0.0,", "nan,", 1),
                       "sinh missing column": "q,tau\n1,2\n"}.items():
        yield Attempt("identify", f"--actuator {name}", ["identify", "--actuator", "sinh",
                                                         "--log", "d.csv", "--out", "f.json"],
                      put("d.csv", text), outputs=(("f.json", "json"),))


@generator("observer")
def observer_attempts(rng, ctx):
    yield from _help_and_junk("observer")
    yield Attempt("observer", "good system", ["observer", "--system", "s.json", "--out", "o"],
                  put("s.json", json.dumps(SYSTEM)), outputs=(("o", "observer"),))
    for i in range(50):
        data = json.loads(json.dumps(SYSTEM))
        key = rng.choice(["A", "B", "C", "D", "name", "unknown", "dt", "time"])
        data[key] = json.loads(rng.choice(["[]", "[[1]]", "[[1, 2, 3]]", '"x"', "-1", "1e400",
                                           "[[null, 1], [1, 1]]", '"' + "n" * 500 + '"',
                                           "[0, 0]", "[5]", '"continuous"', "0"]).replace(
                                               "1e400", "1e300"))
        yield Attempt("observer", f"mutated system #{i} ({key})",
                      ["observer", "--system", "s.json", "--out", "o"],
                      put("s.json", json.dumps(data)), outputs=(("o", "observer"),))
    yield Attempt("observer", "deep TOML", ["observer", "--system", "s.toml"],
                  put("s.toml", "A = " + "[" * 5000 + "]" * 5000 + "\n"))
    big = {"A": [[0.0] * 300 for _ in range(300)], "B": [[1.0]] * 300,
           "C": [[1.0] + [0.0] * 299], "D": [[0.0]]}
    yield Attempt("observer", "300 states", ["observer", "--system", "s.json"],
                  put("s.json", json.dumps(big)), timeout=60)
    for d in ("100000", "-1", "2", "0", "x"):
        yield Attempt("observer", f"--delay {d}", ["observer", "--system", "s.json", "--delay",
                                                    d], put("s.json", json.dumps(SYSTEM)),
                      timeout=60)
    for opt, v in (("--dt", "1e300"), ("--dt", "0"), ("--dt", "0.001"), ("--q0", "1,2"),
                   ("--q0", "a,b"), ("--actuator", "1"), ("--integrator", "rk4")):
        yield Attempt("observer", f"--model {opt} {v}", ["observer", "--model", "planar_2link",
                                                         opt, v], timeout=60)
    yield Attempt("observer", "--model 60-link chain", ["observer", "--model", "c.toml"],
                  put("c.toml", chain(60)), timeout=60)
    yield Attempt("observer", "--out exists", ["observer", "--system", "s.json", "--out", "o"],
                  steps(put("s.json", json.dumps(SYSTEM)), put("o/camp_plant.c", "mine")))
    yield Attempt("observer", "full disk", ["observer", "--system", "s.json", "--out", "disk/o"],
                  put("s.json", json.dumps(SYSTEM)), disk=500, outputs=(("disk/o", "observer"),))


def _export_outputs(out="p"):
    return ((out, "export"),)


@generator("export")
def export_attempts(rng, ctx):
    yield from _help_and_junk("export")
    yield Attempt("export", "shipped model", ["export", "pendulum_1link", "--out", "p"],
                  outputs=_export_outputs())
    yield Attempt("export", "relative --out", ["export", "pendulum_1link", "--out", "./a/../p"],
                  outputs=_export_outputs())
    yield Attempt("export", "--out a file", ["export", "pendulum_1link", "--out", "f"],
                  put("f", "x"))
    yield Attempt("export", "--out non-empty", ["export", "pendulum_1link", "--out", "p"],
                  put("p/main.c", "mine"))
    yield Attempt("export", "--force over foreign files",
                  ["export", "pendulum_1link", "--out", "p", "--force"], put("p/main.c", "mine"))
    yield Attempt("export", "--force --force-foreign",
                  ["export", "pendulum_1link", "--out", "p", "--force", "--force-foreign"],
                  put("p/notes.txt", "mine"), outputs=_export_outputs())

    def earlier(d: Path) -> None:
        from softgen.export.project import export
        export("pendulum_1link", d / "disk" / "p")
    for budget in (0, 3000, 30_000, 120_000):
        yield Attempt("export", f"--force of a larger model over an export, full disk "
                                f"({budget} B)",
                      ["export", "planar_2link", "--out", "disk/p", "--force"], earlier,
                      disk=budget, may_change=("disk/p",), outputs=_export_outputs("disk/p"))
    yield Attempt("export", "--build, relative --out", ["export", "pendulum_1link", "--out",
                                                        "rel/p", "--build"],
                  outputs=_export_outputs("rel/p"), timeout=120)
    yield Attempt("export", "--build with a failing compiler",
                  ["export", "pendulum_1link", "--out", "p", "--build", "--cc", "{d}/cc"],
                  put("cc", "#!/bin/sh\necho 'cc: error: bad thing' >&2\nexit 1\n"))
    yield Attempt("export", "60-link chain", ["export", "c.toml", "--out", "p"],
                  put("c.toml", chain(60)), timeout=60)
    yield Attempt("export", "mutated user model", ["export", "m.toml", "--out", "p"],
                  put("m.toml", mutate_toml(ARM, rng)), outputs=_export_outputs(), timeout=120)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        yield Attempt("export", f"{signal.Signals(sig).name} during --build",
                      ["export", "pendulum_1link", "--out", "p", "--build"],
                      signal=(sig, rng.uniform(2.0, 4.0)), timeout=120)


@generator("plot")
def plot_attempts(rng, ctx):

    import numpy as np
    yield from _help_and_junk("plot")
    tr = put("tr.npz", ctx.trace)
    yield Attempt("plot", "a trace", ["plot", "tr.npz", "--out", "f.png"], tr,
                  outputs=(("f.png", "png"),))
    yield Attempt("plot", "--out is the trace --force", ["plot", "tr.npz", "--out", "tr.npz",
                                                         "--force"], tr)
    yield Attempt("plot", "--out is the trace via ./", ["plot", ".", "--out", "./traces.npz",
                                                        "--force"], put("traces.npz", ctx.trace))
    yield Attempt("plot", "--out exists", ["plot", "tr.npz", "--out", "f.png"],
                  steps(tr, put("f.png", "mine")))
    yield Attempt("plot", "--out a directory", ["plot", "tr.npz", "--out", "."], tr)
    yield Attempt("plot", "--list", ["plot", "--list", "tr.npz"], tr)
    yield Attempt("plot", "unknown signal", ["plot", "tr.npz", "zz", "--out", "f.png"], tr)

    def npz(**arrays):
        def make(p: Path) -> None:
            np.savez(p, **arrays)
        return make
    odd = {"scalar t": npz(t=np.array(5.0), q=np.ones(3)),
           "3-D signal": npz(t=np.arange(3.0), q=np.ones((3, 2, 2))),
           "empty": npz(t=np.array([]), q=np.array([])),
           "text t": npz(t=np.array(["a", "b"]), q=np.ones(2)),
           "no t": npz(q=np.ones(3)), "nan": npz(t=np.arange(3.0), q=np.full(3, np.nan)),
           "pickled": lambda p: np.save(p, np.array([object()], dtype=object),
                                        allow_pickle=True)}
    for name, make in odd.items():
        yield Attempt("plot", f"trace: {name}", ["plot", "x.npz", "--out", "f.png"],
                      put("x.npz", make), outputs=(("f.png", "png"),))
    for name, data in {"zip junk": b"PK\x03\x04" + bytes(100), "text": b"hello",
                       "empty": b""}.items():
        yield Attempt("plot", f"file: {name}", ["plot", "x.npz", "--out", "f.png"],
                      put("x.npz", data))
    yield Attempt("plot", "full disk", ["plot", "tr.npz", "--out", "disk/f.png"], tr, disk=100,
                  outputs=(("disk/f.png", "png"),))


@generator("sweep")
def sweep_attempts(rng, ctx):
    yield from _help_and_junk("sweep")
    exp = "ch10-pneumatic-adaptive"
    for vary in ("kd=uniform(1,2)x", "kd=linspace(1,2,1e12)", "zz=uniform(1,2)",
                 "kd=normal(1)", "kd=choice()", "kd=grid(" + ",".join(["1"] * 2000) + ")",
                 "kd=uniform(2,1)", "kd", "=1"):
        # A 2,000-point grid is a valid sweep of minutes: interrupted after a while.
        long = (signal.SIGINT, 12.0) if vary.startswith("kd=grid") else None
        yield Attempt("sweep", f"--vary {vary[:30]}", ["sweep", exp, "--vary", vary,
                                                       "--samples", "2", "--out", "s"],
                      signal=long)
    for opt, v in (("--samples", "0"), ("--samples", str(10 ** 13)), ("--seed", "-1"),
                   ("--workers", "0"), ("--scheduler", "tcp://127.0.0.1:1"),
                   ("--format", "xls")):
        yield Attempt("sweep", f"{opt} {v}", ["sweep", exp, "--vary", "kd=uniform(1,2)", opt, v,
                                              "--out", "s"], timeout=60)
    yield Attempt("sweep", "--resume on a missing --out",
                  ["sweep", exp, "--vary", "kd=uniform(1,2)", "--samples", "2", "--resume",
                   "--out", "none"])
    yield Attempt("sweep", "--out holds a sweep", ["sweep", exp, "--vary", "kd=uniform(1,2)",
                                                   "--out", "s"], put("s/summary.csv", "x"))
    for damage in ("[]", "garbage", "{}"):
        yield Attempt("sweep", f"--resume with sweep.json {damage}",
                      ["sweep", exp, "--vary", "kd=uniform(1,2)", "--resume", "--out", "s"],
                      steps(put("s/sweep.json", damage), put("s/samples.jsonl", "{}\n")))
    yield Attempt("sweep", "--metrics matching nothing",
                  ["sweep", "rigid-2link-adaptive", "--vary", "kd=uniform(1,2)", "--samples",
                   "1", "--quick", "--metrics", "zzz*", "--workers", "1", "--out", "s"],
                  outputs=(("s", "sweep"),), timeout=120)
    yield Attempt("sweep", "a quick sweep", ["sweep", "rigid-2link-adaptive", "--vary",
                                             "kd=uniform(1,2)", "--samples", "2", "--quick",
                                             "--out", "s"], outputs=(("s", "sweep"),),
                  timeout=150)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        yield Attempt("sweep", f"{signal.Signals(sig).name} mid-sweep",
                      ["sweep", "rigid-2link-adaptive", "--vary", "kd=uniform(1,2)",
                       "--samples", "6", "--quick", "--workers", "2", "--out", "s"],
                      signal=(sig, rng.uniform(3.0, 8.0)), timeout=150)


FAKES = '''
import os, time
from pathlib import Path
from softgen.core.metrics import Metrics, finding
from softgen.experiments.registry import Experiment
from softgen.runtime.simulate import save_traces
import numpy as np


def _fast(config, out):
    save_traces(Path(out) / "traces.npz", t=np.arange(50.0), q=np.ones(50))
    return Metrics().add("error", 0.001 * config["x"], "rad")


def _findings(metrics, config):
    v = metrics.flat()["error"]
    return [finding("error below 0.01 rad", "reproduced" if v < 0.01 else "not reproduced",
                    f"error {v:.4g} rad")]


def _compile(config, out):
    from softgen.codegen.build import compile_shared
    c = Path(out) / "big.c"
    body = "".join(f"double f{i}(double x){{double y=x;for(int k=0;k<{i % 7 + 3};k++)"
                   f"y=y*y+{i}.0/(y+1.0);return y;}}\\n" for i in range(6000))
    c.write_text(body)
    compile_shared(c, Path(out) / "big.so")
    return Metrics().add("error", 0.0, "rad")


FAST = Experiment(id="camp-fast", title="fast", section="test", run=_fast, config={"x": 1},
                  findings=_findings)
COMPILE = Experiment(id="camp-compile", title="compile", section="test", run=_compile,
                     config={})
'''


@generator("reproduce")
def reproduce_attempts(rng, ctx):
    yield from _help_and_junk("reproduce")
    fakes = {"camp-fast": "campaign_fakes:FAST", "camp-compile": "campaign_fakes:COMPILE",
             "camp-compile2": "campaign_fakes:COMPILE"}
    mod = put("campaign_fakes.py", FAKES)
    res = (("r", "results"),)
    yield Attempt("reproduce", "unknown id", ["reproduce", "nope", "--out", "r"])
    yield Attempt("reproduce", "--set unknown key", ["reproduce", "camp-fast", "--set", "zz=1",
                                                     "--out", "r"], mod, fakes=fakes)
    yield Attempt("reproduce", "--out a file", ["reproduce", "camp-fast", "--out", "f"],
                  steps(mod, put("f", "x")), fakes=fakes)
    yield Attempt("reproduce", "a fake experiment", ["reproduce", "camp-fast", "--out", "r"],
                  mod, fakes=fakes, outputs=res)

    def earlier(edit: float | None = None):
        def make(d: Path) -> None:
            subprocess.run([PY, "-c", WRAPPER, json.dumps(
                {"argv": ["reproduce", "camp-fast", "--out", str(d / "r")], "fakes": fakes,
                 "syspath": str(d)})], cwd=d, capture_output=True, timeout=120)
            if edit is not None:
                p = d / "r" / "camp-fast" / "metrics.json"
                data = json.loads(p.read_text())
                data["metrics"]["error"] = edit
                p.write_text(json.dumps(data))
        return make
    yield Attempt("reproduce", "again into the results", ["reproduce", "camp-fast", "--out",
                                                          "r"], steps(mod, earlier()),
                  fakes=fakes, outputs=res)
    yield Attempt("reproduce", "--resume after an edited metrics.json",
                  ["reproduce", "camp-fast", "--out", "r", "--resume"],
                  steps(mod, earlier(1.235e5)), fakes=fakes, may_change=("r",), outputs=res,
                  judge=lambda run: "an edited metrics.json kept" if run.status == 0 and
                  "kept" in run.stderr else None)
    yield Attempt("reproduce", "--force", ["reproduce", "camp-fast", "--out", "r", "--force"],
                  steps(mod, earlier()), fakes=fakes, may_change=("r",), outputs=res)
    for budget in (0, 2000, 50_000):
        yield Attempt("reproduce", f"full disk ({budget} B)", ["reproduce", "camp-fast",
                                                               "--out", "disk/r", "--force"],
                      steps(mod, lambda d: shutil.copytree(d / "r", d / "disk" / "r")
                            if (d / "r").exists() else None),
                      fakes=fakes, disk=budget, outputs=(("disk/r", "results"),))
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        for when in (0.5, rng.uniform(2.5, 5.0)):
            yield Attempt("reproduce", f"{signal.Signals(sig).name} at {when:.1f} s "
                                       "(compilers running)",
                          ["reproduce", "camp-compile", "camp-compile2", "--out", "r",
                           "--jobs", "2"], mod, fakes=fakes, signal=(sig, when), timeout=150)
    yield Attempt("reproduce", "--jobs 0", ["reproduce", "camp-fast", "--jobs", "0"], mod,
                  fakes=fakes)


@generator("check")
def check_attempts(rng, ctx):
    yield from _help_and_junk("check")
    soft = put("s.toml", SOFT)
    yield Attempt("check", "a soft model", ["check", "s.toml"], soft, timeout=120)
    for opt, v in (("--dt", "0"), ("--dt", "1e300"), ("--dt", "nan"), ("--kd", "-1"),
                   ("--lam", "nan"), ("--law", "foo"), ("--d-scale", "0")):
        yield Attempt("check", f"{opt} {v}", ["check", "s.toml", opt, v], soft, timeout=120)
    yield Attempt("check", "a rigid model", ["check", "planar_2link"])
    yield Attempt("check", "40-segment body", ["check", "p.toml"], put("p.toml", pcc(40)),
                  timeout=60)
    for i in range(4):
        yield Attempt("check", f"mutated soft model #{i}", ["check", "m.toml"],
                      put("m.toml", mutate_toml(SOFT, rng)), timeout=120)


@generator("bench")
def bench_attempts(rng, ctx):
    yield Attempt("bench", "--calls 0", ["bench", "planar_2link", "--calls", "0"])
    yield Attempt("bench", "unknown model", ["bench", "nope"])
    yield Attempt("bench", "60-link chain", ["bench", "c.toml"], put("c.toml", chain(60)),
                  timeout=60)


def generic(verb: str, rng, ctx) -> Iterable[Attempt]:
    """What every verb gets, including one no generator covers (a new verb)."""
    yield from _help_and_junk(verb)
    yield Attempt(verb, "--out under a file", [verb, "x", "--out", "f/x"], put("f", "mine"))
    yield Attempt(verb, "odd file name", [verb, "a b'\"\n;.toml"], put("a b'\"\n;.toml", ARM))
