"""The compiled checked call (softgen.runtime.fastcall, issue 31 item 6): on every input
it returns, writes and refuses exactly what the Python entry does."""
from __future__ import annotations

import gc
import os
import sysconfig
import threading
import time
import weakref
from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.bundle import load_bundle
from softgen.codegen.build import find_compiler
from softgen.core import children
from softgen.core.errors import BundleError, ShapeError
from softgen.runtime import fastcall


def _can_build() -> bool:
    include = sysconfig.get_paths().get("include")
    return (os.environ.get("SOFTGEN_FASTCALL", "1") != "0" and find_compiler() is not None
            and bool(include) and (Path(include) / "Python.h").is_file())


#: The larger bundle the checks call: a shipped one the default run compiles anyway
#: (conftest.shipped_libraries); panda's library (7 dof) cost the default run its own
#: compile, 7.8 CPU-s at -O3 (conftest.COVERED_BUNDLES; issue 34). N: its dof, every size
#: below is its own.
ARM, N = "pcc_planar_4seg", 4


@pytest.fixture(scope="module")
def bundles():
    if not _can_build():
        pytest.skip("no C compiler or no Python headers: the Python entry is used")
    return {name: load_bundle(name) for name in ("planar_2link", ARM)}


def _functions(bundles):
    return [f for b in bundles.values() for f in b.functions.values() if f._fast is not None]


def test_extension_builds_and_vector_input_functions_use_it(bundles):
    assert fastcall.module() is not None
    fns = _functions(bundles)
    assert fns and all(f.fast_path == "c" for f in fns)
    assert bundles["planar_2link"].inertia.fast_path == "c"      # matrix output, vector input


def _same(a, b) -> None:
    if isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b)
        for x, y in zip(a, b):
            _same(x, y)
        return
    assert type(a) is type(b) is np.ndarray
    assert a.shape == b.shape and a.dtype == b.dtype
    assert a.flags.c_contiguous == b.flags.c_contiguous and a.flags.owndata and b.flags.owndata
    assert np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("seed", range(5))
def test_compiled_entry_equals_python_entry_on_float64_arrays(bundles, seed):
    rng = np.random.default_rng(seed)
    for f in _functions(bundles):
        args = [rng.uniform(-2, 2, r) for r, _ in f.in_shapes]
        if seed == 4 and len(args[0]):        # non-finite inputs pass through, as before
            args[0][rng.integers(len(args[0]))] = rng.choice([np.nan, np.inf, -np.inf])
        new = f(*args)
        buffers = [o.copy() for o in f.outputs]
        old = f._fast(*args)                 # the generated Python entry
        _same(new, old)
        assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(buffers, f.outputs))


def test_results_are_fresh_arrays(bundles):
    f = bundles[ARM].inverse_dynamics
    x = [np.full(N, 0.3)] * 4
    a, b = f(*x), f(*x)
    assert a is not b and not np.shares_memory(a, f.outputs[0])
    a[:] = 1e9
    assert np.array_equal(f(*x), b)


def _outcome(call, args):
    try:
        return ("ok", call(*args))
    except Exception as exc:       # noqa: BLE001 - the exception is what is compared
        return (type(exc), str(exc))


def _other_inputs(rng):
    """Arguments the compiled entry does not take itself: each must reach the Python entry."""
    x = rng.uniform(-1, 1, N)
    wide = rng.uniform(-1, 1, 2 * N)
    return {
        "list": [list(x)] + [x] * 3,
        "int": [np.arange(N)] + [x] * 3,
        "python ints": [list(range(1, N + 1))] + [x] * 3,
        "strided": [wide[::2]] + [x] * 3,
        "column": [x.reshape(N, 1)] + [x] * 3,
        "float32": [x.astype(np.float32)] + [x] * 3,
        "big-endian": [x.astype(">f8")] + [x] * 3,
        "read-only": [np.frombuffer(x.tobytes())] + [x] * 3,    # taken by the C entry
        "last strided": [x] * 3 + [wide[1::2]],
        "too short": [x[:N - 1]] + [x] * 3,
        "too long": [x] * 3 + [wide],
        "matrix": [np.zeros((N, N))] + [x] * 3,
        "scalar": [np.float64(1.0)] + [x] * 3,
        "string": ["abc"] + [x] * 3,
        "none": [None] + [x] * 3,
        "3 args": [x] * 3,
        "5 args": [x] * 5,
        "no args": [],
    }


@pytest.mark.parametrize("case", list(_other_inputs(np.random.default_rng(0))))
def test_other_inputs_are_handled_as_by_the_python_entry(bundles, case):
    f = bundles[ARM].inverse_dynamics
    args = _other_inputs(np.random.default_rng(31))[case]
    new, old = _outcome(f, args), _outcome(f._fast, args)
    assert new[0] == old[0]
    if new[0] == "ok":
        _same(new[1], old[1])
    else:
        assert new[1] == old[1]


@pytest.mark.parametrize("args,match", [
    ((np.zeros(N),) * 3, "expected 4 inputs"),
    ((np.zeros(N - 1),) + (np.zeros(N),) * 3,
     rf"input 'q' expected shape \({N},\), got \({N - 1},\)"),
    ((np.zeros(N),) * 3 + (np.zeros(N + 1),),
     rf"input 'qdd_r' expected shape \({N},\), got \({N + 1},\)"),
    (("ab",) + (np.zeros(N),) * 3, "input 'q' expected numbers"),
])
def test_wrong_inputs_still_give_one_clear_error(bundles, args, match):
    with pytest.raises(ShapeError, match=match):
        bundles[ARM].inverse_dynamics(*args)


def test_keywords_are_handled_as_by_the_python_entry(bundles):
    f = bundles[ARM].inverse_dynamics
    x = np.zeros(N)
    assert _outcome(f, [x]) == _outcome(f._fast, [x])
    for kw in ({"q": x}, {"a0": x, "a1": x, "a2": x, "a3": x}):
        try:
            old = ("ok", f._fast(**kw))
        except Exception as exc:    # noqa: BLE001
            old = (type(exc), str(exc))
        try:
            new = ("ok", f(**kw))
        except Exception as exc:    # noqa: BLE001
            new = (type(exc), str(exc))
        assert new[0] == old[0]
        if new[0] == "ok":
            _same(new[1], old[1])
        else:
            assert new[1] == old[1]


def test_bound_output_is_written_and_released_as_before(bundles):
    f = bundles["planar_2link"].regressor
    rng = np.random.default_rng(4)
    y = [rng.uniform(-1, 1, 2) for _ in range(4)]
    z = [v + 1.0 for v in y]
    want_y, want_z = f(*y), f(*z)                  # (2, 5), C order
    target = np.zeros(10)
    f.bind_output(0, target)
    try:
        _same(f(*y), f._fast(*y))                  # bound: both return outputs[0] as is
        assert np.array_equal(target, want_y.ravel(order="F"))   # the C writes column-major
        assert np.array_equal(f.outputs[0], want_z)              # not written while bound
    finally:
        f.release_output(0)
    target[:] = 0.0
    _same(f(*y), want_y)
    assert np.array_equal(f.outputs[0], want_y) and not target.any()


def test_owner_and_other_thread_at_once_keep_their_results(bundles):
    f = bundles[ARM].inverse_dynamics
    rng = np.random.default_rng(8)
    cases = [tuple(rng.uniform(-1, 1, N) for _ in range(4)) for _ in range(2)]
    expected = [f(*c) for c in cases]
    wrong = [0, 0]
    start = threading.Barrier(2)

    def work(k: int) -> None:
        start.wait()
        for _ in range(3000):
            if not np.array_equal(f(*cases[k]), expected[k]):
                wrong[k] += 1

    t = threading.Thread(target=work, args=(1,))
    t.start()
    work(0)                                        # the owner thread: the compiled entry
    t.join()
    assert wrong == [0, 0]


def test_function_is_collected(bundles):
    b = load_bundle("planar_2link")
    ref = weakref.ref(b.functions["planar_2link_inertia"])
    assert b.functions["planar_2link_inertia"].fast_path == "c"
    del b
    gc.collect()
    assert ref() is None


def test_can_be_turned_off(monkeypatch):
    monkeypatch.setenv("SOFTGEN_FASTCALL", "0")
    assert fastcall._load() is None


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """A compiled function ``res = 2 * arg[0]`` returning ``arg[0][1]`` as its code."""
    if not _can_build() or fastcall.module() is None:
        pytest.skip("no C compiler or no Python headers")
    import ctypes
    d = tmp_path_factory.mktemp("toy")
    (d / "toy.c").write_text(
        "int toy(const double** arg, double** res, long long* iw, double* w, int mem) {\n"
        "  for (int i = 0; i < 2; i++) res[0][i] = 2.0 * arg[0][i];\n"
        "  return (int) arg[0][1];\n}\n"
        "int wait(const double** arg, double** res, long long* iw, double* w, int mem) {\n"
        "  volatile const double* flag = arg[0];\n"
        "  for (long long i = 0; i < 3000000000LL; i++)\n"
        "    if (flag[1] != 0.0) { res[0][0] = flag[1]; return 0; }\n"
        "  return 1;\n}\n")
    proc = children.run([find_compiler(), "-O1", "-fPIC", "-shared", "-o", str(d / "toy.so"),
                         str(d / "toy.c")])
    assert proc.returncode == 0, proc.stderr
    return ctypes.CDLL(str(d / "toy.so"))


def _toy_call(toy, on_error, fallback=lambda *a: ("fallback", a), name="toy", inp=None):
    import ctypes
    inp, out = np.zeros(2) if inp is None else inp, np.zeros(2)
    addr = ctypes.cast(getattr(toy, name), ctypes.c_void_p).value
    return fastcall.module().FastCall(addr, None, 0, threading.get_ident(), (inp,), (out,),
                                      (out,), 1, 1, None, None, fallback, on_error,
                                      (toy, inp, out)), out


def test_other_threads_run_during_the_call(toy):
    """As in CasADi's evaluator, the C runs without the GIL: here it waits for another
    Python thread to write into its input buffer (with the GIL held it would time out)."""
    def on_error(code):
        raise BundleError(f"wait returned error code {code}")
    inp = np.zeros(2)
    fc, _ = _toy_call(toy, on_error, name="wait", inp=inp)

    def release() -> None:
        time.sleep(0.05)
        inp[1] = 5.0
    t = threading.Thread(target=release)
    t.start()
    out = fc(np.zeros(2))
    t.join()
    assert out[0] == 5.0


def test_nonzero_code_raises_through_on_error(toy):
    def on_error(code):
        raise BundleError(f"toy returned error code {code}")
    fc, _ = _toy_call(toy, on_error)
    assert np.array_equal(fc(np.array([1.5, 0.0])), [3.0, 0.0])
    with pytest.raises(BundleError, match="toy returned error code 3"):
        fc(np.array([1.0, 3.0]))
    quiet, _ = _toy_call(toy, None)              # a function that cannot fail: code unread
    assert np.array_equal(quiet(np.array([1.0, 3.0])), [2.0, 6.0])


def test_everything_else_goes_to_the_fallback(toy):
    fc, out = _toy_call(toy, None)
    x = np.array([1.0, 2.0])
    assert fc(x, x) == ("fallback", (x, x))
    assert fc([1.0, 2.0])[0] == "fallback"
    assert fc(np.array([1, 2]))[0] == "fallback"
    seen = []
    t = threading.Thread(target=lambda: seen.append(fc(x)))
    t.start()
    t.join()
    assert seen[0][0] == "fallback"
    assert np.array_equal(fc(x), [2.0, 4.0]) and np.array_equal(out, [2.0, 4.0])


def test_bad_construction_is_refused(toy):
    import ctypes
    m = fastcall.module()
    addr = ctypes.cast(toy.toy, ctypes.c_void_p).value
    good = np.zeros(2)
    for bad in (np.zeros(2, dtype=np.float32), np.zeros((2, 2)).T, [0.0, 0.0]):
        with pytest.raises((ValueError, TypeError)):
            m.FastCall(addr, None, 0, threading.get_ident(), (bad,), (good,), (good,), 1, 1,
                       None, None, print, None, ())


def test_damaged_cache_entry_is_rebuilt(monkeypatch, tmp_path):
    if not _can_build():
        pytest.skip("no C compiler or no Python headers")
    monkeypatch.setenv("SOFTGEN_CACHE_DIR", str(tmp_path))
    lib = fastcall._target()[0]
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"not a shared library")
    mod = fastcall._load()
    assert mod is not None and hasattr(mod, "FastCall") and lib.stat().st_size > 1000
