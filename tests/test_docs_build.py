"""The documentation site builds with ``mkdocs build --strict`` (broken links fail) and stands
alone: offline math, one API page per module with its cross-references rendered, no reference
to files outside the repository or to the machine it was built on."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MATHJAX = "assets/mathjax/es5/tex-mml-chtml.js"
NOTEBOOKS = sorted(p.stem for p in (ROOT / "examples").glob("*.ipynb"))


def _has_math(notebook: str) -> bool:
    cells = json.loads((ROOT / "examples" / f"{notebook}.ipynb").read_text())["cells"]
    return any("$" in "".join(c["source"]) for c in cells if c["cell_type"] == "markdown")


#: Notebooks with math in their Markdown cells.
MATH_NOTEBOOKS = [nb for nb in NOTEBOOKS if _has_math(nb)]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if importlib.util.find_spec("mkdocs") is None:
        pytest.fail("mkdocs is not installed: pip install -e '.[docs]'")
    site = tmp_path_factory.mktemp("docs") / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return site


def _pages(site: Path) -> list[Path]:
    return sorted(site.rglob("*.html"))


def _prose(html: str) -> str:
    """The page without scripts, styles, code blocks and inline code."""
    return re.sub(r"<(script|style|pre|code)\b.*?</\1>", " ", html, flags=re.S)


def _public_modules() -> list[str]:
    out = []
    for path in (ROOT / "conformal_control").rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if not any(p.startswith("_") for p in parts):
            out.append(".".join(parts))
    return sorted(out)


def test_mkdocs_build_strict(site: Path) -> None:
    for page in (
        "index.html",
        "getting-started/index.html",
        "concepts/index.html",
        "controller/index.html",
        "data/index.html",
        "benchmarks/index.html",
        "cli/index.html",
        "api/index.html",
        "changelog/index.html",
        "examples/quickstart/index.html",
    ):
        assert (site / page).is_file(), page
    # generated sections: every parameter and every subcommand, straight from the code
    from conformal_control.cli import build_parser
    from conformal_control.sim.config import PARAMETERS

    controller = (site / "controller/index.html").read_text()
    assert "generated:parameters" not in controller
    for name in PARAMETERS:
        assert f"<code>{name}</code>" in controller, name
    cli = (site / "cli/index.html").read_text()
    subs = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    for name in subs.choices:
        assert f"conformal-control {name}" in cli, name
    started = (site / "getting-started/index.html").read_text()
    assert "generated:run" not in started
    assert started.count("results written to") == 2  # the demo and nexus_4, run at build time
    assert (site / "assets/demo.png").is_file()


def test_algorithm_steps_and_qp_render(site: Path) -> None:
    """Algorithm 1 is a five-item list and the QP is a whole display equation."""
    html = (site / "controller/index.html").read_text()
    section = html.split('id="algorithm-1"', 1)[1].split("<h2", 1)[0]
    ol = re.search(r"<ol>(.*?)</ol>", section, re.S)
    assert ol is not None
    items = re.findall(r"<li>\s*<p>\s*<strong>(\w[\w ]*)</strong>", ol.group(1))
    assert items == ["Sense", "Predict", "Control", "Track", "Score and update"]
    qp = re.search(r'<div class="arithmatex">\\\[(.*?)\\\]</div>', section, re.S)
    assert qp is not None and r"\arg\min_{v \in V}" in qp.group(1) and r"\forall j" in qp.group(1)
    assert r"\begin{aligned}" in qp.group(1)  # two lines: fits the page width


def test_no_cdn_script_and_math_served_locally(site: Path) -> None:
    mathjax = site / MATHJAX
    assert mathjax.is_file() and mathjax.stat().st_size > 500_000
    assert (site / "assets/mathjax/LICENSE").read_text().count("Apache License") >= 1
    fonts = site / "assets/mathjax/es5/output/chtml/fonts/woff-v2"
    assert (fonts / "MathJax_Main-Regular.woff").is_file()
    assert (site / "assets/mathjax/es5/input/tex/extensions/ams.js").is_file()
    for page in _pages(site):
        html = page.read_text()
        rel = page.relative_to(site)
        assert not re.search(r"<script[^>]*\ssrc=\"(https?:)?//", html), rel
        assert not re.search(r"<link[^>]*\shref=\"(https?:)?//[^\"]*\.(css|js)\"", html), rel
        assert not re.search(r"import\(\s*[\"'](https?:)?//", html), rel
        assert not re.search(r"cdn\.jsdelivr|cdnjs\.|unpkg\.com|polyfill\.io", html), rel
    # the math pages and every notebook: math markup, typeset by the local MathJax
    assert len(MATH_NOTEBOOKS) >= 2
    for name in ["concepts", "controller", *(f"examples/{nb}" for nb in NOTEBOOKS)]:
        page = site / name / "index.html"
        html = page.read_text()
        srcs = re.findall(r"<script[^>]*\ssrc=\"([^\"]*tex-mml-chtml\.js)\"", html)
        assert srcs, name
        assert all((page.parent / s).resolve() == mathjax.resolve() for s in srcs), (name, srcs)
        assert "MathJax.Hub" not in html, name  # nbconvert's MathJax-2 loader is gone
        if not name.startswith("examples/") or name.split("/")[1] in MATH_NOTEBOOKS:
            assert 'class="arithmatex"' in html, name
    config = (site / "assets/mathjax-config.js").read_text()
    assert 'processHtmlClass: "arithmatex"' in config


@pytest.mark.parametrize("notebook", MATH_NOTEBOOKS)
def test_notebook_math_is_wrapped(site: Path, notebook: str) -> None:
    """``$...$`` in the notebooks' Markdown cells becomes the site's arithmatex markup."""
    html = (site / "examples" / notebook / "index.html").read_text()
    cells = re.findall(r"jp-RenderedMarkdown[^>]*>(.*?)</div>", html, re.S)
    assert cells
    text = _prose("".join(cells))
    assert not re.search(r"\$[^$\s][^$]*\$", text), "raw $...$ math left in a Markdown cell"
    assert '<span class="arithmatex">\\(' in html


def test_quickstart_math_markup(site: Path) -> None:
    html = (site / "examples/quickstart/index.html").read_text()
    assert r'<span class="arithmatex">\(\lambda_{k+1} = \lambda_k' in html


def test_no_spec_reference_or_machine_path(site: Path) -> None:
    files = [*_pages(site), *site.rglob("*.json"), *site.rglob("*.xml")]
    for path in files:
        text = path.read_text(errors="replace")
        rel = path.relative_to(site)
        for bad in ("/work/", "/root/", "/home/", "SPEC.md", "SPEC §", "SPEC section"):
            assert bad not in text, (rel, bad)
        if path.suffix == ".html":
            # `SPEC` as a command-line metavar (in code) is fine; a citation in prose is not
            assert not re.search(r"\bSPEC\b", _prose(text)), rel


def test_api_reference_one_page_per_module(site: Path) -> None:
    modules = _public_modules()
    assert "conformal_control.cbf.controller" in modules and len(modules) > 50
    api = site / "api"
    pages = []
    for module in modules:
        page = api / module.replace(".", "/") / "index.html"
        assert page.is_file(), module
        assert f'id="{module}"' in page.read_text(), module
        pages.append(page)
    index = (api / "index.html").read_text()
    for module in modules:
        assert f"#{module}" in index, module
    role = re.compile(r":(?:py:)?(mod|meth|class|func|data|attr|obj|exc|const):(`|<code>)")
    for page in [api / "index.html", *pages]:
        found = role.search(page.read_text())
        assert found is None, (page.relative_to(site), found and found.group(0))
    # roles became links, also across modules and to re-exports of private modules
    checks = (site / "api/conformal_control/testing/safety_filter/index.html").read_text()
    assert re.search(r'href="[^"]*cbf/roles/#conformal_control\.cbf\.roles\.SafetyFilter"', checks)
    loop = (site / "api/conformal_control/loop/index.html").read_text()
    assert re.search(r'href="#conformal_control\.loop\.IntervalLog"', loop)
    # each object once, on the page of the module that defines it
    roles = (site / "api/conformal_control/cbf/roles/index.html").read_text()
    cbf = (site / "api/conformal_control/cbf/index.html").read_text()
    assert 'id="conformal_control.cbf.roles.SafetyFilter"' in roles
    assert 'id="conformal_control.cbf.SafetyFilter"' not in cbf
    assert 'href="roles/#conformal_control.cbf.roles.SafetyFilter"' in cbf  # a re-export link
