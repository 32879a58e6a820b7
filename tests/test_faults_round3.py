"""Issue 36, round three: faults of the verbs and model classes added after the second
campaign (Cosserat rods, floating bases, statics, bench, export --set, identify), each
test first naming the symptom found on main, then asserting the promise: no status 0 with
a wrong or unloadable result, nothing lost, no orphan, no traceback, no silent minute.

Fast cases run by default; those that need a compiler are marked.
"""
from __future__ import annotations

import hashlib
import os
import random
from pathlib import Path

import pytest

from softgen.cli import main
from softgen.core.paths import MODELS_DIR
# The bad-input promise and its CLI runner: one home, round 2's (stricter: no NUL).
from test_faults_round2 import _cli, _refused

ROD = MODELS_DIR / "rod_tendon_3seg.toml"



def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# -- statics ----------------------------------------------------------------------------------

def test_statics_refuses_to_write_over_its_model(capsys, tmp_path):
    """Before: ``statics rod.toml --json rod.toml --force`` replaced the model by the
    result (an input overwritten by its own output)."""
    rod = tmp_path / "rod.toml"
    rod.write_text(ROD.read_text())
    before = _sha(rod)
    _refused(capsys, ["statics", rod, "--json", tmp_path / "." / "rod.toml", "--force"],
             "--json", "input")
    assert _sha(rod) == before


@pytest.mark.parametrize("target", ["dir", "missing_dir", "fifo"])
def test_statics_output_is_checked_before_solving(capsys, tmp_path, target):
    """Before: a --json that is a directory or in a missing directory failed only after
    the solve; a FIFO (or, as root, a device such as /dev/full) was replaced by a file."""
    out = {"dir": tmp_path, "missing_dir": tmp_path / "no" / "x.json",
           "fifo": tmp_path / "f"}[target]
    if target == "fifo":
        os.mkfifo(out)
    st, stdout, err = _cli(capsys, ["statics", ROD, "--json", out, "--force"])
    assert st == 2 and stdout == "", (st, stdout)        # nothing solved, nothing printed
    assert len(err) == 1 and err[0].startswith("softgen: error: --json"), err
    if target == "fifo":
        assert not Path(out).is_file()


def test_statics_writes_a_loadable_result(capsys, tmp_path):
    import json
    out = tmp_path / "s.json"
    st, stdout, err = _cli(capsys, ["statics", ROD, "--tendon", "t1=0.3", "--json", out])
    assert st == 0 and not err, err
    data = json.loads(out.read_text())
    assert data["model"] == "rod_tendon_3seg" and len(data["q"]) == 9


def _rod_with_segments(tmp_path: Path, n: int) -> Path:
    text = ROD.read_text()
    head, rest = text.split("[[segments]]", 1)
    segment = "[[segments]]" + rest.split("[[segments]]")[0]
    actuators = text[text.index("[[actuators]]"):]
    body = "".join(segment.replace('"s1"', f'"s{i}"') for i in range(n))
    p = tmp_path / f"rod{n}.toml"
    p.write_text(head + body + actuators)
    return p


def test_statics_checks_the_model_size_first(capsys, tmp_path):
    """Before: ``statics`` on a 200-segment rod derived for minutes without a line (and,
    inside CasADi, without honouring SIGTERM); every other verb refused it in 1 s."""
    import time
    t0 = time.monotonic()
    _refused(capsys, ["statics", _rod_with_segments(tmp_path, 200)], "too large",
             "SOFTGEN_MAX_EXPRESSION_SIZE")
    assert time.monotonic() - t0 < 10


# -- bench ------------------------------------------------------------------------------------

@pytest.mark.parametrize("calls", [0, -3, 10**11])
def test_bench_calls_out_of_range_is_refused_first(capsys, calls):
    """Before: ``bench --calls 0`` built the bundle, then failed with "1 measurement(s)
    failed: pendulum_1link: pendulum_1link.c"."""
    _refused(capsys, ["bench", "pendulum_1link", "--calls", calls], "--calls")


def test_bench_json_output_is_checked_before_timing(capsys, tmp_path):
    _refused(capsys, ["bench", "pendulum_1link", "--calls", "10", "--json", tmp_path],
             "--json", "directory")


def test_check_output_file_property(tmp_path):
    """Seeded: whatever mix of existing file, directory, missing parent and input, the
    check refuses exactly the unsafe outputs and never touches the file system."""
    from softgen.core.atomic import OutputError, check_output_file
    rng = random.Random(36)
    src = tmp_path / "in.txt"
    src.write_text("x")
    for i in range(40):
        kind = rng.choice(["new", "exists", "dir", "input", "noparent"])
        force = rng.random() < 0.5
        p = {"new": tmp_path / f"n{i}.json", "exists": tmp_path / f"e{i}.json",
             "dir": tmp_path / f"d{i}", "input": src,
             "noparent": tmp_path / f"x{i}" / "o.json"}[kind]
        if kind == "exists":
            p.write_text("old")
        if kind == "dir":
            p.mkdir()
        before = sorted(x.name for x in tmp_path.iterdir())
        ok = kind == "new" or (kind == "exists" and force)
        if ok:
            assert check_output_file(p, "--out", force=force, inputs=(src,)) == p
        else:
            with pytest.raises(OutputError, match="--out"):
                check_output_file(p, "--out", force=force, inputs=(src,))
        assert sorted(x.name for x in tmp_path.iterdir()) == before


# -- floating bases ---------------------------------------------------------------------------

@pytest.mark.parametrize("n", [8, 64])
def test_generate_floating_with_a_long_name(capsys, tmp_path, monkeypatch, n):
    """Before: ``generate X.urdf --floating`` (a loaded model object, not a name) took the
    object's repr for a shipped model's name, a path too long for the OS: ``OSError: File
    name too long`` traceback (a URDF given without a directory, as from its folder)."""
    import re
    from softgen.codegen.build import read_manifest
    name = "a" * n
    text = (Path(__file__).parent / "data" / "arm3.urdf").read_text()
    (tmp_path / "arm.urdf").write_text(re.sub(r'<robot name="[^"]*"', f'<robot name="{name}"',
                                              text, count=1))
    monkeypatch.chdir(tmp_path)
    st, out, err = _cli(capsys, ["generate", "arm.urdf", "--floating", "--out", "g",
                                 "--no-build"])
    assert st == 0 and not any("Traceback" in x for x in err), err
    assert read_manifest(tmp_path / "g" / name)["model"] == name


def test_shipped_size_of_anything_is_a_number(tmp_path):
    from softgen.cli.generate import _shipped_size
    rng = random.Random(36)
    for _ in range(30):
        name = "".join(rng.choice("ab/_.") for _ in range(rng.randint(1, 400)))
        assert _shipped_size(name, tmp_path) == 0
    assert _shipped_size(object(), tmp_path) == 0


# -- export --set -----------------------------------------------------------------------------

@pytest.mark.parametrize("model, item, words", [
    ("arm_2link_pneumatic", "substeps=100000000", ("substeps", "100")),
    ("arm_2link_pneumatic", "substeps=0", ("substeps",)),
    ("arm_2link_electric", "dt=1e-12", ("dt", "1e-06")),
    ("arm_2link_electric", "stiffness_margin=-1", ("stiffness_margin", "> 1")),
    ("arm_2link_pneumatic", "lam=-1", ("lam", "positive")),
])
def test_export_set_out_of_range_is_one_line_before_writing(capsys, tmp_path, model, item,
                                                            words):
    """Before: ``--set substeps=100000000`` derived silently for minutes (killed at 90 s);
    ``substeps=0``, ``dt=1e-12`` (a 1e12 Hz program of 1e13 default samples) and
    ``stiffness_margin=-1`` were exported with status 0."""
    out = tmp_path / "p"
    _refused(capsys, ["export", model, "--out", out, "--set", item], "--set", *words)
    assert not out.exists()


def test_example_configs_refuse_exactly_what_is_out_of_range():
    """Seeded: every example config accepts values inside its documented ranges and
    refuses (ValueError naming the field) each value outside them."""
    import dataclasses
    from softgen.studies import examples as ex
    rng = random.Random(36)
    configs = [c for c in vars(ex).values() if isinstance(c, type)
               and issubclass(c, ex.ExampleConfig) and c is not ex.ExampleConfig]
    assert len(configs) == 8                     # the seven loops and the rod's tip
    lo, hi = ex.DT_RANGE
    for cls in configs:
        fields = {f.name for f in dataclasses.fields(cls)}
        for _ in range(20):
            if "dt" in fields:
                good = 10 ** rng.uniform(-6, -1)
                bad = rng.choice([0.0, -good, hi * 10 ** rng.uniform(0.01, 9),
                                  lo * 10 ** -rng.uniform(0.01, 9)])
                cls().replace(dt=good)
                with pytest.raises(ValueError, match=r"\.dt"):
                    cls().replace(dt=bad)
            if "substeps" in fields:
                cls().replace(substeps=rng.randint(1, ex.MAX_SUBSTEPS))
                with pytest.raises(ValueError, match="substeps"):
                    cls().replace(substeps=rng.choice([0, -1, ex.MAX_SUBSTEPS + 1, 10**8]))
            for name in fields & set(ex._POSITIVE + ex._NONNEGATIVE):
                with pytest.raises(ValueError, match=name):
                    cls().replace(**{name: -10 ** rng.uniform(-3, 3)})


def test_example_loop_samples_are_bounded():
    from softgen.core.errors import SoftgenError
    from softgen.studies.examples import MAX_LOOP_SAMPLES, example_for
    with pytest.raises(SoftgenError, match="steps"):
        example_for("planar_2link", steps=MAX_LOOP_SAMPLES + 1)


# -- identify on a floating base --------------------------------------------------------------

@pytest.fixture(scope="module")
def quad(tmp_path_factory):
    from test_identify_floating import quadruped_toml
    from softgen.modelfile.load import load_model
    p = tmp_path_factory.mktemp("quad") / "quad.toml"
    p.write_text(quadruped_toml())
    return load_model(p)


def _floating_log(model, rows: int, rng):
    import numpy as np
    from softgen.app.identify.rigid import IdentificationLog
    n = model.dof
    quat = rng.normal(size=(rows, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    q = np.hstack([rng.normal(size=(rows, 3)), quat, rng.uniform(-1, 1, size=(rows, n))])
    tau = np.hstack([rng.normal(size=(rows, 6)), rng.normal(size=(rows, n))])
    return IdentificationLog(path=Path("log.csv"), t=np.arange(rows) * 0.005, q=q, tau=tau,
                             dt=0.005, torque_source="tau")


def test_identify_checks_of_a_floating_log_read_the_joint_columns(quad):
    """Before: check_log indexed the base pose and wrench columns as joints: every
    floating-base log, even the simulated one issue 35 identifies, ended in ``IndexError:
    index 14 is out of bounds`` (a traceback, no model)."""
    import numpy as np
    from softgen.app.identify.rigid import check_log, joint_columns, unit_hints
    from softgen.core.errors import SoftgenError
    rng = np.random.default_rng(36)
    for _ in range(10):
        log = _floating_log(quad, int(rng.integers(20, 200)), rng)
        check_log(log, quad)                   # a moving log passes
        assert unit_hints(log, quad, None) == []
        q, tau = joint_columns(log, quad)
        assert q.shape[1] == tau.shape[1] == quad.dof
        j = int(rng.integers(quad.dof))
        log.tau[:, 6 + j] = 0.0                # a joint's torque never logged
        with pytest.raises(SoftgenError, match=f"tau{j + 1} constant"):
            check_log(log, quad)
        log.tau[:, 6 + j] = rng.normal(size=len(log.t))
        log.q[:, 7 + j] = 1.0                  # a joint that never moves
        with pytest.raises(SoftgenError, match=f"q{j + 1} never moves"):
            check_log(log, quad)
        log.q[:, 7 + j] = rng.uniform(-1, 1, size=len(log.t))
        log.tau[:, :6] = 0.0                   # contact-free: a zero base wrench is data
        check_log(log, quad)


@pytest.mark.slow          # one floating identification: ~30 s
def test_identify_cli_on_a_floating_log(capsys, tmp_path, quad):
    from test_identify_floating import _write_log
    from softgen.modelfile.load import load_model
    log = _write_log(tmp_path / "quad_log.csv", quad)
    out = tmp_path / "quad_id.toml"
    st, stdout, err = _cli(capsys, ["identify", quad.path, "--log", log, "--out", out])
    assert st == 0 and not any("Traceback" in x for x in err), err
    assert load_model(out).floating


# -- series-elastic actuators -----------------------------------------------------------------

_SEA = ('[model]\nname = "sea1"\nkind = "planar"\n\n[[links]]\nname = "j1"\n'
        'joint = "revolute"\nlength = 0.5\nmass = 1.0\ncom = 0.25\ninertia = 0.02\n\n'
        '[[actuators]]\njoint = "j1"\ntype = "sea"\nmotor_inertia = 0.1\nmotor_damping = 0.1\n')


def test_sea_spring_must_be_stiff_at_rest(tmp_path):
    """Before: an SEA with k = 0 or k = -5 (or law = "-k*phi") was loaded and granted the
    SEA cascade, whose motor reference then pulls the link away. Seeded: τ'(0) > 0 is
    accepted, τ'(0) <= 0 refused naming the key."""
    from softgen.core.errors import ModelError
    from softgen.modelfile.load import load_model
    rng = random.Random(36)
    p = tmp_path / "sea.toml"
    for _ in range(12):
        k = rng.choice([0.0, -1.0, 1.0]) * 10 ** rng.uniform(-3, 3)
        law = rng.choice([None, "k*phi", "k*sinh(phi)", "k*phi + phi**3"])
        p.write_text(_SEA + f"k = {k!r}\n" + (f'law = "{law}"\n' if law else ""))
        if k > 0:
            assert load_model(p).actuators[0].sides[0].law.spring.slope0 > 0
        else:
            with pytest.raises(ModelError, match=r"actuators\[0\]\.(k|law): .*k > 0"):
                load_model(p)
    p.write_text(_SEA + 'k = 2.0\nlaw = "k*phi**3"\n')
    with pytest.raises(ModelError, match="stiff at rest"):
        load_model(p)


# -- a closed stdout pipe ---------------------------------------------------------------------

@pytest.mark.parametrize("argv", [["list"], ["statics", str(ROD)]])
def test_a_closed_stdout_pipe_exits_141_quietly(argv):
    """Before: ``softgen list | head -c 10`` ended in a BrokenPipeError traceback,
    status 1."""
    import subprocess
    import sys
    r, w = os.pipe()
    os.close(r)                      # the reader is gone before any write
    proc = subprocess.run([sys.executable, "-c", "import sys; from softgen.cli import main; "
                           "sys.exit(main(sys.argv[1:]))", *argv], stdout=w,
                          stderr=subprocess.PIPE, text=True, timeout=120)
    os.close(w)
    assert proc.returncode == 141, (proc.returncode, proc.stderr[-500:])
    assert proc.stderr.count("Traceback") == 0 and "Exception ignored" not in proc.stderr


def test_a_broken_pipe_that_is_not_stdout_is_one_line(capsys, monkeypatch):
    """A BrokenPipeError from another pipe (a child the verb feeds) is not a quiet 141."""
    from softgen.cli import list as list_verb

    def broken(args):
        raise BrokenPipeError(32, "Broken pipe")
    monkeypatch.setattr(list_verb, "run", broken)
    st, out, err = _cli(capsys, ["list"])
    assert st == 1 and len(err) == 1 and err[0].startswith("softgen: error: Broken pipe"), err


# -- a heartbeat on the terminal --------------------------------------------------------------

class _Tty:
    def __init__(self, tty: bool):
        self.lines: list[str] = []
        self.tty = tty

    def write(self, text):
        self.lines.append(text)
        return len(text)

    def flush(self):
        pass

    def isatty(self):
        return self.tty


@pytest.mark.parametrize("tty", [True, False])
def test_heartbeat_speaks_only_after_quiet_stretches_on_a_terminal(monkeypatch, tty):
    """Before: ``identify`` of a floating base's log ran 28 s before its first line (no
    progress at a terminal). Now a quiet stretch of ``every`` seconds gets one line, output
    of the verb itself resets the clock, and a non-terminal sees only the verb's output."""
    import sys
    import time
    from softgen.core.heartbeat import heartbeat
    err, out = _Tty(tty), _Tty(tty)
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(sys, "stdout", out)
    with heartbeat("verb", every=0.2):
        time.sleep(0.5)                              # quiet: about two beats
        beats = [x for x in err.lines if "working" in x]
        for _ in range(6):                           # talking: no beat
            print("line", file=sys.stdout)
            time.sleep(0.05)
        talking = [x for x in err.lines if "working" in x][len(beats):]
    assert sys.stderr is err and sys.stdout is out
    if tty:
        assert 1 <= len(beats) <= 3 and all(x.startswith("softgen: verb: working (") for x in
                                            beats), beats
        assert talking == []
    else:
        assert beats == [] and err.lines == []
    assert out.lines.count("line") == 6


def test_a_signal_inside_an_import_is_the_stop(capsys, monkeypatch):
    """Before (found by tests/test_faults_signals.py under load): a SIGTERM while scipy's
    HiGHS extension initialised became ``ImportError: initialization failed`` caused by
    the Stop, a traceback with status 1 instead of one line and 143."""
    import signal
    from softgen.cli import list as list_verb
    from softgen.core.stop import Stop

    def importing(args):
        try:
            raise Stop(signal.SIGTERM)
        except Stop as exc:
            raise ImportError("initialization failed") from exc
    monkeypatch.setattr(list_verb, "run", importing)
    st, out, err = _cli(capsys, ["list"])
    assert st == 143 and err == ["softgen: error: stopped by SIGTERM"], (st, err)

    def plain(args):
        raise ImportError("no module named x")
    monkeypatch.setattr(list_verb, "run", plain)
    with pytest.raises(ImportError):
        main(["list"])


def test_bench_refuses_to_write_its_figures_over_its_model(capsys, tmp_path):
    """Found by the round-3 campaign's generator: ``bench m.toml --json m.toml`` timed the
    model, then replaced the model file by the figures."""
    m = tmp_path / "m.toml"
    m.write_text((MODELS_DIR / "pendulum_1link.toml").read_text()
                 .replace('"pendulum_1link"', '"pend_copy"'))
    before = _sha(m)
    _refused(capsys, ["bench", m, "--calls", "10", "--json", tmp_path / "." / "m.toml"],
             "--json", "input")
    assert _sha(m) == before


@pytest.mark.parametrize("argv", [["observer", "--model", "{q}"], ["check", "{q}"],
                                  ["estimate", "{q}", "--log", "x.csv"]])
def test_a_floating_file_follows_the_floating_rule(capsys, tmp_path, quad, argv):
    """Found by the round-3 campaign: ``observer --model quad.toml`` (floating = true in
    the file, no --floating) ended in ``RuntimeError: Dimension mismatch for (x-y), x is
    8x1, while y is 14x1``: the rule of --floating (fixed-base verbs refuse it) now holds
    for a file that declares its floating base too."""
    _refused(capsys, [a.replace("{q}", str(quad.path)) for a in argv], "floating base",
             "fixed-base")


def test_observer_library_refuses_a_floating_model(quad):
    from softgen.app.observer import linearise_model
    from softgen.core.errors import SoftgenError
    with pytest.raises(SoftgenError, match="floating base"):
        linearise_model(quad)


# -- Cosserat moduli ---------------------------------------------------------------------------

def test_cosserat_moduli_are_bounded_by_their_own_limit(tmp_path):
    """A steel (2e11 Pa) or nitinol (5e10 Pa) rod was refused by the general bound on
    model numbers (1e9); a modulus beyond diamond's (MAX_MODULUS, 1e12 Pa) is one line
    naming the key. Seeded over both moduli and the whole range."""
    import re
    from softgen.core.errors import ModelError
    from softgen.modelfile.cosserat import MAX_MODULUS
    from softgen.modelfile.load import load_model
    rng = random.Random(36)
    p = tmp_path / "rod.toml"
    for _ in range(16):
        key = rng.choice(["youngs_modulus", "shear_modulus"])
        value = 10 ** rng.uniform(3, 15)
        text = re.sub(r"^youngs_modulus = .*$", f"{key} = {value!r}" +
                      ("\nyoungs_modulus = 1e6" if key == "shear_modulus" else ""),
                      ROD.read_text(), count=1, flags=re.M)
        p.write_text(text)
        if value <= MAX_MODULUS:
            assert load_model(p).kind == "cosserat"
        else:
            with pytest.raises(ModelError, match=rf"segments\[0\]\.{key}: .*1e\+12"):
                load_model(p)


def test_a_steel_rod_has_a_static_shape(capsys, tmp_path):
    import re
    p = tmp_path / "steel.toml"
    p.write_text(re.sub(r"^youngs_modulus = .*$", "youngs_modulus = 2e11", ROD.read_text(),
                        flags=re.M).replace("density = 1100", "density = 7850"))
    st, out, err = _cli(capsys, ["statics", p, "--tendon", "t1=5"])
    assert st == 0 and "tip position" in out, err
