"""The README's Python examples run as written (each ```python block, in a fresh namespace)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"^( *)```python\n(.*?)^\1```", README.read_text(), re.M | re.S)


def _dedent(indent: str, code: str) -> str:
    return "\n".join(line.removeprefix(indent) for line in code.splitlines())


def test_the_readme_has_python_examples():
    assert len(BLOCKS) >= 2


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_python_example_runs(index):
    indent, code = BLOCKS[index]
    namespace: dict = {}
    exec(compile(_dedent(indent, code), f"README.md python block {index}", "exec"), namespace)
    if "record" in namespace:  # the depth wrapper around IK interpolation: an episode ran
        assert namespace["record"].steps > 0
