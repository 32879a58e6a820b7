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
    """The user-level cache of compiled libraries (see the module docstring)."""
    env = os.environ.get("SOFTGEN_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "softgen"


def writable(directory: Path) -> bool:
    """Whether files can be created in ``directory`` (or in the ancestor that exists)."""
    d = Path(directory)
    while not d.exists():
        d = d.parent
    return d.is_dir() and os.access(d, os.W_OK | os.X_OK)


def output_dir(path: str, flag: str) -> Path:
    """``path`` as a directory that can be written (or created), checked before any work.

    Nothing is created here: a run that fails later leaves no empty directory behind.
    """
    return check_dir(path, flag)
