"""The module paths of 0.3 that moved in the relocation of 0.4 (issue 33), served from one table.

``import conformal_control.loop`` (0.3) still works: the finder below, installed by the
package's ``__init__``, answers every old dotted path of :data:`MOVED` (a package's entry
covers its submodules) with the module at its new path, the *same* module object (its
classes are the same classes, ``isinstance`` and pickles keep working), and warns once per
old path with a :class:`~conformal_control.core.exceptions.ConformalControlDeprecationWarning`
naming the new path and the removal date. One table and one finder instead of a stub file per
old module; nothing of the package imports an old path (the test suite turns the warning into
an error).
"""

from __future__ import annotations

import importlib
import sys
import warnings
from importlib.machinery import ModuleSpec
from types import ModuleType
from typing import Any

#: Old dotted path -> new dotted path. A package's entry covers every module below it.
MOVED: dict[str, str] = {
    "conformal_control.flagship.build": "conformal_control.runs.build",
    "conformal_control.flagship.params": "conformal_control.runs.params",
    "conformal_control.sim.episode": "conformal_control.runs.episode",
    "conformal_control.sim.multi": "conformal_control.runs.fleet",
    "conformal_control.engines": "conformal_control.runs.engines",
    "conformal_control.results": "conformal_control.runs.results",
    "conformal_control.commands": "conformal_control.cli.commands",
    "conformal_control.sweep.spec": "conformal_control.experiments.plan",
    "conformal_control.bench.runner": "conformal_control.experiments.bench.suite",
    "conformal_control.sweep": "conformal_control.experiments",
    "conformal_control.bench": "conformal_control.experiments.bench",
    "conformal_control.reproduce": "conformal_control.experiments.reproduce",
    "conformal_control.crowds": "conformal_control.world.crowds",
    "conformal_control.cbf": "conformal_control.families.cbf",
    "conformal_control.mpc": "conformal_control.families.mpc",
    "conformal_control.domains": "conformal_control.families.domains",
    "conformal_control.export": "conformal_control.io.export",
    "conformal_control.plotting": "conformal_control.io.plotting",
    "conformal_control.ros2": "conformal_control.io.ros2",
    "conformal_control.base": "conformal_control.core.base",
    "conformal_control.exceptions": "conformal_control.core.exceptions",
    "conformal_control.progress": "conformal_control.core.progress",
    "conformal_control.fileio": "conformal_control.core.fileio",
    "conformal_control.compiled": "conformal_control.core.compiled",
    "conformal_control.jit": "conformal_control.core.jit",
    "conformal_control.monitor": "conformal_control.core.monitor",
    "conformal_control.registry": "conformal_control.core.registry",
    "conformal_control.losses": "conformal_control.core.losses",
    "conformal_control.spec": "conformal_control.core.spec",
    "conformal_control.loop": "conformal_control.core.loop",
    "conformal_control.update_rules": "conformal_control.core.update_rules",
}

#: Old package fronts that no new package replaces (their modules moved apart): old package ->
#: {public name: the new module that defines it}. ``from conformal_control.sim import
#: run_episode`` keeps working through a stand-in module that imports each name on first use.
FACADES: dict[str, dict[str, str]] = {
    "conformal_control.flagship": {
        "Flagship": "conformal_control.runs.build",
        "RoleSpec": "conformal_control.runs.build",
        "build_flagship": "conformal_control.runs.build",
        "build_rule": "conformal_control.runs.build",
        "PARAMETERS": "conformal_control.runs.params",
        "ResolvedParams": "conformal_control.runs.params",
        "parse_value": "conformal_control.runs.params",
        "resolve_params": "conformal_control.runs.params",
    },
    "conformal_control.sim": {
        "Flagship": "conformal_control.runs.build",
        "build_flagship": "conformal_control.runs.build",
        "build_rule": "conformal_control.runs.build",
        "PARAMETERS": "conformal_control.runs.params",
        "ResolvedParams": "conformal_control.runs.params",
        "parse_value": "conformal_control.runs.params",
        "resolve_params": "conformal_control.runs.params",
        "EpisodeResult": "conformal_control.runs.results.episode",
        "EpisodeMetrics": "conformal_control.runs.results.metrics",
        "ReplayEnvironment": "conformal_control.world.replay",
        "run_episode": "conformal_control.runs.episode",
    },
}

#: When the old paths stop working.
REMOVAL = "removed in 0.4, not before 2027-06-30"


def new_path(old: str) -> str | None:
    """The new dotted path of the module ``old`` moved from (``None``: it did not move).

    Parameters
    ----------
    old
        A dotted module path of 0.3, e.g. ``"conformal_control.loop"``.

    Returns
    -------
    str or None
        Its path since the relocation, the longest entry of :data:`MOVED` that prefixes it
        applied.
    """
    head, tail = old, ""
    while head:
        if head in MOVED:
            return MOVED[head] + tail
        head, _, last = head.rpartition(".")
        tail = f".{last}{tail}"
    return None


class MovedFinder:
    """A meta-path finder and loader answering the old paths of :data:`MOVED` (first on
    ``sys.meta_path``, so an old folder left behind with stale caches is never taken for a
    namespace package)."""

    def __init__(self) -> None:
        self.real_specs: dict[int, ModuleSpec | None] = {}

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> ModuleSpec | None:
        """A spec for an old path, ``None`` for every other name.

        Parameters
        ----------
        fullname
            The dotted name being imported.
        path
            The parent package's ``__path__`` (unused).
        target
            The module being reloaded (unused).

        Returns
        -------
        ModuleSpec or None
            A spec this finder loads, or ``None``.
        """
        if not fullname.startswith("conformal_control."):
            return None
        if fullname not in FACADES and new_path(fullname) is None:
            return None
        return ModuleSpec(fullname, self)  # type: ignore[arg-type]

    def create_module(self, spec: ModuleSpec) -> ModuleType:
        """Import the new path and hand back its module (with a dated warning).

        Parameters
        ----------
        spec
            The spec :meth:`find_spec` returned.

        Returns
        -------
        ModuleType
            The module at the new path.
        """
        from .core.exceptions import ConformalControlDeprecationWarning

        if spec.name in FACADES:
            names = FACADES[spec.name]
            where = ", ".join(sorted(set(names.values())))
            warnings.warn(
                f"{spec.name} moved apart: import its names from {where} ({REMOVAL})",
                ConformalControlDeprecationWarning,
                stacklevel=2,
            )
            return _facade(spec.name, names)
        new = new_path(spec.name)
        assert new is not None
        module = importlib.import_module(new)
        warnings.warn(
            f"{spec.name} moved to {new} ({REMOVAL}); import it from there",
            ConformalControlDeprecationWarning,
            stacklevel=2,
        )
        # the import system sets __spec__ on the module it gets back: keep the real one
        self.real_specs.setdefault(id(module), module.__spec__)
        return module

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module ran at its new path (its own spec is put back).

        Parameters
        ----------
        module
            The module :meth:`create_module` returned.
        """
        module.__spec__ = self.real_specs.pop(id(module), module.__spec__)


def _facade(name: str, names: dict[str, str]) -> ModuleType:
    """A stand-in for an old package front: each name imported from its new module on first
    use; a package (``__path__``) so the old paths of its modules resolve through
    :data:`MOVED`."""
    module = ModuleType(name, f"{name} (moved apart; {REMOVAL})")
    module.__path__ = []
    module.__dict__["__all__"] = sorted(names)

    def __getattr__(attr: str) -> Any:
        if attr not in names:
            raise AttributeError(f"module {name!r} has no attribute {attr!r}")
        return getattr(importlib.import_module(names[attr]), attr)

    module.__getattr__ = __getattr__  # type: ignore[method-assign]
    return module


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, MovedFinder())
