"""The documentation builds with ``mkdocs build --strict`` (broken links fail) and stands
alone: offline math, one API page per module with its cross-references rendered, no reference
to files outside the repository or to the machine it was built on.

The sources are checked too: every Python block of the pages in :data:`EXECUTED` runs (in a
fresh interpreter, in a temporary folder) and prints exactly the output shown after it; every
install line is the README's set-up command, which installs every extra and plugin; no page,
notebook or example mentions SPEC or an absolute path of the machine.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conformal_control.data.ethucy import ETHUCY_RECORDINGS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
MATHJAX = "assets/mathjax/es5/tex-mml-chtml.js"
NOTEBOOKS = sorted(p.stem for p in (ROOT / "examples").glob("*.ipynb"))


def _has_math(notebook: str) -> bool:
    cells = json.loads((ROOT / "examples" / f"{notebook}.ipynb").read_text())["cells"]
    return any("$" in "".join(c["source"]) for c in cells if c["cell_type"] == "markdown")


#: Notebooks with math in their Markdown cells.
MATH_NOTEBOOKS = [nb for nb in NOTEBOOKS if _has_math(nb)]


#: A line of mkdocs' log at level WARNING or above (``WARNING -  ...``, ``ERROR -  ...``).
_LOGGED_PROBLEM = re.compile(r"^\s*(WARNING|ERROR|CRITICAL)\b", re.M)


@pytest.fixture(scope="module")
def build_log(tmp_path_factory: pytest.TempPathFactory, data_root: Path) -> tuple[Path, str]:
    """``mkdocs build --strict`` at its normal verbosity (no ``-q``, which hides warnings);
    the runs shown on the pages read the data where a user's commands do, here
    ``$CONFORMAL_CONTROL_DATA``."""
    if importlib.util.find_spec("mkdocs") is None:
        pytest.fail("mkdocs is not installed: pip install -e '.[docs]'")
    site = tmp_path_factory.mktemp("docs") / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "CONFORMAL_CONTROL_DATA": str(data_root)}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log
    return site, log


@pytest.fixture(scope="module")
def site(build_log: tuple[Path, str]) -> Path:
    return build_log[0]


def test_mkdocs_build_logs_no_warning(build_log: tuple[Path, str]) -> None:
    """Zero warnings, not merely under the strict limit: a fresh install builds cleanly."""
    _, log = build_log
    assert "Documentation built in" in log, log[-2000:]
    problems = [ln for ln in log.splitlines() if _LOGGED_PROBLEM.match(ln)]
    assert problems == [], "\n".join(problems)


def test_each_object_has_one_primary_page() -> None:
    """Pages other than the API reference link to it instead of rendering modules again
    (an object rendered twice has two primary URLs: autorefs warns and strict mode fails)."""
    for page in sorted((ROOT / "docs").rglob("*.md")):
        rendered = re.findall(r"^:::\s*(\S+)", page.read_text(), re.M)
        assert not rendered, (page.relative_to(ROOT), rendered)


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
    from conformal_control.runs.params import PARAMETERS

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
    # the demo, nexus_4 and nexus_4 with a = 1, run at build time with the data
    assert started.count("results written to") == 3
    assert (site / "assets/demo.png").is_file()


def test_generated_outputs_are_there_when_built_with_the_data(site: Path) -> None:
    """Every generated block of a page that needs the data holds what the commands print
    (the build reads the data where a user's commands do): no placeholder anywhere."""
    for page in _pages(site):
        html = page.read_text()
        assert "not generated when this page was built" not in html, page
    started = (site / "getting-started/index.html").read_text()
    rows = _table_rows(started, "conformal-control run ...", "success", "t_goal")
    assert len(rows) == 6 and all(r[1] == "true" and r[2].endswith(" s") for r in rows), rows
    assert "keeps lambda above that floor" in started
    text = re.sub(r"<[^>]+>", "", started)
    assert re.search(r"\$ conformal-control run --scene nexus_4 --param a=1", text)
    data = (site / "data/index.html").read_text()
    rows = _table_rows(data, "scene", "walkable box x (m)", "y (m)")
    assert [r[0] for r in rows] == [f"ethucy:{r}" for r in ETHUCY_RECORDINGS], rows
    assert all(r[9].endswith(" m") for r in rows), rows


def _hooks():
    """``docs/hooks.py``, as mkdocs loads it."""
    spec = importlib.util.spec_from_file_location("_docs_hooks", ROOT / "docs" / "hooks.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "generate",
    [
        lambda h: h.cli_run_output("--scene", "nexus_4"),
        lambda h: h.run_output("--scene sdd:nexus/video3 --start 0.05,0.5 --goal 0.95,0.5"),
        lambda h: h.run_table("nexus_4-variants"),
        lambda h: h.ethucy_tasks(),
    ],
    ids=["run-nexus_4", "run ARGS", "runs NAME", "ethucy-tasks"],
)
def test_a_generated_output_without_its_data_fails_the_strict_build(
    generate, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Built as a new user builds it, without the data: each generated output that needs it
    logs a warning on mkdocs' logger, which ``mkdocs build --strict`` counts and aborts on
    (the issue: the page said the data was missing and the strict build passed)."""
    import logging

    from mkdocs.utils import CountHandler

    hooks = _hooks()
    monkeypatch.setenv("CONFORMAL_CONTROL_DATA", str(tmp_path / "no-data"))
    counter = CountHandler()  # what mkdocs' strict mode counts (mkdocs.commands.build)
    counter.setLevel(logging.WARNING)
    logging.getLogger("mkdocs").addHandler(counter)
    try:
        text = generate(hooks)
    finally:
        logging.getLogger("mkdocs").removeHandler(counter)
    assert "not generated when this page was built" in text and "not found" in text
    assert counter.get_counts() == [("WARNING", 1)]


def _table_rows(html: str, *header: str) -> list[list[str]]:
    """The rows of the page's tables whose columns start with ``header``, as cell texts."""
    out = []
    for table in re.findall(r"<table>(.*?)</table>", html, re.S):
        head = [
            re.sub(r"<[^>]+>", "", h).strip()
            for h in re.findall(r"<th[^>]*>(.*?)</th>", table, re.S)
        ]
        if tuple(head[: len(header)]) == header:
            rows = re.findall(r"<tr>(.*?)</tr>", table.split("</thead>", 1)[1], re.S)
            cells = [re.findall(r"<td[^>]*>(.*?)</td>", r, re.S) for r in rows]
            out += [[re.sub(r"<[^>]+>", "", c).strip() for c in row] for row in cells]
    assert out, f"no table headed {header}"
    return out


def test_plugin_pages_are_generated_from_the_registry(site: Path) -> None:
    """Plugins' role table lists, per role, every plugin the registry holds now (this
    package's and the installed packages'), its base class and check list; the
    ``conformal-control plugins`` outputs carry this version; Write your own plugin
    documents every field of ``PredictionQuery`` and ``Forecast``."""
    import dataclasses

    import conformal_control
    from conformal_control.core import registry
    from conformal_control.predictors.base import Forecast, PredictionQuery
    from conformal_control.testing import ROLE_BASES

    html = (site / "plugins/index.html").read_text()
    rows = {r[0]: r for r in _table_rows(html, "role", "entry-point group", "base class")}
    assert list(rows) == list(registry.ROLES), list(rows)
    packages = {r[0]: r for r in _table_rows(html, "package", "version", "plugins")}
    for role, group in registry.ROLES.items():
        _, grp, base, checks, names = rows[role]
        assert ROLE_BASES[role].__name__ == base and grp == group, rows[role]
        assert checks.startswith("check_"), checks
        assert [n.strip() for n in names.split(",")] == registry.names(role), (role, names)
        for e in registry.entries(role):
            if e.origin != "conformal-control":
                assert e.name in packages[e.origin][2], (e.origin, e.name)
    assert {"conformal-control-kalman", "conformal-control-example-plugin"} <= set(packages)
    assert "from conformal_control import Predictor, Barrier" in re.sub(r"<[^>]+>", "", html)
    version = f"[conformal-control {conformal_control.__version__}]"
    assert html.count(version) > len(registry.names("predictor")) // 2, version
    assert "generated:" not in html
    mine = (site / "write-your-own-plugin/index.html").read_text()
    assert "generated:" not in mine and version in mine
    assert not re.search(r":(meth|func|class|attr):", _prose(mine))  # roles became code
    documented = {r[0] for r in _table_rows(mine, "field")}
    for cls in (PredictionQuery, Forecast):
        assert {f.name for f in dataclasses.fields(cls)} <= documented, cls.__name__
    # the example package's files are shown as they are (included, then highlighted)
    assert '<span class="nc">DistanceSquaredBarrier</span>' in mine and "einsum" in mine
    assert "8&lt;--" not in mine


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


#: TeX that was not typeset: subscripts and superscripts in braces, backslash commands, a
#: Greek letter with an underscore subscript (unicode subscripts such as λ₁ are typography)
RAW_MATH = re.compile(
    r"_\{|\^\{|\\(?:frac|lambda|varepsilon|eta|alpha|sum|le|ge|text)\b|[λεηαγτσρ]_[\w{(]"
)


def test_math_is_typeset_on_every_page(site: Path) -> None:
    """No narrative page shows raw math in its prose: formulas are arithmatex spans that
    MathJax typesets (the API pages quote docstrings, written in ASCII for ``help()``)."""
    checked = 0
    for page in _pages(site):
        rel = page.relative_to(site).as_posix()
        if rel.startswith(("api/", "assets/")):
            continue
        html = page.read_text()
        text = re.sub(r'<(span|div) class="arithmatex">.*?</\1>', " ", html, flags=re.S)
        text = re.sub(r"<[^>]+>", " ", _prose(text))
        found = RAW_MATH.search(text)
        assert found is None, (rel, text[max(found.start() - 60, 0) : found.end() + 40])
        checked += 1
    assert checked > 20
    repro = (site / "reproducing/index.html").read_text()
    assert r"\lambda_1 - \lambda_{K+1}" in repro  # the identity, as math


def test_tables_fit_or_scroll(site: Path) -> None:
    """Every page loads the table style: names in code are never broken inside a cell (the
    table scrolls sideways in Material's scroll frame instead), and the content column
    grows on wide screens."""
    css = (site / "assets/tables.css").read_text()
    rule = re.search(r"\.md-typeset table:not\(\[class\]\) code \{([^}]*)\}", css)
    assert rule is not None and "white-space: nowrap" in rule.group(1)
    assert re.search(r"\.md-grid \{\s*max-width: 80rem", css)
    for page in ("benchmark/index.html", "update-rules/index.html", "index.html"):
        html = (site / page).read_text()
        assert re.search(r'<link[^>]*href="[^"]*assets/tables\.css"', html), page


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
    assert "conformal_control.families.cbf.controller" in modules and len(modules) > 50
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
    assert re.search(
        r'href="[^"]*families/cbf/roles/#conformal_control\.families\.cbf\.roles\.SafetyFilter"',
        checks,
    )
    loop = (site / "api/conformal_control/core/loop/index.html").read_text()
    assert re.search(r'href="#conformal_control\.core\.loop\.IntervalLog"', loop)
    # each object once, on the page of the module that defines it
    roles = (site / "api/conformal_control/families/cbf/roles/index.html").read_text()
    cbf = (site / "api/conformal_control/families/cbf/index.html").read_text()
    assert 'id="conformal_control.families.cbf.roles.SafetyFilter"' in roles
    assert 'id="conformal_control.families.cbf.SafetyFilter"' not in cbf
    # a re-export link
    assert 'href="roles/#conformal_control.families.cbf.roles.SafetyFilter"' in cbf


# ---------------------------------------------------------------------------- the sources
#: Pages whose Python blocks are executed; each block is followed by the output it prints.
EXECUTED = ("README.md", "docs/getting-started.md")
_FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```[ \t]*$", re.S | re.M)


#: pymdownx.snippets' include block: ``--8<--``, a path from the repository's root per
#: line, ``--8<--`` (the block form: not Python, so the formatter leaves it alone).
_SNIPPET = re.compile(r"^--8<--[ \t]*\n(.*?)^--8<--[ \t]*$", re.M | re.S)


def expand_snippets(code: str) -> str:
    """A block as the site shows it: the included files in place of their snippet block."""

    def files(m: re.Match[str]) -> str:
        paths = [p.strip() for p in m.group(1).splitlines() if p.strip()]
        return "\n".join((ROOT / p).read_text().rstrip("\n") for p in paths)

    return _SNIPPET.sub(files, code)


def code_blocks(path: Path) -> list[tuple[str, str, str, str | None]]:
    """``(section heading, language, code, output shown right after it or None)`` per block
    (included files expanded)."""
    text = path.read_text()
    matches = list(_FENCE.finditer(text))
    out = []
    for i, m in enumerate(matches):
        headings = re.findall(r"^#+ (.+)$", text[: m.start()], re.M)
        nxt = matches[i + 1] if i + 1 < len(matches) else None
        shown = None
        if nxt is not None and nxt.group(1) == "text" and not text[m.end() : nxt.start()].strip():
            shown = nxt.group(2)
        code = expand_snippets(m.group(2))
        out.append((headings[-1] if headings else "", m.group(1), code, shown))
    return out


def _python_blocks() -> dict[str, list[tuple[str, str | None]]]:
    """Each distinct executed block -> where it is shown and the output shown there."""
    blocks: dict[str, list[tuple[str, str | None]]] = {}
    for page in EXECUTED:
        for heading, lang, code, shown in code_blocks(ROOT / page):
            if lang == "python":
                blocks.setdefault(code, []).append((f"{page}: {heading}", shown))
    return blocks


PYTHON_BLOCKS = _python_blocks()


def _section_block(page: str, words: str) -> str:
    found = [
        c
        for h, lang, c, _ in code_blocks(ROOT / page)
        if lang == "python" and words.lower() in h.lower()
    ]
    assert len(found) == 1, (page, words, len(found))
    return found[0]


@pytest.mark.parametrize("code", list(PYTHON_BLOCKS), ids=[v[0][0] for v in PYTHON_BLOCKS.values()])
def test_python_blocks_run_and_print_what_the_page_shows(
    code: str, tmp_path: Path, data_root: Path
) -> None:
    env = {**os.environ, "CONFORMAL_CONTROL_DATA": str(data_root), "MPLBACKEND": "Agg"}
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    for where, shown in PYTHON_BLOCKS[code]:
        assert shown is not None, f"{where}: show the block's output in a text block after it"
        assert proc.stdout.rstrip() == shown.rstrip(), where


#: Pages whose Python blocks run in order in one interpreter, as a reader types them (a
#: block uses the classes earlier blocks defined); a block that prints shows its output in
#: a text block right after it, and one that shows none prints nothing.
SESSION_PAGES = (
    "docs/plugins.md",
    "docs/write-your-own-plugin.md",
    "docs/update-rules.md",
    "docs/crowds.md",
    "docs/mpc.md",
)

#: Runs the blocks (JSON list on stdin) in ``__main__`` (so that the contract kit can pickle
#: the classes they define), one stdout capture per block, calls of deprecated API from a
#: block as errors; prints the captures as JSON.
_SESSION = """
import contextlib, io, json, sys, warnings
import __main__
warnings.filterwarnings("error", category=DeprecationWarning, module="__main__")
warnings.filterwarnings("error", category=FutureWarning, module="__main__")
_blocks, _out = json.load(sys.stdin), []
for _i, _code in enumerate(_blocks):
    _buf = io.StringIO()
    with contextlib.redirect_stdout(_buf):
        exec(compile(_code, f"<block {_i + 1}>", "exec"), __main__.__dict__)
    _out.append(_buf.getvalue())
print(json.dumps(_out))
"""


@pytest.mark.parametrize("page", SESSION_PAGES)
def test_session_pages_run_and_print_what_they_show(
    page: str, tmp_path: Path, data_root: Path
) -> None:
    blocks = [(h, c, shown) for h, lang, c, shown in code_blocks(ROOT / page) if lang == "python"]
    assert blocks, page
    env = {**os.environ, "CONFORMAL_CONTROL_DATA": str(data_root), "MPLBACKEND": "Agg"}
    proc = subprocess.run(
        [sys.executable, "-c", _SESSION],
        input=json.dumps([c for _, c, _ in blocks]),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = json.loads(proc.stdout.strip().splitlines()[-1])
    for (heading, _, shown), out in zip(blocks, printed, strict=True):
        where = f"{page}: {heading}"
        if shown is None:
            assert out == "", f"{where}: prints {out[:200]!r} but shows no output"
        else:
            assert out.rstrip() == shown.rstrip(), where


#: Pages whose shell and Python blocks run in order, as a reader types them in an empty
#: folder of a checkout (``.venv`` and ``examples`` linked in): each bash block in a shell,
#: the Python blocks in one interpreter (as :data:`SESSION_PAGES`); a block followed by a
#: text block prints exactly that, and a Python block that shows none prints nothing.
MIXED_PAGES = ("docs/robot-logs.md",)


def _shell(code: str) -> str:
    """A bash block as a Python block of the session: run it, print its output."""
    return (
        "import subprocess as _sp\n"
        f"_p = _sp.run(['bash', '-euo', 'pipefail', '-c', {code!r}], capture_output=True, "
        "text=True)\n"
        "print(_p.stdout, end='')\n"
        "assert _p.returncode == 0, _p.stderr[-3000:]\n"
    )


@pytest.mark.parametrize("page", MIXED_PAGES)
def test_mixed_pages_run_in_order_and_print_what_they_show(
    page: str, tmp_path: Path, data_root: Path
) -> None:
    blocks = [
        (h, lang, c, shown)
        for h, lang, c, shown in code_blocks(ROOT / page)
        if lang in ("bash", "python")
    ]
    assert {lang for _, lang, _, _ in blocks} == {"bash", "python"}, page
    (tmp_path / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)
    (tmp_path / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    env = {**os.environ, "CONFORMAL_CONTROL_DATA": str(data_root), "MPLBACKEND": "Agg"}
    codes = [_shell(c) if lang == "bash" else c for _, lang, c, _ in blocks]
    proc = subprocess.run(
        [sys.executable, "-c", _SESSION],
        input=json.dumps(codes),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = json.loads(proc.stdout.strip().splitlines()[-1])
    for (heading, lang, _, shown), out in zip(blocks, printed, strict=True):
        where = f"{page}: {heading} ({lang})"
        if shown is not None:
            assert out.rstrip() == shown.rstrip(), where
        elif lang == "python":
            assert out == "", f"{where}: prints {out[:200]!r} but shows no output"


def test_plugin_pages_use_the_public_api_and_show_no_stale_version() -> None:
    """Every name the plugin snippets import exists and is not deprecated (importing it
    warns of nothing); no sample output carries a hard-coded version: the
    ``conformal-control plugins`` outputs are generated when the site is built."""
    import warnings

    n = 0
    for page in ("docs/plugins.md", "docs/write-your-own-plugin.md", "docs/getting-started.md"):
        text = (ROOT / page).read_text()
        assert not re.search(r"\[conformal-control \d", text), page
        for _, lang, code, _ in code_blocks(ROOT / page):
            if lang != "python":
                continue
            imports = re.findall(
                r"^from (conformal_control\S*) import (\([^()]+\)|.+)$", code, re.M
            )
            for module, names in imports:
                names = re.sub(r"#[^\n]*", "", names)
                for name in filter(None, (x.strip(" \n()") for x in names.split(","))):
                    with warnings.catch_warnings():
                        warnings.simplefilter("error")
                        assert hasattr(importlib.import_module(module), name), (page, name)
                    n += 1
    assert n >= 15


def test_getting_started_shows_the_front_door_stepwise_api_and_a_plugin() -> None:
    page = "docs/getting-started.md"
    front = _section_block(page, "front door")
    assert "cc.run(" in front and len(front.splitlines()) <= 15
    step = _section_block(page, "step-wise API")
    assert "StepwiseCBF(" in step and ".step(" in step and ".observe(" in step
    assert len(step.splitlines()) <= 15
    plugin = _section_block(page, "contract kit")
    assert re.search(r"^class \w+\(Predictor\):", plugin, re.M)
    assert "from conformal_control.testing import" in plugin
    assert "registry.register(" in plugin
    # the README shows the same two blocks (run above as one)
    assert _section_block("README.md", "front door") == front
    assert _section_block("README.md", "step-wise API") == step


def _setup_command() -> str:
    """The README's set-up command, which must come first and install everything."""
    _, lang, code, _ = code_blocks(ROOT / "README.md")[0]
    assert lang == "bash"
    lines = code.strip().splitlines()
    assert len(lines) == 2 and lines[1] == ".venv/bin/python -m pytest", lines
    setup = lines[0]
    assert setup.startswith(
        "python3 -m venv .venv && .venv/bin/pip install -q -c constraints.txt torch==2.13.0 "
    )
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    extras = sorted(pyproject["project"]["optional-dependencies"])
    installed = re.search(r'-e "\.\[([\w,]+)\]"', setup)
    assert installed is not None and sorted(installed.group(1).split(",")) == extras, extras
    plugins = sorted(p.parent.name for p in (ROOT / "plugins").glob("*/pyproject.toml"))
    assert plugins
    for name in plugins:
        assert f" -e plugins/{name}" in setup, name
    assert setup.endswith(" -e examples/plugin_example")
    return setup


def test_install_lines_are_the_readme_set_up_command() -> None:
    setup = _setup_command()
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    n = 0
    for page in pages:
        for i, line in enumerate(page.read_text().splitlines(), 1):
            if "pip install" in line or "python3 -m venv" in line:
                where = f"{page.relative_to(ROOT)}:{i}"
                assert line.count("pip install") == 1 and setup in line, where
                n += 1
    assert n >= 3  # README, index, getting started


def _text_files() -> list[Path]:
    """Documentation, examples and the sources users read (package, plugins, docs hooks)."""
    files = [ROOT / "README.md", ROOT / "CONTRIBUTING.md"]
    files += [
        p for p in (ROOT / "docs").rglob("*") if p.suffix in {".md", ".yml", ".js", ".css", ".py"}
    ]
    files += [
        p
        for d in ("conformal_control", "plugins")
        for p in (ROOT / d).rglob("*.py")
        if ".egg-info" not in str(p)
    ]
    files += [
        p
        for p in (ROOT / "examples").rglob("*")
        if p.suffix in {".md", ".py", ".ipynb", ".toml", ".txt", ".json", ".yaml"}
        and ".egg-info" not in str(p)
    ]
    return sorted(p for p in files if p.is_file() and "assets/mathjax" not in p.as_posix())


def _readable_text(path: Path) -> str:
    """The file's text; for a notebook its sources and text outputs (not image data)."""
    text = path.read_text(errors="replace")
    if path.suffix != ".ipynb":
        return text
    parts = []
    for cell in json.loads(text)["cells"]:
        parts.append("".join(cell["source"]))
        for output in cell.get("outputs", []):
            parts.append("".join(output.get("text", [])))
            for kind, data in output.get("data", {}).items():
                if not kind.startswith("image/"):
                    parts.append(data if isinstance(data, str) else "".join(data))
    return "\n".join(parts)


#: An absolute path of a machine (a URL's path is preceded by a word character or a dot).
MACHINE_PATH = re.compile(r"(?<![\w.~])/(work|root|home|Users|tmp|opt|mnt|var|private)/")


def test_sources_mention_no_spec_or_machine_path() -> None:
    files = _text_files()
    assert ROOT / "README.md" in files and ROOT / "docs/getting-started.md" in files
    assert any(p.suffix == ".ipynb" for p in files)
    for path in files:
        text = _readable_text(path)
        rel = path.relative_to(ROOT)
        assert not re.search(r"\bSPEC\b", text), rel
        found = MACHINE_PATH.search(text)
        assert found is None, (rel, text[max(found.start() - 40, 0) : found.end() + 40])


# ---------------------------------------------------------------------------- the data path
#: Pages still to be moved to the user's data path by the lanes that own them (issue 23,
#: item 1); listed here so that the test covers every other page and says which are left.
DATA_PATH_PENDING: frozenset[str] = frozenset()


def _user_pages() -> list[Path]:
    """What a user reads: the README, the site's pages, the plugins' READMEs, notebooks."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    pages += sorted((ROOT / "plugins").glob("*/README.md"))
    pages += sorted((ROOT / "examples").glob("*.ipynb"))
    return pages


def test_docs_show_the_users_data_path_not_the_test_machines() -> None:
    """No page tells a user to read data from ``../shared`` (where the tests find it beside
    the checkout): commands rely on the lookup order (``--data-root``,
    ``$CONFORMAL_CONTROL_DATA``, the per-user folder ``fetch-data`` fills) or write ``DATA``."""
    checked = 0
    for page in _user_pages():
        rel = page.relative_to(ROOT).as_posix()
        if rel in DATA_PATH_PENDING:
            continue
        text = _readable_text(page)
        found = re.search(r"\.\./shared|(?<![/\w])shared/data|\bthe shared data\b", text)
        assert found is None, (rel, text[max(found.start() - 60, 0) : found.end() + 40])
        checked += 1
    assert checked >= 25
    for rel in DATA_PATH_PENDING:  # the exemption goes once a page is fixed
        assert "../shared" in (ROOT / rel).read_text(), f"{rel} is fixed: drop it from the list"


def test_the_data_page_explains_the_lookup_order_the_code_uses(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Data's missing-data error is what the command prints for a user without data (on
    Linux, home folder shown as ``~``), and the page names the three places in order."""
    page = (ROOT / "docs/data.md").read_text()
    shown = re.search(r"```text\n\$ conformal-control run --scene nexus_4\n(error: .*)\n```", page)
    assert shown is not None
    home = tmp_path / "home"
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.delenv("CONFORMAL_CONTROL_DATA", raising=False)
    monkeypatch.delenv("XDG_DATA_HOME", raising=False)
    monkeypatch.chdir(tmp_path)
    cli = "from conformal_control.cli import main; raise SystemExit(main())"
    proc = subprocess.run(
        [sys.executable, "-c", cli, "run", "--scene", "nexus_4", "-q"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode != 0
    printed = proc.stderr.strip().replace(str(home), "~")
    assert printed == shown.group(1)
    order = [page.index(s) for s in ("--data-root DIR", "$CONFORMAL_CONTROL_DATA`", "per-user")]
    assert order == sorted(order)


def _pages_with_python() -> list[str]:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return [
        str(p.relative_to(ROOT))
        for p in pages
        if any(lang == "python" for _, lang, _, _ in code_blocks(p))
    ]


@pytest.mark.parametrize("page", _pages_with_python())
def test_every_python_block_parses_and_its_package_imports_resolve(page: str) -> None:
    """Blocks that are fragments (a cluster address, the reader's own policy) are not run,
    but they parse, and every name they import from this package exists: a renamed module
    or class fails here, not in a reader's session."""
    import ast
    import importlib
    import importlib.util

    for heading, lang, code, _ in code_blocks(ROOT / page):
        if lang != "python":
            continue
        where = f"{page}: {heading}"
        try:
            tree = ast.parse(code)
        except SyntaxError as exc:  # pragma: no cover - the assertion names the block
            raise AssertionError(f"{where}: {exc}") from exc
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "conformal_control"
            ):
                module = importlib.import_module(node.module or "")
                for alias in node.names:
                    assert (
                        alias.name == "*"
                        or hasattr(module, alias.name)
                        or (importlib.util.find_spec(f"{node.module}.{alias.name}") is not None)
                    ), f"{where}: {node.module} has no {alias.name}"
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.startswith("conformal_control"):
                        importlib.import_module(alias.name)


def _undefined(code: str, known: set[str]) -> tuple[set[str], set[str]]:
    """(names ``code`` reads that it, the blocks before it and the builtins never define;
    the names defined so far)."""
    import ast
    import builtins

    tree = ast.parse(code)
    defined = set(known)
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
            defined.add(node.id)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            defined.add(node.name)
        elif isinstance(node, ast.arg):
            defined.add(node.arg)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            defined |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, ast.ExceptHandler) and node.name:
            defined.add(node.name)
    used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
    return used - defined - set(dir(builtins)), defined


@pytest.mark.parametrize("page", _pages_with_python())
def test_no_python_block_reads_a_name_nothing_defines(page: str) -> None:
    """A reader copying a block (after the blocks before it on the page) has every name it
    uses: the issue's shield and PettingZoo snippets called a `my_policy` no block defined."""
    known: set[str] = set()
    for heading, lang, code, _ in code_blocks(ROOT / page):
        if lang != "python":
            continue
        missing, known = _undefined(code, known)
        assert not missing, f"{page}: {heading}: {sorted(missing)} defined nowhere"


def test_the_api_navigation_names_every_module_one_way() -> None:
    """Every entry and section of the API reference's navigation is the full dotted path of
    its module (the issue: sections were dotted, modules short)."""
    hooks = _hooks()
    seen = []

    def walk(items: list) -> None:
        for item in items:
            ((label, target),) = item.items()
            if isinstance(target, list):
                assert label == next(iter(target[0])), label  # the section is its package
                walk(target)
            else:
                module = target.removeprefix("api/").removesuffix(".md")
                module = module.removesuffix("/index").replace("/", ".")
                assert label == module, (label, target)
                seen.append(label)

    walk(hooks.api_nav("conformal_control"))
    assert sorted(seen) == hooks.public_modules()
