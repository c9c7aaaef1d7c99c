"""The shape of the package, measured from its own source: the figures of the "house".

Rooms are modules, floors the layers of ``tests/test_architecture.py`` (read from there,
so the figures follow the rules the test enforces), arrows the imports between modules --
module-level AND inside functions (a function-level import closes a circle all the same,
it only closes it later), ``if TYPE_CHECKING:`` blocks aside (they never run). Usage::

    python benchmarks/house.py            # the table
    python benchmarks/house.py --json     # the same figures as JSON

Figures:

* rooms, floors, arrows (distinct module -> module imports; none to a folder that only
  groups units, whose ``__init__`` imports nothing), arrows running up (a unit
  importing a unit of its own or a higher layer, which the layer rule forbids), the
  function-level imports among them;
* circles: strongly connected groups of modules in the import graph (every import);
* the longest parameter lists of functions and constructors (compiled ``@jit`` kernels
  aside, as their arguments are arrays by design);
* private names (``_x``) imported from another module, and the module pairs;
* reads of other objects' private attributes (:func:`private_reads`): ``obj._x`` where
  ``obj`` is not ``self``, ``cls``, ``super()`` or ``type(self)`` (a class's own code),
  and ``getattr``/``hasattr``/``setattr`` of a private name given as text; in the engines
  and in the whole package;
* circles again with the ``if TYPE_CHECKING:`` imports counted (a circle of annotations
  still ties the modules' designs together);
* lines of ``runs/episode.py`` and ``runs/fleet.py`` (``sim/`` of 0.3), and of the whole
  package.

``--path`` follows a call path instead (:func:`follow`): the CLI's ``run`` from its
arguments to the first update of lambda, traced call by call (``sys.setprofile``; code run
while a module is being imported is left out). The *path* is the chain of modules on the
stack at that update (consecutive frames of one module count once); the path **enters** a
module when a function of the path calls into it (the path's own modules included); a
call from the path into a module of a lower floor that returns before the update is one
**return to a higher layer** (the path went down for a detour and climbed back). Calls
made inside a detour are the detour's business and are not counted.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import json
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "conformal_control"


def _layers() -> dict[str, int]:
    spec = importlib.util.spec_from_file_location(
        "_arch_test", ROOT / "tests" / "test_architecture.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return dict(mod.LAYERS)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _targets(node: ast.Import | ast.ImportFrom, me: str, is_pkg: bool) -> list[tuple[str, str]]:
    """(module, imported name or '') for each conformal_control target of an import."""
    if isinstance(node, ast.Import):
        return [(a.name, "") for a in node.names if a.name.startswith("conformal_control")]
    package = me if is_pkg else me.rpartition(".")[0]
    if node.level:
        base = package.split(".")
        base = base[: len(base) - node.level + 1]
        target = ".".join([*base, node.module] if node.module else base)
    else:
        target = node.module or ""
    if not target.startswith("conformal_control"):
        return []
    out = []
    for alias in node.names:
        sub = f"{target}.{alias.name}"
        p = ROOT / sub.replace(".", "/")
        if p.with_suffix(".py").exists() or (p / "__init__.py").exists():
            out.append((sub, ""))
        else:
            out.append((target, alias.name))
    return out


def imports(path: Path, typing: bool = False) -> list[tuple[str, str, bool]]:
    """(target module, name, inside a function) for every runtime import of ``path``
    (with ``typing``, the ``if TYPE_CHECKING:`` imports too)."""
    me = module_name(path)
    is_pkg = path.name == "__init__.py"
    out: list[tuple[str, str, bool]] = []

    class Visitor(ast.NodeVisitor):
        depth = 0

        def visit_If(self, node: ast.If) -> None:
            if _is_type_checking(node) and not typing:  # never runs
                for n in node.orelse:
                    self.visit(n)
            else:
                self.generic_visit(node)

        def _fn(self, node: ast.AST) -> None:
            self.depth += 1
            self.generic_visit(node)
            self.depth -= 1

        visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = _fn

        def visit_Import(self, node: ast.Import) -> None:
            out.extend((t, n, self.depth > 0) for t, n in _targets(node, me, is_pkg))

        visit_ImportFrom = visit_Import  # type: ignore[assignment]

    Visitor().visit(ast.parse(path.read_text()))
    return out


def _unit(module: str) -> str:
    """The unit of LAYERS holding ``module`` (the longest dotted key prefixing it), as the
    layer test reads it; ``""`` for the package and for grouping folders."""
    layers = _layers_cached()
    parts = module.split(".")[1:]
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in layers:
            return ".".join(parts[:n])
    return ""


_LAYERS: dict[str, int] = {}


def _layers_cached() -> dict[str, int]:
    if not _LAYERS:
        _LAYERS.update(_layers())
    return _LAYERS


def _sccs(g: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(g.get(v, ())):
            if w not in g:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def _is_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    for d in fn.decorator_list:
        name = d.func if isinstance(d, ast.Call) else d
        text = ast.unparse(name)
        if text.split(".")[-1] in ("jit", "njit", "vectorize", "guvectorize", "kernel"):
            return True
    return False


def parameter_lists(files: list[Path], kernels: bool = False) -> list[tuple[int, str, bool]]:
    """(number of parameters, qualified name, takes **kwargs) of every function (of every
    compiled kernel with ``kernels``)."""
    out = []
    for path in files:
        mod = module_name(path)
        tree = ast.parse(path.read_text())
        # a kernel's interpreted form (@kernel(python=f)) counts as the kernel
        twins = {
            kw.value.id
            for n in ast.walk(tree)
            if isinstance(n, ast.Call) and ast.unparse(n.func).split(".")[-1] == "kernel"
            for kw in n.keywords
            if kw.arg == "python" and isinstance(kw.value, ast.Name)
        }

        def visit(
            nodes: list[ast.stmt], prefix: str, mod: str = mod, twins: set[str] = twins
        ) -> None:
            for node in nodes:
                if isinstance(node, ast.ClassDef):
                    visit(node.body, f"{prefix}{node.name}.")
                elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    if (_is_kernel(node) or node.name in twins) != kernels:
                        continue
                    a = node.args
                    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
                    if names and names[0] in ("self", "cls"):
                        names = names[1:]
                    out.append((len(names), f"{mod}.{prefix}{node.name}", a.kwarg is not None))
                    visit(node.body, f"{prefix}{node.name}.")

        visit(tree.body, "")
    return sorted(out, key=lambda r: (-r[0], r[1]))


_ATTR_FUNCTIONS = ("getattr", "hasattr", "setattr", "delattr")


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_reads(files: list[Path]) -> list[tuple[str, int, str]]:
    """(module, line, expression) of every read of another object's private attribute.

    ``obj._x`` counts unless ``obj`` is the method's own ``self``/``cls`` (the first
    parameter of a function defined in a class body, also in functions nested in it),
    ``super()`` or ``type(...)`` (a class reading its own); ``getattr(obj, "_x")`` and
    the like count when the name is given as text. A module's own private names
    (``_helper``) are names, not attributes, and do not count; library internals
    (``argparse._Action``, ``os._exit``) do.
    """
    out: list[tuple[str, int, str]] = []
    for path in files:

        class Visitor(ast.NodeVisitor):
            def __init__(self, mod: str) -> None:
                self.mod = mod
                self.own: list[str | None] = [None]
                self.in_class = [False]

            def visit_ClassDef(self, node: ast.ClassDef) -> None:
                self.in_class.append(True)
                self.generic_visit(node)
                self.in_class.pop()

            def _fn(self, node: ast.FunctionDef | ast.AsyncFunctionDef) -> None:
                args = [*node.args.posonlyargs, *node.args.args]
                own = args[0].arg if self.in_class[-1] and args else self.own[-1]
                self.own.append(own)
                self.in_class.append(False)
                self.generic_visit(node)
                self.in_class.pop()
                self.own.pop()

            visit_FunctionDef = visit_AsyncFunctionDef = _fn

            def _mine(self, v: ast.expr) -> bool:
                if isinstance(v, ast.Name):
                    return v.id == self.own[-1]
                if not (isinstance(v, ast.Call) and isinstance(v.func, ast.Name)):
                    return False
                if v.func.id == "super":
                    return True
                return v.func.id == "type" and len(v.args) == 1 and self._mine(v.args[0])

            def visit_Attribute(self, node: ast.Attribute) -> None:
                if _is_private(node.attr) and not self._mine(node.value):
                    out.append((self.mod, node.lineno, ast.unparse(node)))
                self.generic_visit(node)

            def visit_Call(self, node: ast.Call) -> None:
                if (
                    isinstance(node.func, ast.Name)
                    and node.func.id in _ATTR_FUNCTIONS
                    and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant)
                    and isinstance(node.args[1].value, str)
                    and _is_private(node.args[1].value)
                    and not self._mine(node.args[0])
                ):
                    out.append((self.mod, node.lineno, ast.unparse(node)))
                self.generic_visit(node)

        Visitor(module_name(path)).visit(ast.parse(path.read_text()))
    return sorted(out)


def typing_circles(files: list[Path]) -> list[list[str]]:
    """The import graph's circles with the ``if TYPE_CHECKING:`` imports counted."""
    g: dict[str, set[str]] = {}
    for p in files:
        me = module_name(p)
        deps: set[str] = set()
        for target, _, _ in imports(p, typing=True):
            parts = target.split(".")
            for d in {".".join(parts[:i]) for i in range(2, len(parts) + 1)}:
                if d != me and not me.startswith(d + "."):
                    deps.add(d)
        g[me] = deps
    return _sccs(g)


def follow(argv: list[str]) -> dict[str, Any]:
    """The call path of ``conformal-control ARGV`` up to the first update of lambda (a call
    of ``update`` in ``update_rules/``): the path's modules, the modules it enters, its
    returns to a higher layer (see the module docstring), the detours by module pair.

    Parameters
    ----------
    argv : list of str
        The command line after ``conformal-control`` (the command runs in this process).
    """
    import sys

    layers = _layers()
    pkg = str(PKG)
    moved = str(PKG / "_moved.py")

    def layer(module: str) -> int:
        return layers.get(_unit(module), 99)

    calls: list[list[Any]] = []  # [module stack, returned, entry (a module's first frame)]
    active: list[int] = []
    state: dict[str, Any] = {"spine": None, "importing": 0}

    def profile(frame: Any, event: str, arg: Any) -> None:
        if event not in ("call", "return"):
            return
        code = frame.f_code
        if not code.co_filename.startswith(pkg) or code.co_filename == moved:
            return  # _moved.py is the import system's finder (asked at every import)
        if code.co_name == "<module>":  # an import: not the run's path
            state["importing"] += 1 if event == "call" else -1
            return
        if state["importing"]:
            return
        if event == "return":
            if active:
                calls[active.pop()][1] = True
            return
        module = module_name(Path(code.co_filename))
        stack = calls[active[-1]][0] if active else ()
        entry = not (stack and stack[-1] == module)
        ms = (*stack, module) if entry else stack
        if code.co_name == "update" and "/update_rules/" in code.co_filename:
            state["spine"] = ms
            sys.setprofile(None)
            return
        calls.append([ms, False, entry])
        active.append(len(calls) - 1)

    from conformal_control.cli import main as cli_main

    sys.setprofile(profile)
    try:
        cli_main(argv)
    finally:
        sys.setprofile(None)
    spine = state["spine"]
    if spine is None:
        raise RuntimeError("the command never updated lambda")
    entered = set(spine)
    pairs: dict[tuple[str, str], int] = {}
    for ms, returned, entry in calls:
        if len(ms) < 2 or not returned or not entry or spine[: len(ms) - 1] != ms[:-1]:
            continue  # a call inside a detour, or the path itself
        caller, callee = ms[-2], ms[-1]
        entered.add(callee)
        if layer(callee) < layer(caller):
            pairs[(caller, callee)] = pairs.get((caller, callee), 0) + 1
    return {
        "path (modules on the stack at the update)": list(spine),
        "files entered": len(entered),
        "returns to a higher layer": sum(pairs.values()),
        "_detail": {
            "entered": sorted(entered),
            "returns": [f"{n:3d}  {a} <- {b}" for (a, b), n in sorted(pairs.items())],
        },
    }


def measure() -> dict[str, Any]:
    layers = _layers()
    files = sorted(PKG.rglob("*.py"))
    g: dict[str, set[str]] = {}
    edges: dict[tuple[str, str], bool] = {}  # (a, b) -> only inside functions
    private: list[tuple[str, str, str]] = []
    n_function_level = 0
    # folders that only group units (an __init__ importing nothing of the package, e.g.
    # core/): running their __init__ is no dependency, so no arrow points at them
    grouping = {
        module_name(p) for p in files if p.name == "__init__.py" and not imports(p, typing=True)
    }
    for p in files:
        me = module_name(p)
        deps: set[str] = set()
        for target, name, nested in imports(p):
            n_function_level += nested
            parts = target.split(".")
            # importing a.b.c runs a/__init__ and a/b/__init__ first
            chain = {".".join(parts[:i]) for i in range(2, len(parts) + 1)}
            for d in chain:
                if d == me or me.startswith(d + ".") or (d in grouping and d != target):
                    continue
                deps.add(d)
                edges[(me, d)] = edges.get((me, d), True) and nested
            if name.startswith("_") and not name.startswith("__") and target != me:
                private.append((me, target, name))
        g[me] = deps
    up = []
    for (a, b), nested in sorted(edges.items()):
        u, v = _unit(a), _unit(b)
        if u and v and u != v and layers.get(v, -1) >= layers.get(u, 99):
            up.append((a, b, nested))
    circles = _sccs(g)
    in_circle = {m: i for i, c in enumerate(circles) for m in c}
    closing = [
        (a, b)
        for (a, b), nested in edges.items()
        if nested and a in in_circle and in_circle.get(b) == in_circle[a]
    ]
    params = parameter_lists(files)
    # what sim/ held in 0.3 (its package front aside): one episode and a fleet
    runners = [PKG / "runs" / "episode.py", PKG / "runs" / "fleet.py"]
    sim_lines = sum(len(f.read_text().splitlines()) for f in runners if f.exists())
    reads = private_reads(files)
    typed = typing_circles(files)
    return {
        "rooms (modules)": len(files),
        "floors (layers)": len(set(layers.values())),
        "arrows (module -> module imports)": len(edges),
        "function-level imports": n_function_level,
        "arrows running up": len(up),
        "arrows running up, function-level only": sum(1 for *_, n in up if n),
        "circles (strongly connected groups)": len(circles),
        "modules in circles": sum(len(c) for c in circles),
        "function-level imports inside circles": len(closing),
        "longest parameter lists": [
            f"{n}{' + **kwargs' if kw else ''}  {name}" for n, name, kw in params[:10]
        ],
        "functions over 15 parameters": sum(1 for n, *_ in params if n > 15),
        "longest compiled kernel": " ".join(map(str, parameter_lists(files, True)[0][:2])),
        "api.run": next(
            f"{n}{' + **kwargs' if kw else ''}"
            for n, name, kw in params
            if name == "conformal_control.api.run"
        ),
        "circles counting typing-only imports": len(typed),
        "private names imported across modules": len(private),
        "module pairs with private imports": len({(a, b) for a, b, _ in private}),
        "reads of other objects' private attributes": len(reads),
        "  of which in runs/engines/": sum(
            1 for m, *_ in reads if m.startswith(f"{PKG.name}.runs.engines")
        ),
        "lines of runs/episode.py + runs/fleet.py": sim_lines,
        "lines of the package": sum(len(f.read_text().splitlines()) for f in files),
        "_detail": {
            "up": [f"{a} -> {b}{' (in a function)' if n else ''}" for a, b, n in up],
            "circles": circles,
            "closing": [f"{a} -> {b}" for a, b in sorted(closing)],
            "private": [f"{a} <- {b}.{n}" for a, b, n in private],
            "private reads": [f"{m}:{line}  {text}" for m, line, text in reads],
            "typing circles": typed,
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--json", action="store_true", help="print JSON")
    ap.add_argument("--detail", action="store_true", help="list the offending imports")
    ap.add_argument(
        "--path",
        nargs=argparse.REMAINDER,
        metavar="ARGV",
        help="follow the call path of `conformal-control ARGV` to the first lambda update "
        "instead (e.g. --path run --scene nexus_4 --epsilon -0.1 --no-plot --out DIR -q)",
    )
    args = ap.parse_args()
    m = follow(args.path) if args.path else measure()
    detail = m.pop("_detail")
    if args.json:
        print(json.dumps({**m, **({"detail": detail} if args.detail else {})}, indent=1))
        return
    for k, v in m.items():
        if isinstance(v, list):
            print(f"{k}:")
            for x in v:
                print(f"    {x}")
        else:
            print(f"{k:45s} {v}")
    if args.detail:
        for k, rows in detail.items():
            print(f"\n{k}:")
            for r in rows:
                print(f"    {r}")


if __name__ == "__main__":
    main()
