"""``fcp-planar-dense``: the ETH/UCY planar protocol with a start every few steps.

The published protocol (:mod:`~conformal_control.experiments.bench.planar`, ``fcp-planar``) has 13
scenarios, one to three per recording: too few to put an interval on a collision rate or to
separate two methods. This suite keeps everything of that protocol (the five recordings, eth's
published time base, the robot, radii, limits, warm-up, goal tolerance, step limits, metrics,
and each dataset's start pose and goal) and only adds start time steps, by a rule
(:data:`RULE`):

* every :data:`STRIDE` (20) time steps, on the multiples of 20, from the first start whose
  scenario has :data:`~conformal_control.experiments.bench.planar.HISTORY_SAMPLES` samples of
  history
  to the last whose scenario (its step limit of protocol steps, then the plan's 12 steps of
  truth) ends within the recording;
* split by time: a dataset's **boundary** is the middle time step of its starts' range; a
  scenario is ``dev`` when it (its last step and the 12 steps after) ends before the
  boundary, ``test`` when it starts at or after it. Scenarios straddling the boundary are in
  neither. univ's one recording is too short for two parts (a scenario of 300 steps): all
  its scenarios are ``test``.

The task list is shipped (``planar_manifests/fcp-planar-dense.json``) and regenerated from
the data by :func:`generate_manifest` (a test compares the bytes). Methods are tuned on
``dev``, reported on ``test``; :func:`dense_report` gives per dataset and method the mean of
every metric over scenarios with a bootstrap 95 % interval (seeds averaged per scenario
first), and paired comparisons over the same scenarios
(:mod:`~conformal_control.experiments.bench.stats`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .planar import HISTORY_SAMPLES, TASKS, PlanarTask, recording
from .planar_fcp import scenario_samples
from .stats import bootstrap_mean, paired_comparison

__all__ = [
    "RULE",
    "STRIDE",
    "SUITE",
    "dense_report",
    "dense_tasks",
    "dump_manifest",
    "generate_manifest",
    "load_manifest",
]

SUITE = "fcp-planar-dense"
#: Time steps between two starts.
STRIDE = 20
#: Steps of truth needed after a scenario's last step (the plan's horizon).
TAIL_STEPS = 12
#: The generation rule, written into the manifest.
RULE = (
    f"start time steps on the multiples of {STRIDE}, from the first with "
    f"{HISTORY_SAMPLES} samples of history to the last whose scenario (max_steps protocol "
    f"steps, then {TAIL_STEPS} steps of truth) ends within the recording; split at the middle "
    "time step of that range (the boundary): dev = scenarios ending (with the "
    f"{TAIL_STEPS} steps) before it, test = scenarios starting at or after it; univ: all test"
)
#: Datasets without a dev part (a recording too short for two).
TEST_ONLY = ("univ",)


def _starts(task: PlanarTask, data_root: str | Path | None) -> list[tuple[int, int, int]]:
    """``(timestep, first sample, last sample + tail)`` of every start the rule allows."""
    rec = recording(task, data_root)
    off = task.frame_offset // 10
    n = rec.positions.shape[0]
    out = []
    first_ts = HISTORY_SAMPLES - 1 + rec.first - off
    ts = int(math.ceil(first_ts / STRIDE) * STRIDE)
    while True:
        i0 = rec.sample(ts, task.frame_offset)
        if i0 >= n:
            break
        _, last = scenario_samples(rec, i0, task.max_steps)
        end = last + TAIL_STEPS
        if end <= n - 1 and last - i0 + 1 >= task.max_steps:
            out.append((ts, i0, end))
        ts += STRIDE
    return out


def generate_manifest(data_root: str | Path | None = None) -> dict[str, Any]:
    """The suite's tasks, from the recordings by :data:`RULE`.

    Parameters
    ----------
    data_root : str or Path, optional
        The data folder.
    """
    datasets: dict[str, Any] = {}
    for name, task in TASKS.items():
        starts = _starts(task, data_root)
        if not starts:
            raise ValueError(f"{name}: no start fits the rule")
        lo, hi = starts[0][0], starts[-1][0]
        boundary = (lo + hi) // 2
        off = task.frame_offset // 10
        rec = recording(task, data_root)
        if name in TEST_ONLY:
            dev, test = [], [s[0] for s in starts]
        else:
            b_sample = boundary + off - rec.first
            dev = [s[0] for s in starts if s[2] < b_sample]
            test = [s[0] for s in starts if s[0] >= boundary]
        datasets[name] = {
            "recording": task.recording,
            "frame_offset": task.frame_offset,
            "max_steps": task.max_steps,
            "init_pose": list(task.init_pose),
            "goal": list(task.goal),
            "boundary_timestep": boundary,
            "dev": dev,
            "test": test,
        }
    return {
        "suite": SUITE,
        "version": 1,
        "protocol": "fcp-planar",
        "rule": RULE,
        "datasets": datasets,
    }


def dump_manifest(manifest: Mapping[str, Any]) -> str:
    """The manifest's text as shipped (sorted keys, one-space indent, final newline)."""
    return json.dumps(manifest, indent=1, sort_keys=True) + "\n"


def load_manifest() -> dict[str, Any]:
    """The shipped manifest."""
    path = resources.files("conformal_control.experiments.bench") / "planar_manifests"
    path = path / f"{SUITE}.json"
    out: dict[str, Any] = json.loads(path.read_text())
    return out


def dense_tasks(split: str = "test") -> dict[str, PlanarTask]:
    """The suite's tasks of a split (``dev``, ``test`` or ``all``), one
    :class:`~conformal_control.experiments.bench.planar.PlanarTask` per dataset with the split's
    starts (datasets without any left out).

    Parameters
    ----------
    split : {"dev", "test", "all"}
        Which part.
    """
    if split not in ("dev", "test", "all"):
        raise ValueError(f"split must be dev, test or all, got {split!r}")
    out = {}
    for name, spec in load_manifest()["datasets"].items():
        starts = spec["dev"] + spec["test"] if split == "all" else spec[split]
        b = int(spec["boundary_timestep"])
        part: tuple[int, int] | None = None
        if split != "all" and spec["dev"]:  # a dataset with two parts
            part = (-(10**9), b - 1) if split == "dev" else (b, 10**9)
        if starts:
            out[name] = PlanarTask(
                dataset=name,
                recording=spec["recording"],
                start_timesteps=tuple(int(s) for s in starts),
                frame_offset=int(spec["frame_offset"]),
                max_steps=int(spec["max_steps"]),
                init_pose=(*(float(v) for v in spec["init_pose"]),),  # type: ignore[arg-type]
                goal=(float(spec["goal"][0]), float(spec["goal"][1])),
                part=part,
            )
    return out


# ------------------------------------------------------------------------------ report
#: The metrics reported with intervals (lower is better for each).
DENSE_METRICS = ("collision_rate", "infeasible_rate", "steps_to_goal", "reached")


def per_scenario(
    rows: Sequence[Mapping[str, Any]],
) -> dict[tuple[str, str, str], dict[int, dict[str, float]]]:
    """(dataset, method, predictor) -> start -> each metric averaged over the seeds."""
    acc: dict[tuple[str, str, str], dict[int, list[Mapping[str, Any]]]] = {}
    for r in rows:
        key = (str(r["dataset"]), str(r["method"]), str(r["predictor"]))
        acc.setdefault(key, {}).setdefault(int(r["start_timestep"]), []).append(r)
    out: dict[tuple[str, str, str], dict[int, dict[str, float]]] = {}
    for key, by_start in acc.items():
        out[key] = {}
        for start, rs in by_start.items():
            vals: dict[str, float] = {}
            for m in DENSE_METRICS:
                xs = [float(r[m]) for r in rs if r.get("n_recorded", 1) > 0]
                xs = [x for x in xs if math.isfinite(x)]
                vals[m] = float(np.mean(xs)) if xs else math.nan
            out[key][start] = vals
    return out


def dense_report(
    rows: Sequence[Mapping[str, Any]],
    baseline: str = "mpc",
    reference: str = "oracle_mpc",
) -> tuple[str, list[dict[str, Any]]]:
    """Per dataset and method: every metric's mean over scenarios with its bootstrap 95 %
    interval; each method paired with ``baseline`` (the fixed-margin MPC) and with
    ``reference`` (the oracle) over the scenarios both ran. With several datasets, the
    same over all their scenarios pooled (dataset ``all``). Returns the markdown and the
    rows.

    Parameters
    ----------
    rows : sequence of mappings
        :func:`~conformal_control.experiments.bench.planar.run_planar`'s rows.
    baseline : str
        The method every other is paired with first.
    reference : str
        The oracle row (how far each method trails it).
    """
    data: dict[tuple[str, str, str], dict[Any, dict[str, float]]] = dict(per_scenario(rows))
    pooled: dict[tuple[str, str, str], dict[Any, dict[str, float]]] = {}
    for (ds, method, pred), by_start in data.items():
        into = pooled.setdefault(("all", method, pred), {})
        into.update({(ds, start): v for start, v in by_start.items()})
    if len({k[0] for k in data}) > 1:
        data.update(pooled)
    lines = [
        "| dataset | method | predictor | scenarios | collision rate | reached | "
        "infeasible rate | steps to goal |",
        "|---|---|---|---|---|---|---|---|",
    ]
    table: list[dict[str, Any]] = []
    paired: list[str] = [
        "| dataset | method | predictor | against | metric | wins/losses/ties | "
        "mean difference [95 % CI] |",
        "|---|---|---|---|---|---|---|",
    ]
    datasets = list(dict.fromkeys(k[0] for k in data))
    for ds in datasets:
        for (d, method, pred), by_start in data.items():
            if d != ds:
                continue
            starts = sorted(by_start)
            est = {m: bootstrap_mean([by_start[s][m] for s in starts]) for m in DENSE_METRICS}
            table.append(
                {"dataset": ds, "method": method, "predictor": pred, "n": len(starts)}
                | {m: e.mean for m, e in est.items()}
                | {f"{m}_low": e.low for m, e in est.items()}
                | {f"{m}_high": e.high for m, e in est.items()}
            )
            lines.append(
                f"| {ds} | {method} | {pred} | {len(starts)} | "
                f"{est['collision_rate'].format(3)} | {est['reached'].format(3, percent=True)} | "
                f"{est['infeasible_rate'].format(3)} | {est['steps_to_goal'].format(3)} |"
            )
            for other in (baseline, reference):
                if other == method:
                    continue
                base = data.get((ds, other, pred)) or _any_predictor(data, ds, other)
                if base is None:
                    continue
                common = [s for s in starts if s in base]
                for m in ("collision_rate", "reached", "steps_to_goal"):
                    c = paired_comparison(
                        [by_start[s][m] for s in common],
                        [base[s][m] for s in common],
                        metric=m,
                        lower_is_better=m != "reached",
                    )
                    pct = m == "reached"
                    paired.append(
                        f"| {ds} | {method} | {pred} | {other} | {m} | "
                        f"{c.wins}/{c.losses}/{c.ties} | {c.difference.format(3, percent=pct)} |"
                    )
    text = "\n".join(lines) + "\n\nPaired (same scenarios):\n\n" + "\n".join(paired) + "\n"
    return text, table


def _any_predictor(
    data: Mapping[tuple[str, str, str], dict[Any, dict[str, float]]], ds: str, method: str
) -> dict[Any, dict[str, float]] | None:
    """A method's scenarios under whatever predictor it ran (the oracle's own)."""
    for (d, m, _), v in data.items():
        if d == ds and m == method:
            return v
    return None


# ------------------------------------------------------------------------------ commands
def is_dense_folder(folder: str | Path) -> bool:
    """Whether ``folder`` holds a run of this suite."""
    cfg = Path(folder) / "config.json"
    if not cfg.is_file():
        return False
    try:
        return bool(json.loads(cfg.read_text()).get("suite") == SUITE)
    except (ValueError, AttributeError):
        return False


def tasks_of(folder: str | Path) -> dict[str, PlanarTask]:
    """The tasks a run's ``config.json`` records."""
    cfg = json.loads((Path(folder) / "config.json").read_text())
    out = {}
    for name, spec in cfg["protocol"]["datasets"].items():
        out[name] = PlanarTask(
            dataset=name,
            recording=spec["recording"],
            start_timesteps=tuple(int(s) for s in spec["start_timesteps"]),
            frame_offset=int(spec["frame_offset"]),
            max_steps=int(spec["max_steps"]),
            init_pose=(*(float(v) for v in spec["init_pose"]),),  # type: ignore[arg-type]
            goal=(float(spec["goal"][0]), float(spec["goal"][1])),
            part=None if spec.get("part") is None else (int(spec["part"][0]), int(spec["part"][1])),
        )
    return out


def write_dense_report(
    rows: Sequence[Mapping[str, Any]], tasks: Mapping[str, PlanarTask], out: str | Path
) -> dict[str, Path]:
    """``dense.md`` (intervals and paired comparisons, then the protocol's table with the
    seeds' ranges) and ``dense.csv``."""
    import csv

    from .planar import METRICS, planar_table

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    text, table = dense_report(rows)
    plain, _ = planar_table(rows, tasks)
    defs = "\n".join(f"- **{k}**: {v}" for k, v in METRICS.items())
    md = folder / "dense.md"
    md.write_text(
        f"# {SUITE}: means over scenarios with bootstrap 95 % intervals\n\n{text}\n"
        f"## Per dataset, as the protocol's table (seeds' range)\n\n{plain}\n"
        f"Metric definitions:\n\n{defs}\n"
    )
    path = folder / "dense.csv"
    keys = list(table[0]) if table else ["dataset", "method", "predictor", "n"]
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        for r in table:
            w.writerow(r)
    return {"markdown": md, "csv": path}


def run_command(
    out: str,
    methods: str | None,
    predictor: str | None,
    data_root: str | None,
    datasets: str | None = None,
    seeds: str | None = None,
    split: str = "test",
) -> int:
    """``bench run --suite fcp-planar-dense``: run a split, write the folder and report.

    Parameters
    ----------
    out : str
        The output folder.
    methods : str, optional
        Comma-separated planar methods (None: all).
    predictor : str, optional
        Comma-separated predictors (None: ``recorded,constant_velocity``).
    data_root : str, optional
        The data folder.
    datasets : str, optional
        Comma-separated datasets (None: all of the split).
    seeds : str, optional
        Comma-separated random states (None: 0).
    split : {"dev", "test", "all"}
        Which part.
    """
    from .planar import run_planar

    tasks = dense_tasks(split)
    try:
        seed_list = [int(v) for v in (seeds or "0").split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"--seeds takes comma-separated integers, got {seeds!r}") from None
    preds = [p.strip() for p in (predictor or "recorded,constant_velocity").split(",") if p]
    rows = run_planar(
        out,
        methods=[m.strip() for m in methods.split(",") if m.strip()] if methods else None,
        predictors=preds,
        datasets=[d.strip() for d in datasets.split(",") if d.strip()] if datasets else None,
        data_root=data_root,
        seeds=seed_list,
        tasks=tasks,
        suite=SUITE,
        progress=lambda line: print(line, flush=True),
    )
    files = write_dense_report(rows, tasks, Path(out) / "report")
    print(files["markdown"].read_text())
    return 0


def report_command(folder: str, out: str | None) -> int:
    """``bench report FOLDER`` for a folder of this suite."""
    from .planar import read_planar_rows

    rows = read_planar_rows(folder)
    files = write_dense_report(rows, tasks_of(folder), out or Path(folder) / "report")
    print(files["markdown"].read_text())
    print("wrote " + ", ".join(str(f) for f in files.values()))
    return 0
