"""What every bundle builder shares: the options, the identity, the model's source.

Kept apart from :mod:`softgen.bundles.bundle` (assembly) and the capability builders
(:mod:`softgen.bundles.rigid`, :mod:`softgen.bundles.soft`) so that the builders need
not import the assembler that imports them (no import cycle).
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

from softgen.core.paths import MODELS_DIR

#: RK4 steps per sample in the generated actuated plants.
PLANT_SUBSTEPS = 10


@dataclass(frozen=True)
class BundleOptions:
    """Options that change the generated code (part of the content hash)."""

    route: str = "auto"             # how C q̇_r is built (symbolic/rigid.py, mechanics.py)
    loop_steps: int = 1000          # samples per call of a bundle's <diagram>_loop
    loop_substeps: int = 1          # plant integration steps per sample in those loops
    loop_dt: float = 1e-3           # sample time of the bundles' closed-loop diagrams, s

    def check(self) -> BundleOptions:
        if self.route not in ("auto", "recursive", "matrix-free", "explicit"):
            raise ValueError(f"route: expected 'auto', 'recursive', 'matrix-free' or "
                             f"'explicit', got {self.route!r}")
        for name in ("loop_steps", "loop_substeps"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name}: expected a positive integer, got {v!r}")
        v = self.loop_dt
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v)
                                                                          and v > 0):
            raise ValueError(f"loop_dt: expected a positive number of seconds, got {v!r}")
        return self


#: The options of the shipped bundles in ``generated/``.
DEFAULT_OPTIONS = BundleOptions()


def identity_bytes(model_text: str, options: BundleOptions) -> bytes:
    """What the bundle hash covers besides CasADi's and the code generator's versions."""
    return model_text.encode() + b"\n" + json.dumps(options.__dict__, sort_keys=True).encode()


def model_source(model) -> dict:
    """``model_file`` and ``model_sha256`` of the manifest: where the model came from.

    A shipped model is recorded as ``models/<file>`` (relative, so ``generated/`` is
    the same on every machine); any other file by its absolute path.
    """
    if model.path is None:
        return {"model_file": f"{model.name}.toml",
                "model_sha256": hashlib.sha256(b"").hexdigest()}
    path = Path(model.path).resolve()
    try:
        shown = f"models/{path.relative_to(MODELS_DIR.resolve()).as_posix()}"
    except ValueError:
        shown = str(path)
    source = {"model_file": shown,
              "model_sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    chain = getattr(model, "chain", None)
    if chain is not None:
        # A URDF chain cut with --root/--tip: the file alone is the whole tree, so the
        # staleness check and the no-compiler fallback must cut the same chain again.
        source["model_chain"] = {"root": chain[0], "tip": chain[1]}
        if len(chain) > 2 and chain[2]:
            source["model_chain"]["floating"] = True        # --floating (issue 35)
    return source


def actuator_record(model) -> list[dict]:
    """The manifest's ``actuators``: per declared actuator its joint, type, drive, each
    side's law (text, constants) with the properties judged once at load, and the pair's
    stiffness range under its input limits (:mod:`softgen.modelfile.laws`)."""
    out: list[dict] = []
    links = getattr(model, "links", None)
    if links is None:
        # A Cosserat rod's tendons, chambers and torques (their input map is part of the
        # rod's dynamics: no law to record).
        return [{"name": a.name, "type": a.type, "one_sided": a.one_sided,
                 "max": a.max} for a in getattr(model, "actuators", ()) or ()]
    for a in getattr(model, "actuators", ()) or ():
        rec: dict = {"joint": links[a.joint].name if links else a.joint, "type": a.type,
                     "drive": a.drive, "family": a.family}
        if a.sides:
            rec["sides"] = [{"side": sd.name, "law": sd.text,
                             "constants": dict(sd.constants),
                             "properties": sd.law.properties.as_dict()} for sd in a.sides]
        if a.pair is not None:
            rec["pair"] = a.pair.as_dict()
        out.append(rec)
    return out


def model_chain(manifest: dict) -> dict:
    """``root=`` and ``tip=`` of :func:`softgen.modelfile.load.load_model` for the
    manifest's model (empty unless it is a chain cut out of a URDF file)."""
    chain = manifest.get("model_chain") or {}
    out = {"root": chain.get("root"), "tip": chain.get("tip")} if chain else {}
    if chain.get("floating"):
        out["floating"] = True
    return out


def model_file_path(manifest: dict) -> Path:
    """The model file a manifest was generated from (``model_file``, made absolute)."""
    p = Path(manifest.get("model_file", ""))
    return p if p.is_absolute() else MODELS_DIR.parent / p
