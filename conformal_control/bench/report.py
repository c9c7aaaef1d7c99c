"""Benchmark reports, built from the stored per-episode rows only.

:func:`write_report` reads the rows of a benchmark run (one per scenario x method) and
writes

* ``leaderboard.md`` / ``leaderboard.csv`` -- per method: success, reached and collision
  rates, collision frames, time to goal, minimum distance, time in personal space,
  fallback share, ... as means over scenarios with bootstrap 95 % CIs, and the paired
  comparison with the baseline method on the same scenarios;
* ``per_scene.csv`` / ``per_scene.md`` -- the same per source (video) and method;
* ``frontier.png`` -- collision rate against mean time to goal, CIs as error bars, one
  point per method/setting, the Pareto front marked;
* ``success_vs_epsilon.png`` -- success rate against epsilon for the epsilon families.

Time to goal for the frontier counts an episode that did not reach its goal at its time
limit (so a method cannot look fast by failing); the leaderboard also gives the mean over
reached episodes only.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .stats import Estimate, PairedComparison, bootstrap_mean, paired_comparison

__all__ = ["MethodSummary", "summarise", "write_report"]

#: (column, row metric, is a rate, lower is better) of the leaderboard.
COLUMNS: tuple[tuple[str, str, bool, bool], ...] = (
    ("success", "success", True, False),
    ("reached", "goal_reached", True, False),
    ("collision rate", "any_collision", True, True),
    ("collision frames", "n_collide", False, True),
    ("time to goal (s, limit if not reached)", "t_goal_or_limit", False, True),
    ("time to goal (s, reached)", "t_goal", False, True),
    ("d_min (m)", "d_min", False, False),
    ("personal space (s)", "time_in_personal_space", False, True),
    ("path length (m)", "path_length", False, True),
    ("mean speed (m/s)", "mean_speed", False, False),
    ("fallback share", "fallback_share", False, True),
    ("solver calls", "n_qp_solves", False, True),
    ("l_avg", "l_avg", False, True),
    ("lambda mean (1/s)", "lambda_mean_si", False, False),
    ("wall (s)", "wall_s", False, True),
)


def _num(v: Any) -> float:
    if v is None or v == "":
        return math.nan
    if isinstance(v, str):
        low = v.strip().lower()
        if low in ("true", "false"):
            return 1.0 if low == "true" else 0.0
        try:
            return float(v)
        except ValueError:
            return math.nan
    return float(v)


def _prepared(row: Mapping[str, Any]) -> dict[str, Any]:
    r = dict(row)
    reached = _num(r.get("goal_reached")) == 1.0
    t_goal = _num(r.get("t_goal"))
    limit = _num(r.get("time_limit"))
    r["t_goal_or_limit"] = t_goal if reached else limit
    # lambda statistics are reported in the scene's unit; the benchmark compares in 1/s
    r["lambda_mean_si"] = _num(r.get("lambda_mean")) * _num(r.get("lambda_unit_si") or 1.0)
    return r


@dataclass
class MethodSummary:
    """One leaderboard row: estimates per column and the paired comparison."""

    method: str
    family: str
    setting: str
    n: int
    n_failed: int
    estimates: dict[str, Estimate]
    paired: dict[str, PairedComparison]


def _ok_rows(rows: Iterable[Mapping[str, Any]]) -> tuple[list[dict[str, Any]], list[Any]]:
    ok, failed = [], []
    for r in rows:
        if str(r.get("status", "ok")) == "ok":
            ok.append(_prepared(r))
        else:
            failed.append(r)
    return ok, failed


def summarise(
    rows: Sequence[Mapping[str, Any]], *, baseline: str = "nolearn", seed: int = 0
) -> list[MethodSummary]:
    """One :class:`MethodSummary` per method, in order of first appearance."""
    ok, failed = _ok_rows(rows)
    by_method: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in ok:
        by_method[str(r["method"])].append(r)
    failed_count: dict[str, int] = defaultdict(int)
    for r in failed:
        failed_count[str(r.get("method"))] += 1
    base = {str(r["scenario"]): r for r in by_method.get(baseline, [])}
    out = []
    for method, mrows in by_method.items():
        est = {
            col: bootstrap_mean([_num(r.get(metric)) for r in mrows], seed=seed)
            for col, metric, _, _ in COLUMNS
        }
        paired: dict[str, PairedComparison] = {}
        if method != baseline and base:
            common = [r for r in mrows if str(r["scenario"]) in base]
            for col, metric, _, lower in COLUMNS[:5]:
                paired[col] = paired_comparison(
                    [_num(r.get(metric)) for r in common],
                    [_num(base[str(r["scenario"])].get(metric)) for r in common],
                    metric=metric,
                    lower_is_better=lower,
                    seed=seed,
                )
        first = mrows[0]
        out.append(
            MethodSummary(
                method=method,
                family=str(first.get("family", method)),
                setting=str(first.get("setting", "") or ""),
                n=len(mrows),
                n_failed=failed_count.get(method, 0),
                estimates=est,
                paired=paired,
            )
        )
    return out


def _pareto(points: list[tuple[float, float]]) -> list[bool]:
    """Which points no other point beats on both coordinates (lower is better)."""
    front = []
    for i, (x, y) in enumerate(points):
        dominated = any(
            (x2 <= x and y2 <= y) and (x2 < x or y2 < y)
            for j, (x2, y2) in enumerate(points)
            if j != i and not (math.isnan(x2) or math.isnan(y2))
        )
        front.append(not dominated and not (math.isnan(x) or math.isnan(y)))
    return front


def _leaderboard_md(summaries: list[MethodSummary], baseline: str, title: str) -> str:
    cols = [c for c, _, _, _ in COLUMNS[:9]]
    lines = [
        f"# {title}",
        "",
        f"Means over scenarios with bootstrap 95 % CIs; baseline for "
        f"the paired comparison: `{baseline}`.",
        "",
    ]
    lines.append("| method | n | " + " | ".join(cols) + " |")
    lines.append("|---|---:|" + "---|" * len(cols))
    for s in summaries:
        cells = []
        for col, _, rate, _ in COLUMNS[:9]:
            cells.append(s.estimates[col].format(3, percent=rate))
        fail = f" ({s.n_failed} failed)" if s.n_failed else ""
        lines.append(f"| `{s.method}` | {s.n}{fail} | " + " | ".join(cells) + " |")
    lines += ["", f"## Paired comparison with `{baseline}` (same scenarios)", ""]
    lines.append("| method | metric | n | wins | losses | ties | mean difference [95 % CI] |")
    lines.append("|---|---|---:|---:|---:|---:|---|")
    for s in summaries:
        for col, pc in s.paired.items():
            rate = any(c == col and r for c, _, r, _ in COLUMNS)
            lines.append(
                f"| `{s.method}` | {col} | {pc.n} | {pc.wins} | {pc.losses} | {pc.ties} | "
                f"{pc.difference.format(3, percent=rate)} |"
            )
    return "\n".join(lines) + "\n"


def _write_csv(path: Path, header: list[str], rows: list[list[Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def _leaderboard_csv(path: Path, summaries: list[MethodSummary]) -> None:
    header = ["method", "family", "setting", "n", "n_failed"]
    for col, _, _, _ in COLUMNS:
        header += [col, f"{col} low", f"{col} high"]
    rows = []
    for s in summaries:
        row: list[Any] = [s.method, s.family, s.setting, s.n, s.n_failed]
        for col, _, _, _ in COLUMNS:
            e = s.estimates[col]
            row += [e.mean, e.low, e.high]
        rows.append(row)
    _write_csv(path, header, rows)


def _per_scene(rows: list[dict[str, Any]], out: Path, seed: int) -> None:
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[(str(r.get("source", "?")), str(r["method"]))].append(r)
    header = [
        "source",
        "method",
        "n",
        "success",
        "collision rate",
        "collision frames",
        "time to goal (s)",
    ]
    table: list[list[Any]] = []
    for (src, method), g in sorted(groups.items()):
        table.append(
            [
                src,
                method,
                len(g),
                np.mean([_num(r.get("success")) for r in g]),
                np.mean([_num(r.get("any_collision")) for r in g]),
                np.mean([_num(r.get("n_collide")) for r in g]),
                np.nanmean([_num(r.get("t_goal_or_limit")) for r in g]),
            ]
        )
    _write_csv(out / "per_scene.csv", header, table)
    md = ["| " + " | ".join(header) + " |", "|---|---|---:|---:|---:|---:|---:|"]
    for row in table:
        md.append(
            f"| {row[0]} | `{row[1]}` | {row[2]} | {100 * row[3]:.0f} % | "
            f"{100 * row[4]:.0f} % | {row[5]:.2f} | {row[6]:.2f} |"
        )
    (out / "per_scene.md").write_text("\n".join(md) + "\n")


def _frontier(summaries: list[MethodSummary], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    xcol, ycol = COLUMNS[4][0], COLUMNS[2][0]
    pts = [(s.estimates[xcol].mean, s.estimates[ycol].mean) for s in summaries]
    front = _pareto(pts)
    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    for s, (x, y), on_front in zip(summaries, pts, front, strict=True):
        if math.isnan(x) or math.isnan(y):
            continue
        ex, ey = s.estimates[xcol], s.estimates[ycol]
        ax.errorbar(
            x,
            100 * y,
            xerr=[[x - ex.low], [ex.high - x]],
            yerr=[[100 * (y - ey.low)], [100 * (ey.high - y)]],
            fmt="o" if on_front else "s",
            ms=7 if on_front else 5,
            mfc="C3" if on_front else "white",
            color="C3" if on_front else "0.35",
            capsize=2,
            lw=0.8,
        )
        ax.annotate(s.method, (x, 100 * y), textcoords="offset points", xytext=(5, 4), fontsize=7)
    fp = sorted((p for p, f in zip(pts, front, strict=True) if f), key=lambda p: p[0])
    if len(fp) > 1:
        ax.plot(
            [p[0] for p in fp],
            [100 * p[1] for p in fp],
            "--",
            color="C3",
            lw=1,
            label="Pareto front",
        )
        ax.legend(loc="upper right")
    ax.set_xlabel("mean time to goal (s; time limit when not reached)")
    ax.set_ylabel("episodes with a collision (%)")
    ax.set_title(title)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _success_vs_epsilon(rows: list[dict[str, Any]], path: Path, seed: int) -> bool:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fams: dict[str, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        setting = str(r.get("setting") or "")
        if setting.startswith("eps="):
            fams[str(r.get("family"))][float(setting[4:])].append(_num(r.get("success")))
    if not fams:
        return False
    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    for fam, by_eps in sorted(fams.items()):
        eps = sorted(by_eps)
        est = [bootstrap_mean(by_eps[e], seed=seed) for e in eps]
        ax.errorbar(
            eps,
            [100 * e.mean for e in est],
            yerr=[[100 * (e.mean - e.low) for e in est], [100 * (e.high - e.mean) for e in est]],
            marker="o",
            capsize=3,
            label=fam,
        )
    base = [_num(r.get("success")) for r in rows if r.get("method") == "nolearn"]
    if base:
        ax.axhline(100 * float(np.nanmean(base)), color="0.4", ls=":", label="nolearn")
    ax.set_xlabel("epsilon (target average loss)")
    ax.set_ylabel("success rate (%)")
    ax.set_title("Success against epsilon (95 % CIs)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def write_report(
    rows: Sequence[Mapping[str, Any]],
    out: str | Path,
    *,
    baseline: str = "nolearn",
    title: str = "Benchmark",
    seed: int = 0,
) -> dict[str, Path]:
    """Write the leaderboard, per-scene table and figures into ``out``; return the files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ok, _ = _ok_rows(rows)
    if not ok:
        raise ValueError("no successful episode in the results: nothing to report")
    summaries = summarise(rows, baseline=baseline, seed=seed)
    files = {
        "leaderboard.md": out / "leaderboard.md",
        "leaderboard.csv": out / "leaderboard.csv",
        "per_scene.csv": out / "per_scene.csv",
        "per_scene.md": out / "per_scene.md",
        "frontier.png": out / "frontier.png",
    }
    files["leaderboard.md"].write_text(_leaderboard_md(summaries, baseline, title))
    _leaderboard_csv(files["leaderboard.csv"], summaries)
    _per_scene(ok, out, seed)
    _frontier(summaries, files["frontier.png"], title)
    if _success_vs_epsilon(ok, out / "success_vs_epsilon.png", seed):
        files["success_vs_epsilon.png"] = out / "success_vs_epsilon.png"
    return files
