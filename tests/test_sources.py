"""The sources speak to their readers: papers are cited by author and year, never by an internal number, and
no comment, name or file refers to a work item by its number.

The documentation site is checked as rendered in ``tests/test_docs.py``; this test reads the files themselves
(code, tests, scripts, documentation sources, the README and the changelog, their file names), so that no
build step has to translate them.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: a source document's short number (the word "paper" and three digits starting with 0, with or without a space or
#: an underscore), a work item's number (the words "issue", "task" or "item" and a number), a name ending in a
#: source document's number or starting with one, and the path of the private copies of the papers
INTERNAL_LABEL = re.compile(
    r"(?<![A-Za-z])(?:paper[ _]?0\d\d|issue[ _]?#?\d+|task[ _]?\d+|item ?\d+)(?!\d)"
    r"|(?<=[A-Za-z])_00\d\b"
    r"|(?<![\w.])00\d_\w"
    r"|shared/papers",
    re.IGNORECASE,
)
#: names that carry a number but are no label (none today)
KNOWN: tuple[str, ...] = ()
SUFFIXES = {".py", ".md", ".yml", ".yaml", ".toml", ".txt", ".cfg", ".xml", ".csv"}


def _sources() -> list[Path]:
    files = [ROOT / name for name in ("README.md", "CHANGELOG.md", "CITATION.cff", "mkdocs.yml", "Makefile")]
    for folder in ("smo_gym", "tests", "scripts", "docs"):
        files += [
            p
            for p in sorted((ROOT / folder).rglob("*"))
            if p.is_file() and p.suffix in SUFFIXES and "__pycache__" not in p.parts
        ]
    return [p for p in files if p.resolve() != Path(__file__).resolve()]


def _labels(text: str) -> list[str]:
    for name in KNOWN:
        text = text.replace(name, "")
    return [m.group(0) for m in INTERNAL_LABEL.finditer(text)]


def test_the_pattern_finds_internal_labels_and_nothing_else():
    # the examples are assembled, so that this file holds no label itself
    paper, issue, task = "pa" + "per", "is" + "sue", "ta" + "sk"
    found = _labels(
        f"{paper} 003, {paper.title()} 000's gain, {paper}_001.png, figures/{paper}000, {issue} 14, {issue}_2, "
        f"{task} 3, item 6, reproduce_000(), 000_4235a19db356aa4d.txt, shared/papers/README.md"
    )
    assert len(found) == 11, found
    assert not _labels(
        "Wetzlinger et al., Efimov et al. 2017 (Fig. 1, h0.001_omega250.png), 100_000 steps, 1_000_000, dt=0.001, "
        "0.003 rad, issues, the task's observation, an item of the list, papers"
    )


def test_no_internal_labels_in_the_sources():
    sources = _sources()
    assert len(sources) > 100  # the walk found the tree
    offenders = []
    for path in sources:
        rel = path.relative_to(ROOT).as_posix()
        offenders += [f"{rel} (file name): {label}" for label in _labels(rel)]
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            offenders += [f"{rel}:{number}: {label}" for label in _labels(line)]
    assert not offenders, "\n".join(offenders)
