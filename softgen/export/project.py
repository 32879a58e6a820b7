"""``softgen export MODEL --out DIR``: a self-contained C project of a model and a loop.

The project holds the model's generated bundle (``<model>.c``/``.h``, copied unchanged),
the C of the example scenario's closed-loop diagram (``<model>_loop.c``/``.h``: the one
function ``<model>_loop_step`` of :meth:`softgen.blocks.ClosedLoop.step_fun`, generated
by CasADi's CodeGenerator), typed wrappers of both emitted from their manifests
(``<model>_api.h``/``.c``, ``<model>_loop_api.h``/``.c``), the hand-written runtime
(``softgen_rt.h``) and fixed-rate loop (``softgen_loop.h``), one generic ``main.c`` and
the generated ``scenario.h`` it reads (:mod:`softgen.export.example`), a ``Makefile``, a
``CMakeLists.txt`` (C99, ``-O2``, ``-lm``) and a README.

The scenario is the model's registered example (:mod:`softgen.studies.examples`: the one
the capability decision grants, or ``--example ID``, with ``--set KEY=VALUE`` on its typed
config), and its Python twin is ``scenario.run()``. A model no example serves is refused
in one line before anything is written. The export is deterministic: the same model gives
the same bytes. The files are written as a set (:func:`softgen.core.atomic.write_set`):
all of them complete on disk as temporaries in the same directory before any is renamed
over its namesake, so a full disk leaves an earlier export whole; and
``softgen_export.json``, renamed last, records what was written with each file's sha256,
sealed by a hash of the record itself: ``--force`` removes a file of an earlier export
(after the new set is in place) only when a valid record lists it, it is a name an
export writes (:func:`export_names`) *and* the file still has the recorded hash, so
neither a hand-edited record nor a hand-edited file makes it delete a user's file. A
folder holding files no valid record accounts for (:func:`foreign_files`) is refused
unless ``force_foreign`` (``--force-foreign``).
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shlex
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from softgen.bundles.bundle import check_model_unchanged, generate
from softgen.codegen.build import (build_level, check_source, compiler_reason, find_compiler,
                                   read_manifest)
from softgen.codegen.generate import BundleSpec, Generated
from softgen.codegen.generate import render as render_bundle
from softgen.core import children
from softgen.core.atomic import output_error, write_set
from softgen.core.errors import BuildError, BundleError, SoftgenError
from softgen.core.provenance import seal
from softgen.core.paths import GENERATED_DIR, output_dir, writable
from softgen.export.api import api_header, api_source
from softgen.export.example import example_text, python_loop, scenario_header
from softgen.studies.examples import Example, example_for
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model, model_path
from softgen.modelfile.model import RobotModel
from softgen.modelfile.soft import SoftModel

__all__ = ["ExportResult", "bundle_files", "build_project", "export", "python_loop", "render",
           "summary"]

TEMPLATES = Path(__file__).parent / "templates"

#: Bumped whenever the exported files for the same bundle would change.
EXPORT_VERSION = "2"

# -- which bundle ------------------------------------------------------------------------

@contextlib.contextmanager
def bundle_files(model, generated_root: Path | None = None):
    """Yield ``(bundle_dir, manifest, note)`` for ``model``, generating it first if needed.

    A shipped model's bundle is read from ``generated_root`` (default: where ``softgen
    generate`` writes); when it is missing or stale (its model file, CasADi or the code
    generator changed, or its C source does not match the manifest) it is generated
    again there, or in a temporary directory when that is not writable. A model file
    given by path, or loaded (a URDF chain cut by ``--root``/``--tip``), is always
    generated in a temporary directory. ``note`` says which (empty when the bundle was
    current).
    """
    if isinstance(model, (RobotModel, SoftModel)):
        with tempfile.TemporaryDirectory(prefix="softgen-export-") as tmp:
            bundle = generate(model, Path(tmp))
            chain = f" ({_part_text(model.chain)} of {model.path})" \
                if getattr(model, "chain", None) else ""
            yield bundle, read_manifest(bundle), \
                f"generated {model.name}{chain} in a temporary directory"
        return
    path = model_path(model)            # one ModelError line for an unknown name
    root = Path(generated_root or GENERATED_DIR)
    shipped = path.resolve().parent == MODELS_DIR.resolve()
    why = f"{path} is not a shipped model"
    if shipped:
        bundle = root / path.stem
        try:
            manifest = read_manifest(bundle)
            check_source(bundle, manifest)
            check_model_unchanged(manifest, bundle)
            why = ""
        except BundleError as exc:
            why = str(exc).splitlines()[0]
        if not why:      # current: outside the try, so the caller's errors pass through
            yield bundle, manifest, ""
            return
        if writable(root):
            bundle = generate(path.stem, root)
            yield bundle, read_manifest(bundle), f"regenerated {bundle} ({why})"
            return
    with tempfile.TemporaryDirectory(prefix="softgen-export-") as tmp:
        name = load_model(path).name
        bundle = generate(path, Path(tmp))
        yield bundle, read_manifest(bundle), f"generated {name} in a temporary directory ({why})"


# -- rendering ---------------------------------------------------------------------------

def _chain_text(manifest: dict) -> str:
    """`` --root R --tip T --floating`` of a bundle of a URDF chain or tree (empty for a
    whole file on a fixed base)."""
    chain = manifest.get("model_chain") or {}
    return ("".join(f" --{k} {chain[k]}" for k in ("root", "tip") if chain.get(k))
            + (" --floating" if chain.get("floating") else ""))


def _part_text(chain: tuple) -> str:
    """What ``load_model(..., root=, tip=, floating=)`` took of a URDF file, in words."""
    root, tip = chain[0], chain[1]
    part = (f"the chain {root or 'root'} -> {tip}" if tip else
            f"the tree below {root}" if root else "the whole tree")
    return part + (" on a floating base" if len(chain) > 2 and chain[2] else "")


def _template(name: str, values: dict[str, str]) -> str:
    """Template ``name`` with every ``@KEY@`` replaced (one left over is a bug: raised)."""
    text = (TEMPLATES / name).read_text()
    for key, value in values.items():
        text = text.replace(f"@{key}@", value)
    left = sorted(set(re.findall(r"@[A-Z_]+@", text)))
    if left:
        raise RuntimeError(f"export template {name}: unfilled placeholders {left}")
    return text


def loop_bundle(ex: Example, model: str) -> tuple[dict, bytes, bytes]:
    """``(manifest, C, header)`` of ``<model>_loop_step``, the example diagram's one step."""
    d = ex.loop
    f = d.step_fun()
    if f.name() != f"{model}_loop_step":
        raise SoftgenError(f"scenario {ex.scenario.name}: diagram {d.name}: expected the "
                           f"name {model}_loop (its step names the generated C)")
    files = render_bundle(BundleSpec(
        name=f"{model}_loop", functions=[Generated(f, f"one sample of {d.name}: "
                                                     + " -> ".join(d.order))],
        identity=repr((model, d.describe())).encode()))
    return (json.loads(files["manifest.json"]), files[f"{model}_loop.c"],
            files[f"{model}_loop.h"])


def render(manifest: dict, c_src: bytes, h_src: bytes, manifest_bytes: bytes,
           ex: Example) -> dict[str, bytes]:
    """The exported project's files (name -> bytes); a function of the bundle and the
    example scenario only."""
    m = manifest["model"]
    loop_manifest, loop_c, loop_h = loop_bundle(ex, m)
    files = {f"{m}.c": c_src, f"{m}.h": h_src,
             "manifest.json": manifest_bytes,
             "softgen_rt.h": (TEMPLATES / "softgen_rt.h").read_bytes(),
             f"{m}_api.h": api_header(manifest, h_src.decode()).encode(),
             f"{m}_api.c": api_source(manifest).encode(),
             f"{m}_loop.c": loop_c, f"{m}_loop.h": loop_h,
             f"{m}_loop_api.h": api_header(loop_manifest, loop_h.decode()).encode(),
             f"{m}_loop_api.c": api_source(loop_manifest).encode(),
             "softgen_loop.h": (TEMPLATES / "softgen_loop.h").read_bytes(),
             "main.c": (TEMPLATES / "main.c").read_bytes(),
             "scenario.h": scenario_header(ex, m, manifest["hash"]).encode()}
    values = {"MODEL": m, "EXAMPLE_TITLE": ex.title}
    files["Makefile"] = _template("Makefile.in", values).encode()
    files["CMakeLists.txt"] = _template("CMakeLists.txt.in", values).encode()
    table = "\n".join(f"- `{f}`: {s.get('doc', '')}" for f, s in
                      {**manifest["functions"], **loop_manifest["functions"]}.items())
    files["README.md"] = _template("README.md.in", {
        **values, "MODEL_FILE": manifest.get("model_file", m) + _chain_text(manifest),
        "HASH": manifest["hash"][:16], "CASADI_VERSION": manifest.get("casadi_version", "?"),
        "EXAMPLE_TEXT": example_text(ex), "ORDER": " -> ".join(ex.loop.order),
        # A shipped model's file is recorded relative to the repository: name it instead.
        "MODEL_ARG": m if not Path(manifest.get("model_file", m)).is_absolute()
        else manifest["model_file"],
        "CHAIN_ARGS": "".join(f', {k}="{v}"' for k, v in
                              (manifest.get("model_chain") or {}).items() if v),
        "SECONDS": f"{ex.scenario.n_steps * ex.loop.dt:g}",
        "FUNCTIONS": table}).encode()
    record = {"model": m, "bundle_hash": manifest["hash"], "export_version": EXPORT_VERSION,
              "example": ex.kind,
              "files": {k: hashlib.sha256(v).hexdigest() for k, v in sorted(files.items())}}
    record["seal"] = seal(record)
    files[RECORD] = (json.dumps(record, indent=2) + "\n").encode()
    return files


#: What an export writes about itself: its files and their sha256 (used by --force).
RECORD = "softgen_export.json"


# -- writing and building ----------------------------------------------------------------

@dataclass
class ExportResult:
    """What :func:`export` did."""

    out: Path
    model: str
    files: list[str]
    example: str                 # "slotine_li", "theorem5", "electric_pd", "theorem10"
    note: str                    # bundle regenerated? ("" if it was current)
    kept: list[str]              # files of an earlier export left in place (see export)
    build_seconds: float | None = None
    binary: Path | None = None
    dt: float = 1e-3             # the example's sample time, s


def _check_out_dir(out: Path, force: bool) -> None:
    output_dir(out, "--out")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise SoftgenError(f"--out {out}: exists and is not empty; give a new or empty "
                           "directory, or --force to overwrite the exported files")


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def export_names(model: str) -> set[str]:
    """Every file name an export of ``model`` writes or once wrote (export versions 1-2)."""
    return {f"{model}{suffix}" for suffix in (".c", ".h", "_api.c", "_api.h", "_loop.c",
                                               "_loop.h", "_loop_api.c", "_loop_api.h")} | {
        "manifest.json", "softgen_rt.h", "softgen_loop.h", "main.c", "scenario.h",
        "example_config.h", "Makefile", "CMakeLists.txt", "README.md", RECORD}


def build_products(model: str) -> set[str]:
    """What building an export of ``model`` adds to its folder (the Makefile's objects,
    library and example; CMake's ``build/``): the export's own, never a user's."""
    return {f"{model}{suffix}" for suffix in (".o", "_api.o", "_loop.o", "_loop_api.o",
                                               "_example")} | {"main.o", f"lib{model}.a",
                                                               "build"}


def _record(out: Path) -> dict | None:
    """The sealed record of an earlier export in ``out`` (None: none, or not valid)."""
    try:
        record = json.loads((out / RECORD).read_text())
        if record.get("seal") != seal(record) or not isinstance(record.get("files"), dict) \
                or not isinstance(record.get("model"), str):
            return None
    except (OSError, ValueError, UnicodeDecodeError, AttributeError, TypeError):
        return None
    return record


def foreign_files(out: Path) -> list[str]:
    """Entries of ``out`` that no valid export record accounts for: not listed by the
    earlier export's sealed record, not its record itself, not what building it makes
    (:func:`build_products`). Hidden temporaries of an interrupted export are ours."""
    if not out.is_dir():
        return []
    record = _record(out)
    own = {RECORD} | (set(record["files"]) | build_products(record["model"])
                      if record is not None else set())
    return sorted(p.name for p in out.iterdir()
                  if p.name not in own and not _our_temporary(p.name))


def _our_temporary(name: str) -> bool:
    """``.<file>.<pid>.tmp`` of :func:`softgen.core.atomic.write_set` (and the older
    ``mkstemp`` names ``.<file>.<random>.tmp``)."""
    return name.startswith(".") and name.endswith(".tmp")


def _clean_temporaries(out: Path) -> None:
    """Temporaries of an export killed before its renames (its process is gone)."""
    if not out.is_dir():
        return
    for p in out.iterdir():
        if not (_our_temporary(p.name) and p.is_file()):
            continue
        pid = p.name[:-len(".tmp")].rpartition(".")[2]
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
            p.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def previous_files(out: Path) -> dict[str, str]:
    """The files a valid earlier record of ``out`` lists, with their sha256.

    Empty when there is no record, or it is not valid JSON, or its seal does not match
    its content (hand-edited). Only names an export of the record's model writes
    (:func:`export_names`) are returned, so that not even a re-sealed record can point
    at a file of another name."""
    record = _record(out)
    if record is None:
        return {}
    files, model = record["files"], record["model"]
    own = export_names(model) - {RECORD}
    return {k: v for k, v in files.items() if k in own and isinstance(v, str)}


def export(model, out: Path | str, *, force: bool = False, build: bool = False,
           cc: str | None = None, generated_root: Path | None = None,
           example: str | None = None, overrides: dict | None = None,
           force_foreign: bool = False,
           progress: Callable[[str], None] | None = None) -> ExportResult:
    """Write the C project of ``model`` to ``out`` (see the module docstring).

    ``out`` must be new or empty unless ``force``: then the files of this export are
    written over, and a file an earlier export wrote but this one does not is removed
    only if the earlier (sealed) record lists it and its content still has the recorded
    sha256; anything else is left in place (``ExportResult.kept``). ``build`` compiles
    the project with the Makefile (``make CC=<compiler>``; without make, the same
    commands directly) and fails with one line if there is no C compiler.
    """
    out = Path(out)
    _check_out_dir(out, force)
    foreign = foreign_files(out) if force else []
    if foreign and not force_foreign:
        shown = ", ".join(foreign[:4]) + (f" and {len(foreign) - 4} more"
                                          if len(foreign) > 4 else "")
        raise SoftgenError(f"--out {out}: holds files no softgen export record lists "
                           f"({shown}); --force replaces only an earlier export's files: "
                           "choose another --out, or add --force-foreign to write the "
                           "export among them (same-named files are overwritten)")
    compiler = None
    if build:
        compiler = find_compiler(cc)
        if compiler is None:
            raise SoftgenError("--build: no C compiler found" + (f" ({cc or 'CC'} not on PATH)"
                               if cc else "") + "; install gcc or clang, set CC, or drop --build")
    say = progress or (lambda line: None)       # phase lines: never a silent minute
    say("export: deriving the example scenario and generating its C ...")
    ex = example_for(model, example=example, overrides=overrides)
    with bundle_files(model, generated_root) as (bundle, manifest, note):
        m = manifest["model"]
        files = render(manifest, *((bundle / f).read_bytes() for f in
                                   (f"{m}.c", f"{m}.h", "manifest.json")), ex)
    kept = _write_files(out, files, force)
    res = ExportResult(out=out, model=m, files=sorted(files), example=ex.kind, note=note,
                       kept=kept, dt=ex.dt)
    if build:
        say(f"export: building {out} with make ...")
        res.build_seconds, res.binary = build_project(out, m, compiler)
    return res


def _write_files(out: Path, files: dict[str, bytes], force: bool) -> list[str]:
    """Write the export's files into ``out``; return the earlier export's files kept.

    The new set is written complete first, as hidden temporaries beside the files they
    replace, and only then renamed over them, the record last (it vouches for the
    others): a full disk or an interrupt while writing leaves the earlier export whole
    (issue 36: its sources were deleted first, then the writes failed). Then, with
    ``force``, a file of the earlier export that this one does not write is removed if
    its (sealed) record lists it with the hash it still has, and kept otherwise.
    """
    _clean_temporaries(out)
    earlier = previous_files(out) if force else {}
    write_set(out, files, last=(RECORD,))
    kept = []
    for name, digest in sorted(earlier.items()):
        path = out / name
        if name in files or not path.is_file() or path.is_symlink():
            continue
        if _sha256(path) == digest:
            try:
                path.unlink()
            except OSError as exc:
                raise output_error(path, exc) from None
        else:
            kept.append(name)
    return kept


def build_project(out: Path, model: str, compiler: str) -> tuple[float, Path]:
    """Build an exported project with its Makefile; return (seconds, example binary)."""
    make = shutil.which("make")
    t0 = time.perf_counter()
    # The Makefile's -O2, or $SOFTGEN_BUILD_LEVEL (codegen.build.build_level) when set.
    level = build_level("-O2")
    if make:
        # make runs in the project folder (cwd): "-C out" on top of it made any relative
        # --out fail (issue 36).
        cmds = [[make, f"CC={compiler}", *([f"CFLAGS={level}"] if level != "-O2" else [])]]
    else:   # the Makefile's commands, without make
        flags = [compiler, "-std=c99", "-ffp-contract=off", level]
        objs = [f"{model}.o", f"{model}_api.o", f"{model}_loop.o", f"{model}_loop_api.o",
                "main.o"]
        cmds = [[*flags, "-c", "-o", o, o[:-2] + ".c"] for o in objs]
        cmds.append([*flags, "-o", f"{model}_example", *objs, "-lm"])
    for cmd in cmds:
        proc = children.run(cmd, cwd=out)           # ends with softgen (issue 36)
        if proc.returncode != 0:
            raise BuildError(f"building {out} failed ({shlex.join(cmd)} in {out}): "
                             f"{compiler_reason(proc.stderr)}", proc.stderr[-4000:])
    return time.perf_counter() - t0, out / f"{model}_example"


def summary(res: ExportResult) -> list[str]:
    """The lines ``softgen export`` prints: where things went and how to build and run."""
    o = shlex.quote(str(res.out))
    lines = [f"softgen export: {res.note}"] if res.note else []
    lines.append(f"wrote {len(res.files)} files to {res.out}: {', '.join(res.files)}")
    if res.kept:
        lines.append(f"kept {', '.join(res.kept)}: listed by the earlier export but changed "
                     "since, so not removed")
    lines += [f"build: make -C {o}",
              f"   or: cmake -S {o} -B {o}/build && cmake --build {o}/build"]
    if res.build_seconds is not None:
        lines.append(f"built with make in {res.build_seconds:.1f} s")
    lines.append(f"run:   {o}/{res.model}_example [--fast] [--steps N | --seconds S] "
                 f"[--csv FILE] [--rt] [--check]   ({res.example}, {1 / res.dt:g} Hz; see "
                 f"{o}/README.md)")
    return lines
