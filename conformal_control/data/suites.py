"""Scenario suites: versioned lists of crossing scenarios on real crowds, and their loader.

A *scenario* is one episode to run: a recording (an SDD video in raw or TrajNet form, or
an ETH/UCY recording), the frame the robot starts at, its start and goal (metres, and
image fractions where the recording has an image), and a time limit (mapped to the
episode's ``max_frames``). A *suite* is a manifest of scenarios shipped with the package
(``conformal_control/data/suite_manifests/<suite>.json``) together with the parameters of the
generator that produced it (:mod:`conformal_control.experiments.bench.generator`), what the
generator
measured for every scenario (crossing pedestrians, density, the ``nolearn`` baseline's
outcome) and a ``dev`` / ``test`` split by recording.

Usage::

    from conformal_control.experiments.bench import load_suite, load_scenario
    from conformal_control.runs.episode import run_episode

    suite = load_suite("crossings-v1")
    sc = suite.scenarios_for("dev")[0]
    scene = load_scenario(sc, data_root)
    result = run_episode(scene, "constant_velocity", learn=False, max_frames=sc.max_frames)
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from .scene import Scene
from .scenes import load_scene

__all__ = [
    "SCHEMA",
    "SCHEMA_VERSION",
    "SPLITS",
    "Scenario",
    "Suite",
    "dump_manifest",
    "load_scenario",
    "load_suite",
    "shipped_scenario",
    "suite_names",
    "validate_manifest",
]

SCHEMA = "conformal-control/bench-suite"
SCHEMA_VERSION = 1
SPLITS = ("dev", "test")
SOURCES = ("sdd", "trajnet", "ethucy")
#: Seconds of data kept after the time limit when a scenario's scene is built (the last
#: interval's truth and an oracle's look-ahead need a few frames past the end).
TAIL_S = 4.0

_SCENARIO_KEYS: dict[str, type | tuple[type, ...]] = {
    "id": str,
    "recording": str,
    "source": str,
    "scene": str,
    "split": str,
    "window": int,
    "start_frame": int,
    "fps": (int, float),
    "start_m": list,
    "goal_m": list,
    "start_fraction": (list, type(None)),
    "goal_fraction": (list, type(None)),
    "length_m": (int, float),
    "v_ref": (int, float),
    "time_limit_s": (int, float),
    "max_frames": int,
    "history_frames": int,
    "stats": dict,
    "nolearn": (dict, type(None)),
}


@dataclass(frozen=True)
class Scenario:
    """One crossing episode of a suite (see the module docstring).

    Attributes
    ----------
    id : str
        Unique within the suite (``<recording slug>-w<window index>``).
    recording : str
        The recording's id (``sdd:<scene>/video<N>``, ``...:trajnet``, ``ethucy:<name>``).
    source : {"sdd", "trajnet", "ethucy"}
    scene : str
        Name for :func:`conformal_control.data.load_scene`.
    split : {"dev", "test"}
    window : int
        Index of the generator's time window in the recording.
    start_frame : int
        Frame (at ``fps``) the robot starts at.
    fps : float
        Frame rate of the replayed data (30 for every source).
    start_m, goal_m : tuple of float
        Start and goal in metres (the scene's coordinates).
    start_fraction, goal_fraction : tuple of float or None
        The same as fractions of the reference image's width and height (SDD, TrajNet).
    length_m : float
        Straight-line start-goal distance.
    v_ref : float
        Reference (nominal) robot speed, m/s: the scene's speed bound.
    time_limit_s : float
        Time limit (a multiple of ``length_m / v_ref``).
    max_frames : int
        The time limit in frames: pass it to ``run_episode(..., max_frames=)``.
    history_frames : int
        Frames of data kept before the start.
    stats : dict
        What the generator measured (see :mod:`conformal_control.experiments.bench.generator`).
    nolearn : dict or None
        Outcome of the suite's ``nolearn`` baseline run (see the manifest's ``nolearn``).
    """

    id: str
    recording: str
    source: str
    scene: str
    split: str
    window: int
    start_frame: int
    fps: float
    start_m: tuple[float, float]
    goal_m: tuple[float, float]
    start_fraction: tuple[float, float] | None
    goal_fraction: tuple[float, float] | None
    length_m: float
    v_ref: float
    time_limit_s: float
    max_frames: int
    history_frames: int
    stats: dict[str, Any] = field(default_factory=dict)
    nolearn: dict[str, Any] | None = None

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scenario:
        def pair(v: Any) -> tuple[float, float] | None:
            return None if v is None else (float(v[0]), float(v[1]))

        return cls(
            id=d["id"],
            recording=d["recording"],
            source=d["source"],
            scene=d["scene"],
            split=d["split"],
            window=int(d["window"]),
            start_frame=int(d["start_frame"]),
            fps=float(d["fps"]),
            start_m=pair(d["start_m"]),  # type: ignore[arg-type]
            goal_m=pair(d["goal_m"]),  # type: ignore[arg-type]
            start_fraction=pair(d.get("start_fraction")),
            goal_fraction=pair(d.get("goal_fraction")),
            length_m=float(d["length_m"]),
            v_ref=float(d["v_ref"]),
            time_limit_s=float(d["time_limit_s"]),
            max_frames=int(d["max_frames"]),
            history_frames=int(d["history_frames"]),
            stats=dict(d.get("stats") or {}),
            nolearn=None if d.get("nolearn") is None else dict(d["nolearn"]),
        )

    @property
    def collided_nolearn(self) -> bool | None:
        """Whether the suite's nolearn baseline collided (None if not measured)."""
        return None if self.nolearn is None else bool(self.nolearn.get("n_collide", 0) > 0)


@dataclass
class Suite:
    """A loaded manifest: its header (generator parameters, split rule, recordings) and
    its scenarios."""

    name: str
    manifest: dict[str, Any]
    scenarios: list[Scenario]

    def scenarios_for(self, split: str | None = None) -> list[Scenario]:
        """The scenarios of one split (``None``: all), in manifest order."""
        if split is not None and split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        return [s for s in self.scenarios if split is None or s.split == split]

    def scenario(self, scenario_id: str) -> Scenario:
        """The scenario with this id (a clear error naming close ids otherwise)."""
        for s in self.scenarios:
            if s.id == scenario_id:
                return s
        raise ValueError(f"suite {self.name} has no scenario {scenario_id!r}")

    @property
    def recordings(self) -> list[dict[str, Any]]:
        return list(self.manifest["recordings"])

    def table(self, split: str | None = None) -> list[dict[str, Any]]:
        """One row per scenario of ``split`` (``None``: all), as ``bench scenarios`` lists
        them: ``id``, ``split``, ``scene``, ``start_frame``, ``max_frames``, ``n_crossing``,
        ``density`` (the corridor's), ``nolearn_collide`` (None if not measured).

        Parameters
        ----------
        split : {"dev", "test"}, optional
            The split.
        """
        return [
            {
                "id": s.id,
                "split": s.split,
                "scene": s.scene,
                "start_frame": s.start_frame,
                "max_frames": s.max_frames,
                "n_crossing": s.stats.get("n_crossing"),
                "density": s.stats.get("corridor_density"),
                "nolearn_collide": None if s.nolearn is None else s.nolearn["n_collide"],
            }
            for s in self.scenarios_for(split)
        ]

    def summary(self, split: str | None = None) -> list[dict[str, Any]]:
        """Counts per (source, split): scenarios and scenarios where nolearn collided.

        Parameters
        ----------
        split : {"dev", "test"}, optional
            Only this split (``None``: both).
        """
        rows: dict[tuple[str, str], dict[str, Any]] = {}
        for s in self.scenarios_for(split):
            row = rows.setdefault(
                (s.source, s.split),
                {"source": s.source, "split": s.split, "scenarios": 0, "nolearn_collision": 0},
            )
            row["scenarios"] += 1
            row["nolearn_collision"] += int(bool(s.collided_nolearn))
        return [rows[k] for k in sorted(rows)]


def _manifest_dir() -> Path:
    return Path(str(resources.files("conformal_control.data") / "suite_manifests"))


def suite_names() -> list[str]:
    """Names of the suites shipped with the package (``<name>-v<version>``)."""
    return sorted(p.stem for p in _manifest_dir().glob("*.json"))


def validate_manifest(manifest: Any, where: str = "manifest") -> None:
    """Raise ``ValueError`` naming the first problem if ``manifest`` is not a valid suite."""
    if not isinstance(manifest, dict):
        raise ValueError(f"{where}: expected a JSON object")
    if manifest.get("schema") != SCHEMA or manifest.get("schema_version") != SCHEMA_VERSION:
        raise ValueError(
            f"{where}: expected schema {SCHEMA!r} version {SCHEMA_VERSION}, got "
            f"{manifest.get('schema')!r} version {manifest.get('schema_version')!r}"
        )
    for key in ("suite", "version", "generator", "nolearn", "split_rule", "recordings"):
        if key not in manifest:
            raise ValueError(f"{where}: missing key {key!r}")
    recs = {r.get("id"): r for r in manifest["recordings"]}
    scenarios = manifest.get("scenarios")
    if not isinstance(scenarios, list):
        raise ValueError(f"{where}: 'scenarios' must be a list")
    seen: set[str] = set()
    for i, sc in enumerate(scenarios):
        label = f"{where}: scenario #{i} ({sc.get('id', '?') if isinstance(sc, dict) else '?'})"
        if not isinstance(sc, dict):
            raise ValueError(f"{label}: expected an object")
        for key, typ in _SCENARIO_KEYS.items():
            if key not in sc:
                raise ValueError(f"{label}: missing key {key!r}")
            if not isinstance(sc[key], typ) or isinstance(sc[key], bool):
                raise ValueError(f"{label}: {key} has type {type(sc[key]).__name__}")
        if sc["id"] in seen:
            raise ValueError(f"{label}: duplicate id")
        seen.add(sc["id"])
        if sc["split"] not in SPLITS:
            raise ValueError(f"{label}: split must be one of {SPLITS}")
        if sc["source"] not in SOURCES:
            raise ValueError(f"{label}: source must be one of {SOURCES}")
        if sc["recording"] not in recs:
            raise ValueError(f"{label}: recording {sc['recording']!r} is not listed")
        if recs[sc["recording"]].get("split") != sc["split"]:
            raise ValueError(f"{label}: split differs from its recording's split")
        if sc["max_frames"] < 1 or sc["time_limit_s"] <= 0:
            raise ValueError(f"{label}: the time limit must be positive")


def load_suite(name: str, path: str | os.PathLike[str] | None = None) -> Suite:
    """Load a shipped suite by name (``crossings-v1``) or a manifest file (``path``)."""
    if path is None:
        known = suite_names()
        if name not in known:
            raise ValueError(f"unknown suite {name!r}; shipped suites: {', '.join(known)}")
        path = _manifest_dir() / f"{name}.json"
    path = Path(path)
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    validate_manifest(manifest, str(path))
    return Suite(
        name=f"{manifest['suite']}-v{manifest['version']}",
        manifest=manifest,
        scenarios=[Scenario.from_dict(d) for d in manifest["scenarios"]],
    )


#: (manifest path, size, mtime) -> {scenario id: Scenario} of the last shipped suite read
_SCENARIOS: dict[tuple[str, int, int], dict[str, Scenario]] = {}


def shipped_scenario(suite: str, scenario_id: str) -> Scenario:
    """One scenario of a shipped suite, read once per process (``scenario:<suite>/<id>``
    scene names come here: a benchmark loads one scene per scenario and method, and
    parsing and checking the manifest each time took longer than building the scene).

    The index is rebuilt when the manifest file changes (size or modification time).
    :class:`Scenario` is frozen, so the shared instances cannot be changed by a caller.
    """
    known = suite_names()
    if suite not in known:
        raise ValueError(f"unknown suite {suite!r}; shipped suites: {', '.join(known)}")
    path = _manifest_dir() / f"{suite}.json"
    st = path.stat()
    stamp = (str(path), st.st_size, st.st_mtime_ns)
    index = _SCENARIOS.get(stamp)
    if index is None:
        loaded = load_suite(suite)
        index = {sc.id: sc for sc in loaded.scenarios}
        _SCENARIOS.clear()  # one suite at a time: a benchmark runs one
        _SCENARIOS[stamp] = index
    sc = index.get(scenario_id)
    if sc is None:
        return load_suite(suite).scenario(scenario_id)  # raises, naming the suite
    return sc


def dump_manifest(manifest: dict[str, Any]) -> str:
    """The manifest as shipped: JSON, one-space indent, keys in insertion order, final
    newline (the generator's output is compared to the shipped file byte for byte)."""
    return json.dumps(manifest, indent=1, ensure_ascii=True, allow_nan=False) + "\n"


def load_scenario(scenario: Scenario | dict[str, Any], data_root: Any = None) -> Scene:
    """The :class:`~conformal_control.data.Scene` of a scenario, ready for ``run_episode``.

    The scene holds the data from ``history_frames`` before the start to
    :data:`TAIL_S` seconds after the time limit; ``scene.meta["max_frames"]`` is the time
    limit in frames (pass it as ``run_episode(..., max_frames=scenario.max_frames)``).
    """
    sc = scenario if isinstance(scenario, Scenario) else Scenario.from_dict(scenario)
    last = sc.start_frame + sc.max_frames + round(TAIL_S * sc.fps)
    scene = load_scene(
        sc.scene,
        data_root,
        start_m=sc.start_m,
        goals_m=[sc.goal_m],
        start_frame=sc.start_frame,
        v_max=sc.v_ref,
        history_frames=sc.history_frames,
        last_frame=last,
    )
    scene.meta.update(
        {
            "scenario": sc.id,
            "recording": sc.recording,
            "split": sc.split,
            "max_frames": sc.max_frames,
            "time_limit_s": sc.time_limit_s,
        }
    )
    return scene
