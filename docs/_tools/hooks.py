"""MkDocs hooks of smo_gym's documentation: benchmark pages built from the files under ``results/``.

Markers in a page's Markdown, replaced before conversion:

``<!-- results-text: PATH -->``
    a text results file (``results/wrapper/bench_wrapper.txt``): its lines that start with ``|`` are Markdown
    tables and stay so, a first line ``# command, date`` becomes the command in a code block, every other line
    a paragraph.
``<!-- results-returns: PATH -->``
    ``summary.csv`` of ``scripts/rl_benchmark.py`` (its ``#`` lines skipped): mean +- standard deviation over seeds
    of the return, and the range over seeds where the file has ``min`` and ``max``, one row per sensing (trained on
    -> evaluated on), one column per environment, algorithm and budget.

After conversion (every page, the API reference included) the Sphinx roles of the docstrings are made readable:
``:class:`~smo_gym.observers.Levant``` -> ``Levant`` as code.
"""

from __future__ import annotations

import csv
import html
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

_MARKER = re.compile(r"^<!-- (results-text|results-returns): (\S+) -->$", re.MULTILINE)
_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const):<code>(~?)([^<]*)</code>")


def _results_text(path: Path) -> str:
    lines = path.read_text().splitlines()
    out: list[str] = []
    in_table = False
    for k, line in enumerate(lines):
        if line.startswith("|"):
            if not in_table:
                out.append("")
            out.append(line)
            in_table = True
            continue
        if in_table:
            out.append("")
            in_table = False
        if k == 0 and line.startswith("# "):
            out += ["```text", line[2:], "```", ""]
        elif line.strip():
            out += [html.escape(line.strip()) if not line.lstrip().startswith("- ") else line.strip(), ""]
    return "\n".join(out)


def _results_returns(path: Path) -> str:
    with path.open() as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    columns = []  # (env, algorithm, steps) in file order
    cells: dict[tuple[str, str], dict[tuple[str, str, int], str]] = {}
    for r in rows:
        col = (r["env"], r["algo"], int(r["steps"]))
        if col not in columns:
            columns.append(col)
        label = (r["train_sensing"], r["eval_sensing"])
        cell = f"{float(r['mean']):.0f} +- {float(r['std']):.0f}"
        if r.get("min") and r.get("max"):
            cell += f" [{float(r['min']):.0f}, {float(r['max']):.0f}]"
        cells.setdefault(label, {})[col] = f"{cell} ({r['seeds']})"

    def name(label):
        train, ev = label
        return train if train == ev else f"{train} -> {ev}"

    order = sorted(cells, key=lambda lab: (lab[0] != lab[1], list(cells).index(lab)))
    titles = [f"{env.removesuffix('-v5')} {algo} {steps // 1000}k" for env, algo, steps in columns]
    head = "| trained on -> evaluated on | " + " | ".join(titles)
    lines = [head + " |", "|---" * (len(columns) + 1) + "|"]
    for label in order:
        lines.append(f"| {name(label)} | " + " | ".join(cells[label].get(c, "-") for c in columns) + " |")
    return "\n".join(lines)


def on_files(files, config):
    """The figures under ``results/`` join the site at the same relative path (pages link them as
    ``results/...``)."""
    from mkdocs.structure.files import File

    for path in sorted((ROOT / "results").rglob("*.png")):
        files.append(
            File(
                str(path.relative_to(ROOT)),
                src_dir=str(ROOT),
                dest_dir=config["site_dir"],
                use_directory_urls=config["use_directory_urls"],
            )
        )
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    def replace(match: re.Match) -> str:
        kind, rel = match.groups()
        path = ROOT / rel
        if not path.is_file():
            raise FileNotFoundError(
                f"expected the results file {rel} of page {page.file.src_path}, actual value: missing"
            )
        return _results_text(path) if kind == "results-text" else _results_returns(path)

    return _MARKER.sub(replace, markdown)


def on_page_content(content: str, page, config, files) -> str:
    return _ROLE.sub(lambda m: f"<code>{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}</code>", content)
