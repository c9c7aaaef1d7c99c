"""What the README and the docs say a command prints, compared with what it prints now.

Three kinds of claims are checked:

* an **output block**: a ``text`` block right after a ``bash`` block that runs
  ``conformal-control run`` shows (an excerpt of) what that run prints: every line shown
  must be a line printed;
* a **session**: ``$ conformal-control ...`` lines in a ``text`` or ``console`` block, each
  followed by what it prints: every line shown must be printed, in order (a shown line
  ending in ``...`` is a prefix);
* **figures in prose**, listed in :data:`PROSE` with the command they come from and the
  printed lines they stand for.

Blocks filled in when the docs are built (``<!-- generated: ... -->``) are checked by the
docs build (``tests/test_docs_build.py``), which fails when one cannot be generated.
"""

from __future__ import annotations

import functools
import os
import re
import shlex
from pathlib import Path

import pytest

from conformal_control.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _docs_build_module():
    """``tests/test_docs_build.py``, whose page parser this module shares (the tests
    folder is no package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "_docs_build_helpers", ROOT / "tests" / "test_docs_build.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_DOCS_BUILD = _docs_build_module()
code_blocks = _DOCS_BUILD.code_blocks
#: Pages run block after block, in order, by the docs build's tests (their outputs too).
RUN_IN_ORDER = {ROOT / p for p in _DOCS_BUILD.MIXED_PAGES}
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: Sessions whose output depends on the machine, checked by the test named beside them.
ELSEWHERE = {
    "run --scene nexus_4": "tests/test_docs_build.py::"
    "test_the_data_page_explains_the_lookup_order_the_code_uses (a user without data)",
    "run --predictor lstm": "tests/cli/commands/test_feedback.py::"
    "test_lstm_on_the_builtin_scene_needs_no_downloaded_data (a first use: training)",
}

#: Figures in prose: (page, the sentence as written, the command, lines it prints).
PROSE: list[tuple[str, str, str, list[str]]] = [
    (
        "README.md",
        "passes 1.068 m from the nearest pedestrian instead of 1.135 m, solves 183\nQPs "
        "instead of 202 and arrives 0.07 s earlier",
        "run --scene sdd:nexus/video3 --start 0.05,0.5 --goal 0.95,0.5 --no-learning",
        ["d_min 1.068 m", "n_qp_solves 183", "t_goal 13.12 s"],
    ),
    (
        "README.md",
        "On the built-in scene: goal in 14.28 s, no collision frame, `d_min` 1.363 m.",
        "run --crowd social_force",
        ["t_goal 14.28 s", "n_collide 0", "d_min 1.363 m"],
    ),
    (
        "README.md",
        "The Kalman filter scores ADE 0.504 m, FDE 1.059 m on zara1",
        "eval-predictor --predictor kalman --dataset ethucy:zara1",
        ["kalman ethucy:zara1: ADE 0.504 m FDE 1.059 m..."],
    ),
    (
        "README.md",
        "(constant velocity: 0.516 m,\n1.078 m)",
        "eval-predictor --predictor constant_velocity --dataset ethucy:zara1",
        ["constant_velocity ethucy:zara1: ADE 0.516 m FDE 1.078 m..."],
    ),
    (
        "README.md",
        "Predicting each other instead (`--reciprocity none`) they touch in 1 pair-frame and\n"
        "hit pedestrians in 28 frames.",
        "run --scene sdd:nexus/video3 --start 0.05,0.5 --goal 0.95,0.5 --robots 10 "
        "--reciprocity none",
        ["n_collide_pedestrian 28", "n_collide_robot_pairs 1"],
    ),
    (
        "docs/getting-started.md",
        "It reaches its goal in 8.3 s without a collision\nframe, and the average loss (−0.234)",
        "run --scene nexus_4",
        ["t_goal 8.283 s", "n_collide 0", "l_avg -0.2338"],
    ),
]


def _command(line: str) -> str:
    """A command as a page writes it, as the CLI's arguments (``.venv/bin/`` and the
    program's name dropped)."""
    return re.sub(r"^(\.venv/bin/)?conformal-control\s+", "", line.strip())


def _run_commands(code: str) -> list[str]:
    joined = code.replace("\\\n", " ")
    return [
        _command(ln) for ln in joined.splitlines() if re.match(r"^\S*conformal-control run\b", ln)
    ]


def _output_blocks() -> list[tuple[str, str, list[str]]]:
    """(where, command, lines shown) of every output block."""
    out = []
    for page in PAGES:
        if page in RUN_IN_ORDER:
            continue
        for heading, lang, code, shown in code_blocks(page):
            if lang != "bash" or shown is None or "generated:" in shown:
                continue
            runs = _run_commands(code)
            where = f"{page.relative_to(ROOT)}: {heading}"
            assert len(runs) == 1, f"{where}: an output block follows {len(runs)} run commands"
            out.append((where, runs[0], [ln for ln in shown.splitlines() if ln.strip()]))
    return out


def _sessions() -> list[tuple[str, str, list[str]]]:
    """(where, command, lines shown) of every ``$ conformal-control`` line of a page."""
    out = []
    for page in PAGES:
        if page in RUN_IN_ORDER:
            continue
        for heading, lang, code, _ in code_blocks(page):
            if lang not in ("text", "console") or not code.startswith("$ conformal-control"):
                continue
            where = f"{page.relative_to(ROOT)}: {heading}"
            for part in re.split(r"^(?=\$ )", code, flags=re.M):
                if not part.strip():
                    continue
                first, *shown = part.rstrip("\n").splitlines()
                out.append((where, _command(first[2:]), [ln for ln in shown if ln.strip()]))
    return out


OUTPUT_BLOCKS = _output_blocks()
SESSIONS = [s for s in _sessions() if s[1] not in ELSEWHERE]


def _key(command: str) -> str:
    """A command without its ``--out`` (the cache key: where it writes changes nothing)."""
    return " ".join(re.sub(r"\s--out\s+\S+", "", command).split())


@functools.cache
def _printed(command: str, data_root: str, home: str) -> list[str]:
    """The lines ``conformal-control COMMAND`` prints (stderr, then stdout), run once per
    command in a fresh folder; the home folder shown as ``~``."""
    import contextlib
    import io
    import tempfile

    argv = shlex.split(command)
    if "--out" in argv:  # where it writes is no part of what it prints
        i = argv.index("--out")
        del argv[i : i + 2]
    with tempfile.TemporaryDirectory() as tmp:
        if argv[0] in ("run", "sweep"):
            argv += ["--out", f"{tmp}/out"]
        if argv[0] == "run":
            argv.append("--no-plot")
        out, err = io.StringIO(), io.StringIO()
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                main(argv)
        finally:
            os.chdir(cwd)
    text = (err.getvalue() + out.getvalue()).replace(home, "~")
    return [" ".join(ln.split()) for ln in text.splitlines() if ln.strip()]


@pytest.fixture
def printed(data_root: Path, tmp_path_factory: pytest.TempPathFactory, monkeypatch):
    """``printed(command)``: its lines, the data read where the tests keep it, caches
    (trained weights, parsed tracks) in a home folder of the test session's."""
    home = tmp_path_factory.getbasetemp() / "home"
    monkeypatch.setenv("CONFORMAL_CONTROL_DATA", str(data_root))
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.delenv("CONFORMAL_CONTROL_CACHE", raising=False)
    monkeypatch.setenv("CONFORMAL_CONTROL_QUIET", "1")
    return lambda command: _printed(_key(command), str(data_root), str(home))


def _matches(shown: str, line: str) -> bool:
    shown = " ".join(shown.split())
    return line.startswith(shown[:-3]) if shown.endswith("...") else line == shown


def _assert_shown(
    where: str, command: str, shown: list[str], lines: list[str], ordered: bool = True
) -> None:
    """Every shown line is printed (in the order shown, if ``ordered``)."""
    i = 0
    for want in shown:
        if not ordered:
            i = 0
        while i < len(lines) and not _matches(want, lines[i]):
            i += 1
        assert i < len(lines), (
            f"{where}: `conformal-control {command}` does not print {want!r} (after the lines "
            f"before it); it printed:\n" + "\n".join(lines)
        )
        i += 1


def test_the_pages_have_claims_to_check() -> None:
    commands = {c for _, c, _ in OUTPUT_BLOCKS + SESSIONS}
    assert len(OUTPUT_BLOCKS) >= 4 and len(SESSIONS) >= 5, (OUTPUT_BLOCKS, SESSIONS)
    assert any("--robots 10" in c for c in commands)  # the README's fleet and the docs'
    for command, test in ELSEWHERE.items():  # the exemption goes once the session does
        assert any(c == command for _, c, _ in _sessions()), f"drop {command!r}: {test}"


@pytest.mark.parametrize(
    ("where", "command", "shown"), OUTPUT_BLOCKS, ids=[w for w, _, _ in OUTPUT_BLOCKS]
)
def test_an_output_block_is_what_its_command_prints(
    where: str, command: str, shown: list[str], printed
) -> None:
    _assert_shown(where, command, shown, printed(command))


@pytest.mark.parametrize(("where", "command", "shown"), SESSIONS, ids=[c for _, c, _ in SESSIONS])
def test_a_session_is_what_its_commands_print(
    where: str, command: str, shown: list[str], printed
) -> None:
    _assert_shown(where, command, shown, printed(command))


@pytest.mark.parametrize(
    ("page", "sentence", "command", "lines"), PROSE, ids=[c for _, _, c, _ in PROSE]
)
def test_figures_in_prose_are_what_the_command_prints(
    page: str, sentence: str, command: str, lines: list[str], printed
) -> None:
    text = (ROOT / page).read_text()
    assert " ".join(sentence.split()) in " ".join(text.split()), f"{page} no longer says it"
    _assert_shown(page, command, lines, printed(command), ordered=False)


def _summary(text: str) -> str | None:
    """A page's summary at its top (an ``!!! abstract "In short"`` block), if it has one."""
    m = re.search(r'^!!! abstract "In short"\n((?:    .*\n|\n)+)', text, re.M)
    return m.group(1) if m else None


def test_a_page_summary_quotes_the_page() -> None:
    """The summary at the top of a long page states the page's own figures: every number
    with a decimal point in it is found in the rest of the page."""
    pages = [p for p in PAGES if _summary(p.read_text()) is not None]
    assert ROOT / "docs/benchmark.md" in pages
    for page in pages:
        text = page.read_text()
        summary = _summary(text)
        assert summary is not None
        rest = text.replace(summary, "")
        figures = re.findall(r"\d+\.\d+", summary)
        assert len(figures) >= 5, page
        for figure in figures:
            assert figure in rest, f"{page.name}: the summary's {figure} is nowhere else"
