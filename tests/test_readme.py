"""The README's Python code blocks run as written (a newcomer copies them)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_readme_has_python_examples():
    assert len(BLOCKS) >= 3


@pytest.mark.parametrize("k", range(len(BLOCKS)))
def test_readme_block_runs(k, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)        # nothing may depend on the checkout as cwd
    code = compile(BLOCKS[k], f"README.md python block {k + 1}", "exec")
    exec(code, {"__name__": f"readme_block_{k + 1}"})
