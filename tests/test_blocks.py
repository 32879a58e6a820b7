"""Blocks, diagrams and the driver: wiring checks and loop equivalences."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.blocks import Block, ClosedLoop, Layout
from softgen.runtime.simulate import DivergenceError, simulate

DT = 1e-2


def plant(dt=DT, name="plant", stiffness=1.0):
    """Mass-spring x'' = -k x + u, RK4 over one sample with u held."""
    def body(x, u, p):
        def f(z):
            return ca.vertcat(z[1], -p["k"] * z[0] + u["tau"])
        z = ca.vertcat(x["q"], x["qd"])
        k1 = f(z)
        k2 = f(z + dt / 2 * k1)
        k3 = f(z + dt / 2 * k2)
        k4 = f(z + dt * k3)
        zn = z + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return {"q": zn[0], "qd": zn[1]}, {"q": x["q"], "qd": x["qd"]}
    return Block.define(name, dt=dt, state={"q": 1, "qd": 1}, inputs={"tau": 1},
                        outputs={"q": 1, "qd": 1}, params={"k": 1}, body=body,
                        p0={"k": stiffness})


def reference(name="ref"):
    return Block.define(name, dt=None, inputs={"t": 1}, outputs={"q_d": 1},
                        body=lambda x, u, p: ({}, {"q_d": ca.sin(u["t"])}))


def pid(dt=DT, name="ctrl"):
    """PD plus an integral state; reads q, qd, q_d, a noise input."""
    def body(x, u, p):
        e = u["q_d"] - u["q"] + u["noise"]
        return ({"i": x["i"] + dt * e},
                {"tau": p["kp"] * e - p["kd"] * u["qd"] + p["ki"] * x["i"]})
    return Block.define(name, dt=dt, state={"i": 1}, inputs={"q": 1, "qd": 1, "q_d": 1,
                                                            "noise": 1},
                        outputs={"tau": 1}, params={"kp": 1, "kd": 1, "ki": 1}, body=body,
                        p0={"kp": 20.0, "kd": 5.0, "ki": 1.0})


def loop(**kw):
    return ClosedLoop("pd_loop", [reference(), pid(**kw), plant()], externals={"noise": 1})


def test_layout_slices_and_join():
    lay = Layout([("q", 2), ("qd", 2), ("p", 4)])
    assert lay.size == 8 and lay.slice("qd") == slice(2, 4)
    v = lay.join({"q": [1, 2], "qd": [3, 4], "p": np.arange(4)})
    assert np.array_equal(lay.split(v)["p"], np.arange(4.0))
    with pytest.raises(KeyError, match="no signal 'x'"):
        lay.slice("x")
    with pytest.raises(ValueError, match="declared twice"):
        Layout([("q", 1), ("q", 2)])


def test_feedthrough_is_read_from_the_expression():
    assert not plant().feedthrough
    assert pid().depends["tau"] == {"q", "qd", "q_d", "noise"}


def test_mismatched_dt_raises():
    with pytest.raises(ValueError, match=r"dt: blocks sample at different times: .*ctrl.*plant"):
        ClosedLoop("bad", [reference(), pid(dt=1e-3), plant(dt=1e-2)], externals={"noise": 1})


def test_unconnected_input_raises():
    with pytest.raises(ValueError, match=r"input ctrl.noise is not connected"):
        ClosedLoop("bad", [reference(), pid(), plant()])


def test_input_connected_twice_raises():
    with pytest.raises(ValueError, match="connected more than once"):
        ClosedLoop("bad", [reference(), pid(), plant()], [("ext.noise", "ctrl.noise"),
                                                          ("ref.q_d", "ctrl.noise")],
                   externals={"noise": 1})


def test_ambiguous_and_mismatched_wires_raise():
    with pytest.raises(ValueError, match="several candidates"):
        ClosedLoop("bad", [reference(), pid(), plant(), plant(name="plant2")],
                   externals={"noise": 1})
    with pytest.raises(ValueError, match="expects 1"):
        wide = Block.define("w", dt=None, outputs={"y": 2},
                            body=lambda x, u, p: ({}, {"y": ca.DM([1, 2])}))
        ClosedLoop("bad", [reference(), pid(), plant(), wide], [("w.y", "ctrl.noise")])


def test_algebraic_loop_raises():
    a = Block.define("a", dt=DT, inputs={"u": 1}, outputs={"y": 1},
                     body=lambda x, u, p: ({}, {"y": 2 * u["u"]}))
    b = Block.define("b", dt=DT, inputs={"y": 1}, outputs={"u": 1},
                     body=lambda x, u, p: ({}, {"u": u["y"] + 1}))
    with pytest.raises(ValueError, match="algebraic loop"):
        ClosedLoop("bad", [a, b])


def test_generated_loop_equals_python_steps():
    """N samples of the generated loop equal N steps of the one-sample function."""
    d = loop()
    rng = np.random.default_rng(0)
    N = 250
    noise = 1e-2 * rng.standard_normal((N, 1))
    x0 = {"plant.q": 0.3, "plant.qd": -0.1}
    tr = simulate(d, steps=N, x0=x0, externals={"noise": noise}, chunk=64)
    step = d.step_fun()
    x, p = d.initial_state(x0), d.parameters()
    ys = []
    for k in range(N):
        xn, y = step(x, p, k, noise[k])
        ys.append(np.array(y).ravel())
        x = np.array(xn).ravel()
    ys = np.array(ys)
    sl = d.signals.slice("plant.q")
    np.testing.assert_allclose(tr["plant.q"], ys[:, sl], rtol=0, atol=1e-12)
    np.testing.assert_allclose(tr["ctrl.tau"], ys[:, d.signals.slice("ctrl.tau")], atol=1e-12)
    np.testing.assert_allclose(tr.t, np.arange(N) * DT, atol=1e-15)
    np.testing.assert_allclose(tr.final_state["plant.q"], x[d.state.slice("plant.q")],
                               atol=1e-12)


def test_plain_c_loop_equals_the_mapaccum_tower_bit_for_bit(need_compiler):
    """The driver's compiled loop (one call of the sample function per sample,
    ``codegen.generate._plain_loop``) gives exactly the numbers of CasADi's
    ``mapaccum`` tower of the same sample function: states, a recorded subset, external
    inputs read per sample, from a sample index k0 > 0."""
    from softgen.codegen.generate import BundleSpec, Generated, render
    from softgen.runtime.compiled import compile_functions
    d = loop()
    N, record = 37, ["plant.q", "ctrl.tau"]
    x0, p = d.initial_state({"plant.q": 0.3, "plant.qd": -0.1}), d.parameters()
    E = np.random.default_rng(3).standard_normal((d.externals.size, N))
    lf = d.loop_fun(N, record)
    args = [lf.mx_in(i) for i in range(lf.n_in())]
    fns = {k: ca.Function(f"test_{k}_loop", args, lf(*args)) for k in ("tower", "plain")}
    sample = {"test_plain_loop": d.sample_fun(record)}
    c_src = render(BundleSpec("test_plain", [Generated(fns["plain"], "")], loops=sample))
    assert b"softgen_plain_test_plain_loop" in c_src["test_plain.c"]
    a = compile_functions("test_tower", [fns["tower"]])["test_tower_loop"]
    b = compile_functions("test_plain", [fns["plain"]], loops=sample)["test_plain_loop"]
    Xa, Ya = a(x0, p, 5, E)
    Xb, Yb = b(x0, p, 5, E)
    assert np.array_equal(Xa, Xb) and np.array_equal(Ya, Yb)
    t = Yb[d.recorded(record).slice("t")].ravel()
    np.testing.assert_allclose(t, (5 + np.arange(N)) * DT, rtol=0, atol=1e-15)
    # The external input moves the loop: the same run without it differs.
    assert not np.array_equal(b(x0, p, 5, 0 * E)[0], Xb)


@pytest.mark.parametrize("chunk", [1, 7])
def test_any_chunk_size_gives_the_same_run(chunk):
    d = loop()
    N = 40
    noise = np.random.default_rng(1).standard_normal((N, 1)) * 1e-2
    ref = simulate(d, steps=N, externals={"noise": noise}, chunk=N)
    tr = simulate(d, steps=N, externals={"noise": noise}, chunk=chunk)
    np.testing.assert_allclose(tr["plant.q"], ref["plant.q"], rtol=0, atol=1e-14)


def test_continuing_a_run_equals_one_run():
    d = loop()
    N = 300
    zero = {"noise": np.zeros((N, 1))}
    one = simulate(d, steps=N, externals=zero, chunk=100)
    a = simulate(d, steps=120, externals={"noise": np.zeros((120, 1))}, chunk=100)
    b = simulate(d, steps=N - 120, x0=a.final_state, k0=a.next_k,
                 externals={"noise": np.zeros((N - 120, 1))}, chunk=100)
    np.testing.assert_allclose(np.vstack([a["q"], b["q"]]), one["q"], atol=1e-14)


def test_diverging_loop_stops_and_names_time_and_signal():
    """Positive feedback through a negative stiffness: the plant runs away to inf."""
    d = ClosedLoop("runaway", [reference(), pid(), plant(stiffness=-1e3)],
                   externals={"noise": 1})
    N = 20000
    with pytest.raises(DivergenceError, match=r"plant\.(q|qd) is not finite at t = ") as e:
        simulate(d, steps=N, x0={"plant.q": 1.0}, externals={"noise": np.zeros((N, 1))})
    assert 0 < e.value.time < N * DT
    tr = simulate(d, steps=N, x0={"plant.q": 1.0}, externals={"noise": np.zeros((N, 1))},
                  on_nonfinite="stop")
    assert tr.stopped_at == pytest.approx(e.value.time) and np.all(np.isfinite(tr["q"]))


def test_nan_reference_is_blamed_on_the_reference():
    ref = Block.define("ref", dt=None, inputs={"t": 1}, outputs={"q_d": 1},
                       body=lambda x, u, p: ({}, {"q_d": ca.log(1.0 - u["t"])}))
    d = ClosedLoop("nanref", [ref, pid(), plant()], externals={"noise": 1})
    with pytest.raises(DivergenceError, match=r"ref\.q_d is not finite at t = 1 s"):
        simulate(d, steps=200, externals={"noise": np.zeros((200, 1))})


def test_stop_condition_ends_the_run():
    d = loop()
    N = 500
    tr = simulate(d, steps=N, x0={"plant.q": 0.0}, externals={"noise": np.zeros((N, 1))},
                  stop=[("q above 0.5", lambda c: c["plant.q"][:, 0] > 0.5)], chunk=64)
    assert tr.stop_reason == "q above 0.5"
    assert np.all(tr["q"] <= 0.5) and tr.stopped_at == pytest.approx(tr.t[-1] + DT)


def test_bad_externals_and_params_are_named():
    d = loop()
    with pytest.raises(ValueError, match=r"externals: noise: expected shape \(10, 1\)"):
        simulate(d, steps=10, externals={"noise": np.zeros(3)})
    with pytest.raises(ValueError, match="params: unknown signal 'ctrl.kx'"):
        simulate(d, steps=10, externals={"noise": np.zeros((10, 1))}, params={"ctrl.kx": 1})


def test_stop_condition_records_the_signals_it_reads():
    d = loop()
    N = 500
    tr = simulate(d, steps=N, externals={"noise": np.zeros((N, 1))}, record=["ctrl.tau"],
                  stop=[("q above 0.5", lambda c: c["plant.q"][:, 0] > 0.5, ["plant.q"])])
    assert tr.stop_reason == "q above 0.5" and "plant.q" in tr.signals


def test_same_loop_under_another_name_is_compiled_once(need_compiler, tmp_path,
                                                       monkeypatch):
    """Two diagrams equal but for their name share one compiled library (the cache is
    keyed by the C without the name, issue 25) and give the same numbers; a diagram
    that differs in a constant gets its own."""
    import softgen.codegen.build as build
    monkeypatch.setenv("SOFTGEN_CACHE_DIR", str(tmp_path))
    built = []
    real = build.compile_shared
    monkeypatch.setattr(build, "compile_shared",
                        lambda c_file, *a, **k: built.append(c_file.name) or real(c_file, *a, **k))
    kw = dict(steps=120, x0={"plant.q": 0.3}, externals={"noise": np.zeros((120, 1))})
    blocks = lambda dt=DT: [reference(), pid(dt), plant(dt)]  # noqa: E731
    a = simulate(ClosedLoop("first_loop", blocks(), externals={"noise": 1}), **kw)
    b = simulate(ClosedLoop("second_loop", blocks(), externals={"noise": 1}), **kw)
    assert built == ["first_loop.c"]
    np.testing.assert_array_equal(a["ctrl.tau"], b["ctrl.tau"])
    assert sorted(p.name.split("_")[0] for p in tmp_path.iterdir() if p.is_dir()) == \
        ["content", "first"]
    simulate(ClosedLoop("third_loop", blocks(2 * DT), externals={"noise": 1}), **kw)
    assert built == ["first_loop.c", "third_loop.c"]
