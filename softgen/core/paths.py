"""Where softgen reads its model files and generated bundles, and where it caches builds.

From a checkout (or an editable install) the model files are ``models/`` and the
bundles ``generated/`` of the repository. From an installed wheel they are package
data (``softgen/_data/models``, ``softgen/_data/generated``), found with
:mod:`importlib.resources`. Either can be overridden:

``SOFTGEN_MODELS_DIR``
    a directory of model files (``<name>.toml``);
``SOFTGEN_GENERATED_DIR``
    where ``softgen generate`` writes bundles and where ``load_bundle`` looks;
``SOFTGEN_CACHE_DIR``
    compiled run-time loops and, when a bundle's own directory is read-only (a
    system-wide install), its compiled library. Default ``$XDG_CACHE_HOME/softgen``
    or ``~/.cache/softgen``.

This module imports nothing of softgen, so every layer may use it.
"""
from __future__ import annotations

import os
import sys
import tempfile
from importlib import resources
from pathlib import Path

from softgen.core.atomic import check_dir

#: The repository root when running from a checkout.
_CHECKOUT = Path(__file__).resolve().parents[2]


def _data_root() -> Path:
    if (_CHECKOUT / "pyproject.toml").is_file() and (_CHECKOUT / "models").is_dir():
        return _CHECKOUT
    return Path(str(resources.files("softgen") / "_data"))


def _env_dir(name: str, default: Path) -> Path:
    v = os.environ.get(name)
    return Path(v).expanduser().resolve() if v else default


DATA_ROOT = _data_root()
MODELS_DIR = _env_dir("SOFTGEN_MODELS_DIR", DATA_ROOT / "models")
GENERATED_DIR = _env_dir("SOFTGEN_GENERATED_DIR", DATA_ROOT / "generated")

#: Suffixes of model files, in the order a bare name looks them up in ``models/``.
MODEL_SUFFIXES = (".toml", ".urdf")


def cache_dir() -> Path:
    """The user-level cache of compiled libraries (see the module docstring).

    A cache that cannot be used (a file in its path, no write permission, a read-only
    file system) is not an error: builds go to a private temporary directory instead,
    said once on stderr (issue 23: the compile failed with a traceback).
    """
    env = os.environ.get("SOFTGEN_CACHE_DIR")
    if env:
        wanted = Path(env).expanduser()
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        wanted = (Path(xdg) if xdg else Path.home() / ".cache") / "softgen"
    why = _unusable(wanted)
    if why is None:
        return wanted
    fallback = Path(tempfile.gettempdir()) / f"softgen-cache-{os.getuid()}"
    if wanted not in _WARNED:
        _WARNED.add(wanted)
        print(f"softgen: warning: cache {wanted} is not usable ({why}); compiled "
              f"libraries go to {fallback} (set SOFTGEN_CACHE_DIR to choose)", file=sys.stderr)
    fallback.mkdir(mode=0o700, exist_ok=True)
    return fallback


_WARNED: set[Path] = set()


def _unusable(d: Path) -> str | None:
    """Why ``d`` cannot hold the cache (created here if it can be), or None."""
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    if not (d.is_dir() and os.access(d, os.W_OK | os.X_OK)):
        return "not writable"
    return None


def writable(directory: Path) -> bool:
    """Whether files can be created in ``directory`` (or in the ancestor that exists)."""
    d = Path(directory)
    while not d.exists():
        d = d.parent
    return d.is_dir() and os.access(d, os.W_OK | os.X_OK)


def derived_output(source: str | Path, suffix: str) -> Path:
    """``<source stem><suffix>`` beside ``source``; in the current directory when the
    source is shipped inside the package (the README's sample log), no place to write
    into (an installed package, or the repository's own tree)."""
    source = Path(source)
    package = Path(__file__).resolve().parents[1]
    if package in source.resolve().parents:
        return Path.cwd() / f"{source.stem}{suffix}"
    return source.with_name(f"{source.stem}{suffix}")


def output_dir(path: str, flag: str) -> Path:
    """``path`` as a directory that can be written (or created), checked before any work.

    Nothing is created here: a run that fails later leaves no empty directory behind.
    """
    return check_dir(path, flag)
