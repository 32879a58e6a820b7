"""Generated bundles: reproducible bytes, manifest contract, compiled == casadi.Function."""
from __future__ import annotations

import ast
import hashlib
import json
import shutil
import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.bundle import GENERATED_DIR, BundleOptions, bundle_spec, generate
from softgen.codegen.build import build, find_compiler
from softgen.codegen.generate import library_name, render
from softgen.core.errors import BuildError, BundleError
from softgen.modelfile.load import list_models, load_model
from softgen.runtime import library
from softgen.bundles.bundle import load_bundle

from conftest import COVERED_BUNDLES, LARGE_BUNDLES, SLOW_BUNDLES


@pytest.fixture(scope="module")
def specs(bundle_specs):
    return {name: bundle_specs(name) for name in list_models()}


def test_generated_dir_matches_generate_all(specs):
    """generated/ in the repository is exactly what `softgen generate --all` writes."""
    present = sorted(p.name for p in GENERATED_DIR.iterdir() if p.is_dir())
    assert present == list_models()
    for name, spec in specs.items():
        for fname, data in render(spec).items():
            path = GENERATED_DIR / name / fname
            assert path.exists(), f"{path} missing: run softgen generate --all"
            assert path.read_bytes() == data, f"{path} is stale: run softgen generate --all"


#: The rod's copy is derived anew (~3.5 CPU-s): with -m slow. Its refusal reasons come
#: from the same decision as the planar arm's (cut to the file name by
#: registry.Decision.portable), which the default run checks (issue 34).
@pytest.mark.parametrize("name", ["planar_2link",
                                  pytest.param("rod_tendon_3seg", marks=pytest.mark.slow)])
def test_manifest_does_not_depend_on_where_the_model_file_lies(tmp_path, name):
    """The decision's reasons name the model file; the manifest cuts them to its file name,
    so generated/ is the same on any clone (CI's clean clone: before, every refusal reason
    held /work/main/models/...). Only ``model_file`` says where the file was."""
    src = GENERATED_DIR.parent / "models" / f"{name}.toml"
    copy = tmp_path / "a place" / f"{name}.toml"
    copy.parent.mkdir(exist_ok=True)
    shutil.copy(src, copy)
    ours = json.loads(render(bundle_spec(load_model(copy)))["manifest.json"])
    shipped = json.loads((GENERATED_DIR / name / "manifest.json").read_bytes())
    assert ours.pop("model_file") == str(copy)
    assert shipped.pop("model_file") == f"models/{name}.toml"
    assert ours == shipped
    assert str(tmp_path) not in json.dumps(ours)


def test_generation_is_byte_identical(tmp_path):
    a = generate("planar_2link", tmp_path / "a")
    b = generate("planar_2link", tmp_path / "b")
    for f in ("planar_2link.c", "planar_2link.h", "manifest.json"):
        assert (a / f).read_bytes() == (b / f).read_bytes()


def test_manifest_contract(specs):
    for name in specs:
        m = json.loads((GENERATED_DIR / name / "manifest.json").read_text())
        for key in ("model", "hash", "casadi_version", "library", "parameters", "functions"):
            assert key in m
        assert m["model"] == name
        assert len(m["parameters"]["names"]) == len(m["parameters"]["nominal"])
        for q in ("inertia", "coriolis", "gravity", "regressor"):
            assert f"{name}_{q}" in m["functions"]
        reg = m["functions"][f"{name}_regressor"]
        assert [i["name"] for i in reg["inputs"]] == ["q", "qd", "qd_r", "qdd_r"]
        assert reg["outputs"][0]["name"] == "Y"
        assert reg["outputs"][0]["shape"] == [m["dof"], len(m["parameters"]["names"])]
        src = (GENERATED_DIR / name / f"{name}.c").read_bytes()
        assert m["library"] == library_name(name, src)
        assert m["source_sha256"] == hashlib.sha256(src).hexdigest()
        for fn in m["functions"].values():
            assert fn["doc"] and "\n" not in fn["doc"]


#: Every shipped bundle, those of conftest.SLOW_BUNDLES with -m slow (their compile was
#: most of a fresh clone's test time), and the one-segment versions of the two largest
#: (conftest.small_bodies), which have the same functions, by default.
BUNDLES = [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_BUNDLES else n
           for n in list_models()] + [n.rsplit("_", 1)[0] + "_1seg" for n in LARGE_BUNDLES]


def _kinds(bundle: Path) -> set[str]:
    """The bundle's generated functions, each by its name after the model's."""
    m = json.loads((bundle / "manifest.json").read_text())
    return {f.removeprefix(m["model"] + "_") for f in m["functions"]}


def test_default_run_compiles_every_kind_of_function(small_bodies):
    """What the default run leaves to -m slow is covered by kind: a one-segment body has
    exactly the functions of the shipped body it cuts, and every function of the other
    slow bundles has a namesake in a bundle compiled by default (so compiled == CasADi
    is checked by default on every kind of generated function)."""
    for name, (_, bundle, big) in small_bodies.items():
        assert _kinds(bundle) == _kinds(GENERATED_DIR / big), name
    default = set().union(*(_kinds(GENERATED_DIR / n) for n in list_models()
                            if n not in SLOW_BUNDLES))
    for name in COVERED_BUNDLES:
        assert _kinds(GENERATED_DIR / name) <= default, \
            (name, sorted(_kinds(GENERATED_DIR / name) - default))


def _bundle(name, small_bodies, **kwargs):
    """The compiled bundle ``name`` and its spec: a shipped one, or a one-segment body."""
    if name in small_bodies:
        path, d, _ = small_bodies[name]
        return load_bundle(d, **kwargs), (lambda: bundle_spec(load_model(path)))
    return load_bundle(name, **kwargs), None


@pytest.mark.parametrize("name", BUNDLES)
def test_regressor_identity_from_the_manifest_alone(need_compiler, shipped_libraries,
                                                    small_bodies, name):
    """Y(q, qd, qd_r, qdd_r) @ pi == inverse dynamics, read from the bundle only."""
    b, _ = _bundle(name, small_bodies)
    rng = np.random.default_rng(11)
    n = b.manifest["dof"]
    for _ in range(20):
        x = [rng.uniform(-3, 3, n) for _ in range(4)]
        assert np.allclose(b.regressor(*x) @ b.parameter_nominal, b.inverse_dynamics(*x),
                           rtol=1e-12, atol=1e-14)


@pytest.mark.compiler
@pytest.mark.parametrize("name", BUNDLES)
def test_compiled_library_equals_casadi_function(need_compiler, specs, shipped_libraries,
                                                 small_bodies, name):
    b, spec_of = _bundle(name, small_bodies, backend="c")
    spec = spec_of() if spec_of else specs[name]
    rng = np.random.default_rng(12)
    # Closed-loop diagrams (x, p, k, e): near their default state, gains 1 to 1.5
    # times their defaults and small external inputs, so that 1000 samples stay finite
    # (smaller gains or 0.1 of measurement noise diverge on the stiff 3D PCC model; an
    # absolute +1.5 takes the rod's tip-loop kd from 0.5 to 2, past its sampled
    # stability limit at 1 ms: NaN in CasADi and C alike; a white tip torque of
    # 0.01 N m per sample drives the rod's adaptive tip law into parameter drift,
    # u ~ 1e26 by 0.9 s, while the plant alone under it stays bounded).
    diagrams = {d[role]: d for d in spec.extra.get("closed_loops", {}).values()
                for role in ("step", "loop")}
    for g in spec.functions:
        f = g.function
        cf = b[f.name()]
        for _ in range(3):
            args = [rng.uniform(-1, 1, f.size_in(i)) for i in range(f.n_in())]
            if f.name() in diagrams:
                d = diagrams[f.name()]
                args = [np.array(d["x0"]).reshape(-1, 1) + 0.01 * args[0],
                        np.array(d["p0"]).reshape(-1, 1) * (1 + 0.5 * np.abs(args[1])),
                        np.abs(args[2]) * 100, 0.001 * args[3]]
            # Sample times, step lengths and gains must be positive (a random
            # negative gain makes the 1000-sample closed loop diverge to NaN).
            # A random pi_hat0 may hold negative inertias: start the loop from 0.
            # Actuated plants: small states (spring deflections of a few hundredths
            # of a radian) and positive spring factors keep RK4 inside its stability
            # region at h = 1e-3.
            scale = {"dt": 1e-3, "h": 1e-3, "lam": 5.0, "kd": 0.1, "kpi": 0.01,
                     "pi_hat0": 0.0, "ref": 0.1, "spring_scale": 1.0}
            if f.name().endswith("_plant"):
                scale["x"] = 0.05
            args = [np.abs(a) * scale[f.name_in(i)] if f.name_in(i) in scale else a
                    for i, a in enumerate(args)]
            # Valve time constants: positive and not stiffer than the RK4 substep.
            args = [0.05 + np.abs(a) if f.name_in(i) == "T_p" else a
                    for i, a in enumerate(args)]
            ref = f(*args)
            ref = [ref] if f.n_out() == 1 else ref
            got = cf(*[a.ravel() if a.shape[1] == 1 else a for a in args])
            got = [got] if f.n_out() == 1 else got
            for r, o in zip(ref, got):
                r = np.array(r)
                r = r.ravel() if r.shape[1] == 1 else r
                assert np.all(np.isfinite(r)), f.name()
                assert np.allclose(o, r, rtol=1e-12, atol=1e-12), f.name()


@pytest.mark.compiler
def test_library_loads_from_a_plain_c_program(need_compiler, tmp_path):
    """The shared library links libm itself: dlopen from C with no -lm works."""
    b = load_bundle("planar_2link", backend="c")
    src = tmp_path / "main.c"
    src.write_text(textwrap.dedent(f"""
        #include <dlfcn.h>
        #include <stdio.h>
        typedef int (*fn_t)(const double**, double**, long long*, double*, int);
        int main(void) {{
            void* h = dlopen("{b.library}", RTLD_NOW);
            if (!h) {{ printf("dlopen: %s\\n", dlerror()); return 1; }}
            fn_t f = (fn_t) dlsym(h, "planar_2link_gravity");
            if (!f) return 2;
            double q[2] = {{0.5, 0.2}}, G[2];
            const double* arg[1] = {{q}};
            double* res[1] = {{G}};
            double w[64]; long long iw[64];
            if (f(arg, res, iw, w, 0)) return 3;
            printf("%.15g %.15g\\n", G[0], G[1]);
            return 0;
        }}"""))
    exe = tmp_path / "main"
    subprocess.run([find_compiler(), str(src), "-o", str(exe), "-ldl"], check=True,
                   capture_output=True)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    G = [float(v) for v in out.split()]
    assert np.allclose(G, b.gravity([0.5, 0.2]), rtol=1e-14)


@pytest.fixture
def bundle_copy(tmp_path):
    dst = tmp_path / "planar_2link"
    shutil.copytree(GENERATED_DIR / "planar_2link", dst,
                    ignore=shutil.ignore_patterns("build"))
    return dst


def test_edited_source_is_refused(bundle_copy):
    c = bundle_copy / "planar_2link.c"
    c.write_text(c.read_text() + "\n/* edited */\n")
    with pytest.raises(BundleError, match="stale or edited"):
        load_bundle(bundle_copy)


def test_bundle_of_an_older_model_file_is_refused(bundle_copy):
    m = json.loads((bundle_copy / "manifest.json").read_text())
    m["hash"] = "0" * 64
    (bundle_copy / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match="stale"):
        load_bundle(bundle_copy)


def test_missing_library_without_build_is_a_clear_error(bundle_copy):
    with pytest.raises(BundleError, match="compiled library missing"):
        load_bundle(bundle_copy, build_missing=False)


def test_missing_bundle_is_a_clear_error(tmp_path):
    with pytest.raises(BundleError, match="softgen generate"):
        load_bundle(tmp_path / "nothing_here")


def test_no_compiler_falls_back_to_casadi_with_a_warning(bundle_copy, monkeypatch):
    monkeypatch.setattr(library, "find_compiler", lambda cc=None: None)
    with pytest.warns(RuntimeWarning, match="no C compiler"):
        b = load_bundle(bundle_copy)
    assert b.backend == "casadi"
    x = [np.full(2, 0.3)] * 4
    assert np.allclose(b.regressor(*x) @ b.parameter_nominal, b.inverse_dynamics(*x))


def test_missing_compiler_is_a_build_error(bundle_copy):
    with pytest.raises(BuildError, match="not found"):
        build(bundle_copy, cc="/nonexistent/cc")


@pytest.mark.compiler
def test_compiler_failure_carries_stderr(need_compiler, bundle_copy):
    c = bundle_copy / "planar_2link.c"
    c.write_text("this is not C\n")
    m = json.loads((bundle_copy / "manifest.json").read_text())
    m["source_sha256"] = hashlib.sha256(c.read_bytes()).hexdigest()
    # A consistent manifest names the library after its source (issue 16).
    from softgen.codegen.generate import library_name
    m["library"] = library_name("planar_2link", c.read_bytes())
    (bundle_copy / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BuildError, match="failed") as err:
        build(bundle_copy)
    assert err.value.stderr


def test_bundle_options_are_checked():
    with pytest.raises(ValueError, match="route"):
        BundleOptions(route="lagrange").check()
    with pytest.raises(ValueError, match="loop_steps"):
        BundleOptions(loop_steps=0).check()
    for bad in (0.0, -1e-3, float("nan"), "1e-3", True):
        with pytest.raises(ValueError, match="loop_dt"):
            BundleOptions(loop_dt=bad).check()


def test_bundle_modules_import_no_cycle():
    """softgen/bundles/*: the import graph among its modules has no cycle (bundle.py
    imports the builders; they share bundles/common.py, not bundle.py)."""
    pkg = Path(__file__).resolve().parents[1] / "softgen" / "bundles"
    graph = {}
    for f in pkg.glob("*.py"):
        mods = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                mods.add(node.module)
            elif isinstance(node, ast.Import):
                mods.update(a.name for a in node.names)
        graph[f.stem] = {m.rsplit(".", 1)[1] for m in mods if m.startswith("softgen.bundles.")}
    seen, stack = set(), []

    def visit(n):
        assert n not in stack, f"import cycle: {' -> '.join(stack + [n])}"
        if n in seen:
            return
        stack.append(n)
        for m in graph.get(n, ()):
            visit(m)
        stack.pop()
        seen.add(n)
    for n in graph:
        visit(n)
    assert "bundle" not in graph["soft"] and "bundle" not in graph["rigid"]


def _two_functions(prefix: str):
    import casadi as ca
    from softgen.codegen.generate import BundleSpec, Generated
    x = ca.SX.sym("x", 3)
    small = ca.Function(f"{prefix}_small", [x], [ca.sin(x) * 2], ["x"], ["y"])
    big = ca.Function(f"{prefix}_big", [x], [ca.cos(x) + ca.sumsqr(x)], ["x"], ["y"])
    return BundleSpec(name=prefix, functions=[Generated(small, "small one"),
                                              Generated(big, "big one", optimization="-O1")])


def test_function_levels_wrap_only_their_functions(need_compiler, tmp_path):
    """A function at its own level is one guarded push/optimize/pop stretch of the C,
    from its heading to its work functions; the library still equals CasADi."""
    spec = _two_functions("lv")
    files = render(spec)
    src = files["lv.c"].decode()
    body = src[src.index("#pragma GCC push_options"):src.index("#pragma GCC pop_options")]
    assert src.count("#pragma GCC optimize") == 1 and '#pragma GCC optimize ("O1")' in body
    assert "/* lv_big:(" in body and "lv_big_work_bytes(" in body and "lv_small" not in body
    m = json.loads(files["manifest.json"])
    assert m["functions"]["lv_big"]["optimization"] == "-O1"
    assert "optimization" not in m["functions"]["lv_small"]
    from softgen.codegen.build import OPT_LEVELS
    from softgen.codegen.manifest import LEVELS, validate_manifest
    assert LEVELS == OPT_LEVELS
    m["functions"]["lv_big"]["optimization"] = "-Ofast"
    with pytest.raises(BundleError, match="lv_big.optimization: expected one of -O1"):
        validate_manifest(m)
    from softgen.codegen.generate import write_bundle
    b = load_bundle(write_bundle(spec, tmp_path), model_check=None, backend="c")
    for g in spec.functions:
        x = np.array([0.3, -1.2, 2.0])
        assert np.allclose(b[g.function.name()](x), np.array(g.function(x)).ravel(),
                           rtol=1e-14, atol=0)


def test_function_levels_of_model_bundles(specs):
    """The electric cascade and Theorem 10 steps at -O1 (measured no slower); the model,
    the estimators and the Theorem 5 and Slotine-Li loops at the bundle's -O3."""
    fns = json.loads(render(specs["planar_2link"])["manifest.json"])["functions"]
    assert fns["planar_2link_electric_cascade_pd"]["optimization"] == "-O1"
    for q in ("inertia", "regressor", "forward_dynamics", "electric_estimator_step",
              "slotine_li_loop"):
        assert "optimization" not in fns[f"planar_2link_{q}"]
    fns = json.loads(render(specs["pcc_planar_4seg"])["manifest.json"])["functions"]
    assert fns["pcc_planar_4seg_theorem10_closed_loop"]["optimization"] == "-O1"
    assert "optimization" not in fns["pcc_planar_4seg_regressor"]
    fns = json.loads(render(specs["arm_2link_pneumatic"])["manifest.json"])["functions"]
    assert not any("optimization" in f for f in fns.values())


def test_generate_keeps_an_up_to_date_bundle(tmp_path):
    """`softgen generate` derives nothing when the bundle is current (a fresh clone's
    generated/), and derives again when its C was edited or with --force."""
    from softgen.bundles.bundle import up_to_date
    from softgen.cli import main
    out = tmp_path / "g"
    d = generate("pendulum_1link", out)
    model = load_model("pendulum_1link")
    assert up_to_date(model, d)
    c = d / "pendulum_1link.c"
    shipped = c.read_bytes()
    c.write_bytes(shipped + b"/* edited */\n")
    assert not up_to_date(model, d)
    assert main(["generate", "pendulum_1link", "--out", str(out), "--no-build"]) == 0
    assert c.read_bytes() == shipped and up_to_date(model, d)
    m = json.loads((d / "manifest.json").read_text())
    m["hash"] = "0" * 64
    (d / "manifest.json").write_text(json.dumps(m))
    assert not up_to_date(model, d)


@pytest.mark.parametrize("first", ["softgen.bundles.rigid", "softgen.bundles.soft",
                                   "softgen.bundles.spring_pair"])
def test_capability_order_does_not_depend_on_which_module_is_imported_first(first):
    """The registry's order is a bundle's function order and its manifest's: a process
    importing a builder module first gets the same order as ``softgen generate`` (it did
    not: generated/ compared stale after tests/test_compose.py)."""
    import sys

    from softgen.bundles.registry import REGISTRY
    code = (f"import {first}\nfrom softgen.bundles.registry import REGISTRY\n"
            "print(' '.join(REGISTRY.names()))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == REGISTRY.names()


def test_code_size_is_the_largest_straight_line_function_brought():
    """The -O1 rule's size (codegen.generate.code_size): an SX function's own count; an MX
    function's largest SX callee, not its few MX nodes (the rod's plant: 22 MX nodes
    around a 23k-instruction step)."""
    import casadi as ca

    from softgen.codegen.generate import LARGE_FUNCTION, code_size
    x = ca.SX.sym("x", 3)
    e = x
    for _ in range(LARGE_FUNCTION):
        e = ca.sin(e) * 1.0001 + x
    big = ca.Function("big", [x], [e])
    small = ca.Function("small", [x], [x * 2])
    assert code_size(big) == big.n_instructions() >= LARGE_FUNCTION
    xm = ca.MX.sym("x", 3)
    composed = ca.Function("composed", [xm], [small(big(xm)) + small(xm)])
    assert composed.n_instructions() < 20
    assert code_size(composed) == big.n_instructions()
    only_small = ca.Function("only_small", [xm], [small(small(xm))])
    assert code_size(only_small) == small.n_instructions()
