"""Run the paper's tables through the sweep runner and write tables, checks and figures.

Outputs in ``out``:

* ``sweep/`` - the sweep folder (one run directory per row x variant, ``results.*``);
  rerunning ``reproduce`` with the same ``out`` resumes it (finished runs are skipped);
* ``table1.md``/``table1.csv``, ``table2.md``/``table2.csv`` - our metrics beside the
  paper's, row by row, for both variants, with the checks;
* ``forms.md``/``forms.csv`` - Table II on nexus_4 from the raw annotations and from the
  TrajNet form (re-linked + interpolated), and the differences;
* ``figures/`` - per table and variant: robot paths over the reference image, lambda(t)
  and loss(t) per row; per table: l_avg against epsilon;
* ``summary.json`` - wall time, executor, predictor, check results.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import run_sweep
from ..executors import Executor
from ..plan import SweepRun
from .paper import PAPER_EDGE, PAPER_TABLES, VARIANTS, PaperRow, PaperTable, variant_a

__all__ = [
    "IDENTITY_TOL",
    "TARGETS",
    "ReproRow",
    "auto_executor",
    "plan",
    "reproduce",
]

#: Targets of ``conformal-control reproduce``.
TARGETS = ("table1", "table2", "forms")
#: Tolerance of the update-identity check.
IDENTITY_TOL = 1e-9
#: Tolerance of the oracle check: with the true future and lambda = 0 every gap is 0.
ORACLE_TOL = 1e-9
METRICS = ("t_goal", "n_collide", "d_min", "l_avg")


@dataclass
class ReproRow:
    """One planned run: which table/variant/row, its configuration, later its results."""

    target: str
    table: PaperTable
    variant: str
    row: PaperRow
    config: SweepRun
    form: str = ""
    result: dict[str, Any] = field(default_factory=dict)
    checks: dict[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> str:
        return self.config.key


def _config(
    table: PaperTable,
    row: PaperRow,
    variant: str,
    *,
    scene: str,
    predictor: str,
    predictor_params: dict[str, Any],
    data_root: str | None,
    frames: int | None,
    seed: int,
    label: str,
) -> SweepRun:
    params = {**table.base, **row.params, "a": variant_a(table, variant), **PAPER_EDGE}
    return SweepRun.from_settings(
        scene,
        params,
        data_root=data_root,
        label=label,
        predictor="oracle" if row.oracle else predictor,
        predictor_params={} if row.oracle else dict(predictor_params),
        learn=row.learn,
        seed=seed,
        max_frames=frames,
    )


def plan(
    targets: Sequence[str],
    *,
    predictor: str = "constant_velocity",
    predictor_params: dict[str, Any] | None = None,
    data_root: str | None = None,
    frames: int | None = None,
    seed: int = 0,
    variants: Sequence[str] = tuple(VARIANTS),
) -> list[ReproRow]:
    """Every run the targets need (``forms``: Table II, published variant, both forms).

    Parameters
    ----------
    targets : sequence of {"table1", "table2", "forms", "all"}
        What to reproduce.
    predictor : str
        A registered predictor.
    predictor_params : dict, optional
        Its parameters.
    data_root : str, optional
        The data folder.
    frames : int, optional
        Simulate at most this many frames per run.
    seed : int
        The runs' seed.
    variants : sequence of {"printed", "published"}
        The parameter variants.
    """
    out: list[ReproRow] = []
    kw: dict[str, Any] = {
        "predictor": predictor,
        "predictor_params": dict(predictor_params or {}),
        "data_root": data_root,
        "frames": frames,
        "seed": seed,
    }
    for target in targets:
        if target not in TARGETS:
            raise ValueError(f"unknown target {target!r}; use {', '.join(TARGETS)} or all")
        if target in PAPER_TABLES:
            table = PAPER_TABLES[target]
            for variant in variants:
                for row in table.rows:
                    label = f"{table.name}-{variant}-{row.label}"
                    cfg = _config(table, row, variant, scene=table.scene, label=label, **kw)
                    out.append(ReproRow(target, table, variant, row, cfg))
        else:  # forms
            table = PAPER_TABLES["table2"]
            for form in ("raw", "trajnet"):
                for row in table.rows:
                    label = f"forms-{form}-{row.label}"
                    cfg = _config(
                        table, row, "published", scene=f"nexus_4:{form}", label=label, **kw
                    )
                    out.append(ReproRow(target, table, "published", row, cfg, form=form))
    return out


# ---------------------------------------------------------------------------- reading runs
def _read_csv_arrays(path: Path) -> dict[str, np.ndarray]:
    with path.open() as fh:
        reader = csv.DictReader(fh)
        cols: dict[str, list[float]] = {c: [] for c in reader.fieldnames or []}
        for r in reader:
            for c in cols:
                v = r[c]
                cols[c].append(float(v) if v not in ("", None) else math.nan)
    return {c: np.array(v) for c, v in cols.items()}


def _load_run(run_dir: str | None) -> dict[str, Any]:
    if not run_dir or not (Path(run_dir) / "metrics.json").exists():
        return {}
    d = Path(run_dir)
    tr = _read_csv_arrays(d / "trajectory.csv")
    tr["frame"] = tr["frame"].astype(int)
    return {
        "metrics": json.loads((d / "metrics.json").read_text()),
        "config": json.loads((d / "config.json").read_text()),
        "trajectory": tr,
        "intervals": _read_csv_arrays(d / "intervals.csv"),
    }


def _check(r: ReproRow) -> dict[str, Any]:
    """Checks that hold whatever the predictor."""
    res = r.result
    m = res.get("metrics") or {}
    checks: dict[str, Any] = {}
    if not m:
        return {"ran": False}
    if r.row.learn:
        resid = m.get("identity_residual")
        checks["identity_residual"] = resid
        checks["identity_ok"] = resid is not None and abs(resid) < IDENTITY_TOL
        if m.get("l_avg") is not None:
            checks["abs_lavg_minus_eps"] = abs(m["l_avg"] - m["epsilon"])
    if r.row.oracle:
        iv = res.get("intervals") or {}
        gaps = iv.get("max_gap", np.zeros(0))
        gaps = gaps[np.isfinite(gaps)]
        max_gap = float(np.max(np.abs(gaps))) if gaps.size else 0.0
        checks["oracle_predictor"] = res["config"]["predictor"]["name"]
        checks["oracle_max_abs_gap"] = max_gap
        checks["oracle_ok"] = (
            checks["oracle_predictor"] == "oracle" and not r.row.learn and max_gap < ORACLE_TOL
        )
    return checks


# ---------------------------------------------------------------------------- tables
def _f(v: Any, spec: str = ".3f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    return format(v, spec)


def _tgoal(m: dict[str, Any]) -> str:
    if not m:
        return "failed"
    if m.get("t_goal") is None:
        return f"not reached ({m.get('frames', 0) / 30:.1f} s run)"
    return _f(m["t_goal"], ".2f")


CSV_COLS = [
    "table",
    "variant",
    "form",
    "row",
    "scene",
    "predictor",
    "a",
    "tau",
    "eta",
    "epsilon",
    "learn",
    "t_goal",
    "paper_t_goal",
    "n_collide",
    "paper_n_collide",
    "d_min",
    "paper_d_min",
    "l_avg",
    "paper_l_avg",
    "l_avg_applied",
    "lambda_final",
    "goal_reached",
    "fallback_share",
    "n_fallback",
    "epsilon_floor",
    "epsilon_attainable",
    "identity_residual",
    "identity_ok",
    "abs_lavg_minus_eps",
    "oracle_max_abs_gap",
    "oracle_ok",
    "frames",
    "wall_s",
    "run_key",
    "run_dir",
    "status",
    "error",
]


def _csv_row(r: ReproRow) -> dict[str, Any]:
    m = (r.result.get("metrics") or {}) if r.result else {}
    p = r.config.spec.params
    out = {
        "table": r.table.name,
        "variant": r.variant,
        "form": r.form,
        "row": r.row.label,
        "scene": r.config.scene,
        "predictor": r.config.spec.role_name("predictor"),
        "a": p.get("a"),
        "tau": p.get("tau"),
        "eta": p.get("eta") if r.row.learn else 0,
        "epsilon": p.get("epsilon"),
        "learn": r.row.learn,
        "run_key": r.key,
        "run_dir": r.result.get("run_dir"),
        "status": r.result.get("status"),
        "error": r.result.get("error"),
    }
    for k in METRICS:
        out[k] = m.get(k)
        out[f"paper_{k}"] = r.row.paper.get(k)
    for k in (
        "l_avg_applied",
        "lambda_final",
        "goal_reached",
        "fallback_share",
        "n_fallback",
        "epsilon_floor",
        "epsilon_attainable",
        "frames",
        "wall_s",
    ):
        out[k] = m.get(k)
    out.update({k: v for k, v in r.checks.items() if k in CSV_COLS})
    return out


def _write_csv(rows: list[ReproRow], path: Path) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_COLS)
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if v is None else v for k, v in _csv_row(r).items()})


def _pair(ours: Any, paper: Any, spec: str) -> str:
    return f"{_f(ours, spec)} ({_f(paper, 'g')})"


def _md_table(rows: list[ReproRow]) -> list[str]:
    lines = [
        "| row | t_goal s (paper) | collision frames (paper) | d_min m (paper) "
        "| l_avg (paper) | fallback % | final λ | checks |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m = r.result.get("metrics") or {}
        c = r.checks
        notes = []
        if "identity_ok" in c:
            ok = "ok" if c["identity_ok"] else "FAIL"
            notes.append(f"identity {ok} ({_f(c['identity_residual'], '.1e')})")
        if "abs_lavg_minus_eps" in c:
            notes.append(f"abs(l_avg−ε) = {_f(c['abs_lavg_minus_eps'], '.4f')}")
        if "oracle_ok" in c:
            ok = "ok" if c["oracle_ok"] else "FAIL"
            notes.append(f"oracle {ok} (max gap {_f(c['oracle_max_abs_gap'], '.1e')})")
        if m and m.get("epsilon_attainable") is False and r.row.learn:
            notes.append("ε below feasibility floor")
        if not m:
            notes.append(f"run failed: {r.result.get('error')}")
        paper = r.row.paper
        lines.append(
            f"| {r.row.label} | {_tgoal(m)} ({_f(paper['t_goal'], 'g')}) "
            f"| {_f(m.get('n_collide'))} ({_f(paper['n_collide'])}) "
            f"| {_pair(m.get('d_min'), paper['d_min'], '.3f')} "
            f"| {_f(m.get('l_avg'), '.4f') if r.row.learn else '-'} ({_f(paper['l_avg'], 'g')}) "
            f"| {_f(100 * m['fallback_share'] if m else None, '.1f')} "
            f"| {_f(m.get('lambda_final'), '.3g')} | {'; '.join(notes)} |"
        )
    return lines


def _table_md(table: PaperTable, rows: list[ReproRow], predictor: str, figs: list[str]) -> str:
    out = [f"# {table.title}", ""]
    p = {k: v for k, v in table.base.items()}
    out.append(
        f"Scene `{table.scene}`, predictor `{predictor}` (gt rows: `oracle`), parameters in the "
        f"paper's units (px, frames): {', '.join(f'{k} = {v:g}' for k, v in p.items())}. "
        "Each cell: ours (paper). Collisions are video frames (30 fps) with a centre "
        "distance below 1 m before the goal; l_avg is the average loss over the updates."
    )
    out.append("")
    for variant, desc in VARIANTS.items():
        vrows = [r for r in rows if r.variant == variant]
        if not vrows:
            continue
        out += [f"## {variant}: {desc} (a = {variant_a(table, variant):g})", ""]
        out += _md_table(vrows)
        out.append("")
    if figs:
        out += ["## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in figs] + [""]
    return "\n".join(out)


def _forms_md(rows: list[ReproRow], predictor: str) -> tuple[str, list[dict[str, Any]]]:
    raw = {r.row.label: r for r in rows if r.form == "raw"}
    tn = {r.row.label: r for r in rows if r.form == "trajnet"}
    lines = [
        "# nexus_4: raw annotations vs TrajNet form",
        "",
        f"Table II configurations (published variant, a = 10), predictor `{predictor}`. "
        "`raw`: the SDD annotations at 30 fps; `trajnet`: the TrajNet-processed tracks "
        "(every 12th frame, 20-sample segments) re-linked and interpolated to 30 fps by "
        "cubic spline. Each cell: raw / trajnet (difference).",
        "",
        "| row | t_goal s | collision frames | d_min m | l_avg |",
        "|---|---|---|---|---|",
    ]
    table_rows = []
    for label, r in raw.items():
        a = r.result.get("metrics") or {}
        b = (tn[label].result.get("metrics") or {}) if label in tn else {}
        cells = []
        entry: dict[str, Any] = {"row": label}
        for k, spec in (("t_goal", ".2f"), ("n_collide", "d"), ("d_min", ".3f"), ("l_avg", ".4f")):
            va, vb = a.get(k), b.get(k)
            diff = vb - va if (va is not None and vb is not None) else None
            entry.update({f"{k}_raw": va, f"{k}_trajnet": vb, f"{k}_diff": diff})
            if k == "l_avg" and not r.row.learn:
                cells.append("-")
                continue
            sp = ".0f" if spec == "d" else spec
            cells.append(
                f"{_f(va, sp)} / {_f(vb, sp)} ({'+' if (diff or 0) >= 0 else ''}{_f(diff, sp)})"
            )
        table_rows.append(entry)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    return "\n".join(lines), table_rows


def forms_data_stats(data_root: str | None, frames: int = 300) -> dict[str, Any]:
    """How the two forms of nexus_4 differ as data, over the first ``frames`` of the run.

    Returns, per form, the tracks present and the agent-frames; and, matching every raw
    agent-frame to the nearest TrajNet agent in the same frame, the share matched within
    1 m and the median distance of those matches (interpolation + re-linking error; the
    TrajNet form also drops some pedestrians).
    """
    from scipy.spatial import cKDTree

    from ...data import load_scene

    out: dict[str, Any] = {"frames": frames}
    win = {}
    for form in ("raw", "trajnet"):
        sc = load_scene(f"nexus_4:{form}", data_root)
        w = sc.tracks.dense(sc.start_index, min(sc.start_index + frames, sc.n_frames))
        win[form] = w
        present = np.isfinite(w[..., 0])
        out[form] = {
            "tracks": int(present.any(axis=0).sum()),
            "agent_frames": int(present.sum()),
        }
    n = min(len(win["raw"]), len(win["trajnet"]))
    dists = []
    for f in range(n):
        a = win["raw"][f][np.isfinite(win["raw"][f][:, 0])]
        b = win["trajnet"][f][np.isfinite(win["trajnet"][f][:, 0])]
        if len(a) and len(b):
            d, _ = cKDTree(b).query(a)
            dists.append(d)
        elif len(a):
            dists.append(np.full(len(a), np.inf))
    d = np.concatenate(dists) if dists else np.zeros(0)
    close = d[d < 1.0]
    out["share_matched_1m"] = float(close.size / d.size) if d.size else None
    out["median_match_m"] = float(np.median(close)) if close.size else None
    out["p90_match_m"] = float(np.percentile(close, 90)) if close.size else None
    return out


# ---------------------------------------------------------------------------- figures
def _figures(
    table: PaperTable, rows: list[ReproRow], fig_dir: Path, data_root: str | None
) -> list[str]:
    from ...data import load_scene
    from ...io.plotting.jobs import FigureJob, draw_all
    from ...io.plotting.reproduce import (
        plot_lambda_loss_rows,
        plot_lavg_vs_epsilon,
        plot_paths_grid,
    )

    fig_dir.mkdir(parents=True, exist_ok=True)
    scene = load_scene(table.scene, data_root)
    made: list[str] = []
    jobs: list[FigureJob] = []
    points = []
    for variant in VARIANTS:
        vrows = [r for r in rows if r.variant == variant]
        if not vrows:
            continue
        a = variant_a(table, variant)
        runs = [
            {
                "label": r.row.label,
                "trajectory": r.result.get("trajectory"),
                "metrics": r.result.get("metrics"),
                "intervals": r.result.get("intervals"),
                "learn": r.row.learn,
                "epsilon": r.config.spec.params.get("epsilon"),
            }
            for r in vrows
        ]
        title = f"{table.name}, {variant} (a = {a:g})"
        p = fig_dir / f"{table.name}-{variant}-paths.png"
        jobs.append((plot_paths_grid, (scene, runs, p), {"title": title}))
        made.append(p.name)
        p = fig_dir / f"{table.name}-{variant}-lambda-loss.png"
        jobs.append((plot_lambda_loss_rows, (runs, p), {"title": title}))
        made.append(p.name)
        for r in vrows:
            m = r.result.get("metrics") or {}
            if r.row.learn:
                points.append(
                    {
                        "series": f"ours, {variant} (a = {a:g})",
                        "epsilon": r.config.spec.params.get("epsilon"),
                        "l_avg": m.get("l_avg"),
                    }
                )
    first = rows[0].variant if rows else None
    for r in rows:
        if r.row.learn and r.variant == first:
            points.append(
                {
                    "series": "paper",
                    "epsilon": r.config.spec.params.get("epsilon"),
                    "l_avg": r.row.paper.get("l_avg"),
                }
            )
    p = fig_dir / f"{table.name}-lavg-vs-epsilon.png"
    jobs.append(
        (plot_lavg_vs_epsilon, (points, p), {"title": f"{table.name}: l_avg against epsilon"})
    )
    made.append(p.name)
    draw_all(jobs)  # about a second each: split between two cores where possible
    return made


# ---------------------------------------------------------------------------- driver
def auto_executor(configs: Sequence[SweepRun]) -> str:
    """``"serial"`` when every run's predictor is a fast one (a dozen episodes then take
    about a second in this process, less than starting worker processes), else
    ``"process"``."""
    from ...core import registry

    fast = all(
        registry.get("predictor", c.spec.role("predictor")[0]).capabilities.batchable
        for c in configs
    )
    return "serial" if fast else "process"


def reproduce(
    targets: Sequence[str],
    out: str | Path,
    *,
    data_root: str | None = None,
    predictor: str = "constant_velocity",
    predictor_params: dict[str, Any] | None = None,
    executor: Executor | str = "auto",
    workers: int | None = None,
    scheduler: str | None = None,
    frames: int | None = None,
    seed: int = 0,
    figures: bool = True,
    progress: bool | None = None,
    variants: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Run the targets (``table1``, ``table2``, ``forms``) and write the reports.

    Parameters
    ----------
    targets : sequence of {"table1", "table2", "forms", "all"}
        What to reproduce: Table I (gates_1), Table II (nexus_4), the raw against the
        TrajNet form of nexus_4.
    out : path
        The output folder (reused to resume: finished runs are skipped).
    data_root : str, optional
        The data folder (or its ``sdd/`` subfolder).
    predictor : str
        A registered predictor (the paper's: ``darts``).
    predictor_params : dict, optional
        Its parameters.
    executor : Executor or str
        Where the runs go (see :func:`~conformal_control.experiments.run_sweep`); ``"auto"``
        (default) runs them in this process when every run's predictor is a fast one
        (capabilities' ``batchable``: a dozen episodes take about
        a second, less than starting worker processes), else on a process pool.
    workers : int, optional
        Worker processes (process pool, Dask LocalCluster).
    scheduler : str, optional
        A Dask scheduler's address.
    frames : int, optional
        Simulate at most this many frames per run (quick looks).
    seed : int
        The runs' seed.
    figures : bool
        Write the figures beside the tables.
    progress : bool, optional
        A progress report (None: on a terminal).
    variants : sequence of {"printed", "published"}, optional
        The parameter variants (default both).

    Returns
    -------
    dict
        The summary (also written to ``out/summary.json``): wall time, runs, failures and
        every check.
    """
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    targets = list(dict.fromkeys(TARGETS if "all" in targets else targets))
    from ...core import registry

    registry.get("predictor", predictor)  # unknown or unavailable: a clear error up front
    variants = list(variants or VARIANTS)
    for v in variants:
        if v not in VARIANTS:
            raise ValueError(f"unknown variant {v!r}; use {', '.join(VARIANTS)}")
    rows = plan(
        targets,
        predictor=predictor,
        predictor_params=predictor_params,
        data_root=data_root,
        frames=frames,
        seed=seed,
        variants=variants,
    )
    unique = list({r.key: r.config for r in rows}.values())
    if executor == "auto":
        executor = auto_executor(unique)
    report = run_sweep(
        unique,
        out / "sweep",
        executor,
        workers=workers,
        scheduler=scheduler,
        plot=False,
        summary_plot=False,  # the report draws its own figures (below)
        table_every=len(unique),  # the journal has every run; the tables once, at the end
        parquet=False,  # the report has its own tables; pyarrow would import pandas
        progress=progress,
    )
    by_key = {row["key"]: row for row in report.rows}
    for r in rows:
        rec = by_key.get(r.key, {})
        r.result = _load_run(rec.get("run_dir")) if rec.get("status") == "ok" else {}
        r.result.update(
            {"status": rec.get("status"), "error": rec.get("error"), "run_dir": rec.get("run_dir")}
        )
        r.checks = _check(r)
    written: list[str] = []
    for target in targets:
        trows = [r for r in rows if r.target == target]
        if target in PAPER_TABLES:
            table = PAPER_TABLES[target]
            figs = _figures(table, trows, out / "figures", data_root) if figures else []
            (out / f"{target}.md").write_text(
                _table_md(table, trows, predictor, [f"figures/{f}" for f in figs])
            )
            _write_csv(trows, out / f"{target}.csv")
            written += [f"{target}.md", f"{target}.csv"]
        else:
            md, _ = _forms_md(trows, predictor)
            st = forms_data_stats(data_root)
            md += (
                f"\nThe data over the first {st['frames']} frames of the run: raw "
                f"{st['raw']['tracks']} tracks / {st['raw']['agent_frames']} agent-frames, "
                f"TrajNet {st['trajnet']['tracks']} tracks / "
                f"{st['trajnet']['agent_frames']} agent-frames; "
                f"{100 * (st['share_matched_1m'] or 0):.1f}% of the raw agent-frames have a "
                f"TrajNet agent within 1 m in the same frame (median distance "
                f"{_f(st['median_match_m'], '.3f')} m, 90th percentile "
                f"{_f(st['p90_match_m'], '.3f')} m).\n"
            )
            (out / "forms_data.json").write_text(json.dumps(st, indent=1) + "\n")
            (out / "forms.md").write_text(md)
            _write_csv(trows, out / "forms.csv")
            written += ["forms.md", "forms.csv"]
    checks = [
        {
            "table": r.table.name,
            "variant": r.variant,
            "form": r.form,
            "row": r.row.label,
            **r.checks,
        }
        for r in rows
    ]
    summary = {
        "targets": targets,
        "predictor": predictor,
        "predictor_params": dict(predictor_params or {}),
        "frames": frames,
        "seed": seed,
        "variants": variants,
        "executor": report.executor,
        "runs": len(report.keys),
        "ran": len(report.ran),
        "skipped": len(report.skipped),
        "failed": len(report.failed),
        "sweep_wall_s": report.wall_s,
        "wall_s": time.perf_counter() - t0,
        "identity_ok": all(c.get("identity_ok", True) for c in checks),
        "oracle_ok": all(c.get("oracle_ok", True) for c in checks),
        "max_abs_lavg_minus_eps_eta100": max(
            (
                c["abs_lavg_minus_eps"]
                for c, r in zip(checks, rows, strict=True)
                if "abs_lavg_minus_eps" in c and r.row.params.get("eta") == 100.0
            ),
            default=None,
        ),
        "checks": checks,
        "files": written,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")
    return summary
