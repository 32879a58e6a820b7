"""``softgen export MODEL --out DIR``: a self-contained C project of a model's bundle.

The project holds the generated ``<model>.c``/``.h`` (copied, unchanged), a hand-written
runtime header (``softgen_rt.h``), typed wrappers emitted from the manifest
(``<model>_api.h``/``.c``: one struct per function with named, sized inputs and
outputs, work buffers sized at compile time, ``init``/``eval``/``free``), a
``Makefile`` and a ``CMakeLists.txt`` (C99, ``-O2``, ``-lm``) and a README. Models with
a shipped controller also get an example, ``main.c``, that runs it against the
generated plant step in a fixed-rate 1 kHz loop (``clock_nanosleep`` on an absolute
deadline) and reports tracking error, compute time and period jitter:

- Theorem 5 (``<model>_theorem5``) on McKibben bundles, σ from
  ``<model>_mckibben_torque`` at the pressures acting now, pressures clipped to
  [0, p_max], plant ``<model>_pneumatic_plant`` (what
  :func:`softgen.control.pneumatic_loop.closed_loop_fun` composes), gains and preset as
  :func:`softgen.experiments.ch10_pneumatic_adaptive.run_case`;
- Slotine–Li (``<model>_slotine_li``, Prop. 10) on the other rigid bundles, plant
  ``<model>_plant_rk4``, gains of the ``rigid-2link-adaptive`` experiment.

:func:`python_loop` runs the same loop with the bundle's casadi.Functions, so that the
C trajectory can be checked against CasADi's own evaluation (the test does, to
1e-12). The export is deterministic: the same model gives the same bytes.

Parts: :mod:`softgen.export.example` (the example's configuration and its Python/CasADi
twin), :mod:`softgen.export.api` (the typed wrappers), ``templates/`` (the
hand-written C, build files and README, filled in by :func:`render`).
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import re
import shlex
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softgen.core.errors import BuildError, BundleError, SoftgenError
from softgen.core.paths import output_dir
from softgen.export.api import api_header, api_source
from softgen.export.example import (ExampleConfig, config_header, example_config, example_kind,
                             example_text, no_example, run_python_loop)

__all__ = ["ExampleConfig", "ExportResult", "bundle_files", "build_project", "example_config",
           "export", "python_loop", "render", "run_python_loop", "summary"]

TEMPLATES = Path(__file__).parent / "templates"

#: Bumped whenever the exported files for the same bundle would change.
EXPORT_VERSION = "1"

# -- which bundle ------------------------------------------------------------------------

@contextlib.contextmanager
def bundle_files(model: str, generated_root: Path | None = None):
    """Yield ``(bundle_dir, manifest, note)`` for ``model``, generating it first if needed.

    A shipped model's bundle is read from ``generated_root`` (default: where ``softgen
    generate`` writes); when it is missing or stale (its model file, CasADi or the code
    generator changed, or its C source does not match the manifest) it is generated
    again there, or in a temporary directory when that is not writable. A model file
    given by path is always generated in a temporary directory. ``note`` says which
    (empty when the bundle was current).
    """
    from softgen.bundles.bundle import check_model_unchanged, generate
    from softgen.codegen.build import check_source, read_manifest
    from softgen.modelfile.model import MODELS_DIR, load_model, model_path
    from softgen.core.paths import GENERATED_DIR, writable

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


def python_loop(model: str, steps: int = 1000, *,
                generated_root: Path | None = None) -> tuple[list[str], np.ndarray]:
    """The example loop of ``softgen export MODEL`` run with CasADi in Python.

    Same functions (rebuilt from the model file, :func:`softgen.bundles.bundle.casadi_functions`),
    same configuration and same order of operations as the exported ``main.c``; returns
    ``(columns, rows)``, one row per sample as its ``--csv`` writes them.
    """
    from softgen.bundles.bundle import casadi_functions
    with bundle_files(model, generated_root) as (_, manifest, _):
        cfg = example_config(manifest)
        if cfg is None:
            raise SoftgenError(f"{manifest['model']}: no example loop ({no_example(manifest)})")
        functions = casadi_functions(manifest)
    return cfg.columns, run_python_loop(cfg, functions, steps)


# -- rendering ---------------------------------------------------------------------------

def _template(name: str, values: dict[str, str], example: bool) -> str:
    """Template ``name`` with ``@KEY@`` replaced and the ``@IF_EXAMPLE@ … @ELSE@ … @END@``
    line blocks (and ``@IF_EXAMPLE_INLINE@ … @END_INLINE@`` spans) kept or dropped."""
    text = (TEMPLATES / name).read_text()
    text = re.sub(r"@IF_EXAMPLE_INLINE@(.*?)@END_INLINE@", lambda mt: mt[1] if example else "",
                  text, flags=re.S)
    out, keep = [], [True]
    for line in text.splitlines(keepends=True):
        tag = line.strip()
        if tag == "@IF_EXAMPLE@":
            keep.append(example)
        elif tag == "@ELSE@":
            keep[-1] = not keep[-1]
        elif tag == "@END@":
            keep.pop()
        elif all(keep):
            out.append(line)
    text = "".join(out)
    for key, value in values.items():
        text = text.replace(f"@{key}@", value)
    left = sorted(set(re.findall(r"@[A-Z_]+@", text)))
    if left:
        raise RuntimeError(f"export template {name}: unfilled placeholders {left}")
    return text

def render(manifest: dict, c_src: bytes, h_src: bytes, manifest_bytes: bytes) -> dict[str, bytes]:
    """The exported project's files (name -> bytes); a function of the bundle only."""
    m = manifest["model"]
    cfg = example_config(manifest)
    example = cfg is not None
    files = {f"{m}.c": c_src, f"{m}.h": h_src,
             "manifest.json": manifest_bytes,
             "softgen_rt.h": (TEMPLATES / "softgen_rt.h").read_bytes(),
             f"{m}_api.h": api_header(manifest, h_src.decode()).encode(),
             f"{m}_api.c": api_source(manifest).encode()}
    title = ("Theorem 5 on the McKibben arm" if cfg and cfg.kind == "theorem5" else
             "Slotine-Li (Prop. 10) on the rigid arm")
    values = {"MODEL": m, "EXAMPLE_TITLE": title}
    if example:
        files["softgen_loop.h"] = (TEMPLATES / "softgen_loop.h").read_bytes()
        files["main.c"] = _template(f"main_{cfg.kind}.c", values, example).encode()
        files["example_config.h"] = config_header(cfg, manifest).encode()
    files["Makefile"] = _template("Makefile.in", values, example).encode()
    files["CMakeLists.txt"] = _template("CMakeLists.txt.in", values, example).encode()
    table = "\n".join(f"- `{f}`: {s.get('doc', '')}" for f, s in manifest["functions"].items())
    files["README.md"] = _template("README.md.in", {
        **values, "MODEL_FILE": manifest.get("model_file", m),
        "HASH": manifest["hash"][:16], "CASADI_VERSION": manifest.get("casadi_version", "?"),
        "EXAMPLE_TEXT": example_text(cfg) if example else "",
        "NO_EXAMPLE_TEXT": f"No example loop exists for {m}: {no_example(manifest)}." if
        not example else "",
        "FUNCTIONS": table}, example).encode()
    record = {"model": m, "bundle_hash": manifest["hash"], "export_version": EXPORT_VERSION,
              "example": cfg.kind if example else None,
              "files": {k: hashlib.sha256(v).hexdigest() for k, v in sorted(files.items())}}
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
    example: str | None          # "theorem5", "slotine_li" or None
    note: str                    # bundle regenerated? ("" if it was current)
    build_seconds: float | None = None
    binary: Path | None = None


def _check_out_dir(out: Path, force: bool) -> None:
    output_dir(out, "--out")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise SoftgenError(f"--out {out}: exists and is not empty; give a new or empty "
                           "directory, or --force to overwrite the exported files")


def export(model: str, out: Path | str, *, force: bool = False, build: bool = False,
           cc: str | None = None, generated_root: Path | None = None) -> ExportResult:
    """Write the C project of ``model``'s bundle to ``out`` (see the module docstring).

    ``out`` must be new or empty unless ``force`` (then the files of the export are
    overwritten, and those a previous export listed in ``softgen_export.json`` but this
    one does not write are removed; nothing else is touched). ``build`` compiles the
    project with the Makefile (``make CC=<compiler>``; without make, the same commands
    directly) and fails with one line if there is no C compiler.
    """
    from softgen.codegen.build import find_compiler
    out = Path(out)
    _check_out_dir(out, force)
    compiler = None
    if build:
        compiler = find_compiler(cc)
        if compiler is None:
            raise SoftgenError("--build: no C compiler found" + (f" ({cc or 'CC'} not on PATH)"
                               if cc else "") + "; install gcc or clang, set CC, or drop --build")
    with bundle_files(model, generated_root) as (bundle, manifest, note):
        m = manifest["model"]
        files = render(manifest, *((bundle / f).read_bytes() for f in
                                   (f"{m}.c", f"{m}.h", "manifest.json")))
    out.mkdir(parents=True, exist_ok=True)
    old = out / RECORD
    if force and old.is_file():
        try:
            previous = json.loads(old.read_text()).get("files", {})
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            previous = {}
        for name in previous:
            if name not in files and "/" not in name and (out / name).is_file():
                (out / name).unlink()
    for name, data in files.items():
        (out / name).write_bytes(data)
    res = ExportResult(out=out, model=m, files=sorted(files), example=example_kind(manifest),
                       note=note)
    if build:
        res.build_seconds, res.binary = build_project(out, m, compiler, res.example is not None)
    return res


def build_project(out: Path, model: str, compiler: str, example: bool) -> tuple[float, Path | None]:
    """Build an exported project with its Makefile; return (seconds, example binary or None)."""
    make = shutil.which("make")
    t0 = time.perf_counter()
    if make:
        cmds = [[make, "-C", str(out), f"CC={compiler}"]]
    else:   # the Makefile's commands, without make
        flags = [compiler, "-std=c99", "-ffp-contract=off", "-O2"]
        objs = [f"{model}.o", f"{model}_api.o"] + (["main.o"] if example else [])
        cmds = [[*flags, "-c", "-o", o, o[:-2] + ".c"] for o in objs]
        if example:
            cmds.append([*flags, "-o", f"{model}_example", *objs, "-lm"])
    for cmd in cmds:
        proc = subprocess.run(cmd, cwd=out, capture_output=True, text=True)
        if proc.returncode != 0:
            raise BuildError(f"building {out} failed ({shlex.join(cmd)})",
                             proc.stderr[-4000:])
    binary = out / f"{model}_example"
    return time.perf_counter() - t0, binary if example else None


def summary(res: ExportResult) -> list[str]:
    """The lines ``softgen export`` prints: where things went and how to build and run."""
    o = shlex.quote(str(res.out))
    lines = [f"softgen export: {res.note}"] if res.note else []
    lines.append(f"wrote {len(res.files)} files to {res.out}: {', '.join(res.files)}")
    if res.example is None:
        lines.append(f"no example loop for {res.model}: it has neither {res.model}_theorem5 nor "
                     f"{res.model}_slotine_li; exported the library, wrappers and build files")
    lines += [f"build: make -C {o}",
              f"   or: cmake -S {o} -B {o}/build && cmake --build {o}/build"]
    if res.build_seconds is not None:
        lines.append(f"built with make in {res.build_seconds:.1f} s")
    if res.example is not None:
        what = "Theorem 5" if res.example == "theorem5" else "Slotine-Li (Prop. 10)"
        lines.append(f"run:   {o}/{res.model}_example [--fast] [--steps N | --seconds S] "
                     f"[--csv FILE] [--rt]   ({what}, 1 kHz; see {o}/README.md)")
    return lines
