"""MkDocs hooks: generated reference sections and the example notebooks.

* ``<!-- generated:parameters -->`` in a page is replaced by the table of every controller
  parameter, built from :data:`conformal_control.sim.config.PARAMETERS` (with units from
  :data:`conformal_control.data.units.PARAM_DIMENSIONS` and the defaults of the built-in and
  the paper scenes), so the table cannot drift from the code.
* ``<!-- generated:cli -->`` is replaced by the help of every subcommand, taken from the
  argparse parsers of :mod:`conformal_control.commands`.
* ``examples/*.ipynb`` are added to the site as ``examples/<name>.ipynb`` (rendered by
  mkdocs-jupyter from their stored outputs; ``tests/test_notebooks.py`` executes them).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


# ---------------------------------------------------------------------------- notebooks
@event_priority(100)  # before mkdocs-jupyter wraps the .ipynb files
def on_files(files: Files, config: Any) -> Files:
    for nb in sorted(EXAMPLES.glob("*.ipynb")):
        files.append(
            File(
                f"examples/{nb.name}",
                src_dir=str(ROOT),
                dest_dir=config["site_dir"],
                use_directory_urls=config["use_directory_urls"],
            )
        )
    return files


# ---------------------------------------------------------------------------- parameters
def _dimension(name: str) -> tuple[str, str]:
    """(paper unit on SDD scenes, SI unit) of a parameter."""
    from conformal_control.data.units import PARAM_DIMENSIONS

    if name not in PARAM_DIMENSIONS:
        si = {"v_max": "m/s", "robot_radius": "m", "agent_radius": "m", "goal_radius": "m"}
        unit = si.get(name, "1" if name == "epsilon" else "-")
        return unit, unit
    p, q = PARAM_DIMENSIONS[name]

    def fmt(length: str, time: str) -> str:
        num = [f"{length}^{p}" if p > 1 else length] if p > 0 else []
        den = [f"{time}^{-q}" if q < -1 else time] if q < 0 else []
        if q > 0:
            num.append(time)
        top = " ".join(num) or "1"
        return f"{top}/{den[0]}" if den else top

    return fmt("px", "frame"), fmt("m", "s")


def _fmt(v: Any) -> str:
    if v is None:
        return "scene"
    if isinstance(v, float) and math.isinf(v):
        return "-inf" if v < 0 else "inf"
    return f"`{v}`"


def _derived(name: str, fps: float) -> str | None:
    """Defaults computed from other parameters (``resolve_params``)."""
    if name == "sensing_radius":
        return "= `rho0`"
    if name == "delta":
        return "1/2 (`surface`)"
    if name == "history":
        return f"`{round(4.0 * fps)}` (4 s)"
    return None


def parameters_table() -> str:
    import dataclasses

    from conformal_control.data.scene import Scene
    from conformal_control.data.scenes import PAPER_SCENES
    from conformal_control.data.sdd import SDD_FPS
    from conformal_control.data.synthetic import crossing_scene
    from conformal_control.sim.config import PARAMETERS

    crossing = crossing_scene(seed=0)
    field_defaults = {f.name: f.default for f in dataclasses.fields(Scene)}
    columns = [  # (defaults, per-scene attributes, fps)
        (crossing.defaults, {k: getattr(crossing, k) for k in field_defaults}, crossing.fps)
    ]
    for name in ("gates_1", "nexus_4"):
        spec = PAPER_SCENES[name]
        columns.append((spec.defaults, {**field_defaults, "v_max": spec.v_max}, SDD_FPS))
    rows = [
        "| parameter | unit on SDD scenes (paper) | SI unit | default | built-in `crossing` "
        "(SI) | `gates_1` | `nexus_4` | meaning |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, (default, doc) in PARAMETERS.items():
        paper, si = _dimension(name)
        cells = []
        for defaults, attrs, fps in columns:
            v = defaults.get(name, attrs.get(name, default))
            cells.append(_derived(name, fps) if v is None else _fmt(v))
        doc = doc.replace("|", "\\|")
        top = "derived" if _derived(name, 1.0) and default is None else _fmt(default)
        rows.append(
            f"| `{name}` | {paper} | {si} | {top} | {' | '.join(map(str, cells))} | {doc} |"
        )
    return "\n".join(rows)


# ---------------------------------------------------------------------------- CLI
def cli_reference() -> str:
    import os

    from conformal_control.cli import build_parser

    os.environ["COLUMNS"] = "100"  # argparse wraps help to the terminal width
    parser = build_parser()
    out = [
        "### `conformal-control`",
        "",
        "```text",
        parser.format_help().rstrip(),
        "```",
        "",
    ]
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in sorted(subs.choices.items()):
        sub.prog = f"conformal-control {name}"
        out += [f"### `{name}`", "", "```text", sub.format_help().rstrip(), "```", ""]
    return "\n".join(out)


# ---------------------------------------------------------------------------- runs
def cli_run_output(*args: str) -> str:
    """What ``conformal-control run ARGS`` prints, run now (so the page shows this version).

    SDD scenes read ``$CONFORMAL_CONTROL_DATA`` (else ``../shared/data`` beside the
    checkout); without data the block says so instead of failing the build.
    """
    import contextlib
    import io
    import os
    import tempfile

    from conformal_control.cli import main

    env_root = os.environ.get("CONFORMAL_CONTROL_DATA")
    root = Path(env_root) if env_root else ROOT.parent / "shared" / "data"
    argv = ["run", *args, "--no-plot", "--quiet"]
    if "--scene" in args:
        if not (root / "sdd").is_dir():
            return f"(the SDD data was not found at {root} when this page was built)"
        argv += ["--data-root", str(root)]
    with tempfile.TemporaryDirectory() as tmp:
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([*argv, "--out", f"{tmp}/run"])
        if code != 0:
            raise RuntimeError(f"conformal-control {' '.join(argv)} failed: {err.getvalue()}")
        text = out.getvalue().replace(f"{tmp}/run", "runs/<scene>-<time>")
    return text.rstrip() + (("\n" + err.getvalue().rstrip()) if err.getvalue() else "")


GENERATORS = {
    "<!-- generated:parameters -->": parameters_table,
    "<!-- generated:cli -->": cli_reference,
    "<!-- generated:run-demo -->": lambda: cli_run_output(),
    "<!-- generated:run-nexus_4 -->": lambda: cli_run_output("--scene", "nexus_4"),
}


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    for marker, make in GENERATORS.items():
        if marker in markdown:
            markdown = markdown.replace(marker, make())
    return markdown
