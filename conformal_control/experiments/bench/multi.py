"""The multi-robot benchmark: fleets crossing real crowds, with and without reciprocity.

A **multi-robot suite** (``multi-crossings-v1``) is derived from a crossing suite
(:mod:`conformal_control.data.suites`): per split and recording a few of its scenarios
(evenly spread over the recording's windows), each under every **layout** of
:data:`LAYOUTS`. A layout turns a scenario's crossing (its start ``p``, goal ``q``, length
``L``, midpoint ``c``, direction ``u`` and normal ``n``) into tasks for ``M`` robots, with
``spacing`` (m) between neighbouring robots:

=========  ==================================================================================
``swap``   ``ceil(M/2)`` robots start at ``p``'s end, the others at ``q``'s end, side by side
           across the crossing at the same lateral offsets; each goes to the other end along
           its line: every line holds two robots head-on
``cross``  half the robots cross along ``u`` (from ``p``'s side), half along ``n`` (the
           perpendicular, through ``c``, from beyond the first stream's side), each stream
           side by side: two streams crossing
``lanes``  one robot per lane across the crossing, neighbouring lanes in opposite directions
``random`` starts and goals drawn in the square about ``c`` of side ``L`` (or
           ``2 spacing sqrt(M)`` if larger: room for the fleet), seeded by the entry:
           starts, and goals, at least ``spacing`` apart, every start at least ``L / 2``
           from its goal
=========  ==================================================================================

Lateral offsets are centred on the crossing's line; a fleet wider than the recording's
walkable area starts partly outside it (the pedestrians are where they were recorded).
Every robot has ``time_factor`` times the scenario's time limit (the fleet must also pass
itself). The manifest (``multi_manifests/<suite>.json``) lists the entries; the tasks are
recomputed from it (:func:`entry_tasks`), deterministically, and stored with every run.

The runner (:func:`run_multi_bench`, ``conformal-control bench run --robots M``) runs every
entry x robots count x method x reciprocity, one :func:`~conformal_control.runs.fleet.run_multi`
each, on a process pool; rows go to ``results.jsonl`` as they finish (a rerun into the same
folder skips what is done). Methods are the single-robot benchmark's
(:mod:`conformal_control.experiments.bench.methods`), applied to every robot. The report
(:func:`write_multi_report`) gives per (robots, method, reciprocity) the fleet metrics with
bootstrap CIs, and the reciprocal rows against the non-reciprocal ones paired by entry.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...data.suites import SPLITS, TAIL_S, Scenario, load_suite
from ...runs.results.multi_metrics import ROBOT_NEAR_M
from .methods import Method, available
from .shifts import Shift, get_shift
from .stats import Estimate, bootstrap_mean, paired_comparison
from .suite import check_tuned_split, incomplete_notice, load_tuned, plan_methods

if TYPE_CHECKING:
    from ...core.spec import RunSpec

__all__ = [
    "LAYOUTS",
    "MultiEntry",
    "MultiSuite",
    "entry_tasks",
    "is_multi_folder",
    "layout_tasks",
    "load_multi_suite",
    "make_multi_manifest",
    "multi_suite_names",
    "read_multi_rows",
    "run_multi_bench",
    "write_multi_report",
]

#: Layouts of a multi-robot entry (see the module docstring).
LAYOUTS = ("swap", "cross", "lanes", "random")

#: How a robot treats the others in a benchmark run: the option values of ``--reciprocity``
#: (``"solo"``: no fleet at all -- each robot run alone on its own task, the baseline a
#: fleet's pedestrian contacts are compared with).
RECIPROCITY_OPTIONS = ("solo", "none", "reciprocal")

#: The robots section's settings a benchmark's base run may give the reciprocal runs besides
#: ``information`` and ``lambda_scope`` (recorded in each row's ``options`` when not the
#: defaults).
RECIPROCAL_OPTIONS = (
    "sidestep",
    "hard_rows",
    "peer_horizon",
    "coordination",
    "priority",
    "floor_margin",
    "floor_core",
)

#: The arms :func:`run_multi_bench` runs by default: every one, paired by entry.
DEFAULT_RECIPROCITY = RECIPROCITY_OPTIONS

#: Metrics of a fleet kept in a row (FleetMetrics names).
FLEET_COLUMNS = (
    "n_robots",
    "goal_rate",
    "success_rate",
    "n_collide_pedestrian",
    "n_collide_pedestrian_avoidable",
    "n_collide_pedestrian_robot_near",
    "n_robots_hit_pedestrian",
    "n_collide_robot_pairs",
    "n_robots_hit_robot",
    "d_min_pedestrian",
    "d_min_robot",
    "t_goal_mean",
    "makespan",
    "n_deadlocked",
    "n_fallback",
    "n_steps",
    "frames",
    "cpu_s",
)

SCHEMA = "conformal-control/multi-suite"
SCHEMA_VERSION = 1


# ---------------------------------------------------------------------------- layouts
def _frame(start: Sequence[float], goal: Sequence[float]) -> tuple[np.ndarray, ...]:
    p = np.asarray(start, dtype=float)
    q = np.asarray(goal, dtype=float)
    length = float(np.hypot(*(q - p)))
    if not (math.isfinite(length) and length > 0):
        raise ValueError(f"a layout needs a start and a goal apart, got {p} and {q}")
    u = (q - p) / length
    n = np.array([-u[1], u[0]])
    return p, q, 0.5 * (p + q), u, n, np.array(length)


def _offsets(k: int, spacing: float) -> np.ndarray:
    out: np.ndarray = (np.arange(k) - 0.5 * (k - 1)) * spacing
    return out


def layout_tasks(
    layout: str,
    n_robots: int,
    start: Sequence[float],
    goal: Sequence[float],
    *,
    spacing: float = 2.5,
    seed: int = 0,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Starts ``(M, 2)`` and goals (one ``(1, 2)`` array per robot), in metres, of a layout
    of :data:`LAYOUTS` about the crossing from ``start`` to ``goal`` (see the module
    docstring); a one-line ``ValueError`` for a layout that cannot be made.

    Parameters
    ----------
    layout : {"swap", "cross", "lanes", "random"}
        The layout.
    n_robots : int
        Robots M (2 to the fleet's maximum).
    start, goal : (x, y)
        The single-robot scenario's start and goal (m), apart.
    spacing : float
        Distance between neighbouring robots (m, > 0).
    seed : int
        Seed of the ``random`` layout.
    """
    if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)):
        raise ValueError(f"the number of robots must be an integer, got {n_robots!r}")
    from ...runs.fleet import MAX_ROBOTS

    if not 2 <= n_robots <= MAX_ROBOTS:
        raise ValueError(f"a fleet has 2 to {MAX_ROBOTS} robots, got {n_robots}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a distance > 0 (m), got {spacing!r}")
    p, q, c, u, n, length_arr = _frame(start, goal)
    L = float(length_arr)
    m = int(n_robots)
    if layout == "swap":
        k = (m + 1) // 2
        off = _offsets(k, spacing)
        a = [p + o * n for o in off]
        b = [q + o * n for o in off[: m - k]]
        starts = np.array(a + b)
        goals = [q + o * n for o in off] + [p + o * n for o in off[: m - k]]
    elif layout == "cross":
        k = (m + 1) // 2
        s1 = [p + o * n for o in _offsets(k, spacing)]
        g1 = [q + o * n for o in _offsets(k, spacing)]
        # the second stream starts beyond the first one's side (clear of its corners)
        far = max(0.5 * L, 0.5 * (k - 1) * spacing + spacing)
        s2 = [c - far * n + o * u for o in _offsets(m - k, spacing)]
        g2 = [c + far * n + o * u for o in _offsets(m - k, spacing)]
        starts, goals = np.array(s1 + s2), g1 + g2
    elif layout == "lanes":
        off = _offsets(m, spacing)
        starts = np.array([(p if i % 2 == 0 else q) + o * n for i, o in enumerate(off)])
        goals = [(q if i % 2 == 0 else p) + o * n for i, o in enumerate(off)]
    elif layout == "random":
        starts, goals = _random_tasks(m, c, L, spacing, seed)
    else:
        raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    return np.asarray(starts, dtype=float), [
        np.asarray(g, dtype=float).reshape(1, 2) for g in goals
    ]


def _random_tasks(
    m: int, c: np.ndarray, L: float, spacing: float, seed: int, tries: int = 5000
) -> tuple[np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    side = max(L, 2.0 * spacing * math.sqrt(m))  # room for the fleet at the spacing
    starts: list[np.ndarray] = []
    goals: list[np.ndarray] = []
    for _ in range(tries):
        if len(starts) == m:
            break
        s = c + rng.uniform(-0.5 * side, 0.5 * side, 2)
        g = c + rng.uniform(-0.5 * side, 0.5 * side, 2)
        if np.hypot(*(g - s)) < 0.5 * L:
            continue
        if any(np.hypot(*(s - o)) < spacing for o in starts):
            continue
        if any(np.hypot(*(g - o)) < spacing for o in goals):
            continue
        starts.append(s)
        goals.append(g)
    if len(starts) < m:
        raise ValueError(
            f"layout random cannot place {m} robots {spacing} m apart in a {side:g} m square "
            f"({len(starts)} placed in {tries} draws)"
        )
    return np.array(starts), goals


# ---------------------------------------------------------------------------- the suite
@dataclass(frozen=True)
class MultiEntry:
    """One entry of a multi-robot suite: a base scenario under a layout."""

    id: str
    scenario: str
    split: str
    recording: str
    layout: str
    seed: int


@dataclass
class MultiSuite:
    """A loaded multi-robot manifest: the base suite, the layout parameters, the entries."""

    name: str
    manifest: dict[str, Any]
    entries: list[MultiEntry] = field(default_factory=list)

    @property
    def base(self) -> str:
        return str(self.manifest["base"])

    @property
    def spacing(self) -> float:
        return float(self.manifest["spacing_m"])

    @property
    def time_factor(self) -> float:
        return float(self.manifest["time_factor"])

    def entries_for(self, split: str | None = None) -> list[MultiEntry]:
        if split is not None and split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        return [e for e in self.entries if split is None or e.split == split]


def _manifest_dir() -> Path:
    return Path(str(resources.files("conformal_control.experiments.bench") / "multi_manifests"))


def multi_suite_names() -> list[str]:
    """Names of the shipped multi-robot suites."""
    return sorted(p.stem for p in _manifest_dir().glob("*.json"))


def make_multi_manifest(
    base: str = "crossings-v2",
    *,
    per_recording: int = 2,
    spacing: float = 2.5,
    time_factor: float = 2.0,
    version: int = 1,
) -> dict[str, Any]:
    """The manifest of a multi-robot suite derived from the crossing suite ``base``: per
    split and recording ``per_recording`` scenarios evenly spread over its windows, each
    under every layout (entry seed: its index in the manifest).

    Parameters
    ----------
    base : str
        The shipped single-robot crossing suite the scenarios come from.
    per_recording : int
        Scenarios per split and recording.
    spacing : float
        Distance between neighbouring robots of a layout (m).
    time_factor : float
        The episodes' time limit, as a multiple of the crossing time.
    version : int
        The suite's version, recorded in the manifest.
    """
    suite = load_suite(base)
    entries: list[dict[str, Any]] = []
    for split in SPLITS:
        by_rec: dict[str, list[Scenario]] = {}
        for sc in suite.scenarios_for(split):
            by_rec.setdefault(sc.recording, []).append(sc)
        for rec in sorted(by_rec):
            scs = by_rec[rec]
            k = min(per_recording, len(scs))
            picks = sorted({round(i * (len(scs) - 1) / max(k - 1, 1)) for i in range(k)})
            for j in picks:
                for layout in LAYOUTS:
                    entries.append(
                        {
                            "id": f"{scs[j].id}-{layout}",
                            "scenario": scs[j].id,
                            "split": split,
                            "recording": rec,
                            "layout": layout,
                            "seed": len(entries),
                        }
                    )
    return {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "suite": "multi-crossings",
        "version": version,
        "base": base,
        "spacing_m": spacing,
        "time_factor": time_factor,
        "layouts": list(LAYOUTS),
        "rule": (
            f"per split and recording of {base}, {per_recording} scenario(s) evenly spread "
            "over its windows, each under every layout"
        ),
        "entries": entries,
    }


def load_multi_suite(
    name: str = "multi-crossings-v1", path: str | Path | None = None
) -> MultiSuite:
    """A shipped multi-robot suite by name, or a manifest file (``path``)."""
    if path is None:
        known = multi_suite_names()
        if name not in known:
            raise ValueError(f"unknown multi-robot suite {name!r}; shipped: {', '.join(known)}")
        path = _manifest_dir() / f"{name}.json"
    p = Path(path)
    try:
        m = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(m, dict) or m.get("schema") != SCHEMA:
        raise ValueError(f"{p}: not a multi-robot suite manifest (schema {SCHEMA!r})")
    for key in ("base", "spacing_m", "time_factor", "entries", "suite", "version"):
        if key not in m:
            raise ValueError(f"{p}: missing key {key!r}")
    entries = []
    for i, e in enumerate(m["entries"]):
        if not isinstance(e, dict) or set(e) != {
            "id", "scenario", "split", "recording", "layout", "seed"
        }:  # fmt: skip
            raise ValueError(
                f"{p}: entry #{i} must have id, scenario, split, recording, layout, seed"
            )
        if e["layout"] not in LAYOUTS or e["split"] not in SPLITS:
            raise ValueError(f"{p}: entry #{i} has layout {e['layout']!r}, split {e['split']!r}")
        entries.append(MultiEntry(**e))
    return MultiSuite(name=f"{m['suite']}-v{m['version']}", manifest=m, entries=entries)


def entry_tasks(
    suite: MultiSuite, entry: MultiEntry, n_robots: int
) -> tuple[Scenario, np.ndarray, list[np.ndarray]]:
    """The base scenario of an entry and its fleet's tasks (m)."""
    base = load_suite(suite.base).scenario(entry.scenario)
    starts, goals = layout_tasks(
        entry.layout,
        n_robots,
        base.start_m,
        base.goal_m,
        spacing=suite.spacing,
        seed=entry.seed * 100 + int(n_robots),
    )
    return base, starts, goals


def entry_scene(base: Scenario, time_factor: float, data_root: str | None) -> Any:
    """The scene of an entry: the scenario's recording from its start, for ``time_factor``
    times its time limit (plus the suite's tail)."""
    from ...data import load_scene

    frames = math.ceil(base.max_frames * time_factor)
    scene = load_scene(
        base.scene,
        data_root,
        start_m=base.start_m,
        goals_m=[base.goal_m],
        start_frame=base.start_frame,
        v_max=base.v_ref,
        history_frames=base.history_frames,
        last_frame=base.start_frame + frames + round(TAIL_S * base.fps),
    )
    scene.meta.update({"scenario": base.id, "max_frames": frames})
    return scene


# ---------------------------------------------------------------------------- the runner
@dataclass(frozen=True)
class MultiRun:
    """One run of the benchmark (what a worker needs; plain data)."""

    key: str
    entry: MultiEntry
    n_robots: int
    method: str
    family: str
    setting: str
    settings: dict[str, Any]  # the method's run_multi keywords (plain data: pickled)
    reciprocity: str
    information: str
    lambda_scope: str
    seed: int
    options: dict[str, Any] = field(default_factory=dict)  # more reciprocal settings
    shift: str = "nominal"


def _key(
    entry: MultiEntry,
    n: int,
    method: Method,
    shift: Shift,
    rec: str,
    info: str,
    scope: str,
    opts: str,
) -> str:
    return f"{entry.id}|M{n}|{method.name}|{shift.name}|{rec}|{info}|{scope}{opts}"


def _options_label(options: Mapping[str, Any]) -> str:
    return "".join(f"|{k}={options[k]}" for k in sorted(options))


def _run_one(run: MultiRun, suite_path: str, data_root: str | None) -> dict[str, Any]:
    """Run one configuration; never raises (a failure is a row with its error)."""
    from ...core.jit import compile_now
    from ...runs.fleet import run_multi

    compile_now()  # a benchmark of fleets: compiled from the start (conformal_control.core.jit)
    t0 = time.perf_counter()
    e = run.entry
    row: dict[str, Any] = {
        "key": run.key,
        "entry": e.id,
        "scenario": e.scenario,
        "split": e.split,
        "recording": e.recording,
        "layout": e.layout,
        "robots": run.n_robots,
        "method": run.method,
        "family": run.family,
        "setting": run.setting,
        "shift": run.shift,
        "reciprocity": run.reciprocity,
        "information": run.information,
        "lambda_scope": run.lambda_scope,
        "options": _options_label(run.options) if run.reciprocity == "reciprocal" else "",
        "status": "failed",
    }
    try:
        suite = load_multi_suite(path=suite_path)
        base, starts, goals = entry_tasks(suite, e, run.n_robots)
        scene = entry_scene(base, suite.time_factor, data_root)
        kw = dict(run.settings)
        if run.reciprocity == "solo":
            row.update(_solo(scene, starts, goals, run.seed, kw))
            row["status"] = "ok"
            row["elapsed_s"] = time.perf_counter() - t0
            return row
        res = run_multi(
            scene,
            starts=starts,
            goals=goals,
            max_frames=scene.meta["max_frames"],
            seed=run.seed,
            record_animation=False,
            reciprocity=run.reciprocity,
            information=run.information,
            lambda_scope="both" if run.reciprocity == "none" else run.lambda_scope,
            **(run.options if run.reciprocity == "reciprocal" else {}),
            **kw,
        )
        m = res.metrics
        row.update({k: m[k] for k in FLEET_COLUMNS})
        row["status"] = "ok"
    except Exception as exc:  # a failed run is data, not a crash
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["elapsed_s"] = time.perf_counter() - t0
    return row


def _solo(
    scene: Any, starts: np.ndarray, goals: Sequence[np.ndarray], seed: int, kw: Mapping[str, Any]
) -> dict[str, Any]:
    """The fleet's figures with every robot run alone on its own task (robot ``i`` with
    seed ``seed + i``, as in the fleet): pedestrian frames and deadlocks summed, the goal
    rate over the robots, no robot pair (:func:`~conformal_control.runs.results.multi_metrics.
    fleet_metrics` of the single-robot runs)."""
    from ...runs.fleet import run_multi
    from ...runs.results.multi_metrics import fleet_metrics

    robots, contacts = [], []
    frames, wall, cpu = 0, 0.0, 0.0
    for i in range(starts.shape[0]):
        res = run_multi(
            scene,
            starts=starts[i : i + 1],
            goals=[goals[i]],
            max_frames=scene.meta["max_frames"],
            seed=seed + i,
            record_animation=False,
            **kw,
        )
        (r,) = res.robots
        robots.append(r.metrics)
        contacts.append(r.contacts)
        frames = max(frames, int(res.metrics.frames))
        wall += res.metrics.wall_s
        cpu += res.metrics.cpu_s
    m = fleet_metrics(
        robots,
        contacts,
        robot_track=np.zeros((0, len(robots), 2)),
        active=np.zeros((0, len(robots)), dtype=bool),
        robot_radius=float(scene.robot_radius),
        frames=frames,
        wall_s=wall,
        lam_unit_name=robots[0].unit("lambda_final"),
        cpu_s=cpu,
    )
    return {k: m[k] for k in FLEET_COLUMNS}


def _runs(
    suite: MultiSuite,
    split: str | None,
    robots: Sequence[int],
    methods: Sequence[Method],
    reciprocity: Sequence[str],
    information: str,
    lambda_scope: str,
    predictor: str,
    seed: int,
    limit: int | None,
    options: Mapping[str, Any],
    shifts: Sequence[Shift],
    data_root: str | None,
) -> list[MultiRun]:
    entries = suite.entries_for(split)
    if limit is not None:
        entries = entries[: int(limit)]
    if not entries:
        raise ValueError(f"no entry of {suite.name} matches (split={split!r})")
    out = []
    for e, n, m, shift in (
        (e, n, m, sh) for sh in shifts for e in entries for n in robots for m in methods
    ):
        if not shift.covers(e.recording):
            continue
        name, params = shift.predictor_for(m.predictor or predictor, None, data_root)
        for rec in reciprocity:
            recip = rec == "reciprocal"
            info = information if recip else "-"
            scope = lambda_scope if recip else ("both" if rec == "none" else "-")
            opts = _options_label(options) if recip else ""
            key = _key(e, n, m, shift, rec, info, scope, opts)
            kw = m.run_kwargs(predictor)
            kw["predictor"] = name
            if params:
                kw["predictor_params"] = params
            run = MultiRun(
                key, e, n, m.name, m.family, m.setting, kw, rec, information, scope,
                seed, dict(options), shift.name,
            )  # fmt: skip
            out.append(run)
    return out


@dataclass
class MultiBenchRun:
    """What :func:`run_multi_bench` did."""

    out_dir: Path
    n_runs: int
    skipped: int
    ran: int
    failed: int
    wall_s: float
    #: fleet episodes a lost worker took with it (not failures; a rerun finishes them)
    unfinished: int = 0
    #: what failed, one line per distinct reason
    infrastructure: tuple[str, ...] = ()

    def summary(self) -> str:
        extra = ""
        if self.unfinished:
            why = self.infrastructure[0] if self.infrastructure else "a worker failed"
            extra = (
                f"; {self.unfinished} left unfinished, not failed: the infrastructure failed "
                f"({why}); run the same command again to finish them before `bench report`"
            )
        return (
            f"{self.n_runs} fleet episodes: {self.skipped} already done, {self.ran} ran "
            f"({self.failed} failed) in {self.wall_s:.1f} s; results in {self.out_dir}{extra}"
        )


def multi_bench_base(
    base: RunSpec | None,
) -> tuple[str, int, str, str, dict[str, Any]]:
    """What the multi-robot benchmark takes from its base run specification:
    ``(predictor, seed, information, lambda_scope, options)``.

    The suite places the robots and the methods set the rest, so a base that sets more is
    a one-line error rather than silently overridden.

    Parameters
    ----------
    base : RunSpec, optional
        None: the constant-velocity predictor, seed 0, the robots section's defaults.
    """
    from ...core.exceptions import InputError
    from ...core.spec import Robots, RunSpec

    if base is None:
        base = RunSpec()
    if not isinstance(base, RunSpec):
        raise InputError(f"base must be a RunSpec, got {type(base).__name__}")
    section = base.robots if base.robots is not None else Robots()
    kept = RunSpec(predictor=base.predictor, seed=base.seed, robots=base.robots)
    extra = [f for f in RunSpec.__dataclass_fields__ if getattr(base, f) != getattr(kept, f)]
    default = Robots()
    taken = ("information", "lambda_scope", *RECIPROCAL_OPTIONS)
    extra += [
        f"robots.{f}"
        for f in Robots.__dataclass_fields__
        if f not in taken and getattr(section, f) != getattr(default, f)
    ]
    if extra:
        raise InputError(
            "the multi-robot benchmark's base run sets only its predictor, seed and the "
            f"robots' {', '.join(taken)} (the suite and the methods set the rest); drop "
            f"{', '.join(extra)}"
        )
    predictor, params = base.role("predictor")
    if not isinstance(predictor, str) or params:
        raise InputError("the multi-robot benchmark's predictor is a registered name")
    options = {
        k: getattr(section, k)
        for k in RECIPROCAL_OPTIONS
        if getattr(section, k) != getattr(default, k)
    }
    # a section without a lambda scope: the reciprocal runs' default
    scope = section.lambda_scope or "pedestrians"
    return predictor, base.seed, section.information, scope, options


def run_multi_bench(
    out: str | Path,
    *,
    robots: Sequence[int] = (5, 10),
    suite: str = "multi-crossings-v1",
    split: str | None = "test",
    methods: Sequence[str] = ("nolearn", "conformal"),
    grids: Mapping[str, Sequence[Any]] | None = None,
    shifts: Sequence[str] = ("nominal",),
    tuned: str | None = "default",
    reciprocity: Sequence[str] = DEFAULT_RECIPROCITY,
    base: RunSpec | None = None,
    data_root: str | None = None,
    workers: int | None = None,
    limit: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> MultiBenchRun:
    """Run the multi-robot benchmark into ``out`` (resumable: finished runs are skipped).

    Parameters
    ----------
    out : path
        The benchmark folder (``bench.json``, ``results.jsonl``).
    robots : sequence of int
        Fleet sizes.
    suite, split
        The multi-robot suite and its split (None: both).
    methods, grids, tuned
        Method families of :mod:`conformal_control.experiments.bench.methods`, their settings (a
        family's ``grids`` entry, else its tuned value for the base suite where one is
        shipped or given as a ``tuned.json``, else its settings), as the single-robot
        benchmark plans them (:func:`~conformal_control.experiments.bench.suite.plan_methods`).
    shifts : sequence of str
        Predictor shifts of :mod:`conformal_control.experiments.bench.shifts` (entries a shift does
        not cover are left out of it).
    reciprocity : sequence of {"solo", "none", "reciprocal"}
        How the robots treat each other (``"none"``: predicted like pedestrians, lambda on
        every row: the behaviour without reciprocity; ``"solo"``: each robot alone on its
        own task, the baseline of the report's fleet-against-solo table). Default: all
        three.
    base : RunSpec, optional
        What every run takes (:func:`multi_bench_base`): the predictor (a method may
        replace it) and the seed; its robots section (:class:`~conformal_control.core.spec.Robots`)
        the reciprocal runs' ``information``, ``lambda_scope`` (see
        :mod:`conformal_control.families.cbf.reciprocal`) and :data:`RECIPROCAL_OPTIONS` (these
        recorded in each row, ``options``, and key when not the defaults). Default:
        constant velocity, seed 0, the section's defaults.
    data_root : str, optional
        The data folder.
    limit : int, optional
        Only the first ``limit`` entries.
    workers : int, optional
        Processes (default: the CPUs; 1 runs in this process).
    progress : callable, optional
        Called with a line per finished run.
    """
    predictor, seed, information, lambda_scope, options = multi_bench_base(base)
    bad = sorted(set(reciprocity) - set(RECIPROCITY_OPTIONS))
    if bad or not reciprocity:
        raise ValueError(f"reciprocity must be among {', '.join(RECIPROCITY_OPTIONS)}, got {bad}")
    ms = suite if Path(suite).suffix == ".json" else None
    loaded = load_multi_suite(path=ms) if ms else load_multi_suite(suite)
    suite_path = str(ms or _manifest_dir() / f"{suite}.json")
    tuned_values = load_tuned(tuned, loaded.base)
    if tuned_values is not None:
        check_tuned_split(tuned_values, split)
    chosen = plan_methods(methods, tuned_values, grids)
    shift_objs = [get_shift(s) for s in shifts]
    missing = {m.name: why for m in chosen if (why := available(m)) is not None}
    if missing:
        raise ValueError(
            "methods unavailable: " + "; ".join(f"{k}: {v}" for k, v in missing.items())
        )
    runs = _runs(
        loaded,
        split,
        robots,
        chosen,
        reciprocity,
        information,
        lambda_scope,
        predictor,
        seed,
        limit,
        dict(options or {}),
        shift_objs,
        data_root,
    )
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(
        json.dumps(
            {
                "kind": "multi",
                "suite": loaded.name,
                "base": loaded.base,
                "split": split,
                "robots": list(robots),
                "methods": [m.as_dict() for m in chosen],
                "reciprocity": list(reciprocity),
                "information": information,
                "lambda_scope": lambda_scope,
                "options": dict(options or {}),
                "predictor": predictor,
                "shifts": list(shifts),
                "tuned": tuned,
                "seed": seed,
                "limit": limit,
                # what this run plans: a report tells an incomplete folder by it
                "keys": [r.key for r in runs],
            },
            indent=2,
            default=str,
        )
        + "\n"
    )
    journal = out / "results.jsonl"
    done = {r["key"] for r in _read_jsonl(journal) if r.get("status") == "ok"}
    todo = [r for r in runs if r.key not in done]
    t0 = time.perf_counter()
    n_failed = 0
    unfinished: list[str] = []
    reasons: list[str] = []
    with journal.open("a") as fh:
        for row in _execute(todo, suite_path, data_root, workers):
            if isinstance(row, BaseException):  # a worker lost: not a failure of the run
                why = " ".join(f"{type(row).__name__}: {row}".split())[:200]
                if why not in reasons:
                    reasons.append(why)
                unfinished.append("")
                continue
            fh.write(json.dumps(row, default=_plain) + "\n")
            fh.flush()
            n_failed += row["status"] != "ok"
            if progress is not None:
                progress(_progress_line(row))
    return MultiBenchRun(
        out_dir=out,
        n_runs=len(runs),
        skipped=len(runs) - len(todo),
        ran=len(todo) - len(unfinished),
        failed=n_failed,
        wall_s=time.perf_counter() - t0,
        unfinished=len(unfinished),
        infrastructure=tuple(reasons),
    )


def _plain(v: Any) -> Any:
    if isinstance(v, (np.integer, np.floating)):
        return v.item()
    if isinstance(v, np.bool_):
        return bool(v)
    return str(v)


def _progress_line(row: Mapping[str, Any]) -> str:
    if row["status"] != "ok":
        return f"FAILED {row['key']}: {row.get('error')}"
    return (
        f"{row['key']}: goal {row['goal_rate']:.2f}, robot pairs {row['n_collide_robot_pairs']}, "
        f"pedestrian {row['n_collide_pedestrian']}, {row['elapsed_s']:.1f} s"
    )


def _execute(
    runs: Sequence[MultiRun], suite_path: str, data_root: str | None, workers: int | None
) -> Iterable[dict[str, Any] | BaseException]:
    """Each run's row as it finishes; the exception instead, for a run the pool lost (a
    worker killed): the run itself catches its own errors (:func:`_run_one`)."""
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n <= 1 or len(runs) <= 1:
        for r in runs:
            yield _run_one(r, suite_path, data_root)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    with ProcessPoolExecutor(max_workers=n, mp_context=ctx) as pool:
        futures = [pool.submit(_run_one, r, suite_path, data_root) for r in runs]
        for f in as_completed(futures):
            try:
                yield f.result()
            except Exception as exc:  # BrokenProcessPool: the machinery, not the run
                yield exc


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue  # a torn last line of an interrupted run
        if isinstance(row, dict) and "key" in row:
            rows.append(row)
    return rows


def is_multi_folder(folder: str | Path) -> bool:
    """Whether ``folder`` holds a multi-robot benchmark (``bench.json`` of kind multi)."""
    f = Path(folder) / "bench.json"
    try:
        return bool(json.loads(f.read_text()).get("kind") == "multi")
    except (OSError, json.JSONDecodeError, AttributeError):
        return False


def read_multi_rows(folder: str | Path) -> list[dict[str, Any]]:
    """The latest successful row of every run of a multi-robot benchmark folder."""
    rows: dict[str, dict[str, Any]] = {}
    for r in _read_jsonl(Path(folder) / "results.jsonl"):
        if r.get("status") == "ok":
            rows[r["key"]] = r
    if not rows:
        raise FileNotFoundError(f"{folder} holds no finished multi-robot runs (results.jsonl)")
    return list(rows.values())


# ---------------------------------------------------------------------------- the report
def _est(values: Iterable[float | None]) -> Estimate:
    v = np.array([math.nan if x is None else float(x) for x in values], dtype=float)
    return bootstrap_mean(v)


def _sum_ratio_ci(
    a: np.ndarray, b: np.ndarray, n_resamples: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """``sum(a) / sum(b)`` and its paired percentile bootstrap CI over the pairs (NaN when
    ``b`` sums to 0)."""
    if b.sum() == 0:
        return math.nan, math.nan, math.nan
    point = a.sum() / b.sum()
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, a.size, size=(n_resamples, a.size))
    sa, sb = a[idx].sum(1), b[idx].sum(1)
    ok = sb > 0
    ratio = sa[ok] / sb[ok]
    lo, hi = np.percentile(ratio, [2.5, 97.5]) if ratio.size else (math.nan, math.nan)
    return float(point), float(lo), float(hi)


def _ratio_ci(
    a: np.ndarray, b: np.ndarray, n_resamples: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """``1 - sum(a) / sum(b)`` (the reduction of a against b) and its paired percentile
    bootstrap CI over the pairs."""
    point, lo, hi = _sum_ratio_ci(a, b, n_resamples, seed)
    return 1.0 - point, 1.0 - hi, 1.0 - lo


def _arm(row: Mapping[str, Any]) -> str:
    """A row's arm: its reciprocity, with the reciprocal options when not the defaults."""
    return f"{row['reciprocity']}{row.get('options') or ''}"


def _total(rows: Iterable[Mapping[str, Any]], key: str) -> float:
    return float(sum(float(r.get(key) or 0.0) for r in rows))


def multi_tables(rows: Sequence[Mapping[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """The report's tables as rows: ``fleet`` (per robots, method, reciprocity) and
    ``paired`` (reciprocal against none, per robots and method; per layout too)."""
    groups: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    for r in rows:
        key = (r["robots"], r["method"], r.get("shift", "nominal"), _arm(r))
        groups.setdefault(key, []).append(r)
    fleet = []
    for (n, method, shift, rec), rs in sorted(groups.items()):
        fleet.append(
            {
                "robots": n,
                "method": method,
                "shift": shift,
                "reciprocity": rec,
                "episodes": len(rs),
                "goal_rate": _est(r["goal_rate"] for r in rs),
                "robot_pair_frames": _est(r["n_collide_robot_pairs"] for r in rs),
                "episodes_robot_collision": _est(float(r["n_collide_robot_pairs"] > 0) for r in rs),
                "pedestrian_frames": _est(r["n_collide_pedestrian"] for r in rs),
                "pedestrian_frames_total": _total(rs, "n_collide_pedestrian"),
                "avoidable_total": _total(rs, "n_collide_pedestrian_avoidable"),
                "robot_near_total": _total(rs, "n_collide_pedestrian_robot_near"),
                "robot_pair_frames_total": _total(rs, "n_collide_robot_pairs"),
                "makespan_s": _est(r["makespan"] for r in rs),
                "deadlocked": _est(r["n_deadlocked"] for r in rs),
                "cpu_s": _est(r["cpu_s"] for r in rs),
            }
        )
    paired = []
    for layout in (None, *LAYOUTS):
        keyed: dict[tuple[Any, ...], dict[str, Mapping[str, Any]]] = {}
        for r in rows:
            if layout is not None and r["layout"] != layout:
                continue
            k = (r["robots"], r["method"], r.get("shift", "nominal"), r["entry"])
            keyed.setdefault(k, {})[_arm(r)] = r
        by: dict[tuple[Any, ...], list[tuple[Mapping[str, Any], Mapping[str, Any]]]] = {}
        # pairs in the order of their entries, not of the rows: the resampled ratio's CI
        # is a function of the set of rows (a pool stores them as episodes finish)
        for (n, method, shift, _), pair in sorted(keyed.items(), key=lambda kv: str(kv[0])):
            if "none" not in pair:
                continue
            for arm, r in pair.items():
                if r["reciprocity"] == "reciprocal":
                    by.setdefault((n, method, shift, arm), []).append((r, pair["none"]))
        for (n, method, shift, arm), pairs in sorted(by.items()):
            rec = np.array([float(a["n_collide_robot_pairs"]) for a, _ in pairs])
            non = np.array([float(b["n_collide_robot_pairs"]) for _, b in pairs])
            red = _ratio_ci(rec, non)
            goal = paired_comparison(
                [a["goal_rate"] for a, _ in pairs],
                [b["goal_rate"] for _, b in pairs],
                metric="goal_rate",
                lower_is_better=False,
            )
            ped = paired_comparison(
                [a["n_collide_pedestrian"] for a, _ in pairs],
                [b["n_collide_pedestrian"] for _, b in pairs],
                metric="pedestrian_frames",
            )
            dl = paired_comparison(
                [a["n_deadlocked"] for a, _ in pairs],
                [b["n_deadlocked"] for _, b in pairs],
                metric="deadlocked",
            )
            paired.append(
                {
                    "layout": layout or "all",
                    "robots": n,
                    "method": method,
                    "shift": shift,
                    "reciprocity": arm,
                    "pairs": len(pairs),
                    "robot_pair_frames_none": float(non.sum()),
                    "robot_pair_frames_reciprocal": float(rec.sum()),
                    "reduction": red,
                    "goal_rate_difference": goal.difference,
                    "pedestrian_frames_difference": ped.difference,
                    "deadlocked_difference": dl.difference,
                }
            )
    solo = _solo_table(rows)
    for rec in sorted({str(r.get("recording", "-")) for r in rows}):
        part = [r for r in rows if str(r.get("recording", "-")) == rec]
        solo += [{**t, "recording": rec} for t in _solo_table(part)]
    return {"fleet": fleet, "paired": paired, "solo": solo}


def _solo_table(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Every fleet arm against its robots run alone, paired by entry: pedestrian frames
    (all, avoidable, with another robot near) summed over the pairs, their ratio to the solo
    runs' with a paired bootstrap CI, and the differences of goal rate and deadlocked
    robots (fleet minus solo); ``recording`` is ``"all"``."""
    keyed: dict[tuple[Any, ...], dict[str, Mapping[str, Any]]] = {}
    for r in rows:
        k = (r["robots"], r["method"], r.get("shift", "nominal"), r["entry"])
        keyed.setdefault(k, {})[_arm(r)] = r
    by: dict[tuple[Any, ...], list[tuple[Mapping[str, Any], Mapping[str, Any]]]] = {}
    # pairs in the order of their entries (the CIs are a function of the set of rows)
    for (n, method, shift, _), arms in sorted(keyed.items(), key=lambda kv: str(kv[0])):
        if "solo" not in arms:
            continue
        for arm, r in arms.items():
            if arm != "solo":
                by.setdefault((n, method, shift, arm), []).append((r, arms["solo"]))
    out = []
    for (n, method, shift, arm), pairs in sorted(by.items()):
        fleet = [a for a, _ in pairs]
        solo = [b for _, b in pairs]
        ped_f = np.array([float(a["n_collide_pedestrian"]) for a in fleet])
        ped_s = np.array([float(b["n_collide_pedestrian"]) for b in solo])
        goal = paired_comparison(
            [a["goal_rate"] for a in fleet],
            [b["goal_rate"] for b in solo],
            metric="goal_rate",
            lower_is_better=False,
        )
        dl = paired_comparison(
            [a["n_deadlocked"] for a in fleet],
            [b["n_deadlocked"] for b in solo],
            metric="deadlocked",
        )
        out.append(
            {
                "recording": "all",
                "robots": n,
                "method": method,
                "shift": shift,
                "reciprocity": arm,
                "pairs": len(pairs),
                "pedestrian_frames_solo": float(ped_s.sum()),
                "avoidable_solo": _total(solo, "n_collide_pedestrian_avoidable"),
                "pedestrian_frames_fleet": float(ped_f.sum()),
                "avoidable_fleet": _total(fleet, "n_collide_pedestrian_avoidable"),
                "robot_near_fleet": _total(fleet, "n_collide_pedestrian_robot_near"),
                "ratio": _sum_ratio_ci(ped_f, ped_s),
                "robot_pair_frames_fleet": _total(fleet, "n_collide_robot_pairs"),
                "goal_rate_solo": float(np.mean([b["goal_rate"] for b in solo])),
                "goal_rate_difference": goal.difference,
                "deadlocked_difference": dl.difference,
            }
        )
    return out


def _fmt(v: Any, col: str = "") -> str:
    if isinstance(v, Estimate):
        return v.format()
    if isinstance(v, tuple) and len(v) == 3:
        if math.isnan(v[0]):
            return "-"
        if col == "ratio":
            return f"{v[0]:.2f}x [{v[1]:.2f}, {v[2]:.2f}]"
        return f"{100 * v[0]:.1f} % [{100 * v[1]:.1f}, {100 * v[2]:.1f}]"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def _md(rows: Sequence[Mapping[str, Any]], cols: Sequence[str]) -> str:
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(_fmt(r[c], c) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def write_multi_report(
    rows: Sequence[Mapping[str, Any]],
    out: str | Path,
    *,
    title: str = "Multi-robot benchmark",
    notice: str | None = None,
) -> Path:
    """Write ``multi_report.md`` (and the tables as JSON) into ``out``; return the page.

    Parameters
    ----------
    rows : sequence of mapping
        The multi-robot benchmark's rows (one per fleet episode, solo arms included).
    out : str or Path
        The report folder (created if missing).
    title : str
        The page's title.
    notice : str, optional
        The page's first line, for a folder with unfinished episodes.
    """
    tables = multi_tables(rows)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fleet_cols = (
        "robots", "method", "shift", "reciprocity", "episodes", "goal_rate", "robot_pair_frames",
        "episodes_robot_collision", "pedestrian_frames", "pedestrian_frames_total",
        "avoidable_total", "robot_near_total", "makespan_s", "deadlocked",
    )  # fmt: skip
    solo_cols = (
        "robots", "method", "shift", "reciprocity", "pairs", "pedestrian_frames_solo",
        "avoidable_solo", "pedestrian_frames_fleet", "avoidable_fleet", "robot_near_fleet",
        "ratio", "robot_pair_frames_fleet", "goal_rate_solo", "goal_rate_difference",
        "deadlocked_difference",
    )  # fmt: skip
    paired_cols = (
        "layout", "robots", "method", "shift", "reciprocity", "pairs", "robot_pair_frames_none",
        "robot_pair_frames_reciprocal", "reduction", "goal_rate_difference",
        "pedestrian_frames_difference", "deadlocked_difference",
    )  # fmt: skip
    splits = sorted({str(r["split"]) for r in rows})
    text = [
        *([notice, ""] if notice else []),
        f"# {title}",
        "",
        f"{len(rows)} fleet episodes ({', '.join(splits)}). Means per episode with 95 % "
        "bootstrap CIs over the entries; robot pair-frames count each pair once per frame.",
        "",
        "## Fleets",
        "",
        _md(tables["fleet"], fleet_cols),
        "",
        "## Fleets against their robots alone (paired by entry)",
        "",
        "`solo`: each robot of the entry run alone on its own task. Pedestrian frames summed "
        "over the pairs: all, `avoidable` (events a point robot with the same speed bound "
        "could have avoided since first sensing the pedestrian; pop-ins never), and "
        f"`robot_near` (another robot within {ROBOT_NEAR_M:g} m of the hit robot); `ratio`: "
        "fleet / solo pedestrian frames with its paired bootstrap CI; differences are fleet "
        "minus solo.",
        "",
        _md([r for r in tables["solo"] if r["recording"] == "all"], solo_cols)
        if tables["solo"]
        else "(no solo runs: add `solo` to `--reciprocity`)",
        "",
        "### Per recording",
        "",
        _md([r for r in tables["solo"] if r["recording"] != "all"], ("recording", *solo_cols)),
        "",
        "## Reciprocal against none (paired by entry)",
        "",
        "`reduction`: 1 - robot pair-frames with reciprocity / without, with its paired "
        "bootstrap CI; differences are reciprocal minus none (goal rate in fractions).",
        "",
        _md([r for r in tables["paired"] if r["layout"] == "all"], paired_cols),
        "",
        "### Per layout",
        "",
        _md([r for r in tables["paired"] if r["layout"] != "all"], paired_cols),
        "",
    ]
    page = out / "multi_report.md"
    page.write_text("\n".join(text))

    def plain(v: Any) -> Any:
        if isinstance(v, Estimate):
            return {"mean": v.mean, "low": v.low, "high": v.high, "n": v.n}
        return v

    (out / "multi_report.json").write_text(
        json.dumps(
            {k: [{c: plain(v) for c, v in r.items()} for r in t] for k, t in tables.items()},
            indent=1,
            default=_plain,
        )
        + "\n"
    )
    return page


# ---------------------------------------------------------------------------- the command
def _ints(text: str, what: str) -> list[int]:
    try:
        out = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"{what} expects integers separated by commas, got {text!r}") from None
    if not out:
        raise ValueError(f"{what} expects at least one integer, got {text!r}")
    return out


def run_command(
    args: Any,
    default_suite: str,
    families: Sequence[str],
    grids: Any,
    settings: Mapping[str, Any] | None = None,
) -> int:
    """``bench run --robots M``: the multi-robot benchmark into ``--out``.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``bench run`` options (``--robots``, ``--suite``, ``--split``,
        ``--shift``, ``--reciprocity``, ``--out``, ...).
    default_suite : str
        The single-robot default of ``--suite`` (it then means ``multi-crossings-v1``).
    families : sequence of str
        The methods to run.
    grids : dict, optional
        Settings per method (``--grid``), as for the single-robot benchmark.
    settings : mapping, optional
        ``--set KEY=VALUE`` (typed): the reciprocal runs' options
        (:data:`RECIPROCAL_OPTIONS`, e.g. ``floor_margin=0``); any other key is refused
        (one line: the suite and the methods set the run parameters).

    Returns
    -------
    int
        The exit status: 0 when every episode ran.
    """
    from ...core.spec import ROBOT_CHOICES, Robots, RunSpec

    robots = _ints(args.robots, "--robots")
    # --set: the reciprocal runs' options (RECIPROCAL_OPTIONS, e.g. floor_margin=0); any
    # other key is a run parameter, which multi_bench_base refuses in one line
    given = dict(settings or {})
    section = {k: given.pop(k) for k in RECIPROCAL_OPTIONS if k in given}
    for k, v in section.items():  # KEY=none reads as None: the choice "none" where it is one
        if v is None and "none" in ROBOT_CHOICES.get(k, ()):
            section[k] = "none"
    suite = args.suite if args.suite != default_suite else "multi-crossings-v1"
    res = run_multi_bench(
        args.out,
        robots=robots,
        suite=suite,
        split=None if args.split == "all" else args.split,
        methods=families,
        grids=grids,
        shifts=[s.strip() for s in args.shift.split(",") if s.strip()],
        tuned=args.tuned,
        reciprocity=[s.strip() for s in args.reciprocity.split(",") if s.strip()],
        base=RunSpec(
            params=given,
            predictor=args.predictor or "constant_velocity",
            robots=Robots(information=args.information, lambda_scope=args.lambda_scope, **section),
        ),
        data_root=args.data_root,
        workers=args.workers,
        limit=args.limit,
        progress=None if args.progress == "off" else print,
    )
    print(res.summary())
    return 0 if res.failed == 0 and not res.unfinished else 1


def multi_unfinished(folder: str | Path) -> tuple[int, int]:
    """``(planned, unfinished)`` fleet episodes of the folder's last ``bench run --robots``:
    those its ``bench.json`` lists without any record in the journal.

    Parameters
    ----------
    folder : str or Path
        The multi-robot benchmark folder.
    """
    try:
        keys = json.loads((Path(folder) / "bench.json").read_text()).get("keys") or []
    except (OSError, ValueError, AttributeError):
        return 0, 0
    done = {r["key"] for r in _read_jsonl(Path(folder) / "results.jsonl")}
    planned = {str(k) for k in keys}
    return len(planned), len(planned - done)


def report_command(folder: str | Path, out: str | Path | None) -> int:
    """``bench report`` of a multi-robot folder: ``multi_report.md`` (printed)."""
    rows = read_multi_rows(folder)
    dest = Path(out) if out else Path(folder) / "report"
    notice = incomplete_notice(*multi_unfinished(folder), command="bench run --robots")
    page = write_multi_report(
        rows, dest, title=f"Multi-robot benchmark: {Path(folder).name}", notice=notice
    )
    print(page.read_text())
    print(f"wrote {page} and {page.with_suffix('.json')}")
    return 0
