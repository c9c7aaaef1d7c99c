"""Plugins by name: registration, entry-point discovery, construction.

Every role has an entry-point group named after it (``conformal_control.predictors``,
``conformal_control.barriers``, ...). Our own core plugins are declared in our
``pyproject.toml`` exactly like a third party would declare theirs, so
``conformal-control plugins`` lists both the same way. A plugin whose dependency is
missing stays listed, marked unavailable, with the import error as its reason; asking for
it raises :class:`PluginUnavailableError` instead of breaking ``import conformal_control``.

Registering at runtime (tests, notebooks) needs no packaging::

    from conformal_control import registry

    @registry.register("predictor", "my_model")
    class MyPredictor(Predictor): ...
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from importlib.metadata import EntryPoint, entry_points
from typing import Any

__all__ = [
    "ROLES",
    "PluginEntry",
    "PluginUnavailableError",
    "create",
    "entries",
    "get",
    "names",
    "register",
]

#: role -> entry-point group
ROLES: dict[str, str] = {
    "predictor": "conformal_control.predictors",
    "barrier": "conformal_control.barriers",
    "safety_filter": "conformal_control.safety_filters",
    "loss": "conformal_control.losses",
    "update_rule": "conformal_control.update_rules",
    "dynamics": "conformal_control.dynamics",
}

#: Core plugins, used when the package runs from a source tree without installed metadata.
_CORE: dict[str, dict[str, str]] = {
    "predictor": {
        "constant_velocity": (
            "conformal_control.predictors.constant_velocity:ConstantVelocityPredictor"
        ),
        "oracle": "conformal_control.predictors.oracle:OraclePredictor",
    },
    "barrier": {"apf": "conformal_control.cbf.barriers:APFBarrier"},
    "safety_filter": {"qp": "conformal_control.cbf.qp:QPSafetyFilter"},
    "loss": {
        "cbf_gap": "conformal_control.cbf.loss:CBFGapLoss",
        "collision": "conformal_control.cbf.safety_losses:CollisionLoss",
        "distance_shortfall": "conformal_control.cbf.safety_losses:DistanceShortfallLoss",
        "miscoverage": "conformal_control.losses:MiscoverageLoss",
        "function": "conformal_control.losses:FunctionLoss",
        "defect_fraction": "conformal_control.domains.factory:DefectFractionLoss",
    },
    "update_rule": {
        "fixed_eta": "conformal_control.update_rules:FixedEtaRule",
        "decaying_eta": "conformal_control.update_rules:DecayingEtaRule",
        "aci": "conformal_control.update_rules:ACIRule",
        "dtaci": "conformal_control.update_rules:DtACIRule",
        "pid": "conformal_control.update_rules:PIDRule",
    },
    "dynamics": {
        "double_integrator": "conformal_control.dynamics:DoubleIntegrator",
        "velocity_tracking": "conformal_control.dynamics:VelocityTrackingDoubleIntegrator",
    },
}


class PluginUnavailableError(ImportError):
    """A registered plugin cannot be loaded (typically a missing optional dependency)."""


@dataclass
class PluginEntry:
    """One registered plugin.

    Attributes
    ----------
    role, name : str
    target : str or type
        ``"module:Class"`` (loaded lazily) or the class itself.
    origin : str
        Where it comes from: the distribution declaring the entry point, or "runtime".
    """

    role: str
    name: str
    target: str | type
    origin: str
    _loaded: type | None = None
    _error: str | None = None

    def load(self) -> type:
        """Import and return the plugin class."""
        if self._loaded is not None:
            return self._loaded
        if self._error is not None:
            raise PluginUnavailableError(self._error)
        if isinstance(self.target, type):
            self._loaded = self.target
            return self._loaded
        module, _, attr = self.target.partition(":")
        try:
            obj: Any = import_module(module)
            for part in attr.split("."):
                obj = getattr(obj, part)
        except ImportError as exc:
            self._error = (
                f"{self.role} plugin {self.name!r} (from {self.origin}) cannot be loaded: {exc}. "
                "Install its optional dependencies (see the README's set-up command)."
            )
            raise PluginUnavailableError(self._error) from exc
        self._loaded = obj
        return obj

    @property
    def available(self) -> bool:
        try:
            self.load()
        except PluginUnavailableError:
            return False
        return True

    @property
    def error(self) -> str | None:
        return None if self.available else self._error

    def summary(self) -> str:
        if not self.available:
            return f"(unavailable) {self._error}"
        cls = self.load()
        summary = getattr(cls, "summary", None)
        return summary() if callable(summary) else (cls.__doc__ or cls.__name__).strip()


_registry: dict[str, dict[str, PluginEntry]] = {role: {} for role in ROLES}
_discovered = False


def _check_role(role: str) -> None:
    if role not in ROLES:
        raise ValueError(f"unknown plugin role {role!r}; roles: {', '.join(ROLES)}")


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    _discovered = True
    for role, group in ROLES.items():
        for name, target in _CORE[role].items():
            _registry[role].setdefault(name, PluginEntry(role, name, target, "conformal-control"))
        ep: EntryPoint
        for ep in entry_points(group=group):
            dist = ep.dist.name if ep.dist is not None else "unknown"
            existing = _registry[role].get(ep.name)
            if existing is not None and existing.target == ep.value:
                existing.origin = dist
                continue
            _registry[role][ep.name] = PluginEntry(role, ep.name, ep.value, dist)


def register(role: str, name: str, *, overwrite: bool = False) -> Callable[[type], type]:
    """Class decorator registering a plugin at runtime under ``role``/``name``."""
    _check_role(role)
    _discover()

    def deco(cls: type) -> type:
        if name in _registry[role] and not overwrite:
            current = _registry[role][name]
            if current.target is not cls:
                raise ValueError(
                    f"a {role} plugin named {name!r} is already registered (from "
                    f"{current.origin}); pass overwrite=True to replace it"
                )
        _registry[role][name] = PluginEntry(role, name, cls, "runtime")
        return cls

    return deco


def unregister(role: str, name: str) -> None:
    """Remove a plugin (mainly for tests)."""
    _check_role(role)
    _registry[role].pop(name, None)


def entries(role: str | None = None) -> list[PluginEntry]:
    """All registered plugins (of one role), sorted by role then name."""
    _discover()
    roles = [role] if role is not None else list(ROLES)
    out: list[PluginEntry] = []
    for r in roles:
        _check_role(r)
        out.extend(_registry[r][n] for n in sorted(_registry[r]))
    return out


def names(role: str) -> list[str]:
    """Names of the plugins of one role."""
    return [e.name for e in entries(role)]


def get(role: str, name: str) -> type:
    """The plugin class registered as ``role``/``name``."""
    _check_role(role)
    _discover()
    try:
        entry = _registry[role][name]
    except KeyError:
        known = ", ".join(sorted(_registry[role])) or "none"
        raise ValueError(f"unknown {role} {name!r}; registered: {known}") from None
    return entry.load()


def create(role: str, name: str, **params: Any) -> Any:
    """Instantiate ``role``/``name`` with ``params`` (a clear error for unknown params)."""
    cls = get(role, name)
    try:
        return cls(**params)
    except TypeError as exc:
        raise ValueError(f"cannot create {role} {name!r} with {params}: {exc}") from exc
