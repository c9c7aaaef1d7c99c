"""Sweep specifications: a grid and/or a list of runs, expanded into runs (:class:`SweepRun`,
a :class:`~conformal_control.core.spec.RunSpec` on a named scene).

A specification is a mapping (from a YAML, JSON or TOML file, or built in Python) with up to
three sections::

    base:                      # every run starts from these values
      scene: nexus_4
      predictor: constant_velocity
      frames: 400
    grid:                      # Cartesian product of these lists ...
      epsilon: [-0.25, 0.0]
      eta: [0.1, 1]
      seed: [0, 1]
    runs:                      # ... crossed with this explicit list (default: one empty run)
      - {label: learn}
      - {label: noLearn, learn: false}

Every run is ``base`` updated by one entry of ``runs`` updated by one point of ``grid``.
A run has these keys (all optional except ``scene``):

``scene``, ``predictor`` (registered name, default ``constant_velocity``),
``predictor_params`` (dict; a key ``predictor_params.NAME`` in a grid sets one entry),
``learn`` (default true; false = the noLearn baseline), ``seed`` (default 0), ``frames``
(limit on simulated frames, default none), ``data_root``, ``label`` (free text), the
settings of the run specification in :data:`EPISODE_KEYS` (roles by name, ``family``
and ``family_params``, ``rule_params``, ``crowd``, ...; a key
``family_params.NAME``, ``rule_params.NAME``, ... sets one entry of that dict), and any
controller parameter of :data:`conformal_control.runs.params.PARAMETERS` (``epsilon``,
``eta``, ``tau``, ``a``, ...; in the scene's units), which go to ``params``.

The **key** of a run is a hash of its normalised settings (everything except ``label``,
``data_root`` and ``meta``, which name but do not change a run; :meth:`SweepRun.hashed`):
a sweep resumed with the same runs skips every key already finished.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import json
import math
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.exceptions import InputError
from ..core.spec import (
    LAMBDA_SAFE_AUTO,
    LAMBDA_SAFE_AUTO_SOURCE,
    OPTION_FIELDS,
    ROLE_FIELDS,
    RunSpec,
)

__all__ = [
    "MAX_RUNS",
    "RESERVED_KEYS",
    "RunConfig",
    "SweepRun",
    "SweepSpec",
    "invalid_runs_message",
    "load_spec",
    "parse_grid_option",
    "run_key",
    "settings_view",
]

#: Most runs one sweep may have (checked before the grid is expanded).
MAX_RUNS = 1_000_000

#: Keys of a run configuration that are not controller parameters.
RESERVED_KEYS = (
    "scene",
    "predictor",
    "predictor_params",
    "learn",
    "seed",
    "frames",
    "data_root",
    "label",
    "meta",
)
#: Keys of the run specification (:class:`~conformal_control.core.spec.RunSpec`) a run
#: configuration holds as they are, under ``episode`` (roles by name and their parameters,
#: the rule, the unit system, the crowd, the family, lambda_safe, the engine); they enter
#: the run key. Derived from the specification's fields: the predictor, ``learn``,
#: ``seed`` and ``frames`` (``max_frames``) are reserved keys of their own.
EPISODE_KEYS: tuple[str, ...] = (
    *(o for o in OPTION_FIELDS if o not in ("learn", "seed", "max_frames")),
    *(r for r in ROLE_FIELDS if r != "predictor"),
    *(f"{r}_params" for r in ROLE_FIELDS if r != "predictor"),
)
#: The fields of 0.3's flat run configuration (:func:`settings_view`).
_FLAT_FIELDS = (
    "scene",
    "predictor",
    "predictor_params",
    "learn",
    "seed",
    "frames",
    "params",
    "data_root",
    "label",
    "episode",
    "meta",
)
#: Keys that do not enter the run key.
UNHASHED_KEYS = ("label", "data_root", "meta")
_PP = "predictor_params."
#: Episode keys holding a dict of a role's parameters: ``family_params.NAME`` (a dotted
#: key, e.g. a grid axis) sets one entry, as ``predictor_params.NAME`` does.
_NESTED = tuple(k for k in EPISODE_KEYS if k.endswith("_params"))


def _canonical(value: Any) -> Any:
    """Numbers that are whole become ints so 4 and 4.0 give the same key."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        if math.isfinite(value) and value.is_integer():
            return int(value)
        return value if math.isfinite(value) else repr(value)
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if hasattr(value, "item"):  # numpy scalar
        return _canonical(value.item())
    raise TypeError(f"cannot use {value!r} ({type(value).__name__}) in a run configuration")


@functools.lru_cache(maxsize=1)
def _default_spec() -> dict[str, Any]:
    """``RunSpec().as_dict()``: the settings a run leaves at their default."""
    return RunSpec().as_dict()


def _role_entry(role: str, value: Any) -> tuple[Any, dict[str, Any]]:
    """A role of :meth:`RunSpec.as_dict` as ``(name, params)``."""
    if isinstance(value, dict):
        if "instance" in value:
            raise TypeError(
                f"cannot use an instance of {value['instance']} as the {role} of a sweep's run "
                "(it has no key); give it by registered name"
            )
        return value.get("name"), dict(value.get("params") or {})
    return value, {}


def settings_view(run: Mapping[str, Any]) -> dict[str, Any]:
    """A stored run (:meth:`SweepRun.as_dict`) in the flat form of 0.3's run
    configurations: ``scene``, ``predictor``, ``predictor_params``, ``learn``, ``seed``,
    ``frames``, ``params``, ``data_root``, ``label``, ``episode``, ``meta``; the run key
    and the results table are computed from it. ``episode`` holds the settings of
    :data:`EPISODE_KEYS` the run changes from their default, and those it names in
    ``given`` even at their default (0.3 kept every setting a sweep wrote). A record
    written by 0.3 (no ``spec``) is already in this form and is returned as it is.

    Parameters
    ----------
    run : mapping
        :meth:`SweepRun.as_dict`, or a 0.3 record's ``config``.
    """
    spec = run.get("spec")
    if not isinstance(spec, Mapping):
        return dict(run)
    default = _default_spec()
    given = set(run.get("given") or ())
    predictor, predictor_params = _role_entry("predictor", spec.get("predictor"))
    episode: dict[str, Any] = {}
    for role in ROLE_FIELDS:
        if role == "predictor":
            continue
        name, params = _role_entry(role, spec.get(role))
        if role in given or name != default[role]:
            episode[role] = name
        if f"{role}_params" in given or params:
            episode[f"{role}_params"] = params
    for option in OPTION_FIELDS:
        if option in ("learn", "seed", "max_frames"):
            continue
        value, unset = spec.get(option), default[option]
        if option == "lambda_safe_source" and spec.get("lambda_safe") == LAMBDA_SAFE_AUTO:
            unset = LAMBDA_SAFE_AUTO_SOURCE  # filled in by the spec itself
        if option in given or value != unset:
            episode[option] = value
    if spec.get("robots") is not None:
        episode["robots"] = spec["robots"]
    return {
        "scene": run.get("scene"),
        "predictor": predictor,
        "predictor_params": predictor_params,
        "learn": spec.get("learn", True),
        "seed": spec.get("seed", 0),
        "frames": spec.get("max_frames"),
        "params": dict(spec.get("params") or {}),
        "data_root": run.get("data_root"),
        "label": run.get("label", ""),
        "episode": episode,
        "meta": dict(run.get("meta") or {}),
    }


@dataclass(frozen=True)
class SweepRun:
    """One run of a sweep: a :class:`~conformal_control.core.spec.RunSpec` on a named
    scene, and the names the sweep gives it.

    The run specification is the one class every entry point builds
    (:func:`conformal_control.run`, the benchmark, the paper's tables); a sweep adds only
    where the run happens and what it is called. The run's **key** is a hash of the scene
    and the specification in 0.3's flat form (:func:`settings_view`): the same content
    0.3's ``RunConfig`` hashed, so a results folder written by 0.3 resumes without a run
    done again.

    Parameters
    ----------
    scene : str
        The scene's name (:func:`conformal_control.data.load_scene`).
    spec : RunSpec
        The run; parameters in its ``units``. ``max_frames`` None: the scene's own limit
        (a benchmark scenario's), else the whole recording.
    data_root : str, optional
        The data folder (names the data, does not change the run: not in the key).
    label : str
        Free text naming the run (not in the key).
    meta : dict
        Free description copied into the results table (not part of the key), e.g. the
        benchmark's method, scenario, split.
    given : tuple of str
        Settings of :data:`EPISODE_KEYS` the sweep wrote out: they stay in the key and the
        table at their default too, as 0.3's run configurations kept them.
    """

    scene: str
    spec: RunSpec = field(default_factory=RunSpec)
    data_root: str | None = None
    label: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    given: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.spec, RunSpec):
            raise TypeError(f"spec must be a RunSpec, got {type(self.spec).__name__}")
        object.__setattr__(self, "given", tuple(self.given))

    @classmethod
    def from_settings(
        cls,
        scene: str,
        params: Mapping[str, Any] | None = None,
        *,
        data_root: str | None = None,
        label: str = "",
        meta: Mapping[str, Any] | None = None,
        **settings: Any,
    ) -> SweepRun:
        """The run of keyword settings, as :meth:`RunSpec.from_settings` takes them
        (``predictor=``, ``predictor_params=``, ``learn=``, ``seed=``, ``max_frames=``,
        the settings of :data:`EPISODE_KEYS`); those of :data:`EPISODE_KEYS` given are
        the run's ``given``.

        Parameters
        ----------
        scene : str
            The scene's name.
        params : mapping, optional
            Controller parameters (in ``units``, default the scene's).
        data_root, label, meta :
            As the attributes of the same names.
        **settings :
            Settings of the run specification.
        """
        spec = RunSpec.from_settings(dict(params or {}), **settings)
        given = tuple(k for k in settings if k in EPISODE_KEYS)
        return cls(str(scene), spec, data_root, str(label), dict(meta or {}), given)

    def hashed(self) -> dict[str, Any]:
        """The part of the run the key is computed from (canonical form)."""
        d = settings_view(self.as_dict())
        for k in UNHASHED_KEYS:
            d.pop(k, None)
        canonical: dict[str, Any] = _canonical(d)
        return canonical

    @property
    def key(self) -> str:
        """The run's key (:func:`run_key` of :meth:`hashed`)."""
        return run_key(self.hashed())

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: the scene, the names, and the specification as
        :meth:`RunSpec.as_dict` writes it (the journal's ``config``)."""
        return {
            "scene": self.scene,
            "data_root": self.data_root,
            "label": self.label,
            "meta": dict(self.meta),
            "given": list(self.given),
            "spec": self.spec.as_dict(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SweepRun:
        """The run stored as :meth:`as_dict` wrote it (the journal's ``config``, a run
        directory's ``sweep.run``), or as 0.3 wrote it (its flat form).

        Parameters
        ----------
        data : mapping
            The stored run.

        Raises
        ------
        InputError
            For a stored specification that does not read back
            (:meth:`RunSpec.from_dict`).
        """
        if isinstance(data.get("spec"), Mapping):
            return cls(
                str(data["scene"]),
                RunSpec.from_dict(dict(data["spec"]), where="stored run"),
                data.get("data_root"),
                str(data.get("label") or ""),
                dict(data.get("meta") or {}),
                tuple(data.get("given") or ()),
            )
        return _from_flat_fields(**{k: v for k, v in data.items() if k in _FLAT_FIELDS})

    def spec_on(self, max_frames: int | None) -> RunSpec:
        """The specification to run: with ``max_frames`` (the scene's limit, e.g. a
        benchmark scenario's) when the run sets none.

        Parameters
        ----------
        max_frames : int or None
            The scene's limit on simulated frames.
        """
        if self.spec.max_frames is not None or not max_frames:
            return self.spec
        return dataclasses.replace(self.spec, max_frames=max_frames)

    @classmethod
    def from_flat(cls, flat: Mapping[str, Any]) -> SweepRun:
        """Build from a flat mapping (reserved keys, settings and controller parameters),
        as a sweep's ``base``, ``runs`` and ``grid`` give them.

        Parameters
        ----------
        flat : mapping
            One run of a sweep specification.

        Raises
        ------
        ValueError
            For a missing scene, an unknown key or a badly typed value.
        TypeError
            For a setting that is no setting of a run.
        """
        from ..core.spec import PARAMETERS

        flat = dict(flat)
        pp = dict(flat.pop("predictor_params", None) or {})
        params = dict(flat.pop("params", None) or {})
        for k in [k for k in flat if k.startswith(_PP)]:
            pp[k[len(_PP) :]] = flat.pop(k)
        nested: dict[str, dict[str, Any]] = {}
        for k in [k for k in flat if k.split(".", 1)[0] in _NESTED and "." in k]:
            head, name = k.split(".", 1)
            nested.setdefault(head, {})[name] = flat.pop(k)
        reserved = {k: flat.pop(k) for k in RESERVED_KEYS if k in flat}
        episode = dict(flat.pop("episode", None) or {})
        episode.update({k: flat.pop(k) for k in EPISODE_KEYS if k in flat})
        for head, entries in nested.items():
            given = episode.get(head)
            if given is not None and not isinstance(given, Mapping):
                raise ValueError(f"'{head}' must be a mapping, got {given!r}")
            episode[head] = {**(given or {}), **entries}
        unknown = sorted(k for k in flat if k not in PARAMETERS)
        if unknown:
            raise ValueError(
                f"unknown sweep key(s) {', '.join(unknown)}; use {', '.join(RESERVED_KEYS)}, "
                f"'predictor_params.NAME', {', '.join(EPISODE_KEYS)} ('family_params.NAME' "
                f"and the like set one entry) or a controller parameter ({', '.join(PARAMETERS)})"
            )
        params.update(flat)
        if not reserved.get("scene"):
            raise ValueError("every run needs a 'scene'")
        learn = reserved.get("learn", True)
        if not isinstance(learn, bool):
            raise ValueError(f"'learn' must be true or false, got {learn!r}")
        seed = reserved.get("seed", 0)
        if isinstance(seed, float) and seed.is_integer():
            seed = int(seed)
        if not isinstance(seed, int) or isinstance(seed, bool):
            raise ValueError(f"'seed' must be an integer, got {seed!r}")
        frames = reserved.get("frames")
        if frames is not None and (not isinstance(frames, int) or frames < 1):
            raise ValueError(f"'frames' must be a positive integer or null, got {frames!r}")
        data_root = reserved.get("data_root")
        return cls.from_settings(
            str(reserved["scene"]),
            params,
            data_root=None if data_root is None else str(data_root),
            label=str(reserved.get("label") or ""),
            meta=dict(reserved.get("meta") or {}),
            predictor=str(reserved.get("predictor") or "constant_velocity"),
            predictor_params=pp,
            learn=learn,
            seed=seed,
            max_frames=frames,
            **episode,
        )


def _from_flat_fields(
    scene: str,
    predictor: str = "constant_velocity",
    predictor_params: Mapping[str, Any] | None = None,
    learn: bool = True,
    seed: int = 0,
    frames: int | None = None,
    params: Mapping[str, Any] | None = None,
    data_root: str | None = None,
    label: str = "",
    episode: Mapping[str, Any] | None = None,
    meta: Mapping[str, Any] | None = None,
) -> SweepRun:
    """The :class:`SweepRun` of 0.3's flat run configuration (same key)."""
    return SweepRun.from_settings(
        scene,
        params,
        data_root=data_root,
        label=label,
        meta=meta,
        predictor=predictor,
        predictor_params=dict(predictor_params or {}),
        learn=learn,
        seed=seed,
        max_frames=frames,
        **dict(episode or {}),
    )


def RunConfig(*args: Any, **kwargs: Any) -> SweepRun:  # 0.3 named a class so
    """Deprecated: 0.3's run configuration, now a :class:`SweepRun` (removed in 0.4, not
    before 2027-06-30). Takes 0.3's arguments (``scene``, ``predictor``,
    ``predictor_params``, ``learn``, ``seed``, ``frames``, ``params``, ``data_root``,
    ``label``, ``episode``, ``meta``) and gives the :class:`SweepRun` of the same key.

    Parameters
    ----------
    *args, **kwargs :
        0.3's arguments.
    """
    import warnings

    from ..core.exceptions import ConformalControlDeprecationWarning

    warnings.warn(
        "RunConfig is now SweepRun (a RunSpec on a named scene): build it with "
        "SweepRun.from_settings(scene, params, predictor=..., max_frames=..., ...) "
        "(RunConfig is removed in 0.4, not before 2027-06-30)",
        ConformalControlDeprecationWarning,
        stacklevel=2,
    )
    return _from_flat_fields(*args, **kwargs)


def invalid_runs_message(errors: Mapping[str, int], total: int) -> str:
    """One sentence: how many of ``total`` runs are invalid, and each distinct reason."""
    n_bad = sum(errors.values())
    parts = []
    for msg, count in errors.items():
        text = " ".join(msg.split()).rstrip(".")
        parts.append(text if total == 1 else f"{text} ({count} run{'s' if count != 1 else ''})")
    return (
        f"{n_bad} of {total} run{'s' if total != 1 else ''} of the sweep "
        f"{'is' if n_bad == 1 else 'are'} invalid, so none was started: " + "; ".join(parts)
    )


def run_key(hashed: Mapping[str, Any]) -> str:
    """Short SHA-256 of the canonical JSON of a configuration (16 hex digits)."""
    text = json.dumps(_canonical(dict(hashed)), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class SweepSpec:
    """A sweep: ``base`` x ``runs`` x product(``grid``).

    Parameters
    ----------
    base : dict
        Values shared by every run.
    grid : dict of lists
        Axes of the Cartesian product (a scalar counts as a one-value list).
    runs : list of dict
        Explicit runs (crossed with the grid); empty means one run.
    """

    base: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list[Any]] = field(default_factory=dict)
    runs: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> SweepSpec:
        unknown = sorted(set(data) - {"base", "grid", "runs"})
        if unknown:
            raise ValueError(
                f"unknown section(s) {', '.join(unknown)} in the sweep spec; "
                "use base, grid and runs"
            )
        for section in ("base", "grid"):
            if data.get(section) is not None and not isinstance(data[section], Mapping):
                raise InputError(
                    f"'{section}' of the sweep spec must be a mapping of names to values, got "
                    f"a {type(data[section]).__name__}"
                )
        base = dict(data.get("base") or {})
        grid_in = dict(data.get("grid") or {})
        grid = {k: list(v) if isinstance(v, (list, tuple)) else [v] for k, v in grid_in.items()}
        for k, v in grid.items():
            if not v:
                raise ValueError(f"grid axis {k!r} has no values")
        runs = list(data.get("runs") or [])
        if not all(isinstance(r, Mapping) for r in runs):
            raise ValueError("'runs' must be a list of mappings")
        return cls(base, grid, [dict(r) for r in runs])

    def size(self) -> int:
        """Number of runs before duplicates are merged: ``len(runs) x product of axes``."""
        return max(len(self.runs), 1) * math.prod(len(v) for v in self.grid.values())

    def expand(self) -> list[SweepRun]:
        """All runs, in order, without duplicates (same key kept once).

        Raises
        ------
        ValueError
            If the sweep has more than :data:`MAX_RUNS` runs (checked before anything is
            built), or a run is invalid.
        """
        n_runs = self.size()
        if n_runs > MAX_RUNS:
            shape = " x ".join(
                [
                    *([f"{len(self.runs)} runs"] if self.runs else []),
                    *(f"{len(v)} {k}" for k, v in self.grid.items()),
                ]
            )
            raise InputError(
                f"the sweep has {n_runs:,} runs ({shape}), more than the {MAX_RUNS:,} one "
                "sweep may hold; split it into several sweeps or use coarser grids"
            )
        axes = list(self.grid)
        out: list[SweepRun] = []
        seen: set[str] = set()
        errors: dict[str, int] = {}
        n = 0
        for run in self.runs or [{}]:
            for point in itertools.product(*(self.grid[a] for a in axes)):
                n += 1
                flat = {**self.base, **run, **dict(zip(axes, point, strict=True))}
                try:
                    cfg = SweepRun.from_flat(flat)
                    key = cfg.key
                except (ValueError, TypeError) as exc:
                    msg = str(exc)
                    errors[msg] = errors.get(msg, 0) + 1
                    continue
                if key not in seen:
                    seen.add(key)
                    out.append(cfg)
        if errors:
            raise ValueError(invalid_runs_message(errors, n))
        return out

    def merged(self, other: SweepSpec) -> SweepSpec:
        """This spec with ``other``'s base and grid entries on top and its runs appended."""
        return SweepSpec(
            {**self.base, **other.base}, {**self.grid, **other.grid}, [*self.runs, *other.runs]
        )


def load_spec(path: str | Path) -> SweepSpec:
    """Read a sweep specification from ``.yaml``/``.yml``, ``.json`` or ``.toml``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"sweep spec {path} not found")
    suffix = path.suffix.lower()
    if suffix not in (".yaml", ".yml", ".json", ".toml"):
        raise ValueError(f"sweep spec {path}: use a .yaml, .yml, .json or .toml file")
    text = path.read_text()
    try:
        if suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        elif suffix == ".json":
            data = json.loads(text)
        else:
            if sys.version_info >= (3, 11):
                import tomllib
            else:  # Python 3.10
                import tomli as tomllib
            data = tomllib.loads(text)
    except RecursionError:
        raise InputError(f"sweep spec {path}: nested too deeply to be a sweep spec") from None
    except ValueError as exc:  # JSONDecodeError, TOMLDecodeError
        raise InputError(f"sweep spec {path}: not valid {suffix[1:].upper()} ({exc})") from None
    except Exception as exc:  # yaml.YAMLError (yaml is imported only for YAML files)
        if type(exc).__module__.startswith("yaml"):
            raise InputError(f"sweep spec {path}: not valid YAML ({exc})") from None
        raise
    if not isinstance(data, Mapping):
        raise ValueError(f"sweep spec {path}: expected a mapping with base/grid/runs")
    return SweepSpec.from_mapping(data)


def parse_grid_option(items: Iterable[str] | None) -> dict[str, list[Any]]:
    """Parse repeated ``--grid KEY=V1,V2,...`` options (values typed like ``--param``)."""
    from ..runs.params import parse_value

    grid: dict[str, list[Any]] = {}
    for item in items or []:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise ValueError(f"--grid expects KEY=V1,V2,..., got {item!r}")
        grid[key] = [parse_value(v) for v in values.split(",")]
    return grid
