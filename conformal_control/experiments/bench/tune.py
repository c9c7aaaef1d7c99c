"""``bench tune``: each method family's setting chosen on the dev split by one stated rule.

Every tuned family (:attr:`~conformal_control.experiments.bench.methods.Family.tune` non-empty)
runs its
tuning grid on the suite's dev split under the nominal predictor; :data:`RULE` picks one
setting per family from the rows alone (:func:`choose`), and :func:`tune` writes
``tuned.json``: the chosen settings, every candidate's figures, the rule, the suite, split,
predictor and number of scenarios, and the time it took. ``bench run`` uses these values by
default (the package ships the ones chosen on ``crossings-v2``'s dev split) and records
where they came from.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ... import __version__
from ...core.spec import RunSpec
from .methods import FAMILIES
from .suite import DEFAULT_SUITE, BenchFolderError, read_rows, run_bench, write_json

__all__ = ["DEFAULT_TUNED", "RULE", "TuneResult", "choose", "tune"]

#: The families ``bench tune`` tunes by default (those ``bench run`` runs by default).
DEFAULT_TUNED = ("fixed", "conformal", "acp", "inflated", "conformal_dtaci_floor")

#: The one rule that picks a family's setting.
RULE = (
    "highest success rate (goal reached in time, no collision frame) on the tuning split; "
    "ties: fewer collision frames per scenario, then shorter mean time to goal (the time "
    "limit when not reached), then the setting listed first in the family's grid"
)


def _num(v: Any) -> float:
    if v is None or v == "":
        return math.nan
    if isinstance(v, str):
        low = v.strip().lower()
        if low in ("true", "false"):
            return float(low == "true")
        try:
            return float(v)
        except ValueError:
            return math.nan
    return float(v)


def _figures(rows: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    ok = [r for r in rows if str(r.get("status", "ok")) == "ok"]
    n = len(ok)
    if n == 0:
        return {"n": 0, "success": math.nan, "collision_frames": math.nan, "time": math.nan}
    t = []
    for r in ok:
        reached = _num(r.get("goal_reached")) == 1.0
        t.append(_num(r.get("t_goal")) if reached else _num(r.get("time_limit")))
    return {
        "n": n,
        "n_failed": len(rows) - n,
        "success": sum(_num(r.get("success")) for r in ok) / n,
        "reached": sum(_num(r.get("goal_reached")) for r in ok) / n,
        "collision_frames": sum(_num(r.get("n_collide")) for r in ok) / n,
        "time": sum(t) / n,
    }


def choose(
    rows: Sequence[Mapping[str, Any]], family: str, grid: Sequence[Any]
) -> tuple[Any, list[dict[str, Any]]]:
    """The setting :data:`RULE` picks for ``family`` among ``grid``, from the rows (those of
    the family whose ``setting`` label matches), and every candidate's figures.

    Raises
    ------
    ValueError
        If no candidate has a successful episode.
    """
    fam = FAMILIES[family]
    candidates = []
    for i, value in enumerate(grid):
        label = fam.method(value).setting
        mine = [r for r in rows if r.get("family") == family and r.get("setting") == label]
        fig = _figures(mine)
        candidates.append({"setting": value, "label": label, **fig, "_order": i})
    valid = [c for c in candidates if c["n"] > 0]
    if not valid:
        raise ValueError(f"no episode of family {family!r} to tune it on")
    best = min(valid, key=lambda c: (-c["success"], c["collision_frames"], c["time"], c["_order"]))
    for c in candidates:
        c.pop("_order")
    return best["setting"], candidates


@dataclass
class TuneResult:
    """What :func:`tune` chose and wrote."""

    path: Path
    values: dict[str, Any]
    data: dict[str, Any]

    def summary(self) -> str:
        lines = [f"tuned on {self.data['suite']} {self.data['split']} ({RULE}):"]
        for fam, entry in self.data["families"].items():
            c = next(x for x in entry["candidates"] if x["setting"] == entry["setting"])
            lines.append(
                f"  {fam}: {entry['label']} (success {100 * c['success']:.1f} %, "
                f"{c['collision_frames']:.2f} collision frames per scenario, n={c['n']})"
            )
        lines.append(f"wrote {self.path} in {self.data['wall_s']:.1f} s")
        return "\n".join(lines)


def tune(
    out: str | Path,
    *,
    suite: str = DEFAULT_SUITE,
    split: str = "dev",
    families: Sequence[str] = DEFAULT_TUNED,
    predictor: str = "constant_velocity",
    data_root: str | None = None,
    executor: str = "batch",
    workers: int | None = None,
    progress: bool | None = None,
    limit: int | None = None,
    seed: int = 0,
    base_params: Mapping[str, Any] | None = None,
) -> TuneResult:
    """Run every family's tuning grid on ``split`` and write ``out/tuned.json``.

    Parameters
    ----------
    out : str or Path
        The folder of the tuning runs and ``tuned.json``.
    suite : str
        A shipped suite.
    split : str
        The split tuned on (``dev``).
    families : sequence of str
        Methods with a tuning grid.
    predictor : str
        The predictor every method uses.
    data_root : str, optional
        The data folder.
    executor : {"batch", "process", "serial", "dask"}
        As for :func:`~conformal_control.experiments.bench.suite.run_bench`.
    workers : int, optional
        Worker processes (default: the CPUs available).
    progress : bool, optional
        False: no progress report; otherwise a bar on a terminal, periodic lines where
        the output is redirected (:func:`~conformal_control.experiments.runner.run_sweep`).
    limit : int, optional
        Only the first ``limit`` scenarios of the split.
    seed : int
        The runs' seed.
    base_params : mapping, optional
        Run parameters (SI) applied to every method.

    Raises
    ------
    ValueError
        For a family without a tuning grid, or an unknown one.
    """
    for fam in families:
        if fam not in FAMILIES:
            raise ValueError(f"unknown method {fam!r}; known: {', '.join(FAMILIES)}")
        if not FAMILIES[fam].tune:
            raise ValueError(f"method {fam!r} has no setting to tune")
    out = Path(out)
    t0 = time.perf_counter()
    grids = {fam: list(FAMILIES[fam].tune) for fam in families}
    run = run_bench(
        out,
        suite=suite,
        split=split,
        methods=list(families),
        grids=grids,
        shifts=("nominal",),
        tuned=None,
        base=RunSpec(params=dict(base_params or {}), predictor=predictor, seed=seed, units="si"),
        data_root=data_root,
        executor=executor,
        workers=workers,
        progress=progress,
        limit=limit,
    )
    if run.unfinished:  # choosing on the episodes that came back would be another rule
        raise BenchFolderError(
            f"{run.unfinished} tuning episodes were left unfinished ({run.infrastructure[0]}); "
            f"run the same `bench tune` again to finish them: no tuned.json was written"
        )
    rows = [r for r in read_rows(out) if r.get("shift", "nominal") == "nominal"]
    chosen: dict[str, Any] = {}
    entries: dict[str, Any] = {}
    for fam in families:
        value, candidates = choose(rows, fam, grids[fam])
        chosen[fam] = value
        entries[fam] = {
            "setting": value,
            "label": FAMILIES[fam].method(value).setting,
            "meaning": FAMILIES[fam].meaning,
            "candidates": candidates,
        }
    n_scen = len({r.get("scenario") for r in rows})
    data = {
        "suite": suite,
        "split": split,
        "predictor": predictor,
        "shift": "nominal",
        "rule": RULE,
        "n_scenarios": n_scen,
        "limit": limit,
        "seed": seed,
        "base_params": dict(base_params or {}),
        "families": entries,
        "version": __version__,
        "command": (
            f"conformal-control bench tune --suite {suite} --split {split} "
            f"--methods {','.join(families)}" + (f" --limit {limit}" if limit else "")
        ),
        "wall_s": time.perf_counter() - t0,
        "episodes": run.n_runs,
        "finished": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    path = out / "tuned.json"
    write_json(path, data)
    return TuneResult(path, chosen, data)
