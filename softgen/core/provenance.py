"""What produced a result: the hash of softgen's code, model files and generated bundles.

``reproduce --resume`` (a ``metrics.json``'s ``run_hash``) and ``sweep --resume`` (the
``code`` of ``sweep.json``) keep earlier results only when this hash is today's. It
lives in the lowest layer because both the app layer and the sweep engine of the
studies layer need it.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import casadi
import numpy

from softgen.core.paths import GENERATED_DIR, MODEL_SUFFIXES, MODELS_DIR

#: The ``softgen`` package directory (this file is ``softgen/core/provenance.py``).
_PACKAGE = Path(__file__).resolve().parents[1]


def code_hash() -> str:
    """sha256 of softgen's sources, the model files and the generated manifests.

    Files are named by their path relative to the package, the models and the bundles
    directories (``softgen/...``, ``models/...``, ``generated/...``), never by where the
    checkout or install lives, so two copies of the same code hash alike.
    """
    # casadi's stubs omit __version__; the attribute exists at run time.
    casadi_version = getattr(casadi, "__version__")  # noqa: B009
    h = hashlib.sha256(f"casadi={casadi_version} numpy={numpy.__version__}\n".encode())
    named = [(f"softgen/{f.relative_to(_PACKAGE)}", f) for f in sorted(_PACKAGE.rglob("*.py"))]
    named += [(f"models/{f.name}", f)
              for f in sorted(f for s in MODEL_SUFFIXES for f in MODELS_DIR.glob(f"*{s}"))]
    named += [(f"generated/{f.parent.name}/{f.name}", f)
              for f in sorted(GENERATED_DIR.glob("*/manifest.json"))]
    for name, f in named:
        h.update(name.encode() + b"\0")
        h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


def seal(record: dict[str, Any]) -> str:
    """sha256 of a record's content (every key but ``seal``), as canonical JSON.

    What binds a saved result to the run that wrote it: the export record
    (``softgen_export.json``) and every ``metrics.json`` of ``reproduce`` carry it, and a
    record whose seal does not match its content (edited by hand, written by another
    tool) is not trusted (issue 36: an edited metrics.json was kept by ``--resume``).
    """
    body = {k: v for k, v in record.items() if k != "seal"}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()
