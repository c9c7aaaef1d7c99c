"""Run the benchmark: scenarios x methods x predictor shifts, on the sweep runner.

Each (shift, scenario, method) triple is one run of a sweep
(:func:`conformal_control.experiments.run_sweep`): resumable by key, failures isolated and
recorded, a progress bar, any executor (the lockstep batch engine, local processes, Dask).
The scene of a run is ``scenario:<suite>/<id>`` (its time limit comes with it), the method's
parameters are in SI (``units="si"``), and the row of every episode carries the scenario's,
the method's and the shift's description (``meta``) so that reports are built from the
stored rows alone (:func:`conformal_control.experiments.bench.report.write_report`).

**Tuned values.** :func:`run_bench` uses, by default, the values ``bench tune`` chose on the
suite's dev split and the package ships
(``conformal_control/experiments/bench/tuned/<suite>.json``), or
a ``tuned.json`` given with ``tuned=``: a tuned family runs its tuned setting only, except a
*reference* family (``fixed``), which runs its whole tuning grid so that the report can show,
clearly labelled, the setting re-tuned on the reported split itself. ``bench.json`` records
where the values came from.

**One folder, one condition.** A folder holds the runs of one suite, split, predictor,
crowd, set of run parameters (``--set``), seed and tuned values. A second ``bench run`` into
it may add methods, shifts or scenarios; one with another condition, or with a method of
the same name defined otherwise, is refused with a one-line error before anything is
written, as is a run into a folder another ``bench run`` is writing to (``bench.json`` is
then left as it is).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...core.exceptions import InputError
from ...data.suites import Scenario, load_suite
from .methods import DEFAULT_METHODS, FAMILIES, Method, available, expand_methods
from .shifts import SHIFTS, Shift, get_shift

if TYPE_CHECKING:
    from ...core.spec import RunSpec

__all__ = [
    "DEFAULT_SUITE",
    "BenchFolderError",
    "BenchRun",
    "Tuned",
    "bench_configs",
    "load_tuned",
    "plan_methods",
    "read_bench",
    "read_rows",
    "run_bench",
]

#: The suite ``bench`` commands use by default.
DEFAULT_SUITE = "crossings-v2"
#: What each run of the benchmark writes (config.json + metrics.json); the rows are in
#: the sweep's journal and tables.
RUN_FILES = "metrics"
#: The keys of ``bench.json`` that define a folder's condition (see the module docstring).
CONDITION_KEYS = (
    "suite",
    "split",
    "predictor",
    "predictor_params",
    "crowd",
    "crowd_params",
    "base_params",
    "seed",
    "tuned_sha256",
)


class BenchFolderError(InputError):
    """A benchmark folder cannot take this run (busy, or another condition)."""


# ------------------------------------------------------------------ tuned values
@dataclass(frozen=True)
class Tuned:
    """Tuned settings (``bench tune``'s ``tuned.json``) and where they come from.

    Attributes
    ----------
    values : dict
        family -> setting.
    source : str
        The file (``shipped:<name>`` for the package's own).
    sha256 : str
        Of the file's bytes.
    data : dict
        The whole file (rule, candidates, the split and suite they were tuned on).
    """

    values: dict[str, Any]
    source: str
    sha256: str
    data: dict[str, Any]

    def describe(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "sha256": self.sha256,
            "suite": self.data.get("suite"),
            "split": self.data.get("split"),
            "rule": self.data.get("rule"),
            "values": dict(self.values),
        }


def _shipped_tuned(suite: str) -> Path | None:
    path = Path(
        str(resources.files("conformal_control.experiments.bench") / "tuned" / f"{suite}.json")
    )
    return path if path.is_file() else None


def load_tuned(tuned: str | Path | None, suite: str) -> Tuned | None:
    """The tuned values to use: ``"default"`` (the package's for ``suite``, if it ships
    any), ``None`` / ``"none"`` (none), or a ``tuned.json`` file (or a ``bench tune``
    folder holding one).

    Raises
    ------
    ValueError
        A file that is not a ``bench tune`` result, or tuned on another suite.
    """
    if tuned is None or tuned == "none":
        return None
    if tuned == "default":
        path = _shipped_tuned(suite)
        if path is None:
            return None
        source = f"shipped:conformal_control/experiments/bench/tuned/{path.name}"
    else:
        path = Path(tuned)
        if path.is_dir():
            path = path / "tuned.json"
        if not path.is_file():
            raise FileNotFoundError(f"no tuned values at {path} (run `bench tune` first)")
        source = str(path)
    raw = path.read_bytes()
    try:
        data = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict) or not isinstance(data.get("families"), dict):
        raise ValueError(f"{path}: not a `bench tune` result (no 'families')")
    if data.get("suite") != suite:
        raise ValueError(f"{path}: tuned on suite {data.get('suite')!r}, this run is on {suite!r}")
    if not isinstance(data.get("split"), str) or not data["split"]:
        raise ValueError(
            f"{path}: does not say which split its values were tuned on (no 'split'); a report "
            "labels tuned methods by it: tune again with `bench tune`"
        )
    values = {}
    for fam, entry in data["families"].items():
        if not isinstance(entry, dict) or "setting" not in entry:
            raise ValueError(f"{path}: family {fam!r} has no 'setting'")
        values[fam] = entry["setting"]
    return Tuned(values, source, hashlib.sha256(raw).hexdigest(), data)


def check_tuned_split(tuned: Tuned, split: str | None) -> None:
    """Warn (:class:`~conformal_control.core.exceptions.TunedOnReportedSplitWarning`) when the
    split a run reports is the one the tuned values were chosen on (or None: every split).

    Parameters
    ----------
    tuned : Tuned
        The tuned values (:func:`load_tuned`), whose file says its split.
    split : str or None
        The split the run reports.
    """
    import warnings

    from ...core.exceptions import TunedOnReportedSplitWarning

    chosen_on = str(tuned.data.get("split"))
    if split is None or split == chosen_on:
        reported = "every split" if split is None else f"the {split} split"
        warnings.warn(
            f"the tuned values ({tuned.source}) were chosen on the {chosen_on} split and this "
            f"run reports {reported}: the tuned methods are not held out there (the report "
            f"labels them 'tuned on {chosen_on}')",
            TunedOnReportedSplitWarning,
            stacklevel=3,
        )


def plan_methods(
    families: Iterable[str],
    tuned: Tuned | None = None,
    grids: Mapping[str, Sequence[Any]] | None = None,
) -> list[Method]:
    """The methods to run: a family's ``grids`` entry if given, else its tuned setting (its
    whole tuning grid plus the tuned setting for a reference family), else its settings."""
    out: list[Method] = []
    grids = dict(grids or {})
    for fam in families:
        if fam in grids or fam not in FAMILIES or tuned is None or fam not in tuned.values:
            out.extend(expand_methods([fam], grids))
            continue
        f = FAMILIES[fam]
        value = tuned.values[fam]
        grid: list[Any] = [value]
        if f.reference and f.tune:
            grid = list(f.tune) + ([value] if value not in f.tune else [])
        out.extend(f.members(grid))
    return out


# ------------------------------------------------------------------ configurations
def _meta(
    suite: str, sc: Scenario, method: Method, crowd: str, shift: Shift, tuned: Tuned | None
) -> dict[str, Any]:
    return {
        "suite": suite,
        "scenario": sc.id,
        "split": sc.split,
        "source": sc.source,
        "recording": sc.recording,
        "time_limit": sc.time_limit_s,
        "method": method.name,
        "family": method.family,
        "setting": method.setting,
        "shift": shift.name,
        "crowd": crowd,
        "tuned_from": None if tuned is None else tuned.source,
        "n_crossing": sc.stats.get("n_crossing"),
        "corridor_density": sc.stats.get("corridor_density"),
        "crossing_speed": sc.stats.get("crossing_speed"),
        # suite scenes count time in frames: lambda in 1/frame = fps / s
        "lambda_unit_si": sc.fps,
    }


def bench_configs(
    suite: str,
    split: str | None,
    methods: Sequence[Method],
    *,
    predictor: str = "constant_velocity",
    predictor_params: Mapping[str, Any] | None = None,
    crowd: str = "replay",
    crowd_params: Mapping[str, Any] | None = None,
    data_root: str | None = None,
    seed: int = 0,
    scenarios: Iterable[str] | None = None,
    limit: int | None = None,
    base_params: Mapping[str, Any] | None = None,
    shifts: Sequence[Shift | str] = ("nominal",),
    tuned: Tuned | None = None,
) -> list[Any]:
    """The sweep's run configurations: one per (shift, scenario, method), shifts outermost.

    Parameters
    ----------
    suite : str
        A shipped suite (``conformal-control bench scenarios``).
    split : {"dev", "test"} or None
        None runs both.
    methods : sequence of Method
    predictor, predictor_params :
        The predictor every method uses (a method may replace it, e.g. the oracle).
    crowd, crowd_params :
        Replayed pedestrians or a reactive crowd (see ``run --crowd``).
    data_root : str, optional
        The data folder.
    seed : int
        The runs' seed.
    scenarios : iterable of str, optional
        Only these scenario ids.
    limit : int, optional
        Only the first ``limit`` scenarios of the split (quick looks, tests).
    base_params : mapping, optional
        Run parameters (SI) applied to every method; a method's own parameters win.
    shifts : sequence of Shift or str
        The predictor shifts (:mod:`conformal_control.experiments.bench.shifts`).
    tuned : Tuned, optional
        Recorded in every row (``tuned_from``).
    """
    from ..plan import SweepRun

    if limit is not None and (int(limit) != limit or limit < 1):
        raise ValueError(f"limit must be a positive number of scenarios, got {limit!r}")
    s = load_suite(suite)
    chosen = s.scenarios_for(split) if split else list(s.scenarios)
    if scenarios is not None:
        wanted = set(scenarios)
        unknown = sorted(wanted - {sc.id for sc in s.scenarios})
        if unknown:
            raise ValueError(f"unknown scenario(s) of {suite}: {', '.join(unknown[:5])}")
        chosen = [sc for sc in chosen if sc.id in wanted]
    if limit is not None:
        chosen = chosen[: int(limit)]
    if not chosen:
        raise ValueError(f"no scenario of suite {suite} matches (split={split!r})")
    shift_list = [get_shift(x) if isinstance(x, str) else x for x in shifts]
    name = s.name
    configs = []
    for shift in shift_list:
        for sc in chosen:
            if not shift.covers(sc.recording):
                continue
            for m in methods:
                kw = m.run_kwargs(predictor)
                own = m.predictor is None
                pred, pred_params = shift.predictor_for(
                    kw["predictor"], predictor_params if own else None, data_root
                )
                episode = {
                    k: v
                    for k, v in kw.items()
                    if k not in ("predictor", "params", "learn", "predictor_params")
                }
                if crowd != "replay":
                    episode["crowd"] = crowd
                    if crowd_params:
                        episode["crowd_params"] = dict(crowd_params)
                episode["record_animation"] = False
                shown = "" if shift.name == "nominal" else f"{shift.name}-"
                configs.append(
                    SweepRun.from_settings(
                        f"scenario:{name}/{sc.id}",
                        {**dict(base_params or {}), **dict(kw["params"])},
                        data_root=data_root,
                        label=f"{shown}{sc.id}-{m.name}",
                        meta=_meta(name, sc, m, crowd, shift, tuned),
                        predictor=pred,
                        predictor_params=pred_params or {},
                        learn=kw["learn"],
                        seed=seed,
                        **episode,
                    )
                )
    if not configs:
        raise ValueError(
            f"no scenario of suite {suite} (split={split!r}) is covered by the shifts "
            f"{', '.join(s.name for s in shift_list)}"
        )
    return configs


# ------------------------------------------------------------------ the folder
class _BenchLock:
    """``OUT/.bench.lock``: one ``bench run`` (or ``tune``) at a time per folder (the
    sweep's own lock, on ``OUT/.lock``, is taken later, by the sweep)."""

    def __init__(self, out: Path) -> None:
        from ..lock import SweepLock

        self._lock = SweepLock(out)
        self._lock.path = out / ".bench.lock"
        self.out = out

    def __enter__(self) -> _BenchLock:
        from ..lock import SweepLockedError

        try:
            self._lock.acquire()
        except SweepLockedError as exc:
            owner = exc.owner
            who = f"PID {owner.get('pid', 'unknown')}" + (
                f" on {owner['host']}" if owner.get("host") else ""
            )
            raise BenchFolderError(
                f"{self.out} is in use by another bench run ({who}); wait for it to finish, "
                "stop it, or use another --out folder"
            ) from None
        return self

    def __exit__(self, *exc: object) -> None:
        self._lock.release()


def read_bench(out: str | Path) -> dict[str, Any] | None:
    """The folder's ``bench.json`` (None if there is none)."""
    path = Path(out) / "bench.json"
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise BenchFolderError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise BenchFolderError(f"{path}: expected a JSON object")
    return data


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, default=str)


def _merged_description(out: Path, new: dict[str, Any]) -> dict[str, Any]:
    """``new`` merged into the folder's ``bench.json``, or :class:`BenchFolderError` if the
    folder holds runs of another condition."""
    old = read_bench(out)
    if old is None:
        return new
    if "tuned_sha256" not in old and "suite" in old:  # written before conditions existed
        old = {**old, "tuned_sha256": None, "predictor_params": old.get("predictor_params")}
    differ = [k for k in CONDITION_KEYS if _canonical(old.get(k)) != _canonical(new.get(k))]
    if differ:
        shown = "; ".join(
            f"{k}: folder {_canonical(old.get(k))}, this run {_canonical(new.get(k))}"
            for k in differ
        )
        raise BenchFolderError(
            f"{out} holds benchmark runs of another condition ({shown}); runs of different "
            "conditions are never pooled: use another --out folder"
        )
    before = {m.get("method"): m for m in old.get("methods", []) if isinstance(m, dict)}
    for m in new["methods"]:
        prev = before.get(m["method"])
        if prev is None:
            continue
        # what runs (the description is prose: a reworded one defines the same method)
        fields = [
            k for k in m if k != "description" and _canonical(prev.get(k)) != _canonical(m[k])
        ]
        if fields:
            shown = "; ".join(
                f"{k}: folder {_canonical(prev.get(k))}, this run {_canonical(m[k])}"
                for k in fields
            )
            raise BenchFolderError(
                f"{out}: method {m['method']} is defined differently from the runs the folder "
                f"holds ({shown}); runs of different definitions are never pooled: use "
                "another --out folder"
            )
    merged = dict(new)
    seen = {m["method"] for m in new["methods"]}
    merged["methods"] = new["methods"] + [
        m for m in old.get("methods", []) if m["method"] not in seen
    ]
    merged["shifts"] = list(dict.fromkeys([*old.get("shifts", []), *new["shifts"]]))
    merged["unavailable"] = {**old.get("unavailable", {}), **new["unavailable"]}
    limits = [old.get("limit"), new.get("limit")]
    merged["limit"] = None if None in limits else max(x for x in limits if x is not None)
    merged["wall_s"] = old.get("wall_s", 0.0)
    return merged


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as indented JSON to ``path`` atomically (a temporary name, renamed)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str) + "\n")
    tmp.replace(path)


@dataclass
class BenchRun:
    """What :func:`run_bench` did (the sweep's report and where the rows are)."""

    out_dir: Path
    n_runs: int
    skipped: int
    ran: int
    failed: int
    unavailable: dict[str, str]
    wall_s: float
    #: episodes the infrastructure lost (not failures of a method; a rerun finishes them)
    unfinished: int = 0
    #: what failed, one line per distinct reason
    infrastructure: tuple[str, ...] = ()

    def summary(self) -> str:
        extra = ""
        if self.unavailable:
            extra = "; methods left out (plugin unavailable): " + ", ".join(self.unavailable)
        if self.unfinished:
            why = self.infrastructure[0] if self.infrastructure else "the executor failed"
            extra += (
                f"; {self.unfinished} left unfinished, not failed: the infrastructure failed "
                f"({why}); run the same command again to finish them before `bench report`"
            )
        return (
            f"{self.n_runs} episodes: {self.skipped} already done, {self.ran} ran "
            f"({self.failed} failed) in {self.wall_s:.1f} s; results in {self.out_dir}{extra}"
        )


def bench_base(
    base: RunSpec | None,
) -> tuple[str, dict[str, Any], str, dict[str, Any], int, dict[str, Any]]:
    """What a benchmark takes from its base run specification: ``(predictor, its params,
    crowd, its params, seed, parameters)``.

    The methods set everything else (rule, roles, learning), so a base that sets more is a
    one-line error rather than silently overridden; its parameters are SI
    (``units="si"``), as every method's.

    Parameters
    ----------
    base : RunSpec, optional
        None: the constant-velocity predictor, the replayed crowd, seed 0, no parameters.
    """
    from ...core.spec import RunSpec

    if base is None:
        return "constant_velocity", {}, "replay", {}, 0, {}
    if not isinstance(base, RunSpec):
        raise InputError(f"base must be a RunSpec, got {type(base).__name__}")
    kept = RunSpec(
        params=base.params,
        predictor=base.predictor,
        crowd=base.crowd,
        seed=base.seed,
        units=base.units,
    )
    extra = [
        f
        for f in RunSpec.__dataclass_fields__
        if f != "units" and getattr(base, f) != getattr(kept, f)
    ]
    if extra:
        raise InputError(
            f"a benchmark's base run sets only its predictor, crowd, seed and parameters "
            f"(the methods set the rest); drop {', '.join(extra)}"
        )
    if base.params and base.units != "si":
        raise InputError("a benchmark's base parameters are SI: RunSpec(units='si', ...)")
    predictor, predictor_params = base.role("predictor")
    crowd, crowd_params = base.role("crowd")
    if not isinstance(predictor, str) or not isinstance(crowd, str):
        raise InputError("a benchmark's base predictor and crowd are registered names")
    return predictor, predictor_params, crowd, crowd_params, base.seed, dict(base.params)


def run_bench(
    out: str | Path,
    *,
    suite: str = DEFAULT_SUITE,
    split: str | None = "test",
    methods: Sequence[str] = DEFAULT_METHODS,
    grids: Mapping[str, Sequence[Any]] | None = None,
    shifts: Sequence[str] = ("nominal",),
    tuned: str | Path | None = "default",
    base: RunSpec | None = None,
    data_root: str | None = None,
    executor: str = "batch",
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool | None = None,
    limit: int | None = None,
) -> BenchRun:
    """Run the benchmark into ``out`` (resumable: finished episodes are skipped).

    Methods whose plugins are not installed are left out and reported (never silently).
    ``bench.json`` in ``out`` records the benchmark's configuration and condition.

    Parameters
    ----------
    out : path
        The benchmark folder (reused to resume).
    suite : str
        A shipped suite (``conformal-control bench scenarios``).
    split : {"dev", "test"} or None
        None runs both.
    methods : sequence of str
        Method families (:data:`~conformal_control.experiments.bench.methods.FAMILIES`).
    grids : mapping, optional
        A family's settings to run instead of its tuned value or its default settings.
    shifts : sequence of str
        Names of :data:`~conformal_control.experiments.bench.shifts.SHIFTS`.
    tuned : path, "default" or None
        The tuned values (see the module docstring).
    base : RunSpec, optional
        What every method runs with (:func:`bench_base`): the predictor (a method may
        replace it, e.g. the oracle) and its parameters, the crowd (replayed, or reacting
        to the robot) and its parameters, the seed, and run parameters in SI (a method's
        own win). Default: constant velocity, the replayed crowd, seed 0.
    data_root : str, optional
        The data folder.
    executor : {"batch", "process", "serial", "dask"}
        ``"batch"`` (default) runs the (scenario, method) pairs the lockstep engine
        supports many at once in this process, with the metrics of the per-episode loop,
        and the others on a process pool of ``workers`` (see
        :mod:`conformal_control.experiments.batch`); the others run one episode per task.
    workers : int, optional
        Worker processes (default: the CPUs available).
    scheduler : str, optional
        A Dask scheduler's address (``executor="dask"``).
    progress : bool, optional
        False: no progress report; otherwise a bar on a terminal, periodic lines where
        the output is redirected (:func:`~conformal_control.experiments.runner.run_sweep`).
    limit : int, optional
        Only the first ``limit`` scenarios of the split.

    Raises
    ------
    BenchFolderError
        ``out`` is in use by another ``bench run``, or holds runs of another condition.
    """
    from ..runner import run_sweep

    predictor, predictor_params, crowd, crowd_params, seed, base_params = bench_base(base)
    out = Path(out)
    if workers is not None and (int(workers) != workers or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    shift_list = [get_shift(s) for s in shifts]
    tuned_values = load_tuned(tuned, suite)
    all_methods = plan_methods(methods, tuned_values, grids)
    unavailable = {m.name: why for m in all_methods if (why := available(m)) is not None}
    chosen = [m for m in all_methods if m.name not in unavailable]
    if not chosen:
        raise ValueError("no method can run: " + "; ".join(unavailable.values()))
    configs = bench_configs(
        suite,
        split,
        chosen,
        predictor=predictor,
        predictor_params=predictor_params,
        crowd=crowd,
        crowd_params=crowd_params,
        data_root=data_root,
        seed=seed,
        limit=limit,
        base_params=base_params,
        shifts=shift_list,
        tuned=tuned_values,
    )
    description: dict[str, Any] = {
        "suite": suite,
        "split": split,
        "predictor": predictor,
        "predictor_params": dict(predictor_params or {}) or None,
        "crowd": crowd,
        "crowd_params": dict(crowd_params or {}),
        "base_params": dict(base_params or {}),
        "seed": seed,
        "tuned_sha256": None if tuned_values is None else tuned_values.sha256,
        "tuned": None if tuned_values is None else tuned_values.describe(),
        "shifts": [s.name for s in shift_list],
        "shift_table": {s.name: s.as_dict() for s in SHIFTS.values()},
        "methods": [m.as_dict() for m in chosen],
        "unavailable": unavailable,
        "limit": limit,
    }
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with _BenchLock(out):
        description = _merged_description(out, description)
        if tuned_values is not None:  # once the folder took the run
            check_tuned_split(tuned_values, split)
        write_json(out / "bench.json", description)
        rep = run_sweep(
            configs,
            out,
            executor,
            workers=workers,
            scheduler=scheduler,
            plot=RUN_FILES,
            summary_plot=False,
            progress=progress,
            # the journal has every episode as it finishes (reports read it); the tables,
            # rewritten whole, three times over the run and at its end (ten times cost 7 %
            # of a profiled run's main process)
            table_every=max(200, len(configs) // 3),
        )
        wall = time.perf_counter() - t0
        description["wall_s"] = float(description.get("wall_s") or 0.0) + wall
        description["last_run"] = {
            "episodes": len(configs),
            "ran": len(rep.ran),
            "wall_s": wall,
            "finished": time.strftime("%Y-%m-%d %H:%M:%S"),
        }
        write_json(out / "bench.json", description)
    return BenchRun(
        out_dir=out,
        n_runs=len(configs),
        skipped=len(rep.skipped),
        ran=len(rep.ran),
        failed=len(rep.failed),
        unavailable=unavailable,
        wall_s=wall,
        unfinished=len(rep.unfinished),
        infrastructure=tuple(rep.infrastructure),
    )


def unfinished_episodes(out: str | Path, *, done: Iterable[str] | None = None) -> tuple[int, int]:
    """``(planned, unfinished)``: the episodes the folder's last ``bench run`` (or ``bench
    tune``) planned (its ``sweep.json``), and how many of them have no record in the
    journal (left unfinished by a lost scheduler or worker, or a stopped run). A failed
    episode has its record: it is data, not unfinished.

    Parameters
    ----------
    out : str or Path
        The benchmark folder.
    done : iterable of str, optional
        The keys of the journal's records, if the caller has read them already (the rows of
        :func:`read_rows`): the journal is then not parsed a second time.
    """
    from ..results import ResultsStore

    out = Path(out)
    try:
        planned = json.loads((out / "sweep.json").read_text()).get("runs") or []
        keys = {str(r["key"]) for r in planned if isinstance(r, dict) and "key" in r}
    except (OSError, ValueError, AttributeError, TypeError):
        return 0, 0  # no plan to compare with
    recorded = set(ResultsStore(out).latest()) if done is None else set(done)
    return len(keys), len(keys - recorded)


def incomplete_notice(planned: int, unfinished: int, command: str = "bench run") -> str | None:
    """The first line of a report over a folder with unfinished episodes (None if none).

    Parameters
    ----------
    planned, unfinished : int
        From :func:`unfinished_episodes`.
    command : str
        The command that finishes them.
    """
    if not unfinished:
        return None
    return (
        f"**INCOMPLETE: {unfinished:,} of the {planned:,} episodes of this folder's last "
        f"`{command}` have not finished** (the infrastructure lost them, or the run was "
        f"stopped): every figure below is over the {planned - unfinished:,} that did, not "
        f"the benchmark; rerun the same `{command}` to finish them."
    )


def read_rows(out: str | Path) -> list[dict[str, Any]]:
    """The stored per-episode rows of a benchmark folder (the latest record of each run)."""
    from ..results import ResultsStore

    out = Path(out)
    if not (out / "results.jsonl").exists():
        raise FileNotFoundError(f"{out} holds no benchmark results (no results.jsonl)")
    return ResultsStore(out).rows(absolute=True)
