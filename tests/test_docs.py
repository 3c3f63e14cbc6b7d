"""The documentation site builds in strict mode, documents every public name, and says no internal labels.

The public modules are the API reference pages (``docs/api/<module>.md``, each rendering ``::: <module>``); every
name in their ``__all__`` must appear in the built page (an anchor ``<module>.<name>``, or the defining module's
for a name that the page renders from there) with a non-empty docstring as griffe reads it: a docstring, or a
``#:`` comment for a data attribute. A submodule listed in ``__all__`` must have its own page instead.
"""

from __future__ import annotations

import importlib
import inspect
import os
import re
import subprocess
import sys
from html import unescape
from pathlib import Path

import pytest

pytest.importorskip("mkdocs")
pytest.importorskip("mkdocstrings_handlers.python")
griffe = pytest.importorskip("griffe")

ROOT = Path(__file__).resolve().parents[1]
API = ROOT / "docs" / "api"
PUBLIC_MODULES = sorted(p.stem for p in API.glob("*.md"))

#: the five source documents' short labels and issue numbers must not reach a reader
INTERNAL_LABEL = re.compile(r"\b(?:[Pp]aper 00\d|[Ii]ssue \d+)\b")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "MUJOCO_GL": "disable", "NO_MKDOCS_2_WARNING": "1"}
    res = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env=env,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    return out


@pytest.fixture(scope="module")
def package():
    """smo_gym as griffe reads it for the site, with the site's extension."""
    ext = griffe.load_extensions(f"{ROOT / 'docs' / '_tools' / 'griffe_smo.py'}:SmoGymConventions")
    return griffe.load("smo_gym", search_paths=[str(ROOT)], extensions=ext, docstring_parser="numpy")


def test_the_public_modules_have_pages():
    assert {
        "smo_gym",
        "smo_gym.observers",
        "smo_gym.sensors",
        "smo_gym.wrappers",
        "smo_gym.design",
        "smo_gym.control",
        "smo_gym.mechanics",
        "smo_gym.envs",
        "smo_gym.rl",
        "smo_gym.specs",
    } <= set(PUBLIC_MODULES)
    for module in PUBLIC_MODULES:
        assert f"::: {module}\n" in (API / f"{module}.md").read_text()


def test_the_site_builds_in_strict_mode(site):
    assert (site / "index.html").is_file()
    for module in PUBLIC_MODULES:
        assert (site / "api" / module / "index.html").is_file()


def _documented_as(module: str, name: str, obj) -> list[str]:
    """The anchors under which ``name`` of ``module`` may be rendered: the module's own, or the defining one's."""
    anchors = [f"{module}.{name}"]
    defining = getattr(obj, "__module__", None)
    if isinstance(defining, str) and not inspect.ismodule(obj):
        anchors.append(f"{defining}.{getattr(obj, '__qualname__', name)}")
    return anchors


def _griffe_docstring(package, path: str) -> str:
    obj = package
    for part in path.split(".")[1:]:
        obj = obj.members[part]
    if obj.is_alias:
        obj = obj.final_target
    return (obj.docstring.value if obj.docstring else "").strip()


@pytest.mark.parametrize("module", PUBLIC_MODULES)
def test_every_public_name_is_documented(module, site, package):
    mod = importlib.import_module(module)
    page = (site / "api" / module / "index.html").read_text()
    missing, undocumented = [], []
    for name in mod.__all__:
        obj = getattr(mod, name)
        if inspect.ismodule(obj):
            if not (API / f"{obj.__name__}.md").is_file() or not (obj.__doc__ or "").strip():
                missing.append(name)
            continue
        anchors = [a for a in _documented_as(module, name, obj) if f'id="{a}"' in page]
        if not anchors:
            missing.append(name)
        elif not _griffe_docstring(package, anchors[0]):
            undocumented.append(name)
    assert not missing, f"{module}: not on the API page: {missing}"
    assert not undocumented, f"{module}: no docstring: {undocumented}"


def test_no_internal_labels_reach_the_reader(site):
    offenders = []
    for page in site.rglob("*.html"):
        text = re.sub(r"<[^>]+>", " ", page.read_text())
        offenders += [f"{page.relative_to(site)}: {m.group(0)}" for m in INTERNAL_LABEL.finditer(text)]
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "results").rglob("*"))]:
        if path.is_file() and path.suffix in (".md", ".txt", ".csv"):
            offenders += [f"{path.relative_to(ROOT)}: {m.group(0)}" for m in INTERNAL_LABEL.finditer(path.read_text())]
    assert not offenders, offenders


def test_benchmark_pages_are_built_from_the_results_files(site):
    """The tables come from the files: a row of each file appears on its page, the RL returns as summary.csv
    gives them, and the hook refuses a missing file rather than leaving the marker."""
    pages = {
        "benchmarks/observers": [
            "results/observers/accuracy.md",
            "results/observers/speed.md",
            "results/observers/throughput.md",
        ],
        "benchmarks/wrapper-accuracy": [
            "results/accuracy/gymnasium.md",
            "results/accuracy/uniform.md",
            "results/accuracy/dm_control.md",
        ],
        "benchmarks/wrapper-cost": ["results/wrapper/bench_wrapper.txt", "results/wrapper/bench_resets.txt"],
    }
    for page, files in pages.items():
        html = (site / page / "index.html").read_text()
        rendered = [  # the cells of every table row on the page, as text
            [
                unescape(re.sub(r"<[^>]+>", "", cell)).strip()
                for cell in re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", tr, re.S)
            ]
            for tr in re.findall(r"<tr>(.*?)</tr>", html, re.S)
        ]
        for rel in files:
            lines = (ROOT / rel).read_text().splitlines()
            # the first data row of the file's first table (the line after its header's separator), every cell
            row = next(lines[i + 1] for i, line in enumerate(lines) if line.startswith("|---") and i + 1 < len(lines))
            cells = [cell.strip().replace("**", "").replace("`", "") for cell in row.strip().strip("|").split("|")]
            assert cells in rendered, (page, rel, cells)
    rl = (site / "benchmarks" / "rl" / "index.html").read_text()
    # summary.csv: 751.0, 166.4, 590.3, 922.5 at 120k steps
    assert "751 +- 166 [590, 922] (3)" in rl and "true -&gt; auto" in rl
    assert "InvertedDoublePendulum-v5  large-batch   unwrapped" in rl  # throughput.txt, verbatim
    assert (site / "results" / "rl_benchmark" / "rl_benchmark.png").is_file()
    for html in site.rglob("*.html"):
        assert "<!-- results-" not in html.read_text()


def test_the_returns_table_reads_summary_csv(tmp_path):
    sys.path.insert(0, str(ROOT / "docs" / "_tools"))
    try:
        import hooks
    finally:
        sys.path.pop(0)
    csv = tmp_path / "summary.csv"
    csv.write_text(
        "env,algo,train_sensing,eval_sensing,steps,seeds,mean,std\n"
        "A-v5,PPO,true,true,50000,3,10.4,1.6\nA-v5,PPO,true,est,50000,3,7.5,0.5\nA-v5,PPO,est,est,50000,2,8.0,2.0\n"
        "A-v5,SAC,true,true,50000,1,20.0,0.0\n"
    )
    lines = hooks._results_returns(csv).splitlines()
    assert lines[0] == "| trained on -> evaluated on | A PPO 50k | A SAC 50k |"  # one column per algorithm
    assert lines[2:] == [
        "| true | 10 +- 2 (3) | 20 +- 0 (1) |",
        "| est | 8 +- 2 (2) | - |",
        "| true -> est | 8 +- 0 (3) | - |",
    ]
    csv.write_text(
        "# scripts/rl_benchmark.py --seeds 2 (2026-01-01 00:00 UTC)\n"
        "env,algo,train_sensing,eval_sensing,steps,seeds,mean,std,min,max\n"
        "A-v5,PPO,true,true,50000,2,10.4,1.6,9.2,11.5\n"
    )
    assert hooks._results_returns(csv).splitlines()[2] == "| true | 10 +- 2 [9, 12] (2) |"
