"""Issue 16, "trust nothing on disk": the numbered cases 1, 2, 3, 6 and 7 of its "Why".

Each test reproduces one case (a truncated or replaced library, an edited custom
model, an edited or incomplete manifest, an impossible model, a runtime trap) and
checks that it now ends in a correct result or in one clear line.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import warnings

import numpy as np
import pytest

from softgen.bundles.bundle import GENERATED_DIR, check_inertia_positive_definite, generate
from softgen.cli import main
from softgen.codegen.build import (clean_orphans, ensure_library, library_path, read_manifest,
                                   record_path, verify_library)
from softgen.codegen.manifest import validate_manifest
from softgen.core.errors import BundleError, ModelError
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model
from softgen.bundles.bundle import load_bundle

PENDULUM = (MODELS_DIR / "pendulum_1link.toml").read_text()


def one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("softgen: error: "), err
    assert "Traceback" not in err
    return err


def copy_bundle(tmp_path, name: str, *, with_build: bool) -> os.PathLike:
    if with_build:
        ensure_library(GENERATED_DIR / name)     # cached normally; builds if needed
    dst = tmp_path / name
    shutil.copytree(GENERATED_DIR / name, dst,
                    ignore=None if with_build else shutil.ignore_patterns("build"))
    return dst


def custom_model(tmp_path, name="custom_arm", text=PENDULUM):
    path = tmp_path / f"{name}.toml"
    path.write_text(re.sub(r'name = "pendulum_1link"', f'name = "{name}"', text))
    return path


# -- case 1: the compiled-library cache ----------------------------------------------

@pytest.mark.compiler
def test_truncated_library_is_repaired_by_generate(need_compiler, tmp_path, capsys):
    """Before: `generate` said "cached" and the next call died with SIGBUS."""
    out = tmp_path / "gen"
    bundle = copy_bundle(out, "pendulum_1link", with_build=True)     # a cached library
    lib = library_path(bundle, read_manifest(bundle))
    with open(lib, "r+b") as fh:
        fh.truncate(1000)
    capsys.readouterr()
    assert main(["generate", "pendulum_1link", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "rebuilt" in text and "cached" not in text.replace("cached library", "")
    assert "size 1000 bytes" in text
    assert verify_library(lib, read_manifest(bundle)) is None
    arm = load_bundle(bundle)
    ref = load_bundle("pendulum_1link", backend="casadi")
    assert np.allclose(arm.inertia([0.3]), ref.inertia([0.3]))


@pytest.mark.compiler
def test_truncated_library_without_build_is_refused_in_one_line(need_compiler, tmp_path):
    bundle = copy_bundle(tmp_path, "pendulum_1link", with_build=True)
    lib = library_path(bundle, read_manifest(bundle))
    with open(lib, "r+b") as fh:
        fh.truncate(1000)
    with pytest.raises(BundleError, match="truncated or replaced") as err:
        load_bundle(bundle, backend="c", build_missing=False)
    assert "\n" not in str(err.value)


@pytest.mark.compiler
def test_library_with_other_content_under_the_right_name(need_compiler, tmp_path):
    """Before: another library under the expected name was loaded; numbers were wrong."""
    bundle = copy_bundle(tmp_path, "pendulum_1link", with_build=True)
    other = copy_bundle(tmp_path, "qbmove_1dof", with_build=True)
    lib = library_path(bundle, read_manifest(bundle))
    shutil.copy(library_path(other, read_manifest(other)), lib)
    with pytest.raises(BundleError, match="compiled library"):
        load_bundle(bundle, backend="c", build_missing=False)
    with pytest.warns(RuntimeWarning, match="rebuilt"):
        arm = load_bundle(bundle)                       # repaired, then correct
    ref = load_bundle("pendulum_1link", backend="casadi")
    q = np.array([0.7])
    assert np.allclose(arm.inertia(q), ref.inertia(q))
    assert np.allclose(arm.gravity(q), ref.gravity(q))


def test_edited_source_with_hash_updated_by_hand_is_refused(tmp_path):
    """Before: an edited .c with `source_sha256` updated by hand was compiled and loaded."""
    bundle = copy_bundle(tmp_path, "pendulum_1link", with_build=False)
    c = bundle / "pendulum_1link.c"
    c.write_bytes(c.read_bytes() + b"\n/* edited */\n")
    m = json.loads((bundle / "manifest.json").read_text())
    m["source_sha256"] = hashlib.sha256(c.read_bytes()).hexdigest()
    (bundle / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match=r"manifest.json: library: expected"):
        load_bundle(bundle)


def test_library_record_must_match_the_source(tmp_path):
    bundle = copy_bundle(tmp_path, "pendulum_1link", with_build=False)
    m = read_manifest(bundle)
    lib = library_path(bundle, m)
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"\x7fELF not really")
    assert "no build record" in verify_library(lib, m)
    record_path(lib).write_text(json.dumps({"size": 15, "sha256": "0" * 64,
                                            "source_sha256": "1" * 64}))
    assert "another C source" in verify_library(lib, m)
    record_path(lib).write_text(json.dumps({"size": 15, "sha256": "0" * 64,
                                            "source_sha256": m["source_sha256"]}))
    assert "content differs" in verify_library(lib, m)


def test_orphan_temporaries_of_dead_builders_are_removed(tmp_path):
    """Before: a SIGKILL during a build left a temporary .so that was never removed."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    build = tmp_path / "build"
    build.mkdir()
    orphan = build / f".libm_0123456789abcdef.so.{dead.pid}.k2j3h4g5.so"
    running = build / f".libm_0123456789abcdef.so.{os.getpid()}.a1b2c3d4.so"
    keep = build / "libm_0123456789abcdef.so"
    for p in (orphan, running, keep):
        p.write_bytes(b"x")
    assert clean_orphans(build) == [orphan]
    assert running.exists() and keep.exists() and not orphan.exists()


def test_orphan_temporaries_of_generate_are_removed(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    bundle = generate("pendulum_1link", tmp_path)
    orphan = bundle / f".manifest.json.{dead.pid}.x1y2z3w4"
    other = bundle / ".keep"
    orphan.write_text("{")
    other.write_text("")
    generate("pendulum_1link", tmp_path)
    assert not orphan.exists() and other.exists()


# -- case 2: staleness for every model -------------------------------------------------

def test_custom_model_records_its_own_path_and_hash(tmp_path):
    path = custom_model(tmp_path)
    bundle = generate(path, tmp_path / "gen")
    m = read_manifest(bundle)
    assert m["model_file"] == str(path.resolve())
    assert m["model_sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    shipped = read_manifest(GENERATED_DIR / "planar_2link")
    assert shipped["model_file"] == "models/planar_2link.toml"


def test_edited_custom_model_is_refused_naming_the_file(tmp_path):
    """Before: masses x10 in a custom file, and load_bundle still returned the old pi."""
    path = custom_model(tmp_path)
    bundle = generate(path, tmp_path / "gen")
    load_bundle(bundle, backend="casadi")
    path.write_text(re.sub(r"mass = ([0-9.e-]+)",
                           lambda mo: f"mass = {float(mo.group(1)) * 10!r}", path.read_text()))
    with pytest.raises(BundleError, match=re.escape(str(path.resolve())) + " changed"):
        load_bundle(bundle, backend="casadi")


def test_manifest_without_model_file_is_refused(tmp_path):
    """Before: deleting `model_file` from the manifest switched the check off."""
    bundle = copy_bundle(tmp_path, "pendulum_1link", with_build=False)
    m = json.loads((bundle / "manifest.json").read_text())
    del m["model_file"]
    (bundle / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match="model_file: missing required key"):
        load_bundle(bundle, backend="casadi")


@pytest.mark.compiler
def test_gone_model_file_loads_with_one_warning(need_compiler, tmp_path):
    path = custom_model(tmp_path, "custom_gone")
    bundle = generate(path, tmp_path / "gen")
    ensure_library(bundle)
    path.unlink()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_bundle(bundle)
        load_bundle(bundle)
    gone = [w for w in caught if "is gone" in str(w.message)]
    assert len(gone) == 1 and str(path.resolve()) in str(gone[0].message)


def test_custom_model_with_a_shipped_name_is_refused(tmp_path, capsys):
    path = custom_model(tmp_path, "planar_2link", PENDULUM)
    before = (GENERATED_DIR / "planar_2link" / "manifest.json").read_bytes()
    assert main(["generate", str(path), "--no-build"]) == 2
    assert "name of a shipped model" in one_line(capsys)
    assert (GENERATED_DIR / "planar_2link" / "manifest.json").read_bytes() == before
    generate(path, tmp_path / "elsewhere")       # allowed outside generated/


# -- case 3: manifests validated on load ---------------------------------------------------

def test_nominal_times_ten_is_refused(tmp_path):
    """Before: parameters.nominal[0] x 10 loaded, and Y @ pi != inverse_dynamics."""
    bundle = copy_bundle(tmp_path, "planar_2link", with_build=False)
    load_bundle(bundle, backend="casadi")
    m = json.loads((bundle / "manifest.json").read_text())
    m["parameters"]["nominal"][0] *= 10
    (bundle / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match=r"parameters.nominal: Y @ nominal differs"):
        load_bundle(bundle, backend="casadi")


@pytest.mark.parametrize("key", ["hash", "library", "parameters", "functions", "model"])
def test_missing_manifest_key_gives_one_line(tmp_path, key):
    """Before: a raw KeyError traceback."""
    bundle = copy_bundle(tmp_path, "pendulum_1link", with_build=False)
    m = json.loads((bundle / "manifest.json").read_text())
    del m[key]
    (bundle / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match=rf"manifest.json: {key}: missing required key") as e:
        load_bundle(bundle, backend="casadi")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("edit, match", [
    (lambda m: m["parameters"]["nominal"].append(1.0), r"parameters.nominal: expected 5"),
    (lambda m: m["functions"]["planar_2link_inertia"]["inputs"][0].update(shape=[2]),
     r"functions.planar_2link_inertia.inputs\[0\].shape: expected 2 entries"),
    (lambda m: m.update(dof="two"), r"dof: expected an integer"),
    (lambda m: m.update(hash="abc"), r"hash: expected 64 hexadecimal digits"),
])
def test_wrong_manifest_values_name_the_key(tmp_path, edit, match):
    bundle = copy_bundle(tmp_path, "planar_2link", with_build=False)
    m = json.loads((bundle / "manifest.json").read_text())
    edit(m)
    (bundle / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match=match):
        load_bundle(bundle, backend="casadi")


def test_non_finite_numbers_never_reach_a_manifest(tmp_path, capsys):
    """Before: a mass of 1e308 gave `Infinity` in manifest.json (not strict JSON)."""
    text = PENDULUM.replace("mass = ", "mass = 1e308 #", 1)
    path = custom_model(tmp_path, "huge", text)
    assert main(["generate", str(path), "--out", str(tmp_path / "g"), "--no-build"]) == 2
    assert "links[0].mass: expected a finite number of magnitude at most" in one_line(capsys)
    assert not (tmp_path / "g").exists()
    m = read_manifest(GENERATED_DIR / "planar_2link")
    m["parameters"]["nominal"][1] = float("inf")
    with pytest.raises(BundleError, match=r"parameters.nominal\[1\]: expected a finite"):
        validate_manifest(m)
    bundle = copy_bundle(tmp_path, "planar_2link", with_build=False)
    (bundle / "manifest.json").write_text(
        (bundle / "manifest.json").read_text().replace("0.0351", "Infinity"))
    with pytest.raises(BundleError, match="non-finite number Infinity"):
        load_bundle(bundle, backend="casadi")


# -- case 6: physically impossible models --------------------------------------------------

PRISMATIC_TIP = """\
[model]
name = "prismatic_tip"
kind = "planar"
[[links]]
joint = "revolute"
mass = 1.0
length = 0.5
com = 0.25
inertia = 0.01
[[links]]
joint = "prismatic"
mass = 0.0
length = 0.3
com = 0.1
inertia = 0.001
"""

TRIANGLE = """\
[model]
name = "bad_inertia"
kind = "spatial"
[[links]]
joint = "revolute"
axis = [0, 0, 1]
mass = 1.0
com = [0.1, 0, 0]
inertia = [0.01, 0.01, 0.05, 0, 0, 0]
"""


def test_massless_prismatic_tip_is_refused(tmp_path):
    """Before: forward_dynamics = [-12.9, inf]."""
    path = tmp_path / "p.toml"
    path.write_text(PRISMATIC_TIP)
    with pytest.raises(ModelError, match=r"links\[1\].mass: expected a positive mass"):
        load_model(path)


def test_inertia_violating_the_triangle_inequality_is_refused(tmp_path):
    path = tmp_path / "t.toml"
    path.write_text(TRIANGLE)
    with pytest.raises(ModelError, match=r"links\[0\].inertia: principal moments .* triangle"):
        load_model(path)


def test_huge_masses_are_refused(tmp_path, capsys):
    """Before: masses of 1e300 gave NaN dynamics."""
    path = custom_model(tmp_path, "heavy", PENDULUM.replace("mass = ", "mass = 1e300 #", 1))
    assert main(["info", str(path)]) == 2
    assert "links[0].mass" in one_line(capsys)


def test_b_not_positive_definite_is_refused_before_generation():
    model = load_model("planar_2link")
    with pytest.raises(ModelError, match=r"B\(q\) is not positive definite at q = "):
        check_inertia_positive_definite(model, lambda q: np.diag([1.0, 0.0]))
    with pytest.raises(ModelError, match=r"B\(q\) has non-finite entries"):
        check_inertia_positive_definite(model, lambda q: np.diag([1.0, np.inf]))
    check_inertia_positive_definite(model, lambda q: np.eye(2))


# -- case 7: runtime traps -----------------------------------------------------------------

@pytest.fixture(scope="module")
def arm():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)    # no compiler: CasADi backend
        return load_bundle("planar_2link")


def test_two_threads_get_their_own_results(arm):
    """Before: 218-393 of 20,000 calls returned the other thread's result."""
    f = arm.regressor
    rng = np.random.default_rng(7)
    cases = [tuple(rng.uniform(-1, 1, 2) for _ in range(4)) for _ in range(2)]
    expected = [f(*c) for c in cases]
    wrong = [0, 0]

    def work(k: int) -> None:
        ins, outs, call = f.inputs, f.outputs, f.call      # this thread's fast path
        for i in range(4000):
            if i % 2:
                if not np.array_equal(f(*cases[k]), expected[k]):
                    wrong[k] += 1
            else:
                for buf, v in zip(ins, cases[k]):
                    buf[:] = v
                call()
                if not np.array_equal(outs[0], expected[k]):
                    wrong[k] += 1

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert wrong == [0, 0]


def test_inputs_cannot_be_rebound(arm):
    """Before: `f.inputs[0] = new_array` was silently ignored."""
    f = arm.inertia
    with pytest.raises(TypeError, match=r"f.inputs\[i\]\[:\] = value"):
        f.inputs[0] = np.array([1.0, 2.0])
    with pytest.raises(AttributeError, match="cannot be rebound"):
        f.inputs = [np.zeros(2)]
    f.inputs[0][:] = [0.1, 0.2]          # the supported way still works
    f.call()
    assert np.allclose(f.outputs[0], f([0.1, 0.2]))


def test_stray_file_does_not_shadow_a_shipped_model(tmp_path, monkeypatch, capsys):
    """Before: a file named planar_2link in the cwd shadowed the shipped model."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "planar_2link").write_text("not a model")
    (tmp_path / "planar_2link.d").mkdir()
    assert load_model("planar_2link").path == MODELS_DIR / "planar_2link.toml"
    assert main(["info", "planar_2link"]) == 0
    capsys.readouterr()
    assert main(["info", "./planar_2link"]) == 2        # an explicit path reads the file
    assert "not valid TOML" in one_line(capsys)


def test_long_and_odd_model_names_give_one_line(capsys, tmp_path, monkeypatch):
    """Before: a 300-character name gave an OSError traceback."""
    monkeypatch.chdir(tmp_path)
    assert main(["info", "x" * 300]) == 2
    assert "at most 64 characters" in one_line(capsys)
    assert main(["info", "a b;c"]) == 2
    one_line(capsys)
    with pytest.raises(BundleError, match="at most 64 characters"):
        load_bundle("y" * 300)
    path = custom_model(tmp_path, "z" * 65)
    with pytest.raises(ModelError, match="model.name: expected a C identifier of at most 64"):
        load_model(path)
