"""The README's Python snippets run verbatim, each in a fresh namespace, from the repository root."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line, source)`` of every fenced ```python block of a Markdown text."""
    blocks = []
    for match in re.finditer(r"^```python\n(.*?)^```", text, flags=re.M | re.S):
        blocks.append((text.count("\n", 0, match.start()) + 1, match.group(1)))
    return blocks


BLOCKS = python_blocks(README.read_text())


def test_the_readme_has_python_snippets():
    assert len(BLOCKS) >= 3


@pytest.mark.parametrize("line, source", BLOCKS, ids=[f"line{line}" for line, _ in BLOCKS])
def test_readme_snippet_runs(line, source, private_calibration_cache, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # snippets that write files write them here
    exec(compile(source, f"README.md:{line}", "exec"), {"__name__": "__readme__"})
