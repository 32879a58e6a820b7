"""``softgen identify``: parameters recovered from simulated noisy, quantised logs.

Logs are made by the model's own inverse dynamics (``<model>_inverse_dynamics``,
computed directly, not through the regressor) along Fourier excitation
trajectories, plus viscous and Coulomb friction; τ gets Gaussian noise and q is
quantised like an encoder. The identified parameters must hold the truth within
3 σ of their own reported standard deviations.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

import softgen
from softgen.app.identify import identify_model
from softgen.app.identify.actuator import fit_mckibben, identify_actuator, rmsre, sinh_model
from softgen.cli import main
from softgen.app.identify.modelfile import model_tables, to_toml
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model
from softgen.studies.excitation import (FourierTrajectory, IdentificationRegressor,
                                        joint_limits, optimise_excitation, stacked_condition)

ARM3 = """
[model]
name = "arm3"
kind = "planar"
description = "three-link planar arm for identification tests"
base_angle_deg = -90.0

[gravity]
g = 9.81

[[links]]
name = "a"
joint = "revolute"
mass = 1.2
length = 0.4
com = 0.2
inertia = 0.02

[[links]]
name = "b"
joint = "revolute"
mass = 0.8
length = 0.3
com = [0.14, 0.01]
inertia = 0.008

[[links]]
name = "c"
joint = "revolute"
mass = 0.4
length = 0.2
com = 0.09
inertia = 0.002

[parameters]
uncertain = ["mass", "com", "inertia"]
"""


def _write_csv(path, header, table):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in table:
            w.writerow([repr(float(v)) for v in row])
    return path


def simulated_log(path, reg, traj, *, seed, dt=2e-3, duration=20.0, counts=2 ** 16,
                  noise=0.01, current_constant=None):
    """A log of ``traj`` with friction, τ noise and encoder quantisation; the truth."""
    rng = np.random.default_rng(seed)
    n = reg.n
    t = np.arange(int(round(duration / dt))) * dt
    q, qd, qdd = traj.evaluate(t)
    f = reg.dyn.inverse_dynamics_fun().map(t.size)
    tau = np.asarray(f(q.T, qd.T, qd.T, qdd.T)).T
    fv, fc = rng.uniform(0.02, 0.2, n), rng.uniform(0.02, 0.2, n)
    tau = tau + fv * qd + fc * np.sign(qd)
    tau = tau + rng.normal(scale=noise * np.std(tau, axis=0), size=tau.shape)
    step = 2 * math.pi / counts
    qm = np.round(q / step) * step
    if current_constant is None:
        header = ["t"] + [f"q{i + 1}" for i in range(n)] + [f"tau{i + 1}" for i in range(n)]
        table = np.hstack([t[:, None], qm, tau])
    else:
        header = ["t"] + [f"q{i + 1}" for i in range(n)] + [f"i{i + 1}" for i in range(n)]
        table = np.hstack([t[:, None], qm, tau / current_constant])
    _write_csv(path, header, table)
    truth = np.concatenate([reg.dyn.parameter_nominal, fv, fc])
    return path, truth


@pytest.fixture(scope="module")
def arm3(tmp_path_factory):
    d = tmp_path_factory.mktemp("arm3")
    path = d / "arm3.toml"
    path.write_text(ARM3)
    model = load_model(path)
    return model, IdentificationRegressor(model)


@pytest.fixture(scope="module")
def arm3_excitation(arm3):
    """One optimised trajectory shared by the tests (the optimisation is the slow part)."""
    _, reg = arm3
    return optimise_excitation(reg, harmonics=3, period=10.0, seed=1, maxiter=15, grid=60)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_arm_parameters_within_3_sigma(arm3, arm3_excitation, tmp_path, seed):
    model, reg = arm3
    ex = arm3_excitation
    log, truth = simulated_log(tmp_path / "log.csv", reg, ex.trajectory, seed=seed)
    out = tmp_path / "arm3_identified.toml"
    res, written = identify_model(model.path, log, out=out)
    assert written == out and out.is_file()
    assert res.names[:reg.n_base] == reg.base_names
    z = (res.estimate - truth) / res.std
    assert np.all(np.abs(z) < 3.0), dict(zip(res.names, np.round(z, 2)))
    # The 3-sigma bounds are not vacuous: every parameter is known to a few per cent.
    assert res.relative_std.max() < 5.0, dict(zip(res.names, np.round(res.relative_std, 2)))
    assert res.consistent
    assert res.condition < 1e3


def test_identified_model_file_reproduces_the_estimates(arm3, arm3_excitation, tmp_path):
    model, reg = arm3
    ex = arm3_excitation
    log, truth = simulated_log(tmp_path / "log.csv", reg, ex.trajectory, seed=3)
    out = tmp_path / "ident.toml"
    res, _ = identify_model(model.path, log, out=out)
    text = out.read_text()
    assert "physically consistent: yes" in text
    for name in reg.base_names:
        assert name in text
    ident = load_model(out)               # a valid model file
    assert ident.name == "arm3_identified"
    pi = np.asarray(IdentificationRegressor(ident).dyn.physical_to_base_fun(
        np.array([ident.nominal[k] for k in ident.uncertain]))).ravel()
    np.testing.assert_allclose(pi, res.estimate[:reg.n_base], rtol=1e-6,
                               atol=1e-6 * np.abs(res.estimate).max())
    # Viscous friction went into the links' damping.
    for i, link in enumerate(ident.links):
        assert ident.nominal[link.damping] == pytest.approx(res.estimate[reg.n_base + i])
    # Never overwritten without --force; with it, it is.
    assert main(["identify", str(model.path), "--log", str(log), "--out", str(out)]) == 2
    assert main(["identify", str(model.path), "--log", str(log), "--out", str(out),
                 "--force"]) == 0


def test_motor_currents_with_a_torque_constant(arm3, arm3_excitation, tmp_path):
    model, reg = arm3
    ex = arm3_excitation
    a, _ = simulated_log(tmp_path / "tau.csv", reg, ex.trajectory, seed=4)
    b, _ = simulated_log(tmp_path / "cur.csv", reg, ex.trajectory, seed=4,
                         current_constant=0.05)
    ra, _ = identify_model(model.path, a, out=tmp_path / "a.toml")
    rb, _ = identify_model(model.path, b, out=tmp_path / "b.toml", torque_constant=[0.05])
    np.testing.assert_allclose(rb.estimate, ra.estimate, rtol=1e-6, atol=1e-9)
    assert main(["identify", str(model.path), "--log", str(b), "--out",
                 str(tmp_path / "c.toml")]) == 2          # currents without K_t: refused


@pytest.mark.parametrize("bad, fragment", [
    ("missing", "missing column(s) tau2"),
    ("nan", "column 'q1': non-finite value"),
    ("time", "irregular sampling"),
])
def test_bad_log_gives_one_line_naming_the_column(arm3, tmp_path, capsys, bad, fragment):
    model, _ = arm3
    t = np.arange(200) * 1e-3
    cols = {"t": t, "q1": np.sin(t), "q2": np.cos(t), "q3": t, "tau1": t, "tau2": t,
            "tau3": t}
    if bad == "missing":
        del cols["tau2"]
    table = np.column_stack(list(cols.values()))
    if bad == "time":
        table[50, 0] += 3e-4
    path = _write_csv(tmp_path / "bad.csv", list(cols), table)
    if bad == "nan":
        lines = path.read_text().splitlines()
        cells = lines[10].split(",")
        cells[1] = "nan"
        lines[10] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")
    assert main(["identify", str(model.path), "--log", str(path), "--out",
                 str(tmp_path / "o.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err


@pytest.mark.parametrize("seed", range(5))
def test_pseudo_inertia_round_trip_and_log_cholesky_bodies_are_physical(seed):
    from softgen.app.identify.rigid import _from_pseudo_inertia, _pseudo_inertia
    rng = np.random.default_rng(seed)
    # A random physical body: principal moments from positive "second moments" (so the
    # triangle inequality holds), rotated; a random centre of mass.
    d = rng.uniform(0.01, 1.0, 3)
    R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Ic = R @ np.diag([d[1] + d[2], d[0] + d[2], d[0] + d[1]]) @ R.T
    m, c = rng.uniform(0.1, 5), rng.normal(scale=0.2, size=3)
    for about_com in (True, False):
        I = Ic if about_com else Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
        J = _pseudo_inertia(m, c, I, about_com)
        assert np.linalg.eigvalsh(J).min() > 0
        m2, c2, I2 = _from_pseudo_inertia(J, about_com)
        assert m2 == pytest.approx(m) and np.allclose(c2, c) and np.allclose(I2, I)
    # Any upper-triangular U with a positive diagonal gives a consistent body.
    U = np.triu(rng.normal(size=(4, 4)))
    U[np.diag_indices(4)] = np.exp(rng.normal(size=4))
    m3, c3, I3 = _from_pseudo_inertia(U @ U.T, True)
    lam = np.linalg.eigvalsh(I3)
    assert m3 > 0 and lam[0] > 0 and lam[0] + lam[1] >= lam[2] * (1 - 1e-12)


# ----------------------------------------------------------------------------- excitation


def test_excitation_lowers_the_condition_number_within_limits(arm3, arm3_excitation,
                                                              tmp_path):
    model, reg = arm3
    ex = arm3_excitation
    assert ex.condition < ex.initial_condition
    lim = joint_limits(model)
    t = np.linspace(0, ex.trajectory.period, 500)
    q, qd, qdd = ex.trajectory.evaluate(t)
    tol = 0.02      # limits are enforced on the optimisation grid; between points a little more
    assert np.all(q >= lim.lower - tol) and np.all(q <= lim.upper + tol)
    assert np.all(np.abs(qd) <= lim.velocity * (1 + tol))
    # q̇ and q̈ are the exact derivatives of q (central differences agree).
    h = 1e-5
    qp, _, _ = ex.trajectory.evaluate(t + h)
    qm, _, _ = ex.trajectory.evaluate(t - h)
    np.testing.assert_allclose((qp - qm) / (2 * h), qd, atol=1e-6)
    out = tmp_path / "traj.csv"
    assert main(["identify", str(model.path), "--excite", "--out", str(out), "--harmonics",
                 "2", "--period", "5", "--maxiter", "5", "--dt", "0.01"]) == 0
    rows = out.read_text().splitlines()
    assert rows[0] == "t,q1,q2,q3,qd1,qd2,qd3,qdd1,qdd2,qdd3" and len(rows) == 501
    assert main(["identify", str(model.path), "--excite", "--out", str(out)]) == 2


def test_fourier_trajectory_is_periodic():
    rng = np.random.default_rng(0)
    tr = FourierTrajectory(4.0, rng.normal(size=2), rng.normal(size=(2, 3)),
                           rng.normal(size=(2, 3)))
    a = tr.evaluate(np.array([0.3]))
    b = tr.evaluate(np.array([4.3]))
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, atol=1e-12)


def test_condition_number_of_a_still_log_is_infinite(arm3):
    _, reg = arm3
    still = FourierTrajectory(10.0, np.zeros(3), np.zeros((3, 1)), np.zeros((3, 1)))
    assert stacked_condition(reg, still, np.linspace(0, 10, 20)) > 1e10


# ----------------------------------------------------------------------------- actuators

#: Thesis Table 6.1 / NOTES ch6-electric-invasive: joint 1's springs.
THESIS_A, THESIS_K = 6.7328, 0.0227


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sinh_fit_reproduces_the_thesis_k_and_a(tmp_path, seed):
    rng = np.random.default_rng(seed)
    N = 600
    q = rng.uniform(-0.4, 0.4, N)
    qa = q - rng.uniform(-0.25, 0.25, N)
    qb = q - rng.uniform(-0.25, 0.25, N)
    tau = THESIS_K * (np.sinh(THESIS_A * (q - qa)) + np.sinh(THESIS_A * (q - qb)))
    tau_s = tau * (1 + 0.02 * rng.normal(size=N))          # 2 % relative sensor noise
    path = _write_csv(tmp_path / "sinh.csv", ["q", "qa", "qb", "tau"],
                      np.column_stack([q, qa, qb, tau_s]))
    fit = identify_actuator("sinh", path)
    k, a = fit.values
    assert abs(k - THESIS_K) < 3 * fit.std[0] and abs(a - THESIS_A) < 3 * fit.std[1]
    assert abs(k / THESIS_K - 1) < 0.02 and abs(a / THESIS_A - 1) < 0.01
    # RMSRE of the thesis's definition: ~ the 2 % relative noise put in.
    assert 1.0 < fit.rmsre_percent < 3.0
    # ... computed as defined: over the samples with |tau| >= 5 % of its maximum.
    phi = np.column_stack([q - qa, q - qb])
    keep = np.abs(tau_s) >= 0.05 * np.abs(tau_s).max()
    rel = (tau_s - sinh_model(k, a, phi))[keep] / tau_s[keep]
    assert fit.rmsre_percent == pytest.approx(100 * np.sqrt(np.mean(rel ** 2)))
    assert fit.rmsre_samples == keep.sum()
    assert rmsre(tau_s, sinh_model(k, a, phi))[0] == pytest.approx(fit.rmsre_percent)


def test_sinh_fit_of_one_spring_by_deflection_and_cli(tmp_path, capsys):
    rng = np.random.default_rng(7)
    phi = rng.uniform(-0.3, 0.3, 400)
    tau = 0.0216 * np.sinh(6.9602 * phi) + rng.normal(scale=2e-4, size=phi.size)
    path = _write_csv(tmp_path / "d.csv", ["deflection", "tau"], np.column_stack([phi, tau]))
    out = tmp_path / "fit.json"
    assert main(["identify", "--actuator", "sinh", "--log", str(path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "RMSRE" in text and out.is_file()
    fit = identify_actuator("sinh", path)
    assert fit.values[0] == pytest.approx(0.0216, rel=0.03)
    assert fit.values[1] == pytest.approx(6.9602, rel=0.02)
    assert main(["identify", "--actuator", "sinh", "--log", str(path), "--out", str(out)]) == 2


def test_mckibben_force_map_recovered(tmp_path):
    rng = np.random.default_rng(3)
    N = 500
    Kg, ln, lm = 0.16, 0.17, 0.14            # arm_2link_pneumatic's muscles (Table 10.1)
    p = rng.uniform(0.5e5, 8e5, N)
    x = rng.uniform(-0.01, 0.02, N)
    F = Kg * ((ln - x) ** 2 - lm ** 2) * p
    F_s = F + rng.normal(scale=0.01 * np.abs(F).mean(), size=N)
    fit = fit_mckibben(p, x, F_s)
    np.testing.assert_allclose(fit.values, [Kg, ln, lm], rtol=0.02)
    assert np.all(np.abs(fit.values - [Kg, ln, lm]) < 3 * fit.std)
    path = _write_csv(tmp_path / "m.csv", ["p", "contraction", "force"],
                      np.column_stack([p, x, F_s]))
    np.testing.assert_allclose(identify_actuator("mckibben", path).values, fit.values)


def test_actuator_data_errors_name_the_column(tmp_path, capsys):
    path = _write_csv(tmp_path / "x.csv", ["q", "tau"], np.ones((5, 2)))
    assert main(["identify", "--actuator", "sinh", "--log", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "qa" in err[0]


# ----------------------------------------------------------------------------- small things


def test_version(capsys):
    from importlib.metadata import version
    assert softgen.__version__ == version("softgen")
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"softgen {softgen.__version__}"


def test_py_typed_is_shipped():
    from pathlib import Path
    assert (Path(softgen.__file__).parent / "py.typed").is_file()


# ----------------------------------------------------------------------------- the 7-DoF arm


@pytest.mark.slow
def test_recovers_panda_parameters_within_3_sigma(tmp_path):
    """Issue 24's done-when: the 7-DoF arm, from a noisy quantised log."""
    model = load_model("panda")
    reg = IdentificationRegressor(model)
    ex = optimise_excitation(reg, harmonics=4, period=10.0, seed=0, maxiter=5, grid=60)
    log, truth = simulated_log(tmp_path / "panda.csv", reg, ex.trajectory, seed=0,
                               duration=30.0, counts=2 ** 18)
    res, out = identify_model("panda", log, out=tmp_path / "panda_identified.toml")
    z = (res.estimate - truth) / res.std
    assert np.all(np.abs(z) < 3.0), dict(zip(res.names, np.round(z, 2)))
    # The model file is physically consistent (projected if need be) and loads.
    assert res.consistent, res.violations
    assert load_model(out).dof == 7


def test_uncertain_damping_replaces_the_viscous_column(tmp_path):
    text = ARM3.replace('inertia = 0.02\n', 'inertia = 0.02\ndamping = 0.1\n').replace(
        'uncertain = ["mass", "com", "inertia"]', 'uncertain = ["mass", "com", "inertia", "damping"]')
    path = tmp_path / "arm3d.toml"
    path.write_text(text)
    reg = IdentificationRegressor(load_model(path))
    assert "d1" in reg.base_names and "fv1" not in reg.friction_names
    assert {"fv2", "fv3", "fc1", "fc2", "fc3"} <= set(reg.friction_names)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 3))
    Y, _ = reg.evaluate(x, rng.normal(size=(200, 3)), rng.normal(size=(200, 3)))
    assert np.linalg.matrix_rank(Y.reshape(-1, reg.p)) == reg.p      # no repeated column


@pytest.mark.parametrize("name", ["arm3_qbmove", "arm3_mckibben_unequal", "arm3_partial",
                                  "arm3_sea", "planar_2link_mckibben", "arm_2link_electric"])
def test_identified_model_file_keeps_declared_actuators(name, tmp_path):
    """The model file ``identify`` writes loads again with the same actuators: declared
    laws (SEA, antagonistic pairs and their constants, passive joints) survive."""
    user = Path(__file__).parent / "data" / "user_models" / f"{name}.toml"
    model = load_model(user if user.is_file() else MODELS_DIR / f"{name}.toml")
    path = tmp_path / "again.toml"
    path.write_text(to_toml(model_tables(model, dict(model.nominal))))
    again = load_model(path)
    assert [(a.type, a.joint, a.drive, a.family, a.sides, a.values) for a in again.actuators] \
        == [(a.type, a.joint, a.drive, a.family, a.sides, a.values) for a in model.actuators]
