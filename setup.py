"""Build hook: ship the model files and the generated C sources inside the wheel.

``models/`` and ``generated/`` stay at the top of the repository (the layout the
project documents); a built wheel carries copies under ``softgen/_data/`` so an
installed softgen finds them (``softgen/paths.py``). Compiled libraries are not
shipped: they are built on first use, into the package or the user cache.
"""
import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildPyWithData(build_py):
    def run(self):
        super().run()
        data = Path(self.build_lib) / "softgen" / "_data"
        models = ROOT / "models"
        for src in sorted([*models.glob("*.toml"), *models.glob("*.urdf")]):
            self._copy(src, data / "models" / src.name)
        for bundle in sorted(p for p in (ROOT / "generated").iterdir() if p.is_dir()):
            for src in sorted(bundle.iterdir()):
                if src.is_file() and (src.suffix in (".c", ".h") or src.name == "manifest.json"):
                    self._copy(src, data / "generated" / bundle.name / src.name)

    @staticmethod
    def _copy(src: Path, dst: Path) -> None:
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)


setup(cmdclass={"build_py": BuildPyWithData})
