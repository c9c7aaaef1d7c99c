"""House rules checked statically: no import cycles, imports pointing down, a loop that
knows no CBF, no private name imported from another module, no function over 15
parameters. Every import counts, the ones inside functions too."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "conformal_control"


def module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _targets(node: ast.Import | ast.ImportFrom, me: str, is_pkg: bool) -> set[str]:
    """The conformal_control modules an import statement loads."""
    if isinstance(node, ast.Import):
        return {a.name for a in node.names if a.name.startswith("conformal_control")}
    package = me if is_pkg else me.rpartition(".")[0]
    if node.level:
        base = package.split(".")
        base = base[: len(base) - node.level + 1]
        target = ".".join([*base, node.module] if node.module else base)
    else:
        target = node.module or ""
    if not target.startswith("conformal_control"):
        return set()
    out = {target}
    for alias in node.names:  # "from . import registry" imports a submodule
        sub = f"{target}.{alias.name}"
        if (PKG.parent / sub.replace(".", "/")).with_suffix(".py").exists() or (
            PKG.parent / sub.replace(".", "/") / "__init__.py"
        ).exists():
            out.add(sub)
    return out


def imports(path: Path) -> set[str]:
    """Every conformal_control module ``path`` imports when it runs: at module level AND
    inside functions (an import in a function closes a circle all the same, only later).
    ``if TYPE_CHECKING:`` blocks are left out (they never run)."""
    me = module_name(path)
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()

    class Visitor(ast.NodeVisitor):
        def visit_If(self, node: ast.If) -> None:
            if _is_type_checking(node):
                for n in node.orelse:
                    self.visit(n)
            else:
                self.generic_visit(node)

        def visit_Import(self, node: ast.Import) -> None:
            out.update(_targets(node, me, is_pkg))

        def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
            out.update(_targets(node, me, is_pkg))

    Visitor().visit(ast.parse(path.read_text()))
    return out


def graph() -> dict[str, set[str]]:
    g = {module_name(p): imports(p) for p in PKG.rglob("*.py")}
    # importing a.b.c runs a/__init__ and a/b/__init__ first
    for mod in list(g):
        for dep in list(g[mod]):
            parts = dep.split(".")
            g[mod] |= {".".join(parts[:i]) for i in range(1, len(parts))}
        # an ancestor package is already initialising when its descendant is imported
        g[mod] = {d for d in g[mod] if not (mod == d or mod.startswith(d + "."))}
    return g


def test_no_import_cycles() -> None:
    g = graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(g.get(m, ())):
            if d not in g:
                continue
            if state.get(d) == 1:
                cycle = [*stack[stack.index(d) :], d]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m)


def test_generic_loop_knows_nothing_about_cbfs_or_data() -> None:
    g = graph()
    for mod in (
        "conformal_control.core.loop",
        "conformal_control.core.base",
        "conformal_control.core.monitor",
        "conformal_control.core.update_rules",
    ):
        bad = {
            d
            for d in g[mod]
            if d.split(".")[1:2]
            and d.split(".")[1]
            in ("families", "data", "runs", "sim", "io", "cli", "commands", "predictors")
        }
        assert not bad, f"{mod} imports {bad}"
    names = {
        n.id.lower() if isinstance(n, ast.Name) else n.attr.lower()
        for n in ast.walk(ast.parse((PKG / "core" / "loop.py").read_text()))
        if isinstance(n, (ast.Name, ast.Attribute))
    }
    for word in ("barrier", "pedestrian", "piqp", "qp", "scene"):
        assert not any(word in n for n in names), f"loop.py uses a name with {word!r}"


#: Every unit (a module or a subpackage, named by its dotted path below the package), by
#: layer: a unit may import (at module level or inside a function) only units of a LOWER
#: layer. A module belongs to the longest unit prefixing its path; a new unit must be
#: placed here.
LAYERS: dict[str, int] = {
    # the generic core: roles, the parameter table, the loop
    "core.base": 0,
    "core.exceptions": -1,  # imports nothing of the package: every unit may raise its errors
    "core.capabilities": -1,  # imports nothing of the package: every unit may read them
    "_moved": 0,  # the old module paths of 0.3 (imports a new path when an old one is asked)
    "core.progress": 0,
    "core.fileio": 1,
    "core.compiled": 1,
    "core.jit": 2,
    "core.monitor": 1,
    "core.registry": 1,
    "core.losses": 1,
    "core.spec": 1,
    "core.loop": 2,
    "core.update_rules": 2,
    # data and plugins
    "data": 3,
    "predictors": 4,
    "families.cbf": 5,
    "world.crowds": 5,
    # worlds and decision problems; figures (read results by duck typing)
    "world": 6,
    "families.domains": 6,
    "io.plotting": 6,
    # decision families driven in the replay world by their contract checks
    "families.mpc": 7,
    # wiring one episode; measuring and writing what it produced; the contract kit
    "runs": 8,  # runs/build.py and runs/params.py: wiring one run (flagship/ of 0.3)
    "runs.results": 8,
    "testing": 8,
    # the backends of the loop, then running episodes
    "runs.engines": 9,
    "runs.episode": 10,
    "runs.fleet": 10,
    "io.ros2": 10,
    # many episodes, environments for RL, the paper's tables
    "experiments": 11,
    "envs": 11,
    "io.export": 11,
    "experiments.bench": 12,
    "experiments.reproduce": 12,
    # the front door and the command line
    "api": 13,
    "cli.commands": 14,
    "cli": 15,
}

#: Imports allowed to break the layering: (importer, imported) -> why. Only for a lazy
#: import whose purpose is to defer a heavy third-party dependency; empty today.
ALLOWED_UP: dict[tuple[str, str], str] = {}


def _unit(module: str) -> str:
    """The key of LAYERS that holds ``module``: the longest dotted unit prefixing it
    (``conformal_control.core.loop`` -> ``core.loop``); ``""`` for the package itself and
    for a folder that only groups units (``core``, whose ``__init__`` imports nothing)."""
    parts = module.split(".")[1:]
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in LAYERS:
            return ".".join(parts[:n])
    return ""


def test_every_unit_has_a_layer() -> None:
    """Every module belongs to a unit of LAYERS, except grouping folders that import
    nothing of the package (their ``__init__`` is a docstring)."""
    g = graph()
    missing = sorted(
        m for m in g if m != "conformal_control" and not _unit(m) and not _imports_nothing(m)
    )
    assert not missing, f"place {missing} in LAYERS (tests/test_architecture.py)"
    unused = sorted(k for k in LAYERS if not any(_unit(m) == k for m in g))
    assert not unused, f"LAYERS names units that do not exist: {unused}"


def _imports_nothing(module: str) -> bool:
    path = PKG.parent / module.replace(".", "/") / "__init__.py"
    return path.exists() and not imports(path)


def test_imports_point_downward() -> None:
    bad = []
    for mod, deps in graph().items():
        u = _unit(mod)
        if not u:  # the package __init__ may re-export the core
            continue
        for dep in deps:
            v = _unit(dep)
            if v and v != u and LAYERS[v] >= LAYERS[u] and (mod, dep) not in ALLOWED_UP:
                bad.append(f"{mod} (layer {LAYERS[u]}) imports {dep} (layer {LAYERS[v]})")
    assert not bad, "imports must point to lower layers:\n" + "\n".join(sorted(bad))


def test_no_private_name_is_imported_from_another_module() -> None:
    """A name starting with ``_`` is its module's own: another module that needs it needs
    a public name (``from .x import _y`` hides a dependency the API does not show)."""
    bad = []
    for path in PKG.rglob("*.py"):
        me = module_name(path)
        is_pkg = path.name == "__init__.py"
        package = me if is_pkg else me.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            if not target.startswith("conformal_control") or target == me:
                continue
            bad += [
                f"{me} imports {target}.{a.name}"
                for a in node.names
                if a.name.startswith("_") and not a.name.startswith("__")
            ]
    assert not bad, "private names imported across modules:\n" + "\n".join(sorted(bad))


#: Most parameters a function or constructor may take (``self`` / ``cls`` aside).
#: Compiled kernels (``@jit`` and friends) are exempt: their arguments are arrays by design.
MAX_PARAMETERS = 15

#: Decorators that compile a function into a kernel (``jit.kernel`` among them).
KERNEL_DECORATORS = ("jit", "njit", "vectorize", "guvectorize", "kernel")


def _is_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    for d in fn.decorator_list:
        name = ast.unparse(d.func if isinstance(d, ast.Call) else d)
        if name.split(".")[-1] in KERNEL_DECORATORS:
            return True
    return False


def _interpreted_twins(tree: ast.Module) -> set[str]:
    """Functions a kernel decorator names as the kernel's interpreted form
    (``@kernel(python=f)``): the same array arguments as the kernel."""
    return {
        kw.value.id
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and ast.unparse(node.func).split(".")[-1] in KERNEL_DECORATORS
        for kw in node.keywords
        if kw.arg == "python" and isinstance(kw.value, ast.Name)
    }


def parameter_counts() -> dict[str, int]:
    """Parameters of every function and method of the package (kernels and their
    interpreted forms aside)."""
    out: dict[str, int] = {}
    twins: set[str] = set()

    def visit(nodes: list[ast.stmt], prefix: str) -> None:
        for node in nodes:
            if isinstance(node, ast.ClassDef):
                visit(node.body, f"{prefix}{node.name}.")
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if not _is_kernel(node) and node.name not in twins:
                    a = node.args
                    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
                    if names and names[0] in ("self", "cls"):
                        names = names[1:]
                    out[f"{prefix}{node.name}"] = len(names)
                visit(node.body, f"{prefix}{node.name}.")

    for path in PKG.rglob("*.py"):
        tree = ast.parse(path.read_text())
        twins = _interpreted_twins(tree)
        visit(tree.body, f"{module_name(path)}.")
    return out


def test_no_function_takes_more_than_fifteen_parameters() -> None:
    counts = parameter_counts()
    bad = [f"{name}: {n} parameters" for name, n in sorted(counts.items()) if n > MAX_PARAMETERS]
    assert not bad, (
        f"more than {MAX_PARAMETERS} parameters (group related ones into a settings object, "
        "conformal_control.core.base.Settings, or a section of the run specification):\n"
        + "\n".join(bad)
    )


def _house():
    import importlib.util

    spec = importlib.util.spec_from_file_location("_house", PKG.parent / "benchmarks" / "house.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_no_import_circles_even_through_typing_only_imports() -> None:
    """An annotation-only import (``if TYPE_CHECKING:``) closing a circle still ties two
    modules' designs together: none either."""
    circles = _house().typing_circles(sorted(PKG.rglob("*.py")))
    assert not circles, f"import circles through typing-only imports: {circles}"


def test_no_engine_reads_another_objects_private_attributes() -> None:
    """The engines read plugins through their declared interface (compiled forms,
    cursors, public methods); the whole package reads at most 15 private attributes of
    other objects (library internals and the contract kit's hooks, listed by
    ``python benchmarks/house.py --detail``)."""
    reads = _house().private_reads(sorted(PKG.rglob("*.py")))
    engines = [r for r in reads if r[0].startswith("conformal_control.runs.engines")]
    assert not engines, f"private reads in the engines: {engines}"
    assert len(reads) <= 15, "private reads of other objects:\n" + "\n".join(map(str, reads))


def test_every_deprecation_names_its_removal_date() -> None:
    """A deprecated name is kept with a date: every ``DeprecationWarning`` the package
    raises says when the old way goes (0.4, not before 2027-06-30)."""
    undated = []
    for path in sorted(PKG.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (
                isinstance(node, ast.Call)
                and ast.unparse(node.func) in ("warnings.warn", "warn")
                and any(
                    isinstance(a, ast.Name) and a.id == "DeprecationWarning"
                    for a in [*node.args[1:], *(k.value for k in node.keywords)]
                )
            ):
                continue
            text = "".join(
                n.value
                for n in ast.walk(node.args[0])
                if isinstance(n, ast.Constant) and isinstance(n.value, str)
            )
            if "not before 2027-06-30" not in text:
                undated.append(f"{module_name(path)}:{node.lineno}")
    assert not undated, "deprecations without a removal date: " + ", ".join(undated)


def test_the_architecture_page_shows_the_floors_of_this_test() -> None:
    """The floors tables of docs/architecture.md and CONTRIBUTING.md are LAYERS (every unit
    on its floor, no other)."""
    import re

    for page in ("docs/architecture.md", "CONTRIBUTING.md"):
        shown: dict[str, int] = {}
        for line in (PKG.parent / page).read_text().splitlines():
            m = re.match(r"^\s*\| (-?\d+) \| (.*) \|$", line)
            if m:
                # the units are the backticked names outside parentheses
                units = re.sub(r"\([^)]*\)", "", m.group(2))
                for name in re.findall(r"`([\w.]+)`", units):
                    shown[name] = int(m.group(1))
        assert shown == LAYERS, page
