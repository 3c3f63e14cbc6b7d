"""The README's Python snippets run verbatim, each in a fresh namespace, from the repository root."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


#: a line ``<!-- no-test: reason -->`` right before a ```python fence exempts that block (software that is not a
#: dependency, such as RLlib); the reason is required
NO_TEST = re.compile(r"^<!-- no-test: \S.* -->\n\Z")


def python_blocks(text: str) -> list[tuple[int, str, bool]]:
    """``(line, source, tested)`` of every fenced ```python block of a Markdown text."""
    blocks = []
    for match in re.finditer(r"^```python\n(.*?)^```", text, flags=re.M | re.S):
        before = text[text.rfind("\n", 0, max(match.start() - 1, 0)) + 1 : match.start()]
        blocks.append((text.count("\n", 0, match.start()) + 1, match.group(1), not NO_TEST.match(before)))
    return blocks


ALL_BLOCKS = python_blocks(README.read_text())
BLOCKS = [(line, source) for line, source, tested in ALL_BLOCKS if tested]


def test_the_readme_has_python_snippets():
    """The quickstarts run: an observer, a wrapped environment, Stable-Baselines3."""
    assert len(BLOCKS) >= 3
    sources = "\n".join(source for _, source in BLOCKS)
    for quickstart in ("observers.Levant", "wrappers.EstimatedVelocity", "model.learn"):
        assert quickstart in sources


def test_no_test_marks_only_the_next_block():
    text = (
        "x\n<!-- no-test: not installed -->\n```python\nA\n```\n\n```python\nB\n```\n"
        "<!-- no-test -->\n```python\nC\n```\n"
    )  # the last mark gives no reason: not honoured
    blocks = [(source, tested) for _, source, tested in python_blocks(text)]
    assert blocks == [("A\n", False), ("B\n", True), ("C\n", True)]


@pytest.mark.parametrize("line, source", BLOCKS, ids=[f"line{line}" for line, _ in BLOCKS])
def test_readme_snippet_runs(line, source, private_calibration_cache, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # snippets that write files write them here
    exec(compile(source, f"README.md:{line}", "exec"), {"__name__": "__readme__"})
