"""Issue 36: the 60 cases of the second fault campaign that were not clean, each test
first reproducing the symptom the campaign found on main, then asserting the promise:
no status 0 with a wrong or unloadable result, nothing lost, no orphan, no traceback,
no silent minute.

======  ================================================================================
case    symptom on main (before)
======  ================================================================================
W01     ``estimate --p0 1e-300 --strict``: σ̂ ≈ 3e-298 called "plausible", status 0
W02     ``estimate --p0 1e-300``: no warning at all (the default run must warn)
W03     ``estimate --p0 1e-6 --strict`` on a log the RLS barely moves from: exit by drift only
W04     ``reproduce --resume`` keeps a metrics.json whose numbers were edited
W05     report.md shows an edited metrics.json of an experiment not run now
W06     law ``k*phi**(2**64)`` accepted
W07     law ``k*(1+phi)**(10**10)`` accepted (stiffness at rest 4e11)
W08     law ``k*phi**(8*9)`` accepted (exponent 72 > 64, folded)
W09     law ``k*sinh(phi)**(2*50)`` accepted
W10     law ``k*phi*exp(700)`` accepted (a constant of 1e304)
W11     ``identify`` on a log with time in ms: status 0, model ``info`` refuses
W12     ``identify`` on a log with q in degrees: status 0, model ``info`` refuses
W13     ``identify`` on a log with τ in mN·m: status 0, model ``info`` refuses
W14     ``identify`` on a log with q and τ columns swapped: status 0, unloadable model
W15     ``identify`` on a log of noise only: status 0, ``mass = -0.017``
W16     ``identify`` on a log with τ ≡ 0: status 0, unloadable model
W17     ``identify --excite --dt 100``: "0 samples", status 0 (and ``--periods 0``)
L01     ``export --force`` of a larger model on a nearly full disk: the earlier
        export's sources deleted, then a traceback
L02     ``plot X.npz --out X.npz --force`` replaces the trace by a PNG
L03     ``export --force`` into a folder that never held an export overwrites main.c
L04     ``generate --force`` on a nearly full disk: .c and manifest replaced, then a
        compile failure that does not say why
L05     ``reproduce`` into an existing results directory overwrites it without --force
O01     SIGTERM of ``reproduce --jobs 2`` during a compile: cc left under PID 1
O02     SIGKILL of ``reproduce --jobs 2`` during a compile: cc left; staging kept
T01     full cache directory: ENOSPC traceback from codegen/generate.py
T02     full temporary directory while CasADi writes the C: traceback
T03     ``export`` onto a full disk: traceback
T04     deeply nested TOML arrays (``info``): RecursionError
T05     deeply nested TOML inline tables (``info``): RecursionError
T06     deeply nested ``observer --system`` TOML: RecursionError
T07     a 500-character observer system name: traceback
T08     ``observer --delay 100000``: traceback (after minutes of rank computations)
T09     ``identify --excite --harmonics 100000``: traceback after 21.6 CPU-s
T10     ``identify --excite --period 1e9``: 7 TiB allocation, traceback
T11     ``identify --excite --periods 1000000``: 74 GiB allocation, traceback
T12     full build directory while the library's record is written: traceback
T13     ``generate --out`` on a full disk: traceback
T14     ``estimate`` of a log of NUL bytes: a line of 3,000 NULs
T15     ``observer --model ... --dt 1e300``: OverflowError traceback
M01     ``check`` on a 40-segment body: 180 CPU-s silent
M02     ``export`` of a 60-link chain: over 60 s silent
M03     ``identify --excite`` on a 60-link chain: over 60 s silent
M04     ``observer --model`` on a 60-link chain: over 60 s silent
M05     ``observer --system`` with 1,000 states: 82 CPU-s silent
M06     ``estimate`` of a 1e7-row log: 90 CPU-s, 6.8 GB, no progress
M07     ``estimate --log /dev/zero`` (and ``identify``): reads until killed
M08     ``identify --log`` on a 60-link chain: silent derivation
M09     ``estimate`` on a 60-joint qbmove chain: silent derivation
M10     ``identify --excite --harmonics 1000``: minutes of optimisation
M11     ``identify`` of a 1e7-row log: silent minutes
U01     ``export --build`` with a relative ``--out``: make fails (cwd=out and -C out)
U02     ``export --build``: make's own error hidden
U03     ``estimate`` of an all-zero log blames "quantised encoders? try --lowpass"
U04     ``estimate`` of a constant log: "not converged" instead of no excitation
U05     ``sweep --resume`` on a missing --out starts fresh (the help says it refuses)
U06     ``sweep --metrics 'zzz*'`` matching nothing: status 0, no metric
U07     ``generate`` whose compile fails: the reason is not on the one line
U08     ``identify`` of a log sampled at 2 s: says only that samples are few
U09     ``identify --excite --maxiter -5``: status 0 with 0 iterations
U10     ``estimate`` σ̂ ≤ 0 after a low-pass: still says "try --lowpass"
U11     ``identify --actuator sinh`` on a URDF: a 35,000-character "found columns" line
E01     (found on the way) ``estimate --out /dev/full --force``: a device node replaced
======  ================================================================================

Fast cases run by default; those that need compiles or subprocess signals are marked.
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import fault_disk
from softgen.cli import main
from softgen.experiments import registry

PY = sys.executable


# -- helpers ----------------------------------------------------------------------------------

def _cli(capsys, argv: list[str]) -> tuple[int, str, list[str]]:
    status = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return status, cap.out, [x for x in cap.err.splitlines() if x.strip()]


def _refused(capsys, argv, *words, status=(2,)) -> str:
    """The promise for bad input: a non-zero status, one ``softgen: error:`` line (no
    traceback), naming ``words``."""
    st, out, err = _cli(capsys, argv)
    errors = [x for x in err if x.startswith("softgen: error:")]
    assert st in status, (st, out, err)
    assert len(errors) == 1 and not any("Traceback" in x for x in err), err
    for w in words:
        assert w in errors[0], (w, errors[0])
    assert "\x00" not in errors[0] and len(errors[0]) < 600, errors[0][:200]
    return errors[0]


def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _tree(d: Path) -> dict[str, str]:
    return {str(p.relative_to(d)): _sha(p) for p in sorted(d.rglob("*")) if p.is_file()}


def _planar_chain(tmp_path, n: int) -> Path:
    links = "".join('[[links]]\njoint = "revolute"\nlength = 0.3\nmass = 1.0\ncom = 0.15\n'
                    'inertia = 0.01\n\n' for _ in range(n))
    p = tmp_path / f"chain{n}.toml"
    p.write_text(f'[model]\nname = "chain{n}"\nkind = "planar"\n\n{links}')
    return p


def _qbmove_chain(tmp_path, n: int) -> Path:
    body = "".join(f'[[links]]\nname = "l{i}"\njoint = "revolute"\nlength = 0.3\nmass = 1.0\n'
                   'com = 0.15\ninertia = 0.01\n\n' for i in range(n))
    acts = "".join(f'[[actuators]]\njoint = "l{i}"\ntype = "qbmove"\na = [6.7, 6.9]\n'
                   'k = [0.02, 0.02]\nmotor_inertia = 3e-6\nmotor_damping = 1e-6\n\n'
                   for i in range(n))
    p = tmp_path / f"qb{n}.toml"
    p.write_text(f'[model]\nname = "qb{n}"\nkind = "planar"\n\n{body}{acts}')
    return p


def _pcc(tmp_path, n: int) -> Path:
    segs = "".join('[[segments]]\nlength = 0.1\nmass = 0.01\nstiffness = 1.0\ndamping = 0.1\n\n'
                   for _ in range(n))
    p = tmp_path / f"pcc{n}.toml"
    p.write_text(f'[model]\nname = "pcc{n}"\nkind = "pcc-planar"\n\n{segs}')
    return p


def _timed_refusal(capsys, argv, *words, seconds=10.0) -> str:
    t0 = time.process_time()
    w0 = time.perf_counter()
    line = _refused(capsys, argv, *words)
    assert time.process_time() - t0 < seconds and time.perf_counter() - w0 < 3 * seconds
    return line


# == W: wrong with status 0 ===================================================================

def _sample_log():
    from softgen.app.estimate import sample_log
    return sample_log()


@pytest.mark.parametrize("strict", [True, False])
def test_W01_W02_estimate_p0_too_small_is_not_plausible(capsys, tmp_path, strict):
    """Before: σ̂ ≈ 3e-298 "plausible", status 0, with and without --strict."""
    argv = ["estimate", "pendulum_qbmove", "--log", _sample_log(), "--method", "noninvasive",
            "--out", tmp_path / "e.csv", "--p0", "1e-300"]
    if strict:
        _refused(capsys, argv + ["--strict"], "--p0", status=(3,))
        return
    st, out, err = _cli(capsys, argv)
    assert st == 0 and "plausible" not in out, out
    warnings = [x for x in err if x.startswith("softgen: warning:")]
    assert warnings and any("--p0" in w for w in warnings), err


def test_W03_strict_never_passes_what_the_default_warns_about(capsys, tmp_path):
    """--strict and the default judge by the same checks: whatever the default warns
    about, --strict refuses (status 3), for a spread of P(0)."""
    for p0 in ("1e-300", "1e-6", "1e-2"):
        argv = ["estimate", "pendulum_qbmove", "--log", _sample_log(), "--method",
                "noninvasive", "--out", tmp_path / "e.csv", "--force", "--p0", p0]
        st, out, err = _cli(capsys, argv)
        warned = any(x.startswith("softgen: warning:") for x in err)
        st_strict, _, err_strict = _cli(capsys, argv + ["--strict"])
        assert warned and st_strict == 3, (p0, err, err_strict)


FAKES = '''\
from softgen.experiments.registry import Experiment
from softgen.core.metrics import Metrics, finding


def _run(config, out):
    return Metrics().add("error", 0.001 * config["x"], "rad")


def _findings(metrics, config):
    v = metrics.flat()["error"]
    return [finding("error below 0.01 rad", "reproduced" if v < 0.01 else "not reproduced",
                    f"error {v:.4g} rad")]


A = Experiment(id="r2-a", title="a", section="test", run=_run, config={"x": 1},
               findings=_findings)
B = Experiment(id="r2-b", title="b", section="test", run=_run, config={"x": 2},
               findings=_findings)
'''


@pytest.fixture
def fakes(tmp_path, monkeypatch):
    src = tmp_path / "src"
    src.mkdir()
    (src / "round2_fakes.py").write_text(FAKES)
    monkeypatch.syspath_prepend(str(src))
    monkeypatch.setitem(registry._MODULES, "r2-a", "round2_fakes:A")
    monkeypatch.setitem(registry._MODULES, "r2-b", "round2_fakes:B")
    import importlib
    importlib.invalidate_caches()
    return src


def _edit_metrics(path: Path, value: float) -> None:
    data = json.loads(path.read_text())
    data["metrics"]["error"] = value
    path.write_text(json.dumps(data, indent=2))


def test_W04_resume_reruns_an_edited_metrics_json(fakes, tmp_path, capsys):
    """Before: the edited number (1.235e+05 rad) kept and reported beside "reproduced"."""
    out = tmp_path / "results"
    assert main(["reproduce", "r2-a", "--out", str(out)]) == 0
    _edit_metrics(out / "r2-a" / "metrics.json", 1.235e5)
    capsys.readouterr()
    assert main(["reproduce", "r2-a", "--out", str(out), "--resume"]) == 0
    err = capsys.readouterr().err
    assert "kept" not in err and "r2-a" in err
    saved = json.loads((out / "r2-a" / "metrics.json").read_text())
    assert saved["metrics"]["error"] == pytest.approx(0.001)
    assert "123500" not in (out / "report.md").read_text()


def test_W05_report_leaves_out_an_edited_metrics_json_of_another_experiment(fakes, tmp_path):
    out = tmp_path / "results"
    assert main(["reproduce", "r2-a", "r2-b", "--out", str(out)]) == 0
    _edit_metrics(out / "r2-b" / "metrics.json", 1.235e5)
    assert main(["reproduce", "r2-a", "--out", str(out), "--force"]) == 0
    report = (out / "report.md").read_text()
    assert "## r2-a" in report and "123500" not in report and "1.235e+05" not in report


def _law_model(tmp_path, law: str) -> Path:
    text = (Path(__file__).parent / "data" / "user_models" / "arm3_sea.toml").read_text()
    assert 'law = "k*phi"' in text
    p = tmp_path / "law.toml"
    p.write_text(text.replace('law = "k*phi"', f'law = "{law}"'))
    return p


@pytest.mark.parametrize("case, law, words", [
    ("W06", "k*phi**(2**64)", "exponent"),
    ("W07", "k*(1+phi)**(10**10)", "exponent"),
    ("W08", "k*phi**(8*9)", "exponent 72"),
    ("W09", "k*sinh(phi)**(2*50)", "exponent 100"),
    ("W10", "k*phi*exp(700)", "exp(700)"),
])
def test_W06_W10_constant_laws_are_bounded_by_value(capsys, tmp_path, case, law, words):
    """Before: status 0 from ``info`` (the literal ``phi**1e308`` was refused)."""
    line = _refused(capsys, ["info", _law_model(tmp_path, law)], "actuators[2].law", words)
    assert "law.toml" in line


# -- identify ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def id_logs(tmp_path_factory):
    """planar_2link logs: a good one and the unit/column faults of the campaign."""
    from softgen.modelfile.load import load_model
    from softgen.studies.excitation import IdentificationRegressor, optimise_excitation
    d = tmp_path_factory.mktemp("idlogs")
    reg = IdentificationRegressor(load_model("planar_2link"))
    ex = optimise_excitation(reg, harmonics=3, period=10.0, seed=1, maxiter=10, grid=60)
    rng = np.random.default_rng(36)
    dt = 2e-3
    t = np.arange(10000) * dt
    q, qd, qdd = ex.trajectory.evaluate(t)
    f = reg.dyn.inverse_dynamics_fun().map(t.size)
    tau = np.asarray(f(q.T, qd.T, qd.T, qdd.T)).T
    tau = tau + 0.1 * qd + 0.05 * np.sign(qd)
    tau = tau + rng.normal(scale=0.01 * np.std(tau, axis=0), size=tau.shape)
    step = 2 * math.pi / 2 ** 16
    q = np.round(q / step) * step

    def write(name, tt, qq, ta):
        path = d / f"{name}.csv"
        with open(path, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["t", "q1", "q2", "tau1", "tau2"])
            for row in np.hstack([tt[:, None], qq, ta]):
                w.writerow([repr(float(v)) for v in row])
        return path

    return {"good": write("good", t, q, tau), "ms": write("ms", t * 1000, q, tau),
            "deg": write("deg", t, np.degrees(q), tau),
            "mNm": write("mNm", t, q, tau * 1000), "swap": write("swap", t, tau, q),
            "noise": write("noise", t, rng.normal(size=q.shape), rng.normal(size=q.shape)),
            "tau0": write("tau0", t, q, 0 * tau)}


def test_identify_good_log_still_identifies(capsys, tmp_path, id_logs):
    out = tmp_path / "ok.toml"
    st, so, err = _cli(capsys, ["identify", "planar_2link", "--log", id_logs["good"],
                                "--out", out])
    assert st == 0 and out.exists(), err
    assert _cli(capsys, ["info", out])[0] == 0


@pytest.mark.parametrize("case, log, words", [
    ("W11", "ms", "time step"), ("W12", "deg", "degrees"), ("W13", "mNm", "mN"),
    ("W14", "swap", "swapped"), ("W15", "noise", "noise"), ("W16", "tau0", "tau"),
])
def test_W11_W16_identify_refuses_what_info_would_refuse(capsys, tmp_path, id_logs, case,
                                                         log, words):
    """Before: status 0 and a model file that ``info`` refuses (``mass = -12.16``)."""
    out = tmp_path / f"{log}.toml"
    line = _refused(capsys, ["identify", "planar_2link", "--log", id_logs[log],
                             "--out", out])
    assert words in line, line
    assert not out.exists()


@pytest.mark.parametrize("args", [["--dt", "100"], ["--periods", "0"]])
def test_W17_excite_with_no_samples_is_refused(capsys, tmp_path, args):
    """Before: "0 samples", status 0, an empty trajectory file."""
    out = tmp_path / "traj.csv"
    t0 = time.process_time()
    _refused(capsys, ["identify", "planar_2link", "--excite", "--out", out, *args], args[0])
    assert time.process_time() - t0 < 5 and not out.exists()


# == L: data lost =============================================================================

def test_L01_export_force_on_a_nearly_full_disk_keeps_the_earlier_export(capsys, tmp_path,
                                                                         monkeypatch):
    """Before: the earlier export's sources deleted, then an ENOSPC traceback, leaving a
    record and a Makefile that name missing files."""
    out = tmp_path / "proj"
    assert _cli(capsys, ["export", "pendulum_1link", "--out", out])[0] == 0
    before = _tree(out)
    fault_disk.install(tmp_path, 20_000, monkeypatch)       # less than the new set
    line = _refused(capsys, ["export", "planar_2link", "--out", out, "--force"],
                    "No space left")
    assert str(tmp_path) in line
    assert _tree(out) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".proj")]


def test_L02_plot_refuses_an_output_that_is_its_input(capsys, tmp_path):
    """Before: ``plot X.npz --out X.npz --force`` replaced the trace by a PNG."""
    from softgen.runtime.simulate import save_traces
    trace = tmp_path / "traces.npz"
    save_traces(trace, t=np.arange(10.0), q=np.ones((10, 2)))
    before = _sha(trace)
    _refused(capsys, ["plot", trace, "--out", trace, "--force"], "--out", "input")
    _refused(capsys, ["plot", tmp_path, "--out", tmp_path / "." / "traces.npz", "--force"],
             "--out")
    assert _sha(trace) == before


def test_L03_export_force_into_a_folder_of_foreign_files_is_refused(capsys, tmp_path):
    """Before: ``export --force`` into a folder that never held an export overwrote the
    user's own main.c."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "main.c").write_text("int main(void) { return 42; }\n")
    (out / "notes.txt").write_text("mine\n")
    before = _tree(out)
    line = _refused(capsys, ["export", "planar_2link", "--out", out, "--force"],
                    "--force-foreign")
    assert "main.c" in line
    assert _tree(out) == before
    # With the flag it writes; files it does not write stay.
    assert _cli(capsys, ["export", "planar_2link", "--out", out, "--force",
                         "--force-foreign"])[0] == 0
    assert (out / "notes.txt").read_text() == "mine\n"
    # An earlier export's folder needs only --force; build products are its own.
    (out / "notes.txt").unlink()
    (out / "planar_2link.o").write_bytes(b"obj")
    assert _cli(capsys, ["export", "planar_2link", "--out", out, "--force"])[0] == 0


def test_L04_generate_force_on_a_nearly_full_disk_keeps_the_bundle(capsys, tmp_path,
                                                                   monkeypatch):
    """Before: .c and manifest replaced, then a compile failure without the reason."""
    model = tmp_path / "arm.toml"
    model.write_text((Path(__file__).parent / "data" / "user_models" / "arm3_sea.toml")
                     .read_text())
    gen = tmp_path / "gen"
    assert _cli(capsys, ["generate", model, "--out", gen, "--no-build"])[0] == 0
    before = _tree(gen)
    # The model changes (the new C differs), and the disk has room for part of it.
    model.write_text(model.read_text().replace("mass = 0.42", "mass = 0.43"))
    fault_disk.install(gen, 50_000, monkeypatch)
    _refused(capsys, ["generate", model, "--out", gen, "--no-build", "--force"],
             "No space left")
    assert _tree(gen) == before


@pytest.mark.compiler
def test_L04_compile_failure_names_its_reason(capsys, tmp_path, monkeypatch):
    """A compile that fails (here: ld on a full disk) says why on its one line."""
    fake = tmp_path / "fakecc"
    fake.write_text("#!/bin/sh\necho '/usr/bin/ld: final link failed: No space left on "
                    "device' >&2\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv("CC", str(fake))
    line = _refused(capsys, ["generate", "pendulum_1link", "--out", tmp_path / "g",
                             "--force"], "No space left on device")
    assert "pendulum_1link.c" in line


def test_L05_reproduce_into_existing_results_is_refused(fakes, tmp_path, capsys):
    """Before: a second run overwrote the first run's results without --force."""
    out = tmp_path / "results"
    assert main(["reproduce", "r2-a", "--out", str(out)]) == 0
    before = _tree(out)
    _refused(capsys, ["reproduce", "r2-a", "--out", out], "--force", "--resume")
    assert _tree(out) == before
    assert main(["reproduce", "r2-a", "--out", str(out), "--resume"]) == 0
    assert main(["reproduce", "r2-a", "--out", str(out), "--force"]) == 0
    # Another experiment into the same directory overwrites nothing of the first.
    assert main(["reproduce", "r2-b", "--out", str(out)]) == 0


# == O: orphans ===============================================================================

ORPHAN_FAKES = '''\
import os
from pathlib import Path
from softgen.codegen.build import compile_shared
from softgen.experiments.registry import Experiment


def _compile(config, out):
    c = Path(out) / "x.c"
    c.write_text("int x;\\n")
    compile_shared(c, Path(out) / "x.so")
    return {"value": 1.0}


COMPILE = Experiment(id="r2-compile", title="compile", section="test", run=_compile,
                     config={})
'''

ORPHAN_DRIVER = '''\
import sys
from softgen.cli import main
from softgen.experiments import registry
registry._MODULES["r2-compile"] = "round2_orphans:COMPILE"
registry._MODULES["r2-compile2"] = "round2_orphans:COMPILE"
if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
'''

#: A compiler that takes its time in a grandchild, as gcc does in cc1.
FAKE_CC = '''#!/bin/sh
echo $$ >> "{mark}"
sleep 300 &
echo $! >> "{mark}"
wait
'''


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow          # two processes started and killed: ~10 s
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_O01_O02_compilers_die_with_reproduce(tmp_path, sig):
    """Before: cc and cc1 left running under PID 1 after SIGTERM or SIGKILL of
    ``reproduce --jobs 2``; the staging folders stayed in --out."""
    if not Path("/proc/self").exists():
        pytest.skip("needs /proc")
    src = tmp_path / "src"
    src.mkdir()
    (src / "round2_orphans.py").write_text(ORPHAN_FAKES)
    (src / "driver.py").write_text(ORPHAN_DRIVER)
    mark = tmp_path / "pids"
    cc = tmp_path / "fakecc"
    cc.write_text(FAKE_CC.format(mark=mark))
    cc.chmod(0o755)
    env = {**os.environ, "CC": str(cc),
           "PYTHONPATH": str(src) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = tmp_path / "results"
    proc = subprocess.Popen([PY, str(src / "driver.py"), "reproduce", "r2-compile",
                             "r2-compile2", "--out", str(out), "--jobs", "2"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 60
    while not (mark.exists() and len(mark.read_text().split()) >= 4):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    pids = [int(x) for x in mark.read_text().split()]
    os.kill(proc.pid, sig)
    proc.communicate(timeout=60)
    deadline = time.monotonic() + 10
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in pids if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, left
    if sig == signal.SIGTERM:
        assert not list(out.glob(".*.running-*"))
    # The next start cleans whatever a SIGKILL left.
    subprocess.run([PY, str(src / "driver.py"), "reproduce", "r2-compile", "--out", str(out),
                    "--force"], env={**env, "CC": "/bin/false"}, capture_output=True,
                   timeout=120)
    assert not list(out.glob(".*.running-*"))


@pytest.mark.parametrize("blocked", [False, True])
def test_O_a_supervised_program_tree_dies_with_its_parent(tmp_path, blocked):
    """core.children.run: the program and its grandchildren end when the process that
    started them is SIGKILLed, also when that process blocks SIGTERM (a pool worker)."""
    if not Path("/proc/self").exists():
        pytest.skip("needs /proc")
    mark = tmp_path / "pids"
    cc = tmp_path / "fakecc"
    cc.write_text(FAKE_CC.format(mark=mark))
    cc.chmod(0o755)
    code = ("import signal, sys; from softgen.core import children\n"
            + ("signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})\n"
               if blocked else "")
            + f"children.run([{str(cc)!r}])\n")
    parent = subprocess.Popen([PY, "-c", code])
    deadline = time.monotonic() + 30
    while not (mark.exists() and len(mark.read_text().split()) >= 2):
        assert parent.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    pids = [int(x) for x in mark.read_text().split()]
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 5
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [p for p in pids if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left


def test_O_supervised_run_returns_like_subprocess_run(tmp_path):
    from softgen.core import children
    r = children.run(["sh", "-c", "echo out; echo err >&2; exit 3"], cwd=tmp_path)
    assert (r.returncode, r.stdout, r.stderr) == (3, "out\n", "err\n")
    with pytest.raises(subprocess.TimeoutExpired):
        children.run(["sleep", "30"], timeout=0.5)
    assert children.run([str(tmp_path / "none")]).returncode == 127


QUEUE_FAKES = '''\
import time
from pathlib import Path
from softgen.experiments.registry import Experiment


def _nap(config, out):
    (Path(out).parent.parent / f"started-{config['i']}").write_text("")
    time.sleep(60)
    return {"value": 1.0}


NAPS = [Experiment(id=f"r2-nap{i}", title="nap", section="test", run=_nap, config={"i": i})
        for i in range(5)]
'''

QUEUE_DRIVER = '''\
import sys
from softgen.cli import main
from softgen.experiments import registry
for i in range(5):
    registry._MODULES[f"r2-nap{i}"] = f"round2_queue:NAPS"
import round2_queue
registry.get = (lambda real: lambda exp_id: round2_queue.NAPS[int(exp_id[-1])]
                if exp_id.startswith("r2-nap") else real(exp_id))(registry.get)
if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
'''


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_O_interrupt_with_queued_experiments_is_one_line(tmp_path, sig):
    """Found by the campaign: SIGINT of ``reproduce`` with experiments still queued
    printed a thread traceback from concurrent.futures (InvalidStateError) after the one
    line, because the queued futures were cancelled from outside the pool's thread."""
    src = tmp_path / "src"
    src.mkdir()
    (src / "round2_queue.py").write_text(QUEUE_FAKES)
    (src / "driver.py").write_text(QUEUE_DRIVER)
    env = {**os.environ, "PYTHONPATH": str(src) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = tmp_path / "results"
    proc = subprocess.Popen([PY, str(src / "driver.py"), "reproduce",
                             *[f"r2-nap{i}" for i in range(5)], "--out", str(out),
                             "--jobs", "2"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while len(list(tmp_path.glob("started-*"))) < 2:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and "Exception in thread" not in err, err
    assert len([x for x in err.splitlines() if x.startswith("softgen: error:")]) == 1, err


# == T: tracebacks ============================================================================

def test_T01_full_cache_is_one_line(tmp_path, monkeypatch):
    """Before: an ENOSPC traceback from codegen/generate.py when a loop's C went into a
    full cache directory."""
    import casadi as ca
    from softgen.core.errors import SoftgenError
    from softgen.runtime.compiled import compile_functions
    cache = tmp_path / "cache"
    monkeypatch.setenv("SOFTGEN_CACHE_DIR", str(cache))
    fault_disk.install(cache, 2_000, monkeypatch)
    x = ca.SX.sym("x")
    f = ca.Function("fullcache_cube", [x], [x * x * x])
    with pytest.raises(SoftgenError, match="No space left") as exc:
        compile_functions("fullcache", [f])
    assert str(cache) in str(exc.value) and "\n" not in str(exc.value)


def test_T02_full_temporary_directory_is_one_line(tmp_path, monkeypatch):
    """Before: CasADi's C written into a full $TMPDIR gave an OSError traceback."""
    import tempfile
    from softgen.codegen.generate import BundleSpec, Generated, render
    from softgen.core.errors import SoftgenError
    import casadi as ca
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))

    def full(*args, **kwargs):
        raise OSError(28, os.strerror(28), str(tmp / "x.c"))
    monkeypatch.setattr(ca.CodeGenerator, "generate", full)
    x = ca.SX.sym("x")
    spec = BundleSpec("tmpfull", [Generated(ca.Function("tmpfull_f", [x], [x]), "f")])
    with pytest.raises(SoftgenError, match="No space left") as exc:
        render(spec)
    assert "\n" not in str(exc.value)


def test_T03_export_onto_a_full_disk_is_one_line(capsys, tmp_path, monkeypatch):
    fault_disk.install(tmp_path, 5_000, monkeypatch)
    _refused(capsys, ["export", "planar_2link", "--out", tmp_path / "p"], "No space left")
    assert not (tmp_path / "p").exists() or not any((tmp_path / "p").iterdir())


@pytest.mark.parametrize("case, value", [("T04", "[" * 5000 + "]" * 5000),
                                         ("T05", "{a=" * 3000 + "1" + "}" * 3000)])
def test_T04_T05_deeply_nested_toml_is_one_line(capsys, tmp_path, case, value):
    p = tmp_path / "deep.toml"
    p.write_text(f'[model]\nname = "a"\nkind = "planar"\nx = {value}\n')
    _refused(capsys, ["info", p], str(p), "nested")


def test_a_list_for_the_model_kind_is_one_line(capsys, tmp_path):
    """Found by the campaign: ``kind = [1]`` was a TypeError traceback."""
    p = tmp_path / "k.toml"
    p.write_text('[model]\nname = "a"\nkind = [1]\n')
    _refused(capsys, ["info", p], str(p))


def test_T06_deeply_nested_system_file_is_one_line(capsys, tmp_path):
    p = tmp_path / "deep.toml"
    p.write_text("A = " + "[" * 5000 + "]" * 5000 + "\n")
    _refused(capsys, ["observer", "--system", p], str(p), "nested")


def _system(tmp_path, n=2, name=None) -> Path:
    A = np.eye(n, k=1).tolist()
    B = [[0.0]] * (n - 1) + [[1.0]]
    C = [[1.0] + [0.0] * (n - 1)]
    data = {"A": A, "B": B, "C": C, "D": [[0.0]]}
    if name is not None:
        data["name"] = name
    p = tmp_path / "sys.json"
    p.write_text(json.dumps(data))
    return p


def test_T07_a_500_character_observer_name_is_one_line(capsys, tmp_path):
    _refused(capsys, ["observer", "--system", _system(tmp_path, name="a" * 500), "--out",
                      tmp_path / "o"], "name", "64")


def test_T08_observer_delay_beyond_n_is_one_line(capsys, tmp_path):
    _timed_refusal(capsys, ["observer", "--system", _system(tmp_path), "--delay", "100000"],
                   "--delay", seconds=5)


def test_T09_excite_harmonics_over_the_limit_is_one_line(capsys, tmp_path):
    """Before: a traceback after 21.6 CPU-s."""
    _timed_refusal(capsys, ["identify", "planar_2link", "--excite", "--out",
                            tmp_path / "t.csv", "--harmonics", "100000"],
                   "--harmonics", "SOFTGEN_MAX_HARMONICS", seconds=5)


@pytest.mark.parametrize("case, args", [("T10", ["--period", "1e9"]),
                                        ("T11", ["--periods", "1000000"])])
def test_T10_T11_excite_trajectory_size_is_checked_first(capsys, tmp_path, case, args):
    """Before: the optimisation ran, then a 7 TiB (74 GiB) allocation traceback."""
    _timed_refusal(capsys, ["identify", "planar_2link", "--excite", "--out",
                            tmp_path / "t.csv", *args], "SOFTGEN_MAX_LOG_ROWS", seconds=5)


@pytest.mark.compiler
def test_T12_full_build_directory_is_one_line(tmp_path, monkeypatch):
    """Before: ENOSPC while the library's record was written was a traceback."""
    from softgen.bundles.bundle import generate
    from softgen.codegen.build import ensure_library
    from softgen.core.errors import SoftgenError
    bundle = generate("pendulum_1link", tmp_path / "g")
    fault_disk.install(bundle / "build", 10, monkeypatch)
    with pytest.raises(SoftgenError, match="No space left") as exc:
        ensure_library(bundle, force=True)
    assert "\n" not in str(exc.value).splitlines()[0]


def test_T13_generate_out_on_a_full_disk_is_one_line(capsys, tmp_path, monkeypatch):
    fault_disk.install(tmp_path, 3_000, monkeypatch)
    _refused(capsys, ["generate", "pendulum_1link", "--out", tmp_path / "g", "--no-build",
                      "--force"], "No space left", str(tmp_path))


def test_T14_log_of_nul_bytes_is_one_readable_line(capsys, tmp_path):
    log = tmp_path / "nul.csv"
    log.write_bytes(b"\0" * 3000)
    _refused(capsys, ["estimate", "pendulum_qbmove", "--log", log, "--method",
                      "noninvasive", "--out", tmp_path / "e.csv"], str(log), "binary")


def test_T15_observer_dt_out_of_range_is_one_line(capsys):
    """Before: an OverflowError traceback from ``observer --model ... --dt 1e300``."""
    _refused(capsys, ["observer", "--model", "planar_2link", "--dt", "1e300"], "--dt")


def test_E01_an_output_that_is_not_a_regular_file_is_refused(capsys, tmp_path):
    """Found on the way (not among the 60): ``estimate --out /dev/full --force`` as root
    renamed a regular file over the device node. Here a FIFO stands for it."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    _refused(capsys, ["estimate", "pendulum_qbmove", "--log", _sample_log(), "--method",
                      "noninvasive", "--out", fifo, "--force"], "not a regular file")
    assert fifo.is_fifo()


# == M: minutes instead of a refusal ==========================================================

@pytest.mark.parametrize("case, argv", [
    ("M01", lambda d: ["check", _pcc(d, 40)]),
    ("M02", lambda d: ["export", _planar_chain(d, 60), "--out", d / "p"]),
    ("M03", lambda d: ["identify", _planar_chain(d, 60), "--excite", "--out", d / "t.csv"]),
    ("M04", lambda d: ["observer", "--model", _planar_chain(d, 60)]),
    ("M08", lambda d: ["identify", _planar_chain(d, 60), "--log", d / "none.csv"]),
    ("M09", lambda d: ["estimate", _qbmove_chain(d, 60), "--log", d / "none.csv",
                       "--method", "noninvasive", "--out", d / "e.csv"]),
])
def test_M_model_size_is_checked_by_every_verb(capsys, tmp_path, monkeypatch, case, argv):
    """Before: minutes of silent derivation (check 180 CPU-s, the others over 60 s)."""
    monkeypatch.delenv("SOFTGEN_MAX_EXPRESSION_SIZE", raising=False)
    _timed_refusal(capsys, argv(tmp_path), "SOFTGEN_MAX_EXPRESSION_SIZE")


def test_M05_observer_system_size_is_checked(capsys, tmp_path):
    """Before: 82 CPU-s without output for 1,000 states."""
    _timed_refusal(capsys, ["observer", "--system", _system(tmp_path, n=1000)],
                   "1,000 states", "SOFTGEN_MAX_OBSERVER_STATES", seconds=8)


def _long_log(path: Path, rows: int) -> Path:
    """A log of ``rows`` rows written fast (the size check reads little of it)."""
    chunk = 100_000
    with open(path, "w") as fh:
        fh.write("t,q1,qa1,qb1\n")
        for start in range(0, rows, chunk):
            k = np.arange(start, min(rows, start + chunk))
            t = k * 0.005
            block = np.column_stack([t, 0.1 * np.sin(t), 0.05 * np.sin(t), 0.15 * np.sin(t)])
            fh.write("\n".join(",".join(f"{v:.9g}" for v in r) for r in block) + "\n")
    return path


@pytest.mark.slow            # writes a 1e7-row (~400 MB) log
def test_M06_a_huge_log_is_refused_quickly(capsys, tmp_path):
    """Before: 90 CPU-s and 6.8 GB with no progress."""
    log = _long_log(tmp_path / "huge.csv", 10_000_000)
    _timed_refusal(capsys, ["estimate", "pendulum_qbmove", "--log", log, "--method",
                            "noninvasive", "--out", tmp_path / "e.csv"],
                   "SOFTGEN_MAX_LOG_ROWS")


def test_M06_the_row_limit_holds_when_streaming(capsys, tmp_path, monkeypatch):
    """The same limit, lowered, on a log whose size does not give it away (a pipe)."""
    monkeypatch.setenv("SOFTGEN_MAX_LOG_ROWS", "5000")
    log = _long_log(tmp_path / "l.csv", 6000)
    _timed_refusal(capsys, ["estimate", "pendulum_qbmove", "--log", log, "--method",
                            "noninvasive", "--out", tmp_path / "e.csv"],
                   "5,000", "SOFTGEN_MAX_LOG_ROWS")


@pytest.mark.parametrize("argv", [
    ["estimate", "pendulum_qbmove", "--method", "noninvasive"],
    ["identify", "planar_2link"],
    ["identify", "--actuator", "mckibben"]])
def test_M07_a_log_of_dev_zero_ends_quickly(capsys, tmp_path, argv):
    """Before: read until killed (``estimate``; ``identify`` the same)."""
    if not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero")
    _timed_refusal(capsys, [*argv, "--log", "/dev/zero", "--out", tmp_path / "o.csv"],
                   "/dev/zero", seconds=5)


def test_M10_excite_harmonics_1000_is_refused(capsys, tmp_path):
    _timed_refusal(capsys, ["identify", "planar_2link", "--excite", "--out", tmp_path / "t.csv",
                            "--harmonics", "1000"], "--harmonics", seconds=5)


def test_M11_identify_log_rows_are_limited(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTGEN_MAX_LOG_ROWS", "1000")
    log = tmp_path / "l.csv"
    t = np.arange(2000) * 1e-3
    np.savetxt(log, np.column_stack([t, np.sin(t), np.cos(t), t, t]), delimiter=",",
               header="t,q1,q2,tau1,tau2", comments="")
    _timed_refusal(capsys, ["identify", "planar_2link", "--log", log, "--out",
                            tmp_path / "o.toml"], "SOFTGEN_MAX_LOG_ROWS")


# == U: unclear ===============================================================================

@pytest.mark.compiler
def test_U01_export_build_with_a_relative_out(capsys, tmp_path, monkeypatch):
    """Before: make ran with cwd=out *and* -C out, so any relative --out failed."""
    monkeypatch.chdir(tmp_path)
    st, out, err = _cli(capsys, ["export", "pendulum_1link", "--out", "rel/proj", "--build"])
    assert st == 0, err
    assert (tmp_path / "rel" / "proj" / "pendulum_1link_example").is_file()


@pytest.mark.compiler
def test_U02_export_build_shows_makes_error(capsys, tmp_path, monkeypatch):
    fake = tmp_path / "badcc"
    fake.write_text("#!/bin/sh\necho 'badcc: error: unrecognized thing' >&2\nexit 1\n")
    fake.chmod(0o755)
    _refused(capsys, ["export", "pendulum_1link", "--out", tmp_path / "p", "--build",
                      "--cc", fake], "unrecognized thing")


def _flat_log(path: Path, value: float) -> Path:
    t = np.arange(4000) * 0.005
    np.savetxt(path, np.column_stack([t, 0 * t + value, 0 * t + value / 3,
                                      0 * t + value / 2]), delimiter=",",
               header="t,q1,qa1,qb1", comments="", fmt="%.9g")
    return path


@pytest.mark.parametrize("case, value", [("U03", 0.0), ("U04", 0.3)])
def test_U03_U04_flat_logs_say_too_little_excitation(capsys, tmp_path, case, value):
    """Before: "quantised encoders? try --lowpass" (all-zero) or "not converged"."""
    log = _flat_log(tmp_path / "flat.csv", value)
    line = _refused(capsys, ["estimate", "pendulum_qbmove", "--log", log, "--method",
                             "noninvasive", "--out", tmp_path / "e.csv"],
                    "too little excitation")
    assert "lowpass" not in line


def test_U05_sweep_resume_on_a_missing_out_is_refused(capsys, tmp_path):
    _refused(capsys, ["sweep", "ch10-pneumatic-adaptive", "--vary", "kd=uniform(1,2)",
                      "--samples", "2", "--resume", "--out", tmp_path / "none"], "--resume")
    assert not (tmp_path / "none").exists()


@pytest.mark.slow        # one quick sample of the experiment
def test_U06_metrics_matching_nothing_is_an_error(capsys, tmp_path):
    _refused(capsys, ["sweep", "rigid-2link-adaptive", "--vary", "kd=uniform(1,2)",
                      "--samples", "1", "--quick", "--metrics", "zzz*", "--workers", "1",
                      "--out", tmp_path / "s"], "zzz*", status=(1, 2))


@pytest.mark.compiler
def test_U07_generate_compile_failure_names_the_compiler_error(capsys, tmp_path,
                                                               monkeypatch):
    fake = tmp_path / "badcc"
    fake.write_text("#!/bin/sh\necho 'x.c:1:1: error: expected identifier' >&2\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv("CC", str(fake))
    _refused(capsys, ["generate", "pendulum_1link", "--out", tmp_path / "g", "--force"],
             "expected identifier")


def test_U08_identify_log_sampled_in_ms_names_the_unit(capsys, tmp_path, id_logs):
    line = _refused(capsys, ["identify", "planar_2link", "--log", id_logs["ms"], "--out",
                             tmp_path / "o.toml"], "milliseconds")
    assert "2 s" in line


def test_U09_excite_negative_maxiter_is_refused(capsys, tmp_path):
    _refused(capsys, ["identify", "planar_2link", "--excite", "--out", tmp_path / "t.csv",
                      "--maxiter", "-5"], "--maxiter")


def test_U10_sigma_negative_after_a_lowpass_does_not_say_try_lowpass(capsys, tmp_path):
    """A warning's hint must fit the run: after a low-pass, 'try --lowpass' misleads."""
    from softgen.app.estimate import plausibility
    import types
    t = np.arange(1000) * 0.005
    result = types.SimpleNamespace(sigma_hat=-np.ones((1000, 1)), updating=np.ones((1000, 1)),
                                   theta={})
    lines = plausibility(t, result, None, lowpass=1.0)
    assert lines and not any("--lowpass" in x for x in lines)
    lines = plausibility(t, result, None, lowpass=None)
    assert any("--lowpass" in x for x in lines)


def test_U11_a_file_that_is_no_csv_gets_a_readable_line(capsys, tmp_path):
    """Before: ``identify --actuator sinh`` on a URDF printed its whole first line as the
    "found" columns: one line of 35,000 characters."""
    p = tmp_path / "r.urdf"
    p.write_text('<robot name="r">' + "<a>" * 5000 + "</a>" * 5000 + "</robot>\n")
    line = _refused(capsys, ["identify", "--actuator", "sinh", "--log", p], "missing column")
    assert len(line) < 400


def test_observer_names_follow_the_model_name_limit(capsys, tmp_path):
    _refused(capsys, ["observer", "--system", _system(tmp_path, name="b" * 70), "--out",
                      tmp_path / "o"], "name", "64")


def test_law_constants_are_folded_as_numpy_computes_them():
    """Property: the checker's folded value of a random constant expression is numpy's
    (seeded), and a law is refused exactly when a folded exponent or constant is out of
    bounds; the bound is the model file's (one limit for every number of a model)."""
    from softgen.core.errors import ModelError
    from softgen.modelfile import expr
    from softgen.modelfile.model import MAX_MAGNITUDE
    assert expr.MAX_CONSTANT == MAX_MAGNITUDE
    rng = np.random.default_rng(3636)
    ops = ["+", "-", "*", "/", "**"]
    for _ in range(300):
        a, b, c = (float(x) for x in rng.integers(-9, 10, 3))
        o1, o2 = rng.choice(ops, 2)
        text = f"(({a:g}){o1}({b:g})){o2}({c:g})"
        with np.errstate(all="ignore"):
            x = np.float64(a)
            ref = eval(f"(x{o1}np.float64({b})){o2}np.float64({c})", {"np": np, "x": x})
        node = __import__("ast").parse(text, mode="eval").body
        got = expr._folded(node, lambda m: AssertionError(m))
        assert (got == ref) or (math.isnan(got) and np.isnan(ref)) or \
            (math.isinf(got) and np.isinf(ref)), (text, got, ref)
        law = f"k*phi**({text})"
        ok = math.isfinite(ref) and abs(ref) <= expr.MAX_EXPONENT
        try:
            expr.parse_law(law, ("phi", "k"), "t")
            accepted = True
        except ModelError:
            accepted = False
        assert accepted == ok or (ok and not accepted and abs(ref) > expr.MAX_CONSTANT), law
