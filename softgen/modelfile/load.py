"""Which file a model name means, and reading it: TOML (rigid or soft body), URDF, or a
TOML model that references a URDF file's chain (``[urdf]``). The readers themselves are
:mod:`softgen.modelfile.model` (rigid chains), :mod:`softgen.modelfile.soft` and
:mod:`softgen.modelfile.urdf`; this module sits above them, so none imports another's
dispatcher.
"""
from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

from softgen.core.errors import ModelError
from softgen.core.paths import MODEL_SUFFIXES, MODELS_DIR  # noqa: F401  (re-exported)
from softgen.modelfile.model import (MAX_NAME, FileReader, RobotModel, _Parser,
                                     read_model_text)
from softgen.modelfile.cosserat import CosseratModel, is_cosserat, parse_cosserat_model
from softgen.modelfile.soft import SoftModel, is_soft, parse_soft_model
from softgen.modelfile.urdf import chain_joints, parse_urdf


# MODEL_SUFFIXES lives in softgen.core.paths (imported above, re-exported here) so that
# softgen.core.provenance can hash the model files without importing this layer.

def shipped_model_file(name: str) -> Path | None:
    """``models/<name>.toml`` or ``models/<name>.urdf``, whichever exists (TOML first)."""
    for suffix in MODEL_SUFFIXES:
        if (MODELS_DIR / f"{name}{suffix}").is_file():
            return MODELS_DIR / f"{name}{suffix}"
    return None

def model_path(name_or_path: str | Path) -> Path:
    """The file of a model given by name (``planar_2link``) or by path.

    A bare name (no directory, no suffix) is a shipped model first: a stray file
    of that name in the current directory does not shadow it. Give ``./name`` or
    a path with a suffix to read such a file.
    """
    text = str(name_or_path)
    p = Path(name_or_path)
    if "/" in text or "\\" in text or p.suffix:
        return p
    valid = 0 < len(text) <= MAX_NAME and text.isascii() and text.isidentifier()
    shipped = shipped_model_file(text) if valid else None
    if shipped is not None:
        return shipped
    if len(text) <= 255 and p.is_file():
        return p
    if not valid:
        raise ModelError(f"model name {text[:40]!r}{'...' if len(text) > 40 else ''}: "
                         f"expected a C identifier of at most {MAX_NAME} characters or a "
                         "path to a .toml or .urdf file")
    known = ", ".join(list_models()) or "(none)"
    raise ModelError(f"unknown model {text!r}: expected one of {known} "
                     f"or a path to a .toml or .urdf file")

def list_models() -> list[str]:
    """Names of the models shipped in ``models/`` (TOML and URDF files)."""
    return sorted({p.stem for suffix in MODEL_SUFFIXES for p in MODELS_DIR.glob(f"*{suffix}")})

def load_model(name_or_path: str | Path, *, root: str | None = None,
               tip: str | None = None, floating: bool = False) -> RobotModel:
    """Load and validate a model file.

    A URDF file loads whole: its tree, fixed joints merged, mimic joints as bodies driven
    by their masters. ``root`` and ``tip`` choose the serial chain between two links of
    a URDF file (joints off it are ignored, fixed links on it merged); ``root`` alone the
    tree below that link; a TOML model gives them in its ``[urdf]`` table instead.
    ``floating`` puts the model on a floating base (a free flyer: the root link and what
    is fixed to it are the base body), as ``floating = true`` in a TOML model's
    ``[model]`` (which then needs the base's ``[base]`` mass, com and inertia) or
    ``[urdf]`` table.

    Raises
    ------
    ModelError
        Unknown key, missing field, wrong shape or non-physical value; the message
        names the file and the key.
    """
    path = model_path(name_or_path)
    text = read_model_text(path)
    if path.suffix.lower() == ".urdf":
        model = parse_urdf(path, text, root=root, tip=tip, floating=floating)
        if root is None and tip is None and not floating:
            return model
        # The file alone does not say which part or which base: the bundle records it
        # (model.chain) and its hash covers it (source_extra).
        extra = f"[chain] root={root} tip={tip}" + (" floating" if floating else "")
        chain = (root, tip, True) if floating else (root, tip)
        return dataclasses.replace(model, source_extra=extra, chain=chain)
    if root is not None or tip is not None:
        raise ModelError(f"{path}: root/tip choose a chain of a URDF file; for a TOML model "
                         "give them in its [urdf] table")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{path}: not valid TOML ({exc})") from None
    except RecursionError:           # arrays or tables nested thousands deep (issue 36)
        raise ModelError(f"{path}: not valid TOML (nested too deeply)") from None
    if isinstance(data, dict) and "urdf" in data:
        return _urdf_reference(path, data, floating)
    if is_soft(data):
        if floating:
            raise ModelError(f"{path}: --floating puts a rigid model on a floating base; "
                             "this is a soft-body model")
        return parse_soft_model(path, data)
    if floating and isinstance(data, dict) and isinstance(data.get("model"), dict):
        if data["model"].get("floating") is not True:
            raise ModelError(f"{path}: model.floating: --floating on a TOML model needs the "
                             "file to declare its base body: floating = true in [model] and "
                             "[base] mass, com and inertia")
    if is_cosserat(data):
        return parse_cosserat_model(path, data)
    return _Parser(path).parse(data)

def as_model(ref):
    """A loaded model (``RobotModel``, ``SoftModel`` or ``CosseratModel``, e.g. a URDF
    chain cut by ``--root``/``--tip``) as it is; a name or path through :func:`load_model`."""
    return ref if isinstance(ref, (RobotModel, SoftModel, CosseratModel)) else load_model(ref)

def _urdf_reference(path: Path, data: dict, floating: bool = False) -> RobotModel:
    """A TOML model that is a URDF file's tree or chain: ``[urdf] file, root, tip,
    floating``, an optional ``[model] name, description`` and optional ``[[actuators]]``
    (as in a TOML model; ``joint`` names a URDF joint or its child link)."""
    r = FileReader(path)
    r.keys(data, "", {"model", "urdf", "actuators"}, {"urdf"})
    model = r.keys(data.get("model", {}), "model", {"name", "description"}, set())
    table = r.keys(data["urdf"], "urdf", {"file", "root", "tip", "floating"}, {"file"})
    fl = table.pop("floating", False)
    if not isinstance(fl, bool):
        raise r.fail("urdf.floating", f"expected true or false, got {fl!r}")
    floating = floating or fl
    for k, v in [*table.items(), *model.items()]:
        if not isinstance(v, str) or not v:
            raise r.fail(f"urdf.{k}" if k in table else f"model.{k}",
                         f"expected a non-empty string, got {v!r}")
    urdf = (path.parent / table["file"]).resolve()
    try:
        text = urdf.read_text()
    except OSError as exc:
        raise r.fail("urdf.file", f"cannot read {urdf} ({exc.strerror})") from None
    name = model.get("name")
    if name is not None and not (name.isascii() and name.isidentifier()
                                 and len(name) <= MAX_NAME):
        raise r.fail("model.name", f"expected a C identifier of at most {MAX_NAME} "
                     f"characters, got {name!r}")
    m = parse_urdf(urdf, text, root=table.get("root"), tip=table.get("tip"), name=name,
                   description=model.get("description"), floating=floating)
    actuators = m.actuators
    if "actuators" in data:
        # URDF joint names become their child links' names (the model's link names);
        # errors name this TOML file, where the actuators are written.
        links = chain_joints(urdf, text, root=table.get("root"), tip=table.get("tip"))
        raw = data["actuators"]
        if isinstance(raw, list):
            for i, t in enumerate(raw):
                j = t.get("joint") if isinstance(t, dict) else None
                if isinstance(j, str) and j not in links and j not in links.values():
                    raise r.fail(f"actuators[{i}].joint", "expected a URDF joint of the chain "
                                 f"({', '.join(links)}) or its child link "
                                 f"({', '.join(links.values())}), got {j!r}")
            raw = [dict(t, joint=links.get(t["joint"], t["joint"]))
                   if isinstance(t, dict) and isinstance(t.get("joint"), str) else t
                   for t in raw]
        actuators = _Parser(path).actuators(raw, list(m.links))
    extra = f"[urdf file] {urdf.name}\n{text}" + ("\n[floating]" if floating and not fl else "")
    return dataclasses.replace(m, path=path, source=str(path.name), actuators=actuators,
                               source_extra=extra,
                               chain=(None, None, True) if floating and not fl else None)
