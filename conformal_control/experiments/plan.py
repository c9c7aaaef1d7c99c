"""Sweep specifications: a grid and/or a list of runs, expanded into run configurations.

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
A run configuration has these keys (all optional except ``scene``):

``scene``, ``predictor`` (registered name, default ``constant_velocity``),
``predictor_params`` (dict; a key ``predictor_params.NAME`` in a grid sets one entry),
``learn`` (default true; false = the noLearn baseline), ``seed`` (default 0), ``frames``
(limit on simulated frames, default none), ``data_root``, ``label`` (free text), the
settings of the run specification in :data:`EPISODE_KEYS` (roles by name, ``family``
and ``family_params``, ``rule_params``, ``crowd``, ...; a key
``family_params.NAME``, ``rule_params.NAME``, ... sets one entry of that dict), and any
controller parameter of :data:`conformal_control.runs.params.PARAMETERS` (``epsilon``,
``eta``, ``tau``, ``a``, ...; in the scene's units), which go to ``params``.

The **key** of a run is a hash of its normalised configuration (everything except
``label`` and ``data_root``, which name but do not change a run): a sweep resumed with
the same runs skips every key already finished.
"""

from __future__ import annotations

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
from ..core.spec import OPTION_FIELDS, ROLE_FIELDS, RunSpec

__all__ = [
    "MAX_RUNS",
    "RESERVED_KEYS",
    "RunConfig",
    "SweepSpec",
    "invalid_runs_message",
    "load_spec",
    "parse_grid_option",
    "run_key",
    "run_spec",
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


@dataclass(frozen=True)
class RunConfig:
    """One fully specified run of a sweep.

    Attributes
    ----------
    scene : str
    predictor : str
    predictor_params : dict
    learn : bool
    seed : int
    frames : int or None
    params : dict
        Controller parameters in the scene's units.
    data_root : str or None
    label : str
    episode : dict
        Other arguments of :func:`~conformal_control.runs.episode.run_episode`
        (:data:`EPISODE_KEYS`).
    meta : dict
        Free description copied into the results table (not part of the key), e.g. the
        benchmark's method, scenario, split.
    """

    scene: str
    predictor: str = "constant_velocity"
    predictor_params: dict[str, Any] = field(default_factory=dict)
    learn: bool = True
    seed: int = 0
    frames: int | None = None
    params: dict[str, Any] = field(default_factory=dict)
    data_root: str | None = None
    label: str = ""
    episode: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def hashed(self) -> dict[str, Any]:
        """The part of the configuration the key is computed from (canonical form)."""
        d = self.as_dict()
        for k in UNHASHED_KEYS:
            d.pop(k, None)
        canonical: dict[str, Any] = _canonical(d)
        return canonical

    @property
    def key(self) -> str:
        return run_key(self.hashed())

    def as_dict(self) -> dict[str, Any]:
        return {
            "scene": self.scene,
            "predictor": self.predictor,
            "predictor_params": dict(self.predictor_params),
            "learn": self.learn,
            "seed": self.seed,
            "frames": self.frames,
            "params": dict(self.params),
            "data_root": self.data_root,
            "label": self.label,
            "episode": dict(self.episode),
            "meta": dict(self.meta),
        }

    @classmethod
    def from_flat(cls, flat: Mapping[str, Any]) -> RunConfig:
        """Build from a flat mapping (reserved keys + controller parameters).

        Raises
        ------
        ValueError
            For a missing scene, an unknown key or a badly typed reserved value.
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
        return cls(
            scene=str(reserved["scene"]),
            predictor=str(reserved.get("predictor") or "constant_velocity"),
            predictor_params=pp,
            learn=learn,
            seed=seed,
            frames=frames,
            params=params,
            data_root=None if data_root is None else str(data_root),
            label=str(reserved.get("label") or ""),
            episode=episode,
            meta=dict(reserved.get("meta") or {}),
        )


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


def run_spec(cfg: Mapping[str, Any], max_frames: int | None = None) -> RunSpec:
    """The :class:`~conformal_control.core.spec.RunSpec` of a run configuration
    (:meth:`RunConfig.as_dict`); ``max_frames`` is the limit when the configuration sets
    none (a benchmark scenario's time limit)."""
    return RunSpec.from_settings(
        dict(cfg.get("params") or {}),
        predictor=cfg.get("predictor") or "constant_velocity",
        predictor_params=dict(cfg.get("predictor_params") or {}),
        learn=bool(cfg.get("learn", True)),
        seed=int(cfg.get("seed", 0)),
        max_frames=cfg.get("frames") or max_frames,
        **dict(cfg.get("episode") or {}),
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

    def expand(self) -> list[RunConfig]:
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
        out: list[RunConfig] = []
        seen: set[str] = set()
        errors: dict[str, int] = {}
        n = 0
        for run in self.runs or [{}]:
            for point in itertools.product(*(self.grid[a] for a in axes)):
                n += 1
                flat = {**self.base, **run, **dict(zip(axes, point, strict=True))}
                try:
                    cfg = RunConfig.from_flat(flat)
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
