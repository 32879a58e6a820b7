"""Every generated file is covered by the bundle's manifest (issue 23): an edited header
is refused by the loader and by export, with one line, like an edited C source."""
from __future__ import annotations

import shutil

import pytest

from softgen.bundles.bundle import GENERATED_DIR, load_bundle
from softgen.codegen.build import read_manifest
from softgen.core.errors import BundleError


@pytest.fixture
def bundle(tmp_path):
    src = GENERATED_DIR / "planar_2link"
    dst = tmp_path / "planar_2link"
    dst.mkdir()
    for f in ("planar_2link.c", "planar_2link.h", "manifest.json"):
        shutil.copy(src / f, dst / f)
    return dst


def test_the_manifest_records_the_header_digest(bundle):
    assert len(read_manifest(bundle)["header_sha256"]) == 64


def test_a_double_made_float_in_the_header_is_refused(bundle):
    h = bundle / "planar_2link.h"
    text = h.read_text()
    assert "double" in text
    h.write_text(text.replace("double", "float", 1))
    with pytest.raises(BundleError, match=r"planar_2link.h: does not match manifest.json "
                                          r"\(stale or edited\)"):
        load_bundle(bundle, backend="casadi")


def test_a_missing_header_is_refused(bundle):
    (bundle / "planar_2link.h").unlink()
    with pytest.raises(BundleError, match=r"planar_2link.h: missing; run `softgen generate"):
        load_bundle(bundle, backend="casadi")


def test_export_repairs_an_edited_header_before_exporting(bundle, tmp_path):
    """export regenerates a stale bundle (its documented rule): the project gets the
    generated header, never the edited one."""
    pristine = (GENERATED_DIR / "planar_2link" / "planar_2link.h").read_bytes()
    from softgen.export.project import export
    h = bundle / "planar_2link.h"
    h.write_text(h.read_text().replace("double", "float", 1))
    res = export("planar_2link", tmp_path / "proj", generated_root=bundle.parent)
    assert "planar_2link.h: does not match manifest.json" in res.note
    assert (tmp_path / "proj" / "planar_2link.h").read_bytes() == pristine
    assert h.read_bytes() == pristine
