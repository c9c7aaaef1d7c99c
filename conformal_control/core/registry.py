"""Plugins by name: registration, entry-point discovery, construction.

Every role has an entry-point group named after it (``conformal_control.predictors``,
``conformal_control.barriers``, ...; :data:`ROLES` maps each role to its group). A role's
name is the one a run uses everywhere: the :class:`~conformal_control.core.spec.RunSpec`
field, the ``config.json`` key and the command line's option (``rule`` / ``--rule``,
``family`` / ``--family``, ``crowd`` / ``--crowd``). Three groups keep the names they were
published under, since third-party plugins register under them: ``rule`` is
``conformal_control.update_rules``, ``family`` is ``conformal_control.families`` and
``crowd`` is ``conformal_control.crowd_models``. The role names of 0.2 (``update_rule``,
``decision_family``, ``crowd_model``) are still accepted, with a ``DeprecationWarning``.
Our own core plugins are declared in our ``pyproject.toml`` exactly like a third party
would declare theirs, so
``conformal-control plugins`` lists both the same way. A plugin whose dependency is
missing stays listed, marked unavailable, with the import error as its reason; asking for
it raises :class:`PluginUnavailableError` instead of breaking ``import conformal_control``.

Registering at runtime (tests, notebooks) needs no packaging::

    from conformal_control.core import registry

    @registry.register("predictor", "my_model")
    class MyPredictor(Predictor): ...

    registry.register("barrier", "my_barrier", "my_package.barriers:MyBarrier")  # lazy

Name clashes: the first registration of a name wins (core plugins first, then entry
points in discovery order); a different target under a taken name is ignored and reported
by :func:`clashes` and ``conformal-control plugins``. Asking for an unknown name raises
:class:`UnknownPluginError`, which lists the known names and the closest matches.
"""

from __future__ import annotations

import difflib
import importlib
import warnings
from dataclasses import dataclass, field
from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .exceptions import ConformalControlDeprecationWarning

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

__all__ = [
    "RENAMED_ROLES",
    "ROLES",
    "Clash",
    "PluginEntry",
    "PluginUnavailableError",
    "UnknownParameterError",
    "UnknownPluginError",
    "check_params",
    "clashes",
    "create",
    "crowd_names",
    "entries",
    "entry",
    "get",
    "names",
    "refresh",
    "register",
    "role_name",
    "unregister",
]

#: role -> entry-point group
ROLES: dict[str, str] = {
    "predictor": "conformal_control.predictors",
    "barrier": "conformal_control.barriers",
    "safety_filter": "conformal_control.safety_filters",
    "fallback": "conformal_control.fallbacks",
    "loss": "conformal_control.losses",
    "rule": "conformal_control.update_rules",
    "dynamics": "conformal_control.dynamics",
    "reference": "conformal_control.references",
    "family": "conformal_control.families",
    "crowd": "conformal_control.crowd_models",
}

#: Role names of 0.2 -> the role's name now (accepted with a ``DeprecationWarning``).
RENAMED_ROLES: dict[str, str] = {
    "update_rule": "rule",
    "decision_family": "family",
    "crowd_model": "crowd",
}

#: An entry point as the registry reads it: ``(group, name, target, distribution, version)``.
Row = tuple[str, str, str, str, str | None]


class PluginUnavailableError(ImportError):
    """A registered plugin cannot be loaded (typically a missing optional dependency)."""


class UnknownPluginError(ValueError):
    """No plugin of that role is registered under that name.

    Attributes
    ----------
    role, name : str
    known : list of str
        Names registered for the role.
    suggestions : list of str
        The closest known names (did you mean ...?).
    """

    def __init__(self, role: str, name: str, known: list[str]) -> None:
        self.role, self.name, self.known = role, name, known
        self.suggestions = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
        hint = (
            f" did you mean {' or '.join(repr(s) for s in self.suggestions)}?"
            if (self.suggestions)
            else ""
        )
        listed = ", ".join(known) or "none"
        super().__init__(
            f"unknown {role} {name!r};{hint} registered {role} plugins: {listed} "
            "(see `conformal-control plugins`)"
        )


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
    version : str or None
        Version of that distribution.
    """

    role: str
    name: str
    target: str | type
    origin: str
    version: str | None = None
    _loaded: type[Any] | None = field(default=None, repr=False)
    _error: str | None = field(default=None, repr=False)

    def load(self) -> type[Any]:
        """Import and return the plugin class (:class:`PluginUnavailableError` if it cannot)."""
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
            for part in attr.split(".") if attr else []:
                obj = getattr(obj, part)
        except ImportError as exc:
            self._error = (
                f"{self.role} plugin {self.name!r} (from {self.origin}) cannot be loaded: {exc}. "
                "Install its optional dependencies (see the README's set-up command)."
            )
            raise PluginUnavailableError(self._error) from exc
        except Exception as exc:  # a broken plugin must not break the others
            self._error = (
                f"{self.role} plugin {self.name!r} (from {self.origin}) cannot be loaded from "
                f"{self.target!r}: {type(exc).__name__}: {exc}"
            )
            raise PluginUnavailableError(self._error) from exc
        if not isinstance(obj, type):
            self._error = (
                f"{self.role} plugin {self.name!r} (from {self.origin}): {self.target!r} is a "
                f"{type(obj).__name__}, not a class"
            )
            raise PluginUnavailableError(self._error)
        self._loaded = obj
        return obj

    @property
    def available(self) -> bool:
        """Whether the plugin class can be imported."""
        try:
            self.load()
        except PluginUnavailableError:
            return False
        return True

    @property
    def error(self) -> str | None:
        """Why the plugin is unavailable (None if it is available)."""
        return None if self.available else self._error

    def summary(self) -> str:
        """One-line description: first line of the class docstring (or ``description``)."""
        if not self.available:
            return f"(unavailable) {self._error}"
        cls = self.load()
        summary = getattr(cls, "summary", None)
        if callable(summary):
            return str(summary())
        doc = (cls.__doc__ or "").strip()
        return doc.splitlines()[0] if doc else cls.__name__


@dataclass(frozen=True)
class Clash:
    """Two registrations of one name with different targets; the first one is kept."""

    role: str
    name: str
    kept: str
    kept_origin: str
    ignored: str
    ignored_origin: str

    def __str__(self) -> str:
        return (
            f"{self.role} {self.name!r}: {self.ignored} (from {self.ignored_origin}) ignored, "
            f"{self.kept} (from {self.kept_origin}) kept"
        )


_registry: dict[str, dict[str, PluginEntry]] = {role: {} for role in ROLES}
_clashes: list[Clash] = []
_discovered = False


def role_name(role: str) -> str:
    """The role's name now: ``role`` itself, or for a role name of 0.2 (``update_rule``,
    ``decision_family``, ``crowd_model``) its new name, with a ``DeprecationWarning``.

    Raises
    ------
    ValueError
        For a name that is no role.
    """
    new = RENAMED_ROLES.get(role)
    if new is not None:
        warnings.warn(
            f"the plugin role {role!r} is now called {new!r} (as the run's field, "
            f"config.json key and --{new} option); {role!r} is "
            "removed in 0.4, not before 2027-06-30",
            ConformalControlDeprecationWarning,
            stacklevel=3,
        )
        return new
    if role not in ROLES:
        raise ValueError(f"unknown plugin role {role!r}; roles: {', '.join(ROLES)}")
    return role


def _check_role(role: str) -> str:
    if role in ROLES:  # the common case, without a call
        return role
    return role_name(role)


def _target_text(target: str | type) -> str:
    if isinstance(target, type):
        return f"{target.__module__}:{target.__qualname__}"
    return target


def _add(entry: PluginEntry) -> None:
    """Add a discovered entry; the first registration of a name wins, clashes are recorded."""
    existing = _registry[entry.role].get(entry.name)
    if existing is None:
        _registry[entry.role][entry.name] = entry
        return
    if _target_text(existing.target) == _target_text(entry.target):
        if existing.origin == "conformal-control" or existing.origin == entry.origin:
            existing.origin, existing.version = entry.origin, entry.version or existing.version
        return
    _clashes.append(
        Clash(
            entry.role,
            entry.name,
            _target_text(existing.target),
            existing.origin,
            _target_text(entry.target),
            entry.origin,
        )
    )


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    _discovered = True
    _add_rows(_entry_point_rows())


def _add_rows(rows: list[Row]) -> None:
    role_of = {group: role for role, group in ROLES.items()}
    for group, name, target, dist, version in rows:
        if group in role_of:
            _add(PluginEntry(role_of[group], name, target, dist, version))


#: The entry-point scan's cache file (in the package's cache folder; one per search path):
#: every command starts with the registry, and ``importlib.metadata`` (its import, the scan
#: of every installed distribution and the parsing of their metadata) is about a tenth of a
#: short ``conformal-control run``.
#:
#: The cache is a hint, never a source of code. Each row names the metadata folder of the
#: installed distribution that declared it (``<site>/<dist>-<version>.dist-info``); a row
#: is used only when that folder is one of the installed distributions' metadata folders
#: on ``sys.path`` and its ``entry_points.txt`` declares exactly the cached rows (and the
#: distribution's name and version match the folder's). One failed row discards the whole
#: cache and the entry points are scanned again. A tampered cache can therefore point a
#: name only at a target an installed distribution declares under that very name, which
#: is what a scan would find; at worst it hides a third-party distribution's plugins until
#: the next scan (our own distribution's rows must be there). We chose this over a signed
#: cache: a signing key would sit in the same user-writable folder as the cache, so whoever
#: can replace the cache could read the key, whereas the installed metadata is exactly what
#: an uncached scan trusts. Checking costs the reading of the few ``entry_points.txt``
#: files that declare our groups (well under a millisecond), not ``importlib.metadata``.
#: The file is still written ``0600`` (its folder, when we create it, ``0700``).
ENTRY_POINT_CACHE = "entry-points.json"

#: Cache format (rows of ``(group, name, target, distribution, version, metadata folder)``).
_CACHE_FORMAT = 2

#: The largest ``entry_points.txt`` read while checking the cache (bytes).
_MAX_ENTRY_POINTS_FILE = 1 << 20


def _metadata_folders() -> tuple[str, set[str]]:
    """What the entry-point scan depends on, and the metadata folders it may read.

    The first value is the fingerprint: for every folder of ``sys.path``, the names and
    times of change of its distributions' metadata folders. Installing, removing or
    re-installing a distribution changes it (``pip`` writes a new metadata folder); other
    files coming and going in a folder (a script's folder, the current folder) do not; a
    metadata file edited in place by hand does not either (:func:`refresh` re-reads them).
    The second is the set of those metadata folders (absolute paths)."""
    import os
    import sys

    parts: list[str] = [sys.version]
    folders: set[str] = set()
    for entry in sys.path:
        folder = entry or "."
        try:
            with os.scandir(folder) as it:
                found = sorted(
                    (e.name, e.stat().st_mtime_ns)
                    for e in it
                    if e.name.endswith((".dist-info", ".egg-info"))
                )
        except OSError:  # a zip file, a path hook, a missing folder: nothing to list
            parts.append(f"{entry}\0-")
            continue
        absolute = os.path.abspath(folder)
        folders.update(os.path.join(absolute, name) for name, _ in found)
        listed = ",".join(f"{name}:{mtime}" for name, mtime in found)
        parts.append(f"{entry}\0{absolute}\0{listed}")
    return "\n".join(parts), folders


def _installed_fingerprint() -> str:
    """The fingerprint of :func:`_metadata_folders`."""
    return _metadata_folders()[0]


def _normalized(name: str) -> str:
    """A distribution name as in its metadata folder's name (PEP 503, ``_`` for runs)."""
    import re

    return re.sub(r"[-_.]+", "_", name).lower()


def _declared(folder: str) -> set[tuple[str, str, str]] | None:
    """``(group, name, target)`` of our groups declared by ``folder/entry_points.txt``
    (None if it cannot be read); parsed as ``importlib.metadata`` does (sections, then
    ``name = value`` lines, ``#`` and ``;`` comments)."""
    import os

    path = os.path.join(folder, "entry_points.txt")
    try:
        with open(path, "rb") as fh:
            data = fh.read(_MAX_ENTRY_POINTS_FILE + 1)
    except OSError:
        return None
    if len(data) > _MAX_ENTRY_POINTS_FILE:
        return None
    groups = set(ROLES.values())
    out: set[tuple[str, str, str]] = set()
    section = None
    for raw in data.decode("utf-8", "replace").splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1].strip()
            continue
        if section in groups and "=" in line:
            name, _, value = line.partition("=")
            out.add((section, name.strip(), value.strip()))
    return out


def _folder_name(folder: str) -> tuple[str, str]:
    """A metadata folder's distribution name and version (``""`` if the name has none)."""
    import os

    stem = os.path.basename(folder).removesuffix(".dist-info").removesuffix(".egg-info")
    name, _, version = stem.partition("-")
    return name, version


def _checked_rows(stored: Any, folders: set[str]) -> list[Row] | None:
    """The cached rows if every one is declared by an installed distribution (see
    :data:`ENTRY_POINT_CACHE`), our own distribution's first in each group; else None."""
    if not isinstance(stored, list):
        return None
    order = {group: i for i, group in enumerate(ROLES.values())}
    by_folder: dict[str, set[tuple[str, str, str]]] = {}
    rows: list[Row] = []
    for row in stored:
        if not (isinstance(row, list) and len(row) == 6):
            return None
        g, n, t, d, v, folder = row
        if not all(isinstance(x, str) for x in (g, n, t, d, folder)):
            return None
        if not (v is None or isinstance(v, str)) or g not in order or folder not in folders:
            return None
        dist_part, version_part = _folder_name(folder)
        if _normalized(dist_part) != _normalized(d):
            return None
        if folder.endswith(".dist-info") and version_part and v != version_part:
            return None
        key = (g, n, t)
        if key in by_folder.setdefault(folder, set()):
            return None
        by_folder[folder].add(key)
        rows.append((g, n, t, d, v))
    for folder, cached in by_folder.items():
        if _declared(folder) != cached:
            return None
    own = {f for f in folders if _normalized(_folder_name(f)[0]) == "conformal_control"}
    if own and not own & set(by_folder):  # our own rows may not be dropped
        if any(_declared(folder) for folder in own):
            return None
    rows.sort(key=lambda r: (order[r[0]], r[3] != "conformal-control"))  # stable
    return rows


def _entry_point_rows(use_cache: bool = True) -> list[Row]:
    """``(group, name, target, distribution, version)`` of every entry point of our
    groups (:data:`ROLES`), our own distribution's first in each group; from the cache file
    when the installed distributions are those it was written for (:func:`_metadata_folders`)
    and every row is declared by one of them (:data:`ENTRY_POINT_CACHE`), else from a scan,
    which then rewrites the cache (best effort: a cache that cannot be read or written is
    ignored)."""
    import json

    path = None
    key = ""
    if use_cache:
        try:
            path = _cache_file()
            fingerprint, folders = _metadata_folders()
            key = "\n".join([*ROLES.values(), fingerprint])
            stored = json.loads(path.read_text())
            if stored.get("format") == _CACHE_FORMAT and stored.get("key") == key:
                checked = _checked_rows(stored.get("rows"), folders)
                if checked is not None:
                    return checked
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass
    scanned = _scan_entry_points()
    rows = [r[:5] for r in scanned]
    if path is not None and all(r[5] is not None for r in scanned):
        _write_cache(
            path, {"format": _CACHE_FORMAT, "key": key, "rows": [list(r) for r in scanned]}
        )
    return rows


def _write_cache(path: Path, content: dict[str, Any]) -> None:
    """Write the cache file ``0600`` (its folder ``0700`` when created here), whole then
    renamed: a reader never sees half a file. Best effort: an error leaves no file."""
    import json
    import os
    import secrets

    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        with os.fdopen(fd, "w") as fh:
            fh.write(json.dumps(content))
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)


def _cache_file() -> Path:
    """The cache file, in the package's cache folder (``$CONFORMAL_CONTROL_CACHE``, else
    ``~/.cache/conformal-control``, as :func:`conformal_control.predictors.cache.cache_dir`,
    a higher layer than this module)."""
    import os
    import sys
    import zlib

    root = os.environ.get("CONFORMAL_CONTROL_CACHE")
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "conformal-control"
    # one file per search path: a script's folder is the first entry of its sys.path, and
    # scripts run from several folders must not overwrite each other's file
    paths = zlib.crc32("\0".join(sys.path).encode())
    return base / f"{ENTRY_POINT_CACHE.removesuffix('.json')}-{paths:08x}.json"


def _scan_entry_points() -> list[tuple[str, str, str, str, str | None, str | None]]:
    """Every entry point of our groups, with the metadata folder of the distribution
    declaring it (None when the distribution is not a folder on disk: such a scan is not
    cached)."""
    import os
    from importlib.metadata import entry_points

    # one scan of the installed distributions for every group, and each distribution's
    # metadata parsed once (not once per entry point and role: a large environment has
    # hundreds of distributions)
    every = entry_points()
    origin: dict[int, tuple[str, str | None, str | None]] = {}

    def dist_of(ep: EntryPoint) -> tuple[str, str | None, str | None]:
        if ep.dist is None:
            return "unknown", None, None
        key = id(ep.dist)
        if key not in origin:
            meta = ep.dist.metadata
            # importlib.metadata has no public name for the metadata folder of a
            # distribution on disk (PathDistribution._path); without it, no cache
            folder = getattr(ep.dist, "_path", None)
            where = os.path.abspath(folder) if isinstance(folder, (str, os.PathLike)) else None
            origin[key] = (meta["Name"], meta["Version"], where)
        return origin[key]

    rows: list[tuple[str, str, str, str, str | None, str | None]] = []
    for group in ROLES.values():
        ep: EntryPoint
        # our own plugins first: a third party cannot take over a core name
        eps = sorted(every.select(group=group), key=lambda e: dist_of(e)[0] != "conformal-control")
        for ep in eps:
            dist, version, folder = dist_of(ep)
            rows.append((group, ep.name, ep.value, dist, version, folder))
    return rows


def refresh() -> None:
    """Forget every registration (runtime ones included) and re-read the entry points.

    For tests, and after installing a plugin package into a running interpreter.
    """
    global _discovered
    for role in ROLES:
        _registry.setdefault(role, {}).clear()
    _clashes.clear()
    _discovered = True
    importlib.invalidate_caches()
    _add_rows(_entry_point_rows(use_cache=False))


def register(
    role: str, name: str, target: str | type | None = None, *, overwrite: bool = False
) -> Any:
    """Register a plugin at runtime under ``role``/``name``.

    Three forms::

        @register("predictor", "mine")              # class decorator
        class Mine(Predictor): ...

        register("predictor", "mine", Mine)         # a class
        register("predictor", "mine", "pkg.mod:Mine")  # lazy: imported on first use

    A name that is taken by a different plugin raises ``ValueError`` unless
    ``overwrite=True``.

    Parameters
    ----------
    role : str
        One of :data:`ROLES`.
    name : str
        The name the plugin is asked for by.
    target : class or str, optional
        The class, or ``"package.module:Class"`` (imported on first use); None: used as a
        class decorator.
    overwrite : bool
        Replace a different plugin registered under the name.

    Returns
    -------
    class or str
        The class (decorator and class forms) or the target string.
    """
    role = _check_role(role)
    _discover()
    if target is not None and not isinstance(target, (str, type)):
        raise TypeError(f"target must be a class or a 'module:Class' string, got {target!r}")
    if isinstance(target, str) and ":" not in target:
        raise ValueError(f"a lazy target must look like 'package.module:Class', got {target!r}")

    def add(obj: str | type) -> str | type:
        current = _registry[role].get(name)
        if current is not None and not overwrite:
            if _target_text(current.target) != _target_text(obj):
                raise ValueError(
                    f"a {role} plugin named {name!r} is already registered ("
                    f"{_target_text(current.target)} from {current.origin}); pass "
                    "overwrite=True to replace it"
                )
        _registry[role][name] = PluginEntry(role, name, obj, "runtime")
        return obj

    if target is not None:
        return add(target)
    return add


def unregister(role: str, name: str) -> None:
    """Remove a plugin (mainly for tests)."""
    role = _check_role(role)
    _discover()
    _registry[role].pop(name, None)


def entries(role: str | None = None) -> list[PluginEntry]:
    """All registered plugins (of one role), sorted by role then name; unavailable included."""
    _discover()
    roles = [_check_role(role)] if role is not None else list(ROLES)
    out: list[PluginEntry] = []
    for r in roles:
        out.extend(_registry[r][n] for n in sorted(_registry[r]))
    return out


def clashes() -> list[Clash]:
    """Registrations ignored because their name was taken by a different plugin."""
    _discover()
    return list(_clashes)


def names(role: str) -> list[str]:
    """Names of the plugins of one role."""
    return [e.name for e in entries(role)]


def crowd_names() -> list[str]:
    """Every crowd a run can have: ``replay`` (the recording), each registered crowd model
    (``crowd`` role: every pedestrian simulated), ``mixed`` (replayed until the robot
    comes near, then simulated). The command line's choices come from here."""
    return ["replay", *names("crowd"), "mixed"]


def entry(role: str, name: str) -> PluginEntry:
    """The registry entry ``role``/``name`` (:class:`UnknownPluginError` if there is none)."""
    role = _check_role(role)
    _discover()
    try:
        return _registry[role][name]
    except KeyError:
        raise UnknownPluginError(role, name, sorted(_registry[role])) from None


def get(role: str, name: str) -> type[Any]:
    """The plugin class registered as ``role``/``name``.

    Raises
    ------
    UnknownPluginError
        No such name (a ``ValueError`` listing the known names and the closest matches).
    PluginUnavailableError
        Registered, but its module cannot be imported (missing optional dependency).
    """
    return entry(role, name).load()


class UnknownParameterError(ValueError):
    """A plugin was given a constructor argument it does not take (with did-you-mean)."""


def check_params(role: str, name: str, cls: type, params: dict[str, Any]) -> None:
    """Raise :class:`UnknownParameterError` for arguments ``cls`` does not take.

    Parameters
    ----------
    role, name : str
        The plugin's role and registered name (named in the message).
    cls : type
        Its class.
    params : dict
        The arguments to check against ``cls``'s constructor: its parameters by name,
        a :class:`~conformal_control.core.base.Settings` group's field as ``<group>__<field>``
        (the group's own fields are checked when it is built), or a former flat name
        the class still maps (``renamed_params``).
    """
    if not params:  # nothing to check (and a signature costs tens of microseconds)
        return
    role = _check_role(role)
    import inspect

    sig = inspect.signature(cls)
    renamed: dict[str, str] = getattr(cls, "renamed_params", {})
    if not renamed and any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values()):
        return
    known = [
        p.name for p in sig.parameters.values() if p.name != "self" and p.kind is not p.VAR_KEYWORD
    ]
    for key in params:
        group, sep, _ = renamed.get(key, key).partition("__")
        if not (key in known or (sep and group in known)):
            close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
            hint = f"; did you mean {close[0]!r}?" if close else ";"
            raise UnknownParameterError(
                f"{role} {name!r} has no parameter {key!r}{hint} "
                f"its parameters: {', '.join(known) or 'none'}"
            )


def create(role: str, name: str, **params: Any) -> Any:
    """Instantiate ``role``/``name`` with ``params``.

    Raises
    ------
    UnknownParameterError
        A parameter the plugin does not take (the message lists the valid ones and the
        closest match).
    """
    role = _check_role(role)
    cls = get(role, name)
    check_params(role, name, cls, params)
    try:
        return cls(**params)
    except TypeError as exc:
        raise ValueError(f"cannot create {role} {name!r} with {params}: {exc}") from exc
