"""Emulated GioSte hardware (section 10.3): identified maps, valves, encoders, loop wiring."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from softgen.control.feasibility import PressureWarning
from softgen.control.pneumatic import pneumatic_arm
from softgen.control.references import SmoothSteps
from softgen.modelfile.load import load_model
from softgen.plants import gioste as gc
from softgen.studies import gioste as gs


@pytest.fixture(scope="module")
def one_link():
    arm = pneumatic_arm(gc.fitted_model(load_model("gioste_1link")))
    return arm, gc.GiosteEmulation(arm)


def _gains(emu, arm, sigma):
    """Section 10.3.4's printed gains (K_d = 12, Λ = 1.8, K_π = 45) as the experiments
    set them (the library's one conversion), K_σ for a 1/s stiffness-error rate."""
    del arm
    return gs.controller_gains(emu, 12.0, 1.8, 45.0, [sigma], stiffness_rate=1.0)


def _run(emu, kind, ref, g, divergence=0.5):
    """A run of the GioSte scenario (what the experiments run), unpadded."""
    sc = gs.scenario(emu, kind, ref, g, dt=1e-3, divergence=divergence,
                     Pi_hat0=emu.arm.Pi_nominal, chunk=100, record=None)
    return sc.loop, dict(sc.x0), sc.run()


# -- valves (eq. 10.10) ----------------------------------------------------------------------

@pytest.mark.parametrize("valve", [gc.VALVE_A, gc.VALVE_B])
def test_valve_inverse_round_trip(valve):
    V = np.linspace(0.0, 6.0, 61)
    np.testing.assert_allclose(valve.voltage(valve.pressure(V)), V, atol=1e-12)
    p = np.linspace(0.0, valve.p_max, 41)
    np.testing.assert_allclose(valve.pressure(valve.voltage(p)), p, rtol=1e-12, atol=1e-6)
    # The fitted coefficients as printed: 0.8611 bar/V and −0.4543 bar for muscle a.
    assert valve.pressure(0.0) == pytest.approx(valve.c0 * 1e5)
    assert 0.5 < valve.v0 < 0.65


def test_valve_interface_clips_and_targets_reachable_pressures(one_link):
    _, emu = one_link
    f = emu.interface_fun()
    pa_max, pb_max = gc.VALVE_A.p_max, gc.VALVE_B.p_max
    cmd = np.array([2.0e5, 3.0e5])
    V, tgt, raw = (np.array(x).ravel() for x in f(cmd))
    np.testing.assert_allclose(tgt, cmd, rtol=1e-12)          # reachable: exact round trip
    np.testing.assert_allclose(V, raw)
    V, tgt, raw = (np.array(x).ravel() for x in f(np.array([-1.0e5, 9.0e5])))
    assert raw[0] < 0 and raw[1] > 6.0                         # what the controller asked
    np.testing.assert_allclose(V, [0.0, 6.0])                 # what the valves got
    assert tgt[0] == 0.0                                       # no vacuum below V0
    assert tgt[1] == pytest.approx(pb_max)
    assert pa_max > 4.7e5 and pb_max > 4.7e5


# -- identified maps (eq. 10.11, section 10.3.5) ---------------------------------------------

@pytest.mark.parametrize("jm", [gc.ONE_LINK, gc.SHOULDER], ids=["one_link", "shoulder"])
def test_physical_stiffness_is_minus_dtau_dq(jm):
    rng = np.random.default_rng(0)
    h = 1e-6
    for q, Va, Vb in zip(rng.uniform(-0.4, 0.6, 20), rng.uniform(0, 6, 20),
                         rng.uniform(0, 6, 20)):
        fd = -(jm.torque(q + h, Va, Vb) - jm.torque(q - h, Va, Vb)) / (2 * h)
        assert jm.sigma_physical(q, Va, Vb) == pytest.approx(fd, rel=1e-7, abs=1e-8)
    # The identified stiffness map is the linearisation at q = 0 only.
    assert jm.sigma_identified(0.0, 2.0, 3.0) == pytest.approx(jm.sigma_physical(0.0, 2.0, 3.0))
    assert abs(jm.sigma_identified(0.3, 2.0, 3.0) - jm.sigma_physical(0.3, 2.0, 3.0)) > 0.1


def test_one_link_maps_as_printed():
    # Eq. 10.11 at q = 0.2, V = (2, 3), by hand.
    q, Va, Vb = 0.2, 2.0, 3.0
    tau = (6.96 - 2.34 * q - 0.71 * q * q) * Va - (7.03 + 2.07 * q - 0.58 * q * q) * Vb
    sig = (2.34 - 0.57 * q) * Va + (2.07 + 0.57 * q) * Vb
    assert gc.ONE_LINK.torque(q, Va, Vb) == pytest.approx(tau, rel=1e-14)
    assert gc.ONE_LINK.sigma_identified(q, Va, Vb) == pytest.approx(sig, rel=1e-14)
    assert [m.torque_a for m in gc.joint_maps(2)] == [gc.SHOULDER.torque_a,
                                                     gc.ONE_LINK.torque_a]


# -- sensors ---------------------------------------------------------------------------------

def test_encoder_quantisation_step(one_link):
    _, emu = one_link
    step = 2 * math.pi / (500 * 4)                           # HEDS-5500 A12, quadrature
    assert emu.encoder_step == pytest.approx(step)
    enc = emu.sensor_blocks(1e-3)[0]
    q = np.random.default_rng(1).uniform(-1, 1, 200)
    qm = np.array([enc.eval([], [x])[1][0] for x in q])
    np.testing.assert_allclose(np.round(qm / step), qm / step, atol=1e-9)
    assert np.max(np.abs(qm - q)) <= step / 2 + 1e-12
    assert len(np.unique(np.round(qm / step))) > 100          # not stuck on a few levels


def test_dirty_derivative_reads_a_ramp(one_link):
    _, emu = one_link
    T, w = 1e-3, 0.5
    enc, vel = emu.sensor_blocks(T)
    qm = np.array([enc.eval([], [x])[1][0] for x in w * np.arange(1, 600) * T])
    _, Y = vel.loop_fun(599)(np.zeros(2), qm[None, :], [])
    vs = np.array(Y)[0, 200:]                                 # 10 filter time constants on
    a = math.exp(-T / emu.hw.velocity_filter)
    kick = emu.encoder_step / T * (1 - a)                     # one count through the filter
    # The quantised ramp is a staircase of mean slope w: filtered, its mean is w and it
    # never strays from w by more than one count's kick.
    assert vs.mean() == pytest.approx(w, rel=0.02)
    assert np.max(np.abs(vs - w)) <= kick


# -- controller's model and the loop -----------------------------------------------------------

def test_map_origin_gives_no_force_at_zero_pressure(one_link):
    _, emu = one_link
    f = emu.truth_fun()
    q = np.array([0.2])
    tau, sp, si = (float(np.array(x).squeeze()) for x in f(q, np.zeros(2)))
    assert tau == 0.0 and sp == 0.0 and si == 0.0
    # Literal composition of eq. 10.10 and 10.11: a pull of A(q) V0 at zero pressure.
    lit = gc.GiosteEmulation(emu.arm, gc.HardwareConfig(map_origin="zero_voltage"))
    tau_lit = float(np.array(lit.truth_fun()(q, np.zeros(2))[0]).squeeze())
    want = gc.ONE_LINK.torque(0.2, gc.VALVE_A.v0, gc.VALVE_B.v0)
    assert tau_lit == pytest.approx(want, rel=1e-12) and abs(tau_lit) > 0.1
    with pytest.raises(ValueError, match="map_origin"):
        gc.map_voltage(1.0, gc.VALVE_A, "zero")


@pytest.mark.parametrize("jm", [gc.ONE_LINK, gc.SHOULDER], ids=["one_link", "shoulder"])
def test_fitted_pair_reproduces_the_map_where_it_is_a_mckibben_pair(jm):
    """Fit a pair to torques generated *by* a pair: the fit recovers it exactly."""
    R, K, ln, lm = 0.012, 0.6, (0.17, 0.16), (0.14, 0.125)
    # Per-pascal torques of that pair as quadratics in q, written as JointMaps with a
    # valve whose map voltage is p / (c1 10^5): the fitted pair must give them back.
    ca_ = K * np.array([ln[0] ** 2 - lm[0] ** 2, -2 * ln[0] * R, R * R])
    cb_ = K * np.array([ln[1] ** 2 - lm[1] ** 2, 2 * ln[1] * R, R * R])
    c1a, c1b = gc.VALVE_A.c1 * 1e5, gc.VALVE_B.c1 * 1e5
    synthetic = gc.JointMaps(tuple(ca_ * c1a), tuple(cb_ * c1b), (0.0,), (0.0,))
    lin = (gc.ValveMap(0.0, gc.VALVE_A.c1, 0.0), gc.ValveMap(0.0, gc.VALVE_B.c1, 0.0))
    fit = gc.fit_muscles(synthetic, (ln[0], lm[0]), valves=lin)
    assert fit["radius"] == pytest.approx(R, rel=1e-6)
    assert fit["gain"] * fit["radius"] == pytest.approx(K, rel=1e-6)
    np.testing.assert_allclose(fit["nominal_length"], ln, rtol=1e-6)
    np.testing.assert_allclose(fit["min_length"], lm, rtol=1e-6)
    assert fit["rms_error"] < 1e-9
    # On the real maps the fit is physical and its error is what the q² terms leave.
    real = gc.fit_muscles(jm, (0.17, 0.14))
    assert all(a > b > 0 for a, b in zip(real["nominal_length"], real["min_length"]))
    assert 0 < real["rms_error"] < 1.0


def test_kpi_vector_divides_gravity_parameters_by_g2():
    arm = pneumatic_arm(load_model("gioste_1link"))
    np.testing.assert_allclose(gc.kpi_vector(arm, 45.0), [45.0, 45.0 / 9.81 ** 2])
    arm2 = pneumatic_arm(load_model("gioste_2link"))
    kp = gc.kpi_vector(arm2, 45.0)
    assert sorted(kp.tolist()) == sorted([45.0, 45.0, 45.0, 45.0 / 9.81 ** 2,
                                          45.0 / 9.81 ** 2])


def test_matched_arm_has_only_the_feedback_stiffness():
    # With the controller's own muscles as the arm, Theorem 5's null-space pressures
    # cancel the muscles' stiffness and Π̂ = Π cancels gravity: what is left of
    # −∂(τ − G)/∂q is the feedback K_d Λ (section 10.3.3, ∂τ_*/∂q = cos q Π̂_2 − K_d Λ),
    # K_d the printed 12 in physical units (K_1 = K_g R of the fitted muscles).
    arm = pneumatic_arm(load_model("gioste_1link"))
    emu = gc.GiosteEmulation(arm, actuator="model")
    g = _gains(emu, arm, 10.0)
    ref0 = np.array([0.1, 0, 0, 0, 10.0, 0])
    net = gs.static_net_stiffness(emu, "theorem5", ref0, g, Pi_hat0=arm.Pi_nominal)
    assert net[0] == pytest.approx(12.0 * 1.8 * emu.arm.act.muscle_gain[0, 0], rel=1e-4)


def test_loop_is_the_composition_of_its_parts(one_link):
    """The generated loop equals sensing, controller, valves, delay line, plant by hand."""
    arm, emu = one_link
    d = gc.delay_samples(emu.hw, 1e-3)
    assert d == 10
    g = _gains(emu, arm, 7.0)
    t = np.arange(250) * 1e-3
    ref = gc.reference_array([SmoothSteps((0.0, 0.0), (0.0, 0.2), 1.0)],
                             [SmoothSteps((0.0,), (7.0,), 1.0)], t)
    _, x0, tr = _run(emu, "open_loop", ref, g)
    assert tr.stopped_at is None
    ctrl = arm.step_fun("open_loop")
    valves, plant, maps = emu.interface_fun(), emu.plant_fun(), emu.maps_fun()
    x = np.concatenate([tr["plant.q"][0], tr["plant.qd"][0], tr["plant.p"][0]])
    # The loop starts from the open-loop law's command at q_d(0), already in the
    # muscles, in the delay line and in the voltages the stiffness map reads.
    p0 = ctrl(arm.Pi_nominal, ref[0, :1], 0.0, ref[0], g.lam, g.kd, np.zeros(2),
              g.kinv, 1e-3)[1]
    V = np.array(valves(p0)[0]).ravel()
    np.testing.assert_allclose(np.array(valves(p0)[1]).ravel(), tr["plant.p"][0])
    qm, v, a = x0["vel.q_prev"], np.zeros(1), math.exp(-1e-3 / emu.hw.velocity_filter)
    ring = [tr["plant.p"][0]] * d
    z = tr["ctrl.Pi_hat"][0]
    for k in range(60):
        qm_new = np.floor(x[:1] / emu.encoder_step + 0.5) * emu.encoder_step
        v = a * v + (1 - a) * (qm_new - qm) / 1e-3
        qm = qm_new
        sig = np.array(maps(qm, V)[2]).ravel()
        assert qm == pytest.approx(tr["enc.q_m"][k], abs=1e-12)
        assert sig == pytest.approx(tr["stiff.sigma"][k], rel=1e-12)
        out = ctrl(z, qm, v, ref[k], g.lam, g.kd, g.kpi, g.kinv, 1e-3)
        z, p = np.array(out[0]).ravel(), np.array(out[1]).ravel()
        np.testing.assert_allclose(p, tr["ctrl.p"][k], rtol=1e-10)
        V, tgt, _ = (np.array(a_).ravel() for a_ in valves(p))
        ring.append(tgt)
        x = np.array(plant(x, ring.pop(0), 1e-3)).ravel()
        np.testing.assert_allclose(x[:1], tr["plant.q"][k + 1], rtol=1e-10, atol=1e-13)


def test_feasibility_warning_names_joint_and_time(one_link):
    arm, emu = one_link
    g = _gains(emu, arm, 60.0)
    t = np.arange(300) * 1e-3
    # 60 N m/rad needs more than 6 V on both muscles: unreachable from the start.
    ref = gc.reference_array([SmoothSteps((0.0,), (0.1,), 1.0)],
                             [SmoothSteps((0.0,), (60.0,), 1.0)], t)
    tr = _run(emu, "theorem5", ref, g)[2]
    with pytest.warns(PressureWarning) as rec:
        viol, clipped = gs.feasibility(emu, tr.t, tr["ctrl.p"], tr["valves.V_raw"],
                                       "unreachable")
    msg = str(rec[0].message)
    assert viol and clipped > 0.9
    assert "unreachable: joint 1 muscle" in msg
    assert re.search(r"from t = [0-9.e+-]+ s to t = [0-9.e+-]+ s", msg)
    # A reachable reference raises nothing.
    ok = gc.reference_array([SmoothSteps((0.0,), (0.1,), 1.0)],
                            [SmoothSteps((0.0,), (8.0,), 1.0)], t)
    tr = _run(emu, "theorem5", ok, _gains(emu, arm, 8.0))[2]
    viol, clipped = gs.feasibility(emu, tr.t, tr["ctrl.p"], tr["valves.V_raw"], "reachable",
                                   warn=False)
    assert not viol and clipped == 0.0


def test_emergency_stop_ends_the_run(one_link):
    arm, emu = one_link
    t = np.arange(500) * 1e-3
    ref = gc.reference_array([SmoothSteps((0.0,), (0.1,), 1.0)],
                             [SmoothSteps((0.0,), (8.0,), 1.0)], t)
    tr = _run(emu, "theorem5", ref, _gains(emu, arm, 8.0), divergence=0.05)[2]
    # The arm drifts off the reference by more than 0.05 rad (a residual error of the
    # muscle model against a feedback stiffness K_d Λ K_1 of about 0.2 N m/rad).
    assert tr.stopped_at is not None
    k = int(round(tr.stopped_at / 1e-3))
    assert tr.t.size == k and np.all(np.abs(tr["plant.q"] - ref[:k, :1]) <= 0.05)


# -- the experiments ---------------------------------------------------------------------------

@pytest.mark.slow
def test_quick_experiments(tmp_path):
    import warnings

    from softgen.experiments.ch10_gioste import EXPERIMENT_1DOF, EXPERIMENT_2DOF

    expected = [
        (EXPERIMENT_1DOF, ["position_rms_error_joint1_phase1", "stiffness_rms_error_joint1_phase3",
                          "position_to_stiffness_coupling_joint1",
                          "stiffness_to_position_coupling_joint1",
                          "parameter_estimate_max_ratio", "pressure_violations",
                          "open_loop_position_rms_error_rise1", "closed_loop_unstable_rise2",
                          "open_loop_position_to_stiffness_coupling_joint1",
                          "open_loop_stiffness_to_position_coupling_joint1",
                          "closed_loop_stiffness_to_position_coupling_joint1"]),
        (EXPERIMENT_2DOF, ["position_rms_error_joint2_phase3", "stiffness_rms_error_joint1_phase2",
                          "position_to_stiffness_coupling_joint2",
                          "stiffness_to_position_coupling_joint1",
                          "parameter_estimate_max_ratio", "pressure_violations"]),
    ]
    for exp, names in expected:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PressureWarning)
            run = exp.run(exp.config.replace(**exp.quick), tmp_path / exp.id)
        assert all(r.unit for r in run), exp.id                 # every metric has a unit
        m = run.flat()
        for name in names:
            assert name in m, (exp.id, name)
        for name, v in m.items():
            if "coupling" in name and not math.isfinite(v):
                # Undefined only when the run it comes from was stopped.
                stops = [k for k in m if "diverged_at" in k and m[k] < _duration(exp)]
                assert stops, (exp.id, name)
            else:
                assert math.isfinite(v), (exp.id, name, v)
        assert (tmp_path / exp.id / "traces.npz").exists()
        assert list((tmp_path / exp.id).glob("*.png"))


def _duration(exp) -> float:
    c = exp.config.replace(**exp.quick)
    return 3 * c.phase_duration if hasattr(c, "phase_duration") else c.track_duration
