"""``softgen estimate``: CSV log in, estimates CSV out, one-line errors on bad logs.

The logs are smooth invented signals, not simulations: these tests check the IO
path and the error messages, not the accuracy of the estimators (thesis chapters
6 and 7; the experiments check that).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from softgen.cli import main
from softgen.core.errors import SoftgenError
from softgen.estimation.csvlog import LogError, read_log

# model, --method, estimator method, sample time, delay L, torque column prefix
CASES = [
    ("pendulum_qbmove", "noninvasive", "noninvasive", 5e-3, 3, "rotatum"),
    ("pendulum_qbmove", "invasive", "electric", 1e-3, 2, "tau"),
    ("pendulum_1link", "invasive", "pneumatic", 1e-2, 2, "tau"),
    ("planar_2link", "noninvasive", "noninvasive", 5e-3, 3, "rotatum"),
]
JOINTS = {"pendulum_qbmove": 1, "pendulum_1link": 1, "planar_2link": 2}


def _signals(model: str, method: str, t: np.ndarray) -> dict[str, np.ndarray]:
    """Measurement columns in the estimator's order (``est.measurements``)."""
    if model == "pendulum_1link":
        return {"q1": 0.2 * np.sin(t), "p1a": 2e5 + 5e4 * np.sin(t),
                "p1b": 2e5 - 5e4 * np.sin(t)}
    n = JOINTS[model]
    q = [0.2 * np.sin(t + i) for i in range(n)]
    qa = [q[i] - 0.4 - 0.05 * np.sin(2 * t + i) for i in range(n)]
    qb = [q[i] + 0.4 + 0.05 * np.sin(3 * t + i) for i in range(n)]
    groups = {"q": q, "qa": qa, "qb": qb}
    if method == "electric":
        groups["tau_a"] = [0.0227 * np.sinh(6.7328 * (q[i] - qa[i])) for i in range(n)]
        groups["tau_b"] = [0.0216 * np.sinh(6.9602 * (q[i] - qb[i])) for i in range(n)]
    return {f"{g}{i + 1}": v[i] for g, v in groups.items() for i in range(n)}


def _write_log(path: Path, model="pendulum_qbmove", method="noninvasive", dt=5e-3, K=400,
               time_name="t", extra=False, edit=None) -> Path:
    """A log of K samples; ``edit(rows)`` may change the string cells before writing."""
    t = np.arange(K) * dt
    cols = _signals(model, method, t)
    header = [time_name, *cols] + (["note"] if extra else [])
    rows = [[repr(float(t[k])), *(repr(float(v[k])) for v in cols.values())]
            + (["ok, fine"] if extra else []) for k in range(K)]
    if edit is not None:
        edit(header, rows)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softgen: error: "), err
    return err[0]


@pytest.mark.parametrize("model,flag,method,dt,L,torque", CASES)
def test_estimate_writes_one_row_per_sample(capsys, tmp_path, model, flag, method, dt, L,
                                            torque):
    K = 300
    log = _write_log(tmp_path / "run.csv", model, method, dt, K)
    assert main(["estimate", model, "--log", str(log), "--method", flag]) == 0
    out = tmp_path / "run_estimate.csv"
    summary = capsys.readouterr().out.strip().splitlines()
    assert len(summary) == 1
    assert f"{K} samples" in summary[0] and f"method {method}" in summary[0]
    assert f"delay {L}" in summary[0] and f"dt {dt:.9g} s" in summary[0]
    assert str(out) in summary[0]

    with out.open(newline="") as fh:
        rows = list(csv.reader(fh))
    n = JOINTS[model]
    assert rows[0] == ["t"] + [f"{c}{i + 1}" for c in ("sigma_hat", f"{torque}_hat",
                                                       f"{torque}_uio") for i in range(n)]
    body = rows[1:]
    assert len(body) == K
    assert [float(r[0]) for r in body] == pytest.approx(np.arange(K) * dt, abs=0)
    for r in body[20:K - L]:                    # after the observer transient
        assert all(math.isfinite(float(c)) for c in r), r
    for r in body[K - L:]:                      # no estimate yet: empty, not "nan"
        assert r[1:] == [""] * 3 * n


def test_time_column_extra_columns_out_and_dt(capsys, tmp_path):
    log = _write_log(tmp_path / "a.csv", time_name="time", extra=True, K=50)
    out = tmp_path / "sub.csv"
    assert main(["estimate", "pendulum_qbmove", "--log", str(log), "--method",
                 "noninvasive", "--out", str(out), "--dt", "0.005", "--powers", "0,2",
                 "--p0", "1e6"]) == 0
    assert out.exists() and not (tmp_path / "a_estimate.csv").exists()
    assert len(out.read_text().splitlines()) == 51


def test_read_log_returns_the_named_columns_in_order(tmp_path):
    log = _write_log(tmp_path / "a.csv", K=10)
    t, Y, dt = read_log(log, ["qb1", "q1"])
    assert Y.shape == (10, 2) and dt == pytest.approx(5e-3, rel=1e-12)
    assert Y[3, 1] == pytest.approx(0.2 * np.sin(t[3]))
    with pytest.raises(LogError, match="12 "):
        read_log(log, ["q1"], min_rows=12)
    assert issubclass(LogError, ValueError) and issubclass(LogError, SoftgenError)


def _drop_qb1(header, rows):
    i = header.index("qb1")
    del header[i]
    for r in rows:
        del r[i]


def _irregular(header, rows):
    rows[50][0] = repr(float(rows[50][0]) + 1e-4)


def _non_numeric(header, rows):
    rows[7][header.index("qa1")] = "abc"


def _empty_cell(header, rows):
    rows[7][header.index("qa1")] = ""


def _nan(header, rows):
    rows[9][header.index("q1")] = "nan"


def _inf(header, rows):
    rows[9][header.index("q1")] = "-inf"


def _backwards(header, rows):
    rows[30][0], rows[31][0] = rows[31][0], rows[30][0]


def _no_time(header, rows):
    header[0] = "stamp"


def _ragged(header, rows):
    rows[4].append("1.0")


@pytest.mark.parametrize("edit,match", [
    (_drop_qb1, "missing column(s) qb1; found t, q1, qa1"),
    (_no_time, "missing column(s) t (or time); found stamp"),
    (_irregular, "row 52: irregular sampling, time step 0.0051 s from row 51 against the "
                 "median step 0.005 s"),
    (_non_numeric, "row 9, column 'qa1': not a number: 'abc'"),
    (_empty_cell, "row 9, column 'qa1': empty cell"),
    (_nan, "row 11, column 'q1': non-finite value 'nan'"),
    (_inf, "row 11, column 'q1': non-finite value '-inf'"),
    (_backwards, "row 33: time 0.15 s is not after 0.155 s of row 32"),
    (_ragged, "row 6: 5 cells, the header has 4"),
])
def test_bad_log_exit_2_names_file_row_column(capsys, tmp_path, edit, match):
    log = _write_log(tmp_path / "bad.csv", K=100, edit=edit)
    assert main(["estimate", "pendulum_qbmove", "--log", str(log), "--method",
                 "noninvasive"]) == 2
    line = _one_error_line(capsys)
    assert "bad.csv" in line and match in line, line
    assert not (tmp_path / "bad_estimate.csv").exists()


@pytest.mark.parametrize("argv,match", [
    (["estimate", "no_such_model", "--log", "{log}"], "unknown model 'no_such_model'"),
    (["estimate", "pendulum_1link", "--log", "{log}", "--method", "noninvasive"],
     "model 'pendulum_1link' has actuator type mckibben; --method noninvasive needs "
     "qbmove actuators"),
    (["estimate", "{planar3}", "--log", "{log}"],
     "model 'planar3' has actuator type none; --method invasive needs McKibben"),
    (["estimate", "pendulum_qbmove", "--log", "{log}", "--method", "noninvasive",
      "--dt", "0.01"], "--dt 0.01 s disagrees with the median time step 0.005 s"),
    (["estimate", "pendulum_qbmove", "--log", "{tmp}/none.csv"], "no such log file"),
    (["estimate", "pendulum_qbmove", "--log", "{log}", "--out", "{log}"], "is the log itself"),
    (["estimate", "pendulum_qbmove", "--log", "{log}", "--powers", "1,x"],
     "--powers: expected comma-separated integers"),
    (["estimate", "pendulum_qbmove", "--log", "{log}", "--powers", "1,2"],
     "expected odd powers"),
    (["estimate", "pendulum_qbmove", "--log", "{log}", "--p0", "-1"],
     "--p0: expected a positive number"),
])
def test_bad_arguments_exit_2_with_one_line(capsys, tmp_path, extra_models, argv, match):
    log = _write_log(tmp_path / "log.csv", K=50)
    argv = [a.replace("{log}", str(log)).replace("{tmp}", str(tmp_path))
            .replace("{planar3}", str(extra_models["planar3"].path)) for a in argv]
    assert main(argv) == 2
    assert match in _one_error_line(capsys)


def test_too_few_rows_and_empty_file(capsys, tmp_path):
    log = _write_log(tmp_path / "short.csv", K=4)      # noninvasive: L = 3 needs 5
    assert main(["estimate", "pendulum_qbmove", "--log", str(log), "--method",
                 "noninvasive"]) == 2
    assert "short.csv: 4 data row(s); the estimator needs at least 5" in \
        _one_error_line(capsys)
    empty = tmp_path / "empty.csv"
    empty.write_text("\n")
    assert main(["estimate", "pendulum_qbmove", "--log", str(empty)]) == 2
    assert "empty.csv: empty file" in _one_error_line(capsys)


def test_missing_columns_listed_in_one_message(capsys, tmp_path):
    log = _write_log(tmp_path / "one_joint.csv", K=50)     # pendulum_qbmove's columns
    assert main(["estimate", "planar_2link", "--log", str(log), "--method",
                 "noninvasive"]) == 2
    assert ("one_joint.csv: missing column(s) q2, qa2, qb2; found t, q1, qa1, qb1"
            in _one_error_line(capsys))
