"""Shared fixtures: models written on the fly, and the C-compiler marker."""
from __future__ import annotations

import os
import resource
import time

import pytest

from softgen.codegen.build import BUILD_LEVEL_ENV, find_compiler
from softgen.modelfile.load import load_model

#: The suite compiles generated C at -O0 (codegen.build.build_level; subprocesses inherit
#: it): what the tests check of a library is its numbers, which are the same bits at -O0
#: (no -ffast-math, no contraction on x86-64), and gcc takes a third of the CPU. Tests of
#: the shipped flags themselves unset it; ``SOFTGEN_BUILD_LEVEL= pytest`` runs the suite
#: at the shipped flags (issue 34: the default suite within 150 CPU-s).
os.environ.setdefault(BUILD_LEVEL_ENV, "-O0")


def _shared_bytecode() -> None:
    """The suite's Python subprocesses (CLI runs, interrupted runs, Dask workers, the
    installed wheel: over a hundred) read compiled bytecode from one cache of the
    session's instead of each compiling softgen's modules from source again.

    Where ``PYTHONDONTWRITEBYTECODE`` is set (to keep ``__pycache__`` out of the source
    tree), every interpreter the suite started compiled the ~180 modules it imports, ~0.3
    CPU-s each time (issue 34). The bytecode goes to ``<cache>/pycache``
    (``PYTHONPYCACHEPREFIX``: nothing is written beside the sources), which Python checks
    against each source's mtime and size as usual. A prefix set by the user is kept."""
    if os.environ.get("PYTHONPYCACHEPREFIX"):
        return
    import sys

    from softgen.core.paths import cache_dir
    prefix = str(cache_dir() / "pycache")
    os.environ["PYTHONPYCACHEPREFIX"] = prefix
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    # This process too, for the modules it imports from here on (the subprocesses then
    # find them compiled).
    sys.pycache_prefix = prefix
    sys.dont_write_bytecode = False


_shared_bytecode()

#: A spatial 3-joint arm mixing revolute and prismatic joints, with damping and
#: joint stiffness, off-diagonal inertias and a tilted gravity: exercises every
#: branch of the mechanics that the shipped planar models do not.
SPATIAL3 = """\
[model]
name = "spatial3"
kind = "spatial"

[gravity]
vector = [0.3, -0.2, -9.81]

[[links]]
joint = "revolute"
axis = [0, 0, 1]
mass = 1.2
com = [0.05, 0.01, 0.1]
inertia = [0.02, 0.03, 0.015, 0.001, -0.002, 0.0005]
damping = 0.05

[[links]]
joint = "prismatic"
axis = [0.6, 0, 0.8]
origin_xyz = [0.1, 0.0, 0.3]
origin_rpy = [0.1, -0.2, 0.3]
mass = 0.8
com = [0.0, 0.02, 0.05]
inertia = [[0.01, 0.0, 0.001], [0.0, 0.012, 0.0], [0.001, 0.0, 0.008]]
stiffness = 40.0

[[links]]
joint = "revolute"
axis = [0, 1, 0]
origin_xyz = [0.0, 0.05, 0.25]
mass = 0.5
com = [0.1, 0.0, 0.0]
inertia = [0.002, 0.004, 0.004, 0.0, 0.0, 0.0]
damping = 0.01
stiffness = 2.0

[parameters]
uncertain = ["mass", "com", "inertia", "damping", "stiffness"]
"""

#: A planar 3-link arm with a prismatic middle joint, lateral com offset,
#: damping, stiffness and uncertain lengths (parameters entering polynomially).
PLANAR3 = """\
[model]
name = "planar3"
kind = "planar"

[[links]]
joint = "revolute"
length = 0.4
mass = 1.0
com = [0.2, 0.01]
inertia = 0.02
damping = 0.1

[[links]]
joint = "prismatic"
length = 0.3
mass = 0.7
com = 0.15
inertia = 0.01
stiffness = 30.0

[[links]]
joint = "revolute"
length = 0.2
mass = 0.3
com = 0.1
inertia = 0.002
damping = 0.02
stiffness = 1.5

[parameters]
uncertain = ["mass", "length", "com", "inertia", "damping", "stiffness"]
"""


@pytest.fixture(scope="session")
def extra_models(tmp_path_factory):
    d = tmp_path_factory.mktemp("models")
    out = {}
    for name, text in (("spatial3", SPATIAL3), ("planar3", PLANAR3)):
        path = d / f"{name}.toml"
        path.write_text(text)
        out[name] = load_model(path)
    return out


@pytest.fixture(scope="session")
def bundle_specs():
    """``bundle_specs(model)``: the bundle spec of a model (a shipped name or a file path),
    derived once for the session. Several files check every shipped and held-out model's
    spec (test_codegen, test_one_truth, test_pcc_bundle, test_actuation_user_models): each
    derived them again, the 3D arm and the rod ~6 CPU-s each (issue 34)."""
    from softgen.bundles.bundle import bundle_spec
    cache = {}

    def get(model):
        key = str(model)
        if key not in cache:
            cache[key] = bundle_spec(load_model(model))
        return cache[key]
    return get


def soft_derivation(model) -> tuple:
    """``(dyn, lin)`` of a soft body (a shipped name or a file path) from the process's one
    derivation (:func:`softgen.bundles.bundle.derivation`, keyed by the file's content), as
    the bundles and the experiments take them: test files that built their own
    ``SoftDynamics`` and ``LinearRoute`` derived the same linear route again, ~1.4 CPU-s
    for the 3D arm each time (issue 34)."""
    from softgen.bundles.bundle import derivation
    ctx = derivation(load_model(model))
    return ctx.dyn, ctx.lin


@pytest.fixture(scope="module")
def loops_at_o1():
    """The module's generated C built at -O1 rather than the suite's -O0: for test files
    whose time is running compiled diagram loops (long closed-loop simulations, sweeps)
    rather than compiling them. -O1 is the level runtime.compiled ships loops at, and the
    numbers are the same bits (no -ffast-math, no contraction on x86-64). Measured per
    file, fresh cache, CPU-s (user+sys with children) at -O0 -> -O1, load ~2 on 2 CPUs:
    test_soft_sampled_identified 29.8 -> 21.9, test_soft_sampled 19.0 -> 14.2,
    test_sweep 18.9 -> 12.3, test_batch 10.5 -> 5.8, test_soft_loop_routes 8.9 -> 7.3;
    files that compile more than they run (test_schedule, test_urdf_trees,
    test_estimators_by_law, test_spring_pair_example) are slower at -O1 and stay at -O0
    (issue 34)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(BUILD_LEVEL_ENV, "-O1")
        yield


@pytest.fixture
def need_compiler():
    if find_compiler() is None:
        pytest.skip("no C compiler found")


#: The shipped bundles whose compile is most of what a fresh clone's default test run
#: paid for libraries: gcc at their flags took rod_tendon_3seg 33 CPU-s and pcc_3d_4seg
#: 25 CPU-s, of 106 CPU-s for all fourteen (load 2-6 on 2 CPUs). Tests that compile them
#: are marked slow; the default run checks the same generated functions on their
#: one-segment versions (:func:`small_bodies`: C of 0.63 and 0.31 MB against 3.4 and
#: 3.1 MB, 8 CPU-s for both derived and compiled, 2 CPU-s once compiled) (issue 34).
LARGE_BUNDLES = ("rod_tendon_3seg", "pcc_3d_4seg")
#: Shipped bundles that no default test loads but test_codegen's every-bundle checks, and
#: whose every generated function has its kind (the name after the model's) in a bundle
#: the default run compiles (test_codegen checks this): compiled only with -m slow. gcc
#: at their flags (load 2-3 on 2 CPUs): panda 7.8, arm_2link_electric 4.7,
#: planar_2link_mckibben 3.3, gioste_2link 3.2, pendulum_qbmove 2.1 CPU-s (issue 34).
COVERED_BUNDLES = ("panda", "arm_2link_electric", "planar_2link_mckibben", "gioste_2link",
                   "pendulum_qbmove")
#: Every shipped bundle compiled only by slow tests.
SLOW_BUNDLES = LARGE_BUNDLES + COVERED_BUNDLES


def one_segment(text: str, old: str, new: str, *, whole_length: bool = False) -> str:
    """The model file ``text`` with its first ``[[segments]]`` only, renamed ``new``;
    with ``whole_length`` that segment is as long as all of them together.

    Everything else (gravity, base, actuators, parameters) is kept: the bundle has the
    same functions, at one segment."""
    import re
    import tomllib
    blocks = re.split(r"(?m)^(?=\[)", text)
    kept, seen = [], False
    for b in blocks:
        if b.startswith("[[segments]]"):
            if seen:
                continue
            seen = True
            if whole_length:
                total = sum(s["length"] for s in tomllib.loads(text)["segments"])
                b, n = re.subn(r"(?m)^length = .*$", f"length = {round(total, 12)!r}", b)
                assert n == 1, "no length in the first [[segments]]"
        kept.append(b)
    assert seen, "no [[segments]]"
    out = "".join(kept).replace(f'name = "{old}"', f'name = "{new}"')
    assert f'name = "{new}"' in out
    return out


@pytest.fixture(scope="session")
def small_bodies():
    """One-segment versions of :data:`LARGE_BUNDLES`, generated and compiled once: name ->
    (model file, bundle directory, the shipped model it cuts). They live in the user cache
    (``softgen.core.paths.cache_dir() / "test-bodies"``) like the run-time loops, so a
    later session derives them again (the tests need the derivation as their reference)
    and rewrites only changed files, and compiles only a C source whose hash changed
    (codegen.build). Without a compiler the bundles are written but not built."""
    from concurrent.futures import ThreadPoolExecutor

    from softgen.bundles.bundle import generate
    from softgen.codegen.build import ensure_library
    from softgen.core.atomic import write_text
    from softgen.core.paths import MODELS_DIR, cache_dir
    root = cache_dir() / "test-bodies"
    root.mkdir(parents=True, exist_ok=True)
    out = {}
    for big in LARGE_BUNDLES:
        name = big.rsplit("_", 1)[0] + "_1seg"
        path = root / f"{name}.toml"
        # The rod in one segment of its whole length: its tip-control loop stays finite
        # from its default state (a single 0.1 m segment of it diverged within 0.5 s).
        text = one_segment((MODELS_DIR / f"{big}.toml").read_text(), big, name,
                           whole_length=big.startswith("rod_"))
        if not path.is_file() or path.read_text() != text:
            write_text(path, text)
        out[name] = (path, generate(path, root / "generated"), big)
    if find_compiler() is not None:
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            list(pool.map(lambda v: ensure_library(v[1]), out.values()))
    return out


@pytest.fixture(scope="session")
def shipped_libraries():
    """Every shipped bundle's library, compiled once for the session, on every CPU.

    Tests that load every shipped bundle (tests/test_codegen.py) compiled them one after
    another on first load, 110 CPU-s on one CPU of a fresh clone (issue 34). Here they
    are built side by side, largest C first (the 3D PCC bundle alone is most of it), by
    threads that each wait on a compiler process; a library already built (by `softgen
    generate`, or earlier in the session) is only verified. Without a compiler: nothing.
    :data:`SLOW_BUNDLES` are left to the (slow) tests that load them.
    """
    from concurrent.futures import ThreadPoolExecutor

    from softgen.codegen.build import ensure_library
    from softgen.core.paths import GENERATED_DIR
    from softgen.modelfile.load import list_models
    if find_compiler() is None:
        return {}
    names = sorted((n for n in list_models() if n not in SLOW_BUNDLES), key=lambda n: -(GENERATED_DIR / n / f"{n}.c").stat().st_size)
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        libs = dict(zip(names, pool.map(lambda n: ensure_library(GENERATED_DIR / n)[0],
                                        names)))
    return libs


# -- CPU accounting (issue 34: the default suite within 150 CPU-s) ---------------------
# SOFTGEN_TEST_CPU=FILE writes one line per test phase: CPU seconds of this process and
# of its finished children (compilers, subprocesses), wall seconds and the node id, so
# that `sort -rn FILE | head` says where a fresh clone's test CPU goes. Off by default.
_CPU_LOG = os.environ.get("SOFTGEN_TEST_CPU")


def _cpu_now() -> tuple[float, float, float]:
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(
        resource.RUSAGE_CHILDREN)
    return (me.ru_utime + me.ru_stime, kids.ru_utime + kids.ru_stime, time.perf_counter())


if _CPU_LOG:
    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        a = _cpu_now()
        yield
        b = _cpu_now()
        with open(_CPU_LOG, "a") as fh:
            fh.write(f"{b[0] - a[0] + b[1] - a[1]:.3f} {b[0] - a[0]:.3f} {b[1] - a[1]:.3f} "
                     f"{b[2] - a[2]:.3f} {item.nodeid}\n")
