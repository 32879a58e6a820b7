"""``softgen observer``: a delayed UIO for a user's system (thesis eq. 5.4, Props. 7-9)."""
from __future__ import annotations

import hashlib
import json
import re

import casadi as ca
import numpy as np
import pytest

from softgen.app.observer import (check_system, linearise_model, observer_function,
                                  read_system)
from softgen.cli import main
from softgen.codegen.build import compile_shared, find_compiler
from softgen.estimation.uio import _prop8


def _toml_matrix(M) -> str:
    return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]"
                           for row in np.atleast_2d(M)) + "]"


def _random_system(seed: int):
    """n = 4, one unknown and one known input, p = 3 outputs, D = 0: for generic
    matrices CB has full column rank and there are no invariant zeros (p > m), so the
    smallest delay is 1."""
    rng = np.random.default_rng(seed)
    n, p = 4, 3
    A = rng.normal(size=(n, n))
    A *= 0.95 / max(abs(np.linalg.eigvals(A)))       # a stable plant: bounded states
    B = rng.normal(size=(n, 2))
    C = rng.normal(size=(p, n))
    D = np.zeros((p, 2))
    return A, B, C, D


def _write_toml(path, A, B, C, D, **extra):
    lines = [f"{k} = {_toml_matrix(v)}" for k, v in (("A", A), ("B", B), ("C", C), ("D", D))]
    lines += [f"{k} = {json.dumps(v)}" for k, v in extra.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def _simulate(A, B, C, D, U, x0):
    X = [x0]
    for u in U[:-1]:
        X.append(A @ X[-1] + B @ u)
    X = np.array(X)
    return X, X @ C.T + U @ D.T


def _run(f, n, p, L, Y, V=None):
    """Feed the step forward windows; row k of the result is Û_k."""
    x = np.zeros(n)
    U_hat = []
    for k in range(len(Y) - L):
        args = [x, Y[k:k + L + 1].reshape(-1)]
        if V is not None:
            args.append(V[k:k + L + 1].reshape(-1))
        x_next, u = f(*args)
        x = np.array(x_next).ravel()
        U_hat.append(np.array(u).ravel())
    return np.array(U_hat)


@pytest.mark.parametrize("seed", range(4))
def test_reconstructs_a_known_unknown_input(tmp_path, seed):
    A, B, C, D = _random_system(seed)
    sysf = _write_toml(tmp_path / "plant.toml", A, B, C, D, unknown=[0], dt=0.01)
    system = read_system(sysf)
    chk = check_system(system, 1)
    assert chk.exists and chk.smallest == 1, [c.line() for c in chk.conditions]
    uio, f = observer_function(system, 1)
    K = 60
    t = np.arange(K)
    rng = np.random.default_rng(100 + seed)
    U = np.column_stack([np.sin(0.3 * t) + 0.5 * np.cos(0.07 * t),     # the unknown input
                         rng.normal(size=K)])                          # a known input
    X, Y = _simulate(A, B, C, D, U, rng.normal(size=4))
    U_hat = _run(f, 4, 3, 1, Y, U[:, 1:])
    # deadbeat: exact once the initial error has gone (n samples), up to rounding
    err = np.abs(U_hat[4:, 0] - U[4:K - 1, 0])
    assert err.max() < 1e-8 * (1 + np.abs(U[:, 0]).max()), err.max()


def test_json_file_gives_the_same_observer(tmp_path):
    A, B, C, D = _random_system(7)
    t = _write_toml(tmp_path / "p.toml", A, B, C, D, unknown=[0], name="plant7")
    j = tmp_path / "p.json"
    j.write_text(json.dumps({"A": A.tolist(), "B": B.tolist(), "C": C.tolist(),
                             "D": D.tolist(), "unknown": [0], "name": "plant7"}))
    (u1, _), (u2, _) = (observer_function(read_system(p), 1) for p in (t, j))
    np.testing.assert_array_equal(u1.F, u2.F)
    np.testing.assert_array_equal(u1.E, u2.E)


@pytest.mark.skipif(find_compiler() is None, reason="no C compiler")
def test_compiled_c_step_equals_the_casadi_function(tmp_path, capsys):
    A, B, C, D = _random_system(3)
    sysf = _write_toml(tmp_path / "plant3.toml", A, B, C, D, unknown=[0], dt=0.01)
    out = tmp_path / "obs"
    assert main(["observer", "--system", str(sysf), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "delay L = 1" in text and "Prop. 7 (eq. 5.3)" in text
    man = json.loads((out / "manifest.json").read_text())
    ob = man["observer"]
    assert ob["delay"] == 1 and ob["dimensions"] == {"n": 4, "m_unknown": 1, "m_known": 1,
                                                     "p": 3}
    assert all(c["holds"] for c in ob["conditions"])
    np.testing.assert_array_equal(np.array(ob["matrices"]["A"]), A)   # repr round-trips
    assert man["header_sha256"] == hashlib.sha256((out / "plant3.h").read_bytes()).hexdigest()
    lib = tmp_path / "libplant3.so"
    compile_shared(out / "plant3.c", lib)
    f_c = ca.external("plant3_step", str(lib))
    _, f = observer_function(read_system(sysf), 1)
    rng = np.random.default_rng(5)
    for _ in range(20):
        args = [rng.normal(size=4), rng.normal(size=6), rng.normal(size=2)]
        for a, b in zip(f(*args), f_c(*args)):
            np.testing.assert_allclose(np.array(b), np.array(a), rtol=1e-13, atol=1e-13)
    # refuses to overwrite without --force, then overwrites with it
    assert main(["observer", "--system", str(sysf), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists; add --force" in err[0]
    assert main(["observer", "--system", str(sysf), "--out", str(out), "--force"]) == 0


def test_no_observer_at_delay_0_but_at_delay_1(tmp_path, capsys):
    # x+ = 0.5 x + u, y = x: u shows in y one sample later (H^0 = D = 0, H^1 has rank 1)
    f = _write_toml(tmp_path / "lag.toml", [[0.5]], [[1.0]], [[1.0]], [[0.0]])
    assert main(["observer", "--system", str(f), "--delay", "0"]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1
    assert "no delayed UIO with delay 0" in err[0]
    assert "rank H^0 = m + rank H^-1: 0 ≠ 1" in err[0]
    assert "smallest delay with an observer is 1" in err[0]
    assert main(["observer", "--system", str(f), "--delay", "1"]) == 0
    assert "rank H^1 = m + rank H^0: 1 = 1 (holds)" in capsys.readouterr().out


def test_no_delay_at_all_is_said(tmp_path, capsys):
    # an invariant zero at 0.35 (test_uio's example): invertible but not strongly observable
    f = _write_toml(tmp_path / "zero.toml", [[0.5, 0.0], [0.0, 0.2]], [[1.0], [1.0]],
                    [[1.0, 1.0]], [[0.0]])
    assert main(["observer", "--system", str(f), "--delay", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Prop. 8" in err[0] and "no delay L ≤ n = 2 gives one" in err[0]


BAD = [
    ("missing", "A = [[1.0]]\nB = [[1.0]]\nC = [[1.0]]\n", r"D: missing required key .*\(p, m\)"),
    ("shape", "A = [[1.0, 0.0], [0.0, 1.0]]\nB = [[1.0], [0.0]]\nC = [[1.0, 0.0, 0.0]]\n"
              "D = [[0.0]]\n", r"C: expected .* shape \(p, n\) = \(p, 2\) .* got shape \(1, 3\)"),
    ("square", "A = [[1.0, 0.0]]\nB = [[1.0]]\nC = [[1.0, 0.0]]\nD = [[0.0]]\n",
     r"A: expected a square 2-D array of shape \(n, n\), got shape \(1, 2\)"),
    ("text", "A = [[1.0]]\nB = [[\"x\"]]\nC = [[1.0]]\nD = [[0.0]]\n",
     r"B\[0\]\[0\]: expected a finite number \(B of shape \(n, m\) = \(1, m\)"),
    ("vector", "A = [[1.0]]\nB = [1.0]\nC = [[1.0]]\nD = [[0.0]]\n",
     r"B: expected a 2-D array .* got \[1.0\]"),
    ("singular", "A = [[1.0, 0.1], [0.0, 1.0]]\nB = [[0.0, 0.0], [1.0, 2.0]]\n"
                 "C = [[1.0, 0.0]]\nD = [[0.0, 0.0]]\n",
     r"B, D: the unknown-input columns \[0, 1\] of \[B; D\] are dependent \(rank 1 < 2\)"),
    ("dt", "time = \"continuous\"\nA = [[0.0]]\nB = [[1.0]]\nC = [[1.0]]\nD = [[0.0]]\n",
     r"dt: missing required key"),
    ("unknown", "A = [[1.0]]\nB = [[1.0]]\nC = [[1.0]]\nD = [[0.0]]\nunknown = [3]\n",
     r"unknown: expected distinct 0-based column indices of B in 0..0"),
    ("typo", "A = [[1.0]]\nB = [[1.0]]\nC = [[1.0]]\nD = [[0.0]]\nunkown = [0]\n",
     r"unkown: unknown key"),
    ("toml", "A = [[1.0]\n", r"not valid TOML"),
]


@pytest.mark.parametrize("case, text, pattern", BAD, ids=[b[0] for b in BAD])
def test_bad_files_give_one_line_naming_the_key(tmp_path, capsys, case, text, pattern):
    f = tmp_path / f"{case}.toml"
    f.write_text(text)
    assert main(["observer", "--system", str(f)]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1, cap.err
    assert err[0].startswith(f"softgen: error: {f}: ")
    assert re.search(pattern, err[0]), err[0]
    assert "Traceback" not in cap.err


def test_continuous_system_is_discretised(tmp_path):
    # Theorem 1's linear part, Euler: the printed E of eq. 6.2
    T, inertia, beta = 1e-2, 0.015, 1e-5
    f = _write_toml(tmp_path / "thm1.toml", [[0.0, 1.0], [0.0, -beta / inertia]],
                    [[0.0], [1 / inertia]], [[1.0, 0.0]], [[0.0]], time="continuous", dt=T)
    system = read_system(f)
    uio, _ = observer_function(system, 2)
    np.testing.assert_allclose(uio.E, [[1.0, T], [-1 / T, -1.0]], atol=1e-9)


def test_model_linearisation_with_operating_point_and_known_inputs():
    """A McKibben arm linearised about a non-equilibrium point (angles from the
    horizontal): the observer, fed absolute positions and pressures, recovers an external
    joint torque on the linearised plant, offset included."""
    system = linearise_model("arm_2link_pneumatic", q0="0.3,-0.2")
    assert system.offset is not None                   # gravity: not an equilibrium
    chk = check_system(system, 2)
    assert chk.exists and chk.smallest == 2, [c.line() for c in chk.conditions]
    _, f = observer_function(system, 2)
    Bu, _, Bv, _ = system.split()
    rng = np.random.default_rng(11)
    # Short run: the Euler-sampled arm is unstable (|eig A| up to 1.71 at dt = 0.01,
    # the muscles' stiffness), so the state and its rounding grow by 1.7 per sample.
    K = 16
    W = 0.05 * np.column_stack([np.sin(0.2 * np.arange(K)), np.cos(0.13 * np.arange(K))])
    P = system.v0 + 1e4 * rng.normal(size=(K, 4))      # pressures around the point
    x = system.x0.copy()
    Y = []
    for k in range(K):
        Y.append(system.C @ x)
        dv = np.concatenate([P[k] - system.v0, [1.0]])
        x = system.x0 + system.A @ (x - system.x0) + Bu @ W[k] + Bv @ dv
    U_hat = _run(f, 4, 2, 2, np.array(Y), P)
    err = np.abs(U_hat[4:] - W[4:K - 2])
    assert err.max() < 1e-8, err.max()


def test_model_linearisation_reports_rk4_sampling_zero(capsys):
    # RK4 sampling of a relative-degree-2 plant has a zero near -1: not strongly observable
    assert main(["observer", "--model", "planar_2link_mckibben", "--integrator", "rk4"]) == 2
    cap = capsys.readouterr()
    assert "Prop. 8" in cap.out and len(cap.err.strip().splitlines()) == 1


def test_qbmove_linearisation_is_strongly_observable_at_the_shortest_window(capsys):
    """Link and motor positions measured, an external torque on the link unknown: the
    system is strongly observable, and Prop. 8 is shown on the shortest window. At L = n
    the rank tolerance (∝ ‖A‖^n, ‖A‖ ≈ 88 for the stiff Euler-sampled motor) would
    count genuine singular values as rounding noise and report a failure."""
    assert main(["observer", "--model", "pendulum_qbmove", "--dt", "0.001"]) == 0
    out = capsys.readouterr().out
    assert "delay L = 2" in out
    assert "Prop. 8: rank [O^1, H^1] = n + rank H^1: 6 = 6 (holds)" in out
    system = linearise_model("pendulum_qbmove", dt=1e-3)
    Bu, Du, _, _ = system.split()
    assert not _prop8(system.A, Bu, system.C, Du, 6, None)[0]   # the L = n test's verdict
