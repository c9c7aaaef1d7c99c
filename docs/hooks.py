"""MkDocs hooks: generated reference pages, offline math and the example notebooks.

* ``<!-- generated:parameters -->`` in a page is replaced by the table of every controller
  parameter, built from ``conformal_control.runs.params.PARAMETERS`` (with units from
  ``conformal_control.data.units.PARAM_DIMENSIONS`` and the defaults of the built-in and
  the paper scenes), so the table cannot drift from the code.
* ``<!-- generated:cli -->`` is replaced by the help of every subcommand, taken from the
  argparse parsers of ``conformal_control.cli.commands``.
* **Outputs of commands**, run at build time: ``<!-- generated:run-demo -->`` (and
  ``run-nexus_4``), ``<!-- generated:run ARGS -->`` (``$ conformal-control run ARGS`` and
  what it prints), ``<!-- generated:runs NAME -->`` (a table of runs, :data:`RUN_TABLES`,
  with a check of what the page says about them), ``<!-- generated:command ARGS -->``,
  ``<!-- generated:ethucy-tasks -->``. An output that needs data the build cannot find is a
  warning (:func:`missing_output`), so ``mkdocs build --strict`` fails instead of
  publishing a page without it.
* **API reference**: one page per public module of the package (``api/<dotted/path>.md``,
  packages at ``api/<dotted/path>/index.md``), found by walking the source tree at build time
  so that new modules appear on their own; the navigation and the module index
  (``<!-- generated:api-index -->`` in ``api.md``) are generated with them. Each object is
  documented once, on the page of the module that defines it (re-exports are listed as
  links). ``SphinxRoles`` (a griffe extension loaded by mkdocstrings, see ``mkdocs.yml``)
  turns the Sphinx roles of the docstrings (``:class:`~a.b.C```, ``:meth:``, ``:func:``,
  ``:mod:``, ``:data:``, ``:attr:``, ...) into cross-reference links.
* **Math offline**: MathJax 3 is served from the ``django-static-mathjax`` package (the
  ``docs`` extra; Apache-2.0, its licence is copied beside it) under ``assets/mathjax/``; no
  page loads a script from a CDN. Notebook pages get their ``$...$`` / ``$$...$$`` math
  wrapped in the same ``arithmatex`` markup as the Markdown pages, and the MathJax-2 and
  Mermaid loaders that nbconvert's template injects (both from CDNs) are removed.
* ``examples/*.ipynb`` are added to the site as ``examples/<name>.ipynb`` (rendered by
  mkdocs-jupyter from their stored outputs; ``tests/test_notebooks.py`` executes them).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import logging
import math
import os
import re
from pathlib import Path
from typing import Any

import griffe
from mkdocs.exceptions import PluginError
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
PACKAGE = "conformal_control"
API_DIR = "api"
MATHJAX_DEST = "assets/mathjax"
#: What the site needs of MathJax's es5 build: the combined TeX/MathML -> CommonHTML
#: component, its fonts, the TeX extensions it autoloads and the menu's lazy parts.
MATHJAX_PARTS = ("tex-mml-chtml.js", "output/chtml", "input/tex/extensions", "input/mml", "ui")

log = logging.getLogger("mkdocs.hooks.conformal_control")


# ---------------------------------------------------------------------------- files
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
    root = mathjax_root()
    for part in MATHJAX_PARTS:
        path = root / "es5" / part
        for src in [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file()):
            rel = src.relative_to(root).as_posix()
            files.append(File.generated(config, f"{MATHJAX_DEST}/{rel}", abs_src_path=str(src)))
    licence = root / "LICENSE"
    files.append(File.generated(config, f"{MATHJAX_DEST}/LICENSE", abs_src_path=str(licence)))
    for module in public_modules():
        files.append(File.generated(config, api_page(module), content=api_markdown(module)))
    return files


def on_config(config: Any) -> Any:
    """Replace the ``API reference: api.md`` entry of the navigation by the module tree;
    find the data where the test suite does (``tests/conftest.py``): unless
    ``$CONFORMAL_CONTROL_DATA`` is set, ``shared/data`` beside the project, when there."""
    beside = ROOT.parent / "shared" / "data"
    if not os.environ.get("CONFORMAL_CONTROL_DATA") and beside.is_dir():
        os.environ["CONFORMAL_CONTROL_DATA"] = str(beside)
    nav = config.get("nav") or []
    for i, item in enumerate(nav):
        if isinstance(item, dict) and item.get("API reference") == "api.md":
            nav[i] = {"API reference": [{"Overview": "api.md"}, *api_nav(PACKAGE)]}
    return config


# ---------------------------------------------------------------------------- MathJax
def mathjax_root() -> Path:
    """The MathJax distribution shipped by ``django-static-mathjax`` (import name ``mathjax``)."""
    spec = importlib.util.find_spec("mathjax")
    root = Path(spec.origin).parent / "static" / "mathjax" if spec and spec.origin else None
    if root is None or not (root / "es5" / "tex-mml-chtml.js").is_file():
        raise PluginError(
            "the docs serve MathJax from the django-static-mathjax package, which is not "
            "installed: pip install -e '.[docs]'"
        )
    return root


_NB_MATHJAX2 = re.compile(r"<!-- Load mathjax -->.*?<!-- End of mathjax configuration -->", re.S)
_NB_MERMAID = re.compile(
    r"<script type=\"module\">(?:(?!</script>).)*?mermaid.*?<!-- End of mermaid configuration -->",
    re.S,
)
_NB_MARKDOWN = re.compile(
    r"(<div class=\"jp-RenderedHTMLCommon jp-RenderedMarkdown[^>]*>)(.*?)(</div>)", re.S
)
_NB_VERBATIM = re.compile(r"(<pre\b.*?</pre>|<code\b.*?</code>)", re.S)
_DISPLAY_MATH = re.compile(r"\$\$(.+?)\$\$", re.S)
_INLINE_MATH = re.compile(r"(?<![\\$])\$(?![\s$])((?:[^$\\]|\\.)+?)(?<!\s)\$(?!\$)", re.S)


def _wrap_math(text: str) -> str:
    text = _DISPLAY_MATH.sub(r'<span class="arithmatex">\\[\1\\]</span>', text)
    return _INLINE_MATH.sub(r'<span class="arithmatex">\\(\1\\)</span>', text)


def notebook_html(html: str, name: str) -> str:
    """Offline notebook page: no CDN loaders, math in the site's ``arithmatex`` markup."""
    html = _NB_MATHJAX2.sub("", html)
    html = _NB_MERMAID.sub("", html)
    if "jp-Mermaid" in html:
        log.warning("%s has Mermaid diagrams, which need a CDN script: they will not render", name)

    def cell(m: re.Match[str]) -> str:
        parts = _NB_VERBATIM.split(m.group(2))
        body = "".join(p if i % 2 else _wrap_math(p) for i, p in enumerate(parts))
        return m.group(1) + body + m.group(3)

    return _NB_MARKDOWN.sub(cell, html)


def on_post_page(output: str, page: Any, config: Any) -> str:
    if page.file.src_uri.endswith(".ipynb"):
        return notebook_html(output, page.file.src_uri)
    return output


# ---------------------------------------------------------------------------- API pages
def public_modules() -> list[str]:
    """Every public module of the package: no part of its dotted path starts with ``_``."""
    out = []
    for path in sorted((ROOT / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if not all(
            (ROOT.joinpath(*parts[:i]) / "__init__.py").is_file() for i in range(1, len(parts))
        ):
            continue  # not inside a regular package
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(p.startswith("_") for p in parts):
            continue
        out.append(".".join(parts))
    return sorted(out)


def _is_package(module: str) -> bool:
    return (ROOT / module.replace(".", "/") / "__init__.py").is_file()


def api_page(module: str) -> str:
    """Docs path of a module's page: packages get ``index.md`` in their folder."""
    path = module.replace(".", "/")
    return f"{API_DIR}/{path}/index.md" if _is_package(module) else f"{API_DIR}/{path}.md"


def api_nav(package: str) -> list[dict[str, Any]]:
    """Navigation of a package: its page, its modules, its subpackages as sections, every
    entry named by its full dotted path (as its page's title and the module index)."""
    modules = public_modules()
    depth = package.count(".") + 1
    items: list[dict[str, Any]] = [{package: api_page(package)}]
    for m in modules:
        if m.startswith(package + ".") and m.count(".") == depth:
            if _is_package(m):
                items.append({m: api_nav(m)})
            else:
                items.append({m: api_page(m)})
    return items


@functools.cache
def _griffe_package() -> Any:
    return griffe.load(
        PACKAGE,
        search_paths=[str(ROOT)],
        extensions=griffe.load_extensions(SphinxRoles()),
        resolve_aliases=True,
        resolve_external=False,
    )


def _private(path: str) -> bool:
    return any(p.startswith("_") for p in path.split("."))


def _final(obj: Any) -> Any | None:
    if not obj.is_alias:
        return obj
    try:
        return obj.final_target
    except Exception:  # external or unresolvable import
        return None


def module_members(module: str) -> tuple[list[str], list[tuple[str, str]]]:
    """(members documented on the module's page, re-exports as (name, target path)).

    A module's page documents what it defines, plus what it re-exports from a private
    module (which has no page). Other imports listed in ``__all__`` are re-exports: links
    to the page of the module that defines them.
    """
    mod = (
        _griffe_package().get_member(module.split(".", 1)[1])
        if "." in module
        else _griffe_package()
    )
    exported = {str(name) for name in mod.exports or ()}
    own, reexports = [], []
    for name, member in mod.members.items():
        if name.startswith("_"):
            continue
        if not member.is_alias:
            if not member.is_module:
                own.append(name)
            continue
        target = _final(member)
        if target is None or name not in exported or not target.path.startswith(PACKAGE + "."):
            continue
        if target.is_module:
            continue
        if _private(target.path):
            own.append(name)
        else:
            reexports.append((name, target.path))
    return own, reexports


def api_markdown(module: str) -> str:
    own, reexports = module_members(module)
    members = "[" + ", ".join(own) + "]" if own else "false"
    text = [
        f"::: {module}",
        "    options:",
        "      heading_level: 1",
        "      show_root_full_path: true",
        f"      members: {members}",
        "",
    ]
    if reexports:
        links = ", ".join(f"[`{name}`][{target}]" for name, target in reexports)
        text += ["", f"**Re-exported here:** {links}.", ""]
    return "\n".join(text)


def api_index() -> str:
    """Table of every public module with the first line of its docstring."""
    pkg = _griffe_package()
    rows = ["| module | what it holds |", "|---|---|"]
    for module in public_modules():
        obj = pkg.get_member(module.split(".", 1)[1]) if "." in module else pkg
        doc = obj.docstring.value.strip().splitlines()[0] if obj.docstring else ""
        doc = doc.replace("|", "\\|")
        rows.append(f"| [`{module}`][{module}] | {doc} |")
    return "\n".join(rows)


# ---------------------------------------------------------------------------- Sphinx roles
_ROLE = re.compile(
    r":(?:py:)?(mod|meth|class|func|data|attr|obj|exc|const|type):"
    r"`(!?)(~?)([^`<]+?)(?:\s*<([^>`]+)>)?`"
)


class SphinxRoles(griffe.Extension):
    """Docstring roles as links: ``:class:`~a.b.C``` becomes ``[`C`][a.b.C]``.

    Targets are resolved as Sphinx does: relative to the object, then its parents, then as
    an absolute path; failing that, by a unique object of that name in the package. An
    object defined in a private module links to its public re-export. A role whose target
    is not found becomes plain code (logged).
    """

    def on_package(self, *, pkg: Any, loader: Any = None, **kwargs: Any) -> None:
        objects = list(_walk(pkg))
        by_name: dict[str, list[Any]] = {}
        public: dict[str, str] = {}
        for obj in objects:
            by_name.setdefault(obj.name, []).append(obj)
            if obj.is_module and not _private(obj.path):
                for name, member in obj.members.items():
                    target = _final(member) if member.is_alias else None
                    if target is not None and _private(target.path) and not name.startswith("_"):
                        public.setdefault(target.path, f"{obj.path}.{name}")
        for obj in objects:
            if obj.docstring is None:
                continue
            obj.docstring.value = _ROLE.sub(
                lambda m, o=obj: _role_link(m, o, pkg, by_name, public), obj.docstring.value
            )


def _walk(obj: Any) -> Any:
    yield obj
    for member in obj.members.values():
        if not member.is_alias and (
            member.is_module or member.is_class or member.is_function or member.is_attribute
        ):
            yield from _walk(member) if (member.is_module or member.is_class) else [member]


def _lookup(pkg: Any, path: str) -> Any | None:
    parts = path.split(".")
    if parts[0] != pkg.name:
        return None
    obj = pkg
    for part in parts[1:]:
        members = obj.all_members if obj.is_class else obj.members  # with inherited ones
        member = members.get(part)
        if member is None:
            return None
        obj = _final(member)
        if obj is None:
            return None
    return obj


def resolve_role(target: str, obj: Any, pkg: Any, by_name: dict[str, list[Any]]) -> Any | None:
    """The object a role's target names, seen from ``obj`` (None if not found)."""
    target = target.strip().lstrip(".")
    scopes, scope = [], obj
    while scope is not None:
        scopes.append(scope.path)
        scope = scope.parent
    for candidate in [*(f"{s}.{target}" for s in scopes), target]:
        found = _lookup(pkg, candidate)
        if found is not None:
            return found
    last = target.rsplit(".", 1)[-1]
    matches = [o for o in by_name.get(last, []) if o.path.endswith("." + target)]
    if not matches and "." in target:  # a stale module path: the name alone, if unique
        matches = by_name.get(last, [])
        if len(matches) == 1:
            log.info("%s: %r resolved by name to %s", obj.path, target, matches[0].path)
    return matches[0] if len(matches) == 1 else None


def _role_link(m: re.Match[str], obj: Any, pkg: Any, by_name: Any, public: dict[str, str]) -> str:
    role, no_link, tilde, text, explicit = m.groups()
    target = (explicit or text).strip()
    if explicit:
        display = text.strip()
    else:
        display = target.lstrip(".").rsplit(".", 1)[-1] if tilde else target.lstrip(".")
        if role in ("meth", "func") and not display.endswith(")"):
            display += "()"
    if no_link:
        return f"`{display}`"
    found = resolve_role(target, obj, pkg, by_name)
    path = found.path if found is not None else ""
    for private_path, public_path in public.items():  # defined privately, documented publicly
        if path == private_path or path.startswith(private_path + "."):
            path = public_path + path[len(private_path) :]
            break
    if not path or _private(path) or not found.has_docstrings:  # not rendered: no anchor
        log.info("%s: %s target %r not documented; rendered as code", obj.path, role, target)
        return f"`{display}`"
    return f"[`{display}`][{path}]"


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
    from conformal_control.runs.params import PARAMETERS

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
def missing_output(what: str, reason: str) -> str:
    """A generated output that cannot be made (its data is missing): a warning, which
    ``mkdocs build --strict`` (the docs' configuration) turns into a failed build, and a
    placeholder saying so in a non-strict build (``mkdocs serve``)."""
    log.warning(
        "%s was not generated: %s; build the docs with the data (set CONFORMAL_CONTROL_DATA, "
        "or run `conformal-control fetch-data`)",
        what,
        reason,
    )
    return f"(not generated when this page was built: {reason}; see Data)"


def _scene_missing(args: tuple[str, ...]) -> str | None:
    """Why the scene ``run ARGS`` names cannot be loaded for want of data, else None."""
    from conformal_control.data import load_scene
    from conformal_control.data.paths import DataNotFoundError

    if "--scene" not in args:
        return None
    try:
        load_scene(args[args.index("--scene") + 1])
    except DataNotFoundError as exc:
        return str(exc)
    return None


def _run_cli(args: tuple[str, ...]) -> tuple[str, str]:
    """(stdout, stderr) of ``conformal-control run ARGS --no-plot --quiet`` in a temporary
    run directory (shown as ``runs/<scene>-<time>``); a failed run fails the build."""
    import contextlib
    import io
    import tempfile

    from conformal_control.cli import main

    argv = ["run", *args, "--no-plot", "--quiet"]
    with tempfile.TemporaryDirectory() as tmp:
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([*argv, "--out", f"{tmp}/run"])
        if code != 0:
            raise PluginError(f"conformal-control {' '.join(argv)} failed: {err.getvalue()}")
        return out.getvalue().replace(f"{tmp}/run", "runs/<scene>-<time>"), err.getvalue()


def cli_run_output(*args: str) -> str:
    """What ``conformal-control run ARGS`` prints, run now (so the page shows this version):
    its warnings first, as a terminal shows them (they are printed before the metrics),
    then the metrics.

    Scenes from data read it where every command does (``$CONFORMAL_CONTROL_DATA``, else
    the per-user data folder; the docs test sets the variable); without it the block says
    so and the strict build fails (:func:`missing_output`).
    """
    why = _scene_missing(args)
    if why is not None:
        return missing_output(f"the output of `conformal-control run {' '.join(args)}`", why)
    out, err = _run_cli(args)
    return (err.rstrip() + "\n" if err.strip() else "") + out.rstrip()


def _metrics_of(text: str) -> dict[str, str]:
    """The ``name value`` lines ``run`` prints, as a dict of their texts."""
    return {
        parts[0]: " ".join(parts[1:])
        for line in text.splitlines()
        if len(parts := line.split()) >= 2 and re.fullmatch(r"[a-z_0-9]+", parts[0])
    }


#: Tables of runs a page shows, by name: (the ``run`` arguments of each row, the metrics
#: shown, a check of what the page's prose says about them: a message when it no longer
#: holds, which fails the strict build).
RUN_TABLES: dict[str, tuple[list[str], list[str], Any]] = {
    "nexus_4-variants": (
        [
            "--scene nexus_4",
            "--scene nexus_4 --no-learning",
            "--scene nexus_4 --predictor oracle --no-learning",
            "--scene nexus_4 --predictor var",
            "--scene nexus_4 --epsilon -0.1 --eta 0.1 --tau 8",
            "--scene nexus_4 --param rho0=15m --param tau=0.4s",
        ],
        ["success", "t_goal", "d_min", "n_qp_solves", "lambda_final"],
        lambda rows: next(
            (
                f"Getting started says lambda changes nothing on nexus_4, but `run {args}` "
                f"solved {m['n_qp_solves']} QPs"
                for args, m in rows[:4]
                if m["n_qp_solves"] != "0"
                or (m["t_goal"], m["d_min"]) != (rows[0][1]["t_goal"], rows[0][1]["d_min"])
            ),
            None,
        ),
    ),
}


def run_table(name: str) -> str:
    """A table of what each run of ``RUN_TABLES[name]`` prints (selected metrics), run
    now; without the data the table says so and the strict build fails."""
    import shlex

    runs, shown, check = RUN_TABLES[name]
    rows = []
    for line in runs:
        args = tuple(shlex.split(line))
        why = _scene_missing(args)
        if why is not None:
            return missing_output(f"the table of runs {name!r}", why)
        rows.append((line, _metrics_of(_run_cli(args)[0])))
    problem = check(rows)
    if problem is not None:
        log.warning("%s", problem)
    head = ["`conformal-control run ...`", *shown]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for line, m in rows:
        out.append(f"| `{line}` | " + " | ".join(m.get(k, "-") for k in shown) + " |")
    return "\n".join(out)


def ethucy_tasks() -> str:
    """Every ETH/UCY recording: its walkable box, its default task and what the default run
    gives (run now); without the data the table says so and the strict build fails."""
    import warnings

    import numpy as np

    import conformal_control as cc
    from conformal_control.data import load_scene
    from conformal_control.data.ethucy import ETHUCY_RECORDINGS
    from conformal_control.data.paths import DataNotFoundError

    rows = [
        "| scene | walkable box x (m) | y (m) | default start (m) | goal (m) | start frame | "
        "success | t_goal | n_collide | d_min |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]

    def pt(xy: Any) -> str:
        return f"({xy[0]:.1f}, {xy[1]:.1f})"

    for rec in ETHUCY_RECORDINGS:
        try:
            scene = load_scene(f"ethucy:{rec}")
        except DataNotFoundError as exc:
            return missing_output("the table of ETH/UCY default tasks", str(exc))
        lo, hi = (np.asarray(c) for c in scene.meta["walkable_box"])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = cc.run(scene, record_animation=False).metrics
        t_goal = "-" if m["t_goal"] is None else f"{m['t_goal']:.2f} s"
        rows.append(
            f"| `ethucy:{rec}` | {lo[0]:.1f} to {hi[0]:.1f} | {lo[1]:.1f} to {hi[1]:.1f} | "
            f"{pt(scene.start)} | {pt(scene.goals[-1])} | {scene.start_frame} | "
            f"{str(m['success']).lower()} | {t_goal} | {m['n_collide']} | {m['d_min']:.2f} m |"
        )
    return "\n".join(rows)


# ---------------------------------------------------------------------------- plugins
def _public_name(obj: type) -> str:
    """How a user imports ``obj``: from the package's top level if it is exported there,
    else from the module that defines it."""
    import conformal_control

    name = obj.__name__
    if getattr(conformal_control, "_LAZY", {}).get(name) == obj.__module__:
        return f"from conformal_control import {name}"
    return f"from {obj.__module__} import {name}"


def roles_table() -> str:
    """Every role of the registry (entry-point group, base class, contract check list, the
    plugins registered under it now), how to import the base classes, and the installed
    distributions other than this package that add plugins (``plugins/``, third parties)."""
    from conformal_control import testing
    from conformal_control.core import registry
    from conformal_control.testing import ROLE_BASES, checks_for

    rows = [
        "| role | entry-point group | base class | contract checks | registered plugins |",
        "|---|---|---|---|---|",
    ]
    top, elsewhere = [], []
    packages: dict[tuple[str, str], list[str]] = {}
    for role, group in registry.ROLES.items():
        base = ROLE_BASES[role]
        entries = registry.entries(role)
        for e in entries:
            if e.origin != "conformal-control":
                packages.setdefault((e.origin, e.version or "?"), []).append(f"`{e.name}`")
        checks = checks_for(role)
        check_name = next(n for n in testing.__all__ if getattr(testing, n) is checks)
        names = ", ".join(f"`{e.name}`" for e in entries) or "-"
        rows.append(
            f"| `{role}` | `{group}` | [`{base.__name__}`][{base.__module__}.{base.__qualname__}]"
            f" | `{check_name}` ({len(checks)}) | {names} |"
        )
        line = _public_name(base)
        (top if line.startswith("from conformal_control import") else elsewhere).append(
            (base.__name__, line)
        )
    imports = (
        f"Base classes import from the package's top level (`from conformal_control import "
        f"{', '.join(n for n, _ in top)}`)"
        + (
            "; the others from their module: " + ", ".join(f"`{line}`" for _, line in elsewhere)
            if elsewhere
            else ""
        )
        + "."
    )
    out = ["\n".join(rows), "", imports]
    if packages:
        out += [
            "",
            "Plugins from installed packages other than conformal-control:",
            "",
            "| package | version | plugins |",
            "|---|---|---|",
        ]
        out += [f"| `{d}` | {v} | {', '.join(n)} |" for (d, v), n in sorted(packages.items())]
    return "\n".join(out)


def fields_table(dotted: str) -> str:
    """The fields of a dataclass (type, default, meaning) from its numpy-style
    ``Attributes`` section; a field the docstring does not describe fails the build."""
    import dataclasses
    import importlib
    import inspect

    module, _, name = dotted.rpartition(".")
    cls = getattr(importlib.import_module(module), name)
    doc = griffe.Docstring(inspect.getdoc(cls) or "", parser="numpy")
    described = {
        a.name: a
        for section in doc.parse()
        if section.kind.value == "attributes"
        for a in section.value
    }
    rows = ["| field | type | default | meaning |", "|---|---|---|---|"]
    for f in dataclasses.fields(cls):
        if f.name not in described:
            raise PluginError(f"{dotted}.{f.name} is not described in its Attributes section")
        attr = described[f.name]
        if f.default is not dataclasses.MISSING:
            default = f"`{f.default!r}`"
        elif f.default_factory is not dataclasses.MISSING:
            default = f"`{f.default_factory()!r}`"
        else:
            default = "required"
        text = " ".join(attr.description.split())
        text = re.sub(r":(?:meth|func):`~?([^`]+)`", r"``\1()``", text)  # Sphinx roles
        text = re.sub(r":\w+:`~?([^`]+)`", r"``\1``", text)
        text = text.replace("``", "`").replace("|", "\\|")
        kind = str(attr.annotation or "").replace("|", "\\|")
        rows.append(f"| `{f.name}` | {kind} | {default} | {text} |")
    return "\n".join(rows)


def run_values_table() -> str:
    """The documented run values a plugin may declare (``RunContext``'s fields)."""
    from conformal_control.core.spec import RUN_VALUES

    rows = ["| run value | what it is |", "|---|---|"]
    rows += [
        f"| `{name}` | {doc.replace('|', chr(92) + '|')} |" for name, doc in RUN_VALUES.items()
    ]
    return "\n".join(rows)


def cli_output(command: str) -> str:
    """``$ conformal-control COMMAND`` and what it prints, run now (versions, plugins and
    counts of this build); a non-zero exit fails the build."""
    import contextlib
    import io
    import shlex

    from conformal_control.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(shlex.split(command))
    if code != 0:
        raise PluginError(f"conformal-control {command} failed ({code}): {err.getvalue()}")
    return f"$ conformal-control {command}\n{out.getvalue().rstrip()}"


def run_output(args: str) -> str:
    """``$ conformal-control run ARGS`` and what it prints (:func:`cli_run_output`)."""
    import shlex

    return f"$ conformal-control run {args}\n" + cli_run_output(*shlex.split(args))


#: ``<!-- generated:KIND ARGUMENT -->`` markers taking an argument.
_ARG_MARKER = re.compile(r"<!-- generated:(fields|command|run|runs) (.+?) -->")
_ARG_GENERATORS = {
    "fields": fields_table,
    "command": cli_output,
    "run": run_output,
    "runs": run_table,
}


GENERATORS = {
    "<!-- generated:api-index -->": api_index,
    "<!-- generated:parameters -->": parameters_table,
    "<!-- generated:cli -->": cli_reference,
    "<!-- generated:run-demo -->": lambda: cli_run_output(),
    "<!-- generated:run-nexus_4 -->": lambda: cli_run_output("--scene", "nexus_4"),
    "<!-- generated:roles -->": roles_table,
    "<!-- generated:run-values -->": run_values_table,
    "<!-- generated:ethucy-tasks -->": ethucy_tasks,
}


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    for marker, make in GENERATORS.items():
        if marker in markdown:
            markdown = markdown.replace(marker, make())
    return _ARG_MARKER.sub(lambda m: _ARG_GENERATORS[m.group(1)](m.group(2)), markdown)
