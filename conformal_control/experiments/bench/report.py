"""Benchmark reports, built from the stored per-episode rows only.

:func:`write_report` reads the rows of a benchmark folder (one per shift x scenario x
method) and writes, per predictor shift:

* ``leaderboard.md`` / ``leaderboard.csv`` -- per method: success, reached and collision
  rates, collision frames, avoidable collision frames, time to goal, d_min, ... as means over
  scenarios with bootstrap 95 % CIs; the avoidable share of the collision frames; paired
  comparisons with ``nolearn`` AND with the tuned fixed lambda on the same scenarios (the
  tuned methods are labelled with the split their file says they were tuned on);
  and, where the folder ran a reference family's whole grid (``fixed``), the setting
  re-tuned on the reported split by the tuning rule, labelled as a reference that peeks at
  it;
* ``frontier-<shift>.png`` -- collision frames per scenario against the rate of reaching
  the goal in time, one point per method with CIs, the Pareto front marked;
* ``strata.md`` / ``strata.csv`` -- success and collision frames per recording, per tertile
  of corridor density and per tertile of the crossing pedestrians' speed;
* ``collisions.md`` / ``collisions.csv`` -- what the collisions are: events, avoidable,
  unavoidable, pop-in and at-fault frames, who closed on whom, penetration;
* ``per_scene.md`` / ``per_scene.csv`` -- per recording and method (all shifts);
* ``targets.md`` -- the benchmark's targets, met or not, with the figures;
* ``no_regret.md`` / ``no_regret.csv`` -- per shift, each adaptive method against the whole
  fixed-lambda grid the folder ran: dominated or not, regret to the best fixed lambda in
  hindsight, difference to the re-tuned one (:mod:`~conformal_control.experiments.bench.regret`);
* ``agents.md`` -- lambda run per agent: the distribution over agents of their average
  loss against epsilon and their bounds (from each run's ``metrics.json``);
* ``success_vs_epsilon.png`` -- success rate against epsilon for the epsilon families.

A report is a pure function of the SET of rows and the seed: the rows are sorted (by shift,
method, scenario, then their whole content) before anything is computed, methods are listed
in a fixed order (the baseline, then by family, then by name), and the bootstrap resamples
sorted values (:func:`~conformal_control.experiments.bench.stats.bootstrap_mean`); shuffling
``results.jsonl``, or two runs finishing their episodes in another order, give the same
files.

Rows of different conditions (crowd, run parameters, ...) are never pooled: a folder holds
one (``bench run`` refuses to mix them), and a report of rows with two runs of one method on
one scenario under one shift is refused.
"""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...io.plotting.jobs import FigureJob, draw_all
from .regret import GridComparison, compare_with_grid, issue_targets
from .shifts import SHIFTS
from .stats import Estimate, PairedComparison, bootstrap_means, paired_comparisons

__all__ = [
    "MethodSummary",
    "canonical_order",
    "summarise",
    "tuned_label",
    "tuned_split",
    "write_report",
]

#: (column, row metric, is a rate, lower is better) of the leaderboard.
COLUMNS: tuple[tuple[str, str, bool, bool], ...] = (
    ("success", "success", True, False),
    ("reached", "goal_reached", True, False),
    ("collision rate", "any_collision", True, True),
    ("collision frames", "n_collide", False, True),
    ("time to goal (s, limit if not reached)", "t_goal_or_limit", False, True),
    ("avoidable collision frames", "n_collide_avoidable", False, True),
    ("d_min (m)", "d_min", False, False),
    ("time to goal (s, reached)", "t_goal", False, True),
    ("at-fault collision frames", "n_collide_at_fault", False, True),
    ("pop-in collision frames", "n_collide_popin", False, True),
    ("personal space (s)", "time_in_personal_space", False, True),
    ("path length (m)", "path_length", False, True),
    ("mean speed (m/s)", "mean_speed", False, False),
    ("fallback share", "fallback_share", False, True),
    ("solver calls", "n_qp_solves", False, True),
    ("l_avg", "l_avg", False, True),
    ("lambda mean (1/s)", "lambda_mean_si", False, False),
    ("wall (s)", "wall_s", False, True),
)
#: The columns of the markdown leaderboard (the CSV has them all).
MD_COLUMNS = (
    "success",
    "reached",
    "collision rate",
    "collision frames",
    "avoidable collision frames",
    "time to goal (s, limit if not reached)",
    "d_min (m)",
)
#: The metrics of the paired comparisons.
PAIRED = ("success", "reached", "collision frames", "avoidable collision frames")
#: Reference label of a family's setting re-tuned on the reported split.
REFERENCE = "re-tuned on this split: a reference that peeks at it"


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
    r["shift"] = str(r.get("shift") or "nominal")
    return r


@dataclass
class MethodSummary:
    """One leaderboard row: estimates per column and the paired comparisons."""

    method: str
    family: str
    setting: str
    n: int
    n_failed: int
    estimates: dict[str, Estimate]
    paired: dict[str, PairedComparison]
    label: str = ""
    paired_fixed: dict[str, PairedComparison] | None = None
    shares: dict[str, float] | None = None

    @property
    def shown(self) -> str:
        return f"`{self.method}`" + (f" ({self.label})" if self.label else "")


def _ok_rows(rows: Iterable[Mapping[str, Any]]) -> tuple[list[dict[str, Any]], list[Any]]:
    ok, failed = [], []
    for r in rows:
        if str(r.get("status", "ok")) == "ok":
            ok.append(_prepared(r))
        else:
            failed.append(r)
    return ok, failed


def _paired_args(
    mrows: list[dict[str, Any]], base: dict[str, dict[str, Any]]
) -> list[tuple[list[float], list[float], str, bool]]:
    """The :func:`~conformal_control.experiments.bench.stats.paired_comparisons` arguments of the
    paired columns (in the order of :data:`PAIRED`)."""
    common = [r for r in mrows if str(r["scenario"]) in base]
    out = []
    for col, metric, _, lower in COLUMNS:
        if col not in PAIRED:
            continue
        out.append(
            (
                [_num(r.get(metric)) for r in common],
                [_num(base[str(r["scenario"])].get(metric)) for r in common],
                metric,
                lower,
            )
        )
    return out


def _shares(mrows: list[dict[str, Any]]) -> dict[str, float]:
    total = sum(_num(r.get("n_collide")) for r in mrows)
    out = {}
    for key in ("n_collide_avoidable", "n_collide_at_fault", "n_collide_popin"):
        vals = [_num(r.get(key)) for r in mrows]
        part = sum(v for v in vals if math.isfinite(v))
        out[key] = part / total if total > 0 else math.nan
    return out


def _head(row: Mapping[str, Any]) -> tuple[str, str, str]:
    return (str(row.get("shift") or "nominal"), str(row.get("method")), str(row.get("scenario")))


def _content(row: Mapping[str, Any]) -> str:
    return json.dumps(row, sort_keys=True, default=str)


def canonical_order(rows: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """``rows`` sorted by shift, method, scenario, then their whole content: what a
    report computes from them no longer depends on the order they were stored in.

    Parameters
    ----------
    rows : iterable of mapping
        Benchmark rows, in any order.
    """
    rows = list(rows)
    heads = [_head(r) for r in rows]
    order = sorted(range(len(rows)), key=heads.__getitem__)
    # only rows whose shift, method and scenario tie need their whole content (serialising
    # every row was most of the sort): the same order as sorting by all four keys at once
    out: list[Mapping[str, Any]] = []
    i = 0
    while i < len(order):
        j = i + 1
        while j < len(order) and heads[order[j]] == heads[order[i]]:
            j += 1
        group = [rows[k] for k in order[i:j]]
        out += sorted(group, key=_content) if len(group) > 1 else group
        i = j
    return out


def summarise(
    rows: Sequence[Mapping[str, Any]],
    *,
    baseline: str = "nolearn",
    seed: int = 0,
    fixed: str | None = None,
) -> list[MethodSummary]:
    """One :class:`MethodSummary` per method, by method name (rows of one shift; their
    order does not matter); ``fixed``: the method every other is also paired with (the
    dev-tuned fixed lambda).

    Parameters
    ----------
    rows : sequence of mapping
        The benchmark's rows of one shift (failed ones counted, not summarised).
    baseline : str
        The method every other is paired with.
    seed : int
        Seed of the bootstrap.
    fixed : str, optional
        The method every other is also paired with.
    """
    ok, failed = _ok_rows(canonical_order(rows))
    by_method: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in ok:
        by_method[str(r["method"])].append(r)
    failed_count: dict[str, int] = defaultdict(int)
    for r in failed:
        failed_count[str(r.get("method"))] += 1
    base = {str(r["scenario"]): r for r in by_method.get(baseline, [])}
    ref = {str(r["scenario"]): r for r in by_method.get(fixed, [])} if fixed else {}
    # every interval of the shift in one pass (the same numbers as one call each)
    cols = [col for col, _, _, _ in COLUMNS]
    paired_cols = [col for col in cols if col in PAIRED]
    samples: list[list[float]] = []
    pairs: list[tuple[list[float], list[float], str, bool]] = []
    for method, mrows in by_method.items():
        samples += [[_num(r.get(metric)) for r in mrows] for _, metric, _, _ in COLUMNS]
        if method != baseline and base:
            pairs += _paired_args(mrows, base)
        if method != fixed and ref:
            pairs += _paired_args(mrows, ref)
    estimates = iter(bootstrap_means(samples, seed=seed))
    comparisons = iter(paired_comparisons(pairs, seed=seed))
    out = []
    for method, mrows in by_method.items():
        est = {col: next(estimates) for col in cols}
        paired: dict[str, PairedComparison] = {}
        if method != baseline and base:
            paired = {col: next(comparisons) for col in paired_cols}
        paired_fixed = None
        if method != fixed and ref:
            paired_fixed = {col: next(comparisons) for col in paired_cols}
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
                paired_fixed=paired_fixed,
                shares=_shares(mrows),
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


# ------------------------------------------------------------------ what to show
@dataclass
class _ShiftView:
    """One shift's summaries and which of them the markdown tables show."""

    shift: str
    summaries: list[MethodSummary]
    shown: list[MethodSummary]
    fixed: str | None  # the tuned fixed lambda's method name
    reference: str | None  # the re-tuned reference's method name
    n_scenarios: int
    tuned_label: str = "tuned on dev"  # from the tuned file (:func:`tuned_label`)


def tuned_split(bench: Mapping[str, Any] | None) -> str | None:
    """The split the folder's tuned values were chosen on, as their file says (``bench.json``
    records it from ``tuned.json``); None if it does not say.

    Parameters
    ----------
    bench : mapping, optional
        The folder's ``bench.json``.
    """
    split = ((bench or {}).get("tuned") or {}).get("split")
    return str(split) if split else None


def tuned_label(bench: Mapping[str, Any] | None) -> str:
    """How the report labels the tuned methods: ``tuned on <split>`` from the tuned file
    (never assumed: a test-tuned file is labelled so).

    Parameters
    ----------
    bench : mapping, optional
        The folder's ``bench.json``.
    """
    split = tuned_split(bench)
    return f"tuned on {split}" if split else "tuned (split not recorded)"


def _tuned_short(bench: Mapping[str, Any] | None) -> str:
    """``dev-tuned``, ``test-tuned``...: the label's short form."""
    split = tuned_split(bench)
    return f"{split}-tuned" if split else "tuned"


def _tuned_names(bench: Mapping[str, Any] | None) -> dict[str, str]:
    """family -> the name of its dev-tuned member (from ``bench.json``)."""
    from .methods import FAMILIES

    tuned = ((bench or {}).get("tuned") or {}).get("values") or {}
    out = {}
    for fam, value in tuned.items():
        if fam in FAMILIES:
            out[fam] = FAMILIES[fam].method(value).name
    return out


def with_tuned(
    bench: Mapping[str, Any] | None, tuned: str | Path, rows: Sequence[Mapping[str, Any]]
) -> tuple[dict[str, Any], list[tuple[str, str]]]:
    """``bench`` with its tuned values replaced by ``tuned``'s (``bench report --tuned``).

    A folder records the tuned file it ran under; a family added to that file later (its
    rows run with ``--grid``) is not labelled tuned. This reads the values from another
    file and says which tuned members have no rows in the folder.

    Parameters
    ----------
    bench : mapping, optional
        The folder's ``bench.json``.
    tuned : str or Path
        A ``bench tune`` folder or its ``tuned.json``, or ``"default"`` (the shipped values).
    rows : sequence of mapping
        The folder's rows.

    Returns
    -------
    bench : dict
        A copy whose ``tuned`` entry describes ``tuned`` (its ``replaced`` the run's source).
    missing : list of (str, str)
        (family, tuned member) of the families with rows in the folder whose tuned member
        has none.

    Raises
    ------
    ValueError
        ``bench`` does not name its suite, or ``tuned`` is not a tuned file of that suite.
    """
    from .suite import load_tuned

    out = dict(bench or {})
    suite = out.get("suite")
    if not isinstance(suite, str):
        raise ValueError("--tuned: the folder's bench.json does not name its suite")
    loaded = load_tuned(str(tuned), suite)
    if loaded is None:
        raise ValueError(f"--tuned {tuned}: suite {suite!r} ships no tuned values")
    before = (out.get("tuned") or {}).get("source")
    out["tuned"] = {**loaded.describe(), "replaced": before}
    present = {str(r.get("method")) for r in rows}
    families = {str(r.get("family")) for r in rows}
    missing = []
    for fam, name in _tuned_names(out).items():
        if fam in families and name not in present:  # _tuned_names: registered families
            missing.append((fam, name))
    return out, missing


def _view(
    shift: str,
    rows: list[dict[str, Any]],
    baseline: str,
    seed: int,
    bench: Mapping[str, Any] | None,
) -> _ShiftView:
    from .methods import FAMILIES
    from .tune import choose

    tuned = _tuned_names(bench)
    fixed = tuned.get("fixed")
    present = {str(r["method"]) for r in rows}
    if fixed not in present:
        fixed = None
    summaries = summarise(rows, baseline=baseline, seed=seed, fixed=fixed)
    reference = None
    ref_family = next((f for f in FAMILIES.values() if f.reference), None)
    if ref_family is not None and ref_family.name in tuned:
        grid = [v for v in ref_family.tune if ref_family.method(v).name in present]
        if len(grid) > 1:
            ok, _ = _ok_rows(rows)
            value, _ = choose(ok, ref_family.name, grid)
            reference = ref_family.method(value).name
    rank = {name: i for i, name in enumerate(FAMILIES)}
    summaries.sort(
        key=lambda s: (s.method != baseline, rank.get(s.family, len(rank)), s.family, s.method)
    )
    shown = []
    for s in summaries:
        fam = FAMILIES.get(s.family)
        if s.method == fixed or s.method == tuned.get(s.family):
            s.label = tuned_label(bench)
        if fam is not None and fam.reference and s.family in tuned and s.method != fixed:
            continue  # the grid's other members: in the CSV only
        shown.append(s)
    if reference is not None:
        ref = next(s for s in summaries if s.method == reference)
        ref_copy = MethodSummary(**{**ref.__dict__, "label": REFERENCE})
        shown.append(ref_copy)
    n_scen = len({str(r.get("scenario")) for r in rows})
    return _ShiftView(shift, summaries, shown, fixed, reference, n_scen, tuned_label(bench))


# ------------------------------------------------------------------ markdown
def _share(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{100 * x:.0f} %"


def _leaderboard_md(views: list[_ShiftView], baseline: str, title: str) -> str:
    rate = {c for c, _, r, _ in COLUMNS if r}
    lines = [
        f"# {title}",
        "",
        "Means over scenarios with bootstrap 95 % CIs. *Avoidable share*: the share of the "
        "collision frames that a point robot with the speed bound could have avoided from "
        "where the robot was when the pedestrian was first sensed (pop-ins excluded; see "
        "the Benchmark page). Paired comparisons on the same scenarios: with "
        f"`{baseline}`, and with the fixed lambda "
        + (views[0].tuned_label if views else "tuned on dev")
        + ".",
        "",
    ]
    for v in views:
        sh = SHIFTS.get(v.shift)
        desc = f": {sh.description}" if sh else ""
        lines += [f"## Shift `{v.shift}`{desc} ({v.n_scenarios} scenarios)", ""]
        lines.append("| method | n | " + " | ".join(MD_COLUMNS) + " | avoidable share |")
        lines.append("|---|---:|" + "---|" * len(MD_COLUMNS) + "---:|")
        for s in v.shown:
            cells = [s.estimates[c].format(3, percent=c in rate) for c in MD_COLUMNS]
            fail = f" ({s.n_failed} failed)" if s.n_failed else ""
            share = _share((s.shares or {}).get("n_collide_avoidable", math.nan))
            lines.append(f"| {s.shown} | {s.n}{fail} | " + " | ".join(cells) + f" | {share} |")
        for against, attr in ((f"`{baseline}`", "paired"), (f"`{v.fixed}`", "paired_fixed")):
            if attr == "paired_fixed" and v.fixed is None:
                continue
            lines += [
                "",
                f"Paired with {against} (wins / losses / ties, mean difference [95 % CI]):",
                "",
                "| method | n | " + " | ".join(PAIRED) + " |",
                "|---|---:|" + "---|" * len(PAIRED),
            ]
            for s in v.shown:
                pcs = getattr(s, attr) or {}
                if not pcs:
                    continue
                n = next(iter(pcs.values())).n
                cells = [
                    f"{pcs[c].wins}/{pcs[c].losses}/{pcs[c].ties}, "
                    f"{pcs[c].difference.format(3, percent=c in rate)}"
                    for c in PAIRED
                ]
                lines.append(f"| {s.shown} | {n} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


def _write_csv(path: Path, header: list[str], rows: list[list[Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def _leaderboard_csv(path: Path, views: list[_ShiftView]) -> None:
    header = ["shift", "method", "family", "setting", "role", "n", "n_failed"]
    for col, _, _, _ in COLUMNS:
        header += [col, f"{col} low", f"{col} high"]
    header += ["avoidable share", "at-fault share", "pop-in share"]
    rows = []
    for v in views:
        for s in v.summaries:
            role = s.label if s.label == v.tuned_label else ""
            if s.method == v.reference:
                role = (role + "; " if role else "") + REFERENCE
            row: list[Any] = [v.shift, s.method, s.family, s.setting, role, s.n, s.n_failed]
            for col, _, _, _ in COLUMNS:
                e = s.estimates[col]
                row += [e.mean, e.low, e.high]
            sh = s.shares or {}
            row += [sh.get(k) for k in ("n_collide_avoidable", "n_collide_at_fault")]
            row += [sh.get("n_collide_popin")]
            rows.append(row)
    _write_csv(path, header, rows)


def _per_scene(rows: list[dict[str, Any]], out: Path) -> None:
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        rec = str(r.get("recording") or r.get("source", "?"))
        groups[(r["shift"], rec, str(r["method"]))].append(r)
    header = [
        "shift",
        "recording",
        "method",
        "n",
        "success",
        "collision rate",
        "collision frames",
        "time to goal (s)",
    ]
    table: list[list[Any]] = []
    for (shift, src, method), g in sorted(groups.items()):
        table.append(
            [
                shift,
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
    md = ["| " + " | ".join(header) + " |", "|---|---|---|---:|---:|---:|---:|---:|"]
    for row in table:
        md.append(
            f"| {row[0]} | {row[1]} | `{row[2]}` | {row[3]} | {100 * row[4]:.0f} % | "
            f"{100 * row[5]:.0f} % | {row[6]:.2f} | {row[7]:.2f} |"
        )
    (out / "per_scene.md").write_text("\n".join(md) + "\n")


# ------------------------------------------------------------------ strata
def _tertiles(values: dict[str, float]) -> tuple[dict[str, str], tuple[float, float]]:
    """scenario -> ``low`` / ``mid`` / ``high`` tertile of its value, and the two cuts."""
    finite = np.array([v for v in values.values() if math.isfinite(v)])
    if finite.size == 0:
        return {}, (math.nan, math.nan)
    lo, hi = (float(x) for x in np.quantile(finite, [1 / 3, 2 / 3]))
    out = {}
    for k, v in values.items():
        if math.isfinite(v):
            out[k] = "low" if v <= lo else ("mid" if v <= hi else "high")
    return out, (lo, hi)


def _strata(views: list[_ShiftView], rows: list[dict[str, Any]], out: Path) -> None:
    by_shift: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        by_shift[r["shift"]].append(r)
    header = ["shift", "method", "stratum", "group", "n", "success", "reached",
              "collision frames", "collision rate"]  # fmt: skip
    table: list[list[Any]] = []
    md = [
        "# Strata",
        "",
        "Per recording, and per tertile (over the reported scenarios) of the corridor "
        "density (pedestrians per 100 m² within 2 m of the robot's segment) and of the "
        "crossing pedestrians' mean speed (m/s): n, success, collision frames per scenario.",
        "",
    ]
    for v in views:
        srows = by_shift[v.shift]
        by_method: dict[Any, list[dict[str, Any]]] = defaultdict(list)
        for r in srows:
            by_method[r["method"]].append(r)
        scen: dict[str, dict[str, Any]] = {}
        for r in srows:
            scen.setdefault(str(r["scenario"]), r)
        dens, dcut = _tertiles({k: _num(r.get("corridor_density")) for k, r in scen.items()})
        speed, scut = _tertiles({k: _num(r.get("crossing_speed")) for k, r in scen.items()})
        kinds = {
            "recording": {k: str(r.get("recording") or r.get("source")) for k, r in scen.items()},
            "density": dens,
            "speed": speed,
        }
        md += [
            f"## Shift `{v.shift}`",
            "",
            f"Density tertile cuts {dcut[0]:.3g} and {dcut[1]:.3g} per 100 m²; speed tertile "
            f"cuts {scut[0]:.3g} and {scut[1]:.3g} m/s.",
            "",
        ]
        names = [s.method for s in v.shown if s.label != REFERENCE]
        for kind, group_of in kinds.items():
            present = set(group_of.values())
            if kind == "recording":
                groups = sorted(present)
            else:
                groups = [g for g in ("low", "mid", "high") if g in present]
            md += [
                f"### {kind}",
                "",
                "success and collision frames per scenario, per method:",
                "",
                f"| {kind} | n | " + " | ".join(f"`{m}`" for m in names) + " |",
                "|---|---:|" + "---|" * len(names),
            ]
            for g in groups:
                cells = []
                n_g = sum(1 for k in group_of if group_of[k] == g)
                for m in names:
                    sel = [
                        r for r in by_method.get(m, ())
                        if group_of.get(str(r["scenario"])) == g
                    ]  # fmt: skip
                    if not sel:
                        cells.append("-")
                        continue
                    succ = float(np.mean([_num(r.get("success")) for r in sel]))
                    coll = float(np.mean([_num(r.get("n_collide")) for r in sel]))
                    reach = float(np.mean([_num(r.get("goal_reached")) for r in sel]))
                    anyc = float(np.mean([_num(r.get("any_collision")) for r in sel]))
                    cells.append(f"{100 * succ:.0f} %, {coll:.2f}")
                    table.append([v.shift, m, kind, g, len(sel), succ, reach, coll, anyc])
                md.append(f"| {g} | {n_g} | " + " | ".join(cells) + " |")
            md.append("")
    _write_csv(out / "strata.csv", header, table)
    (out / "strata.md").write_text("\n".join(md) + "\n")


# ------------------------------------------------------------------ collisions
def _events(row: Mapping[str, Any]) -> list[dict[str, Any]] | None:
    """The collision events of a row's run (from its ``metrics.json``), None if unknown."""
    rd = row.get("run_dir")
    if not rd:
        return None
    path = Path(str(rd)) / "metrics.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    ev = data.get("collision_events")
    return ev if isinstance(ev, list) else None


def _collisions(views: list[_ShiftView], rows: list[dict[str, Any]], out: Path) -> dict[str, Any]:
    """Write the collision tables; return the totals for the targets."""
    header = [
        "shift", "method", "episodes", "episodes with a collision", "events", "collision frames",
        "avoidable", "unavoidable", "undecided", "pop-in", "at fault", "robot closing",
        "pedestrian closing", "both closing", "neither", "median penetration (m)",
    ]  # fmt: skip
    table: list[list[Any]] = []
    md = [
        "# Collisions",
        "",
        "Collision frames split by the event of their nearest pedestrian: avoidable (a point "
        "robot with the speed bound could have kept clear from where the robot was when "
        "that pedestrian was first sensed), unavoidable (proven), undecided, pop-in (the "
        "pedestrian became visible next to the robot or just before; never counted "
        "avoidable); at fault: frames at which the robot moved toward its nearest "
        "pedestrian. Events by who closed on whom at their first frame.",
        "",
        "| shift | method | episodes with a collision | events | collision frames | avoidable "
        "| unavoidable | undecided | pop-in | at fault | robot / pedestrian / both / neither "
        "closing | median penetration (m) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    totals = {"events": 0, "undecided_frames": 0, "frames": 0, "unknown": 0}
    by = defaultdict(list)
    for r in rows:
        by[(r["shift"], str(r["method"]))].append(r)
    for v in views:
        for s in v.shown:
            if s.label == REFERENCE:
                continue
            mrows = by[(v.shift, s.method)]
            sums = {
                k: int(sum(_num(r.get(k)) for r in mrows if math.isfinite(_num(r.get(k)))))
                for k in (
                    "n_collide",
                    "n_collision_events",
                    "n_collide_avoidable",
                    "n_collide_unavoidable",
                    "n_collide_undecided",
                    "n_collide_popin",
                    "n_collide_at_fault",
                )
            }
            closing: dict[str, int] = defaultdict(int)
            pen: list[float] = []
            for r in mrows:
                if _num(r.get("n_collide")) > 0:
                    ev = _events(r)
                    if ev is None:
                        totals["unknown"] += 1
                        continue
                    for e in ev:
                        closing[str(e.get("closing"))] += 1
                        pen.append(float(e.get("penetration") or 0.0))
            any_c = int(sum(_num(r.get("any_collision")) for r in mrows))
            med = float(np.median(pen)) if pen else math.nan
            cl = [closing.get(k, 0) for k in ("robot", "pedestrian", "both", "neither")]
            table.append(
                [
                    v.shift,
                    s.method,
                    len(mrows),
                    any_c,
                    sums["n_collision_events"],
                    sums["n_collide"],
                    sums["n_collide_avoidable"],
                    sums["n_collide_unavoidable"],
                    sums["n_collide_undecided"],
                    sums["n_collide_popin"],
                    sums["n_collide_at_fault"],
                    *cl,
                    med,
                ]
            )
            f = max(sums["n_collide"], 1)
            md.append(
                f"| {v.shift} | `{s.method}` | {any_c} / {len(mrows)} | "
                f"{sums['n_collision_events']} | {sums['n_collide']} | "
                f"{sums['n_collide_avoidable']} ({100 * sums['n_collide_avoidable'] / f:.0f} %) | "
                f"{sums['n_collide_unavoidable']} | {sums['n_collide_undecided']} | "
                f"{sums['n_collide_popin']} ({100 * sums['n_collide_popin'] / f:.0f} %) | "
                f"{sums['n_collide_at_fault']} ({100 * sums['n_collide_at_fault'] / f:.0f} %) | "
                f"{' / '.join(map(str, cl))} | " + ("-" if math.isnan(med) else f"{med:.2f}") + " |"
            )
            totals["events"] += sums["n_collision_events"]
            totals["undecided_frames"] += sums["n_collide_undecided"]
            totals["frames"] += sums["n_collide"]
    _write_csv(out / "collisions.csv", header, table)
    (out / "collisions.md").write_text("\n".join(md) + "\n")
    return totals


# ------------------------------------------------------------------ figures
#: How the figures label the tuned methods and the reference.
_SHORT = {REFERENCE: " (re-tuned here: reference)"}


def _short_label(label: str) -> str:
    """`` (dev-tuned)`` for ``tuned on dev`` (any split), the reference's, or ``""``."""
    if label.startswith("tuned on "):
        return f" ({label.removeprefix('tuned on ')}-tuned)"
    return _SHORT.get(label, "")


def _frontier(v: _ShiftView, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    xcol, ycol = "reached", "collision frames"
    pts = [(-s.estimates[xcol].mean, s.estimates[ycol].mean) for s in v.shown]
    front = _pareto(pts)
    fig, ax = plt.subplots(figsize=(10.0, 5.0), constrained_layout=True)
    markers = "osD^vP*Xhp<>"
    for i, (s, on_front) in enumerate(zip(v.shown, front, strict=True)):
        ex, ey = s.estimates[xcol], s.estimates[ycol]
        if math.isnan(ex.mean) or math.isnan(ey.mean):
            continue
        ax.errorbar(
            100 * ex.mean,
            ey.mean,
            xerr=[[100 * (ex.mean - ex.low)], [100 * (ex.high - ex.mean)]],
            yerr=[[ey.mean - ey.low], [ey.high - ey.mean]],
            fmt=markers[i % len(markers)],
            ms=9 if on_front else 7,
            mfc=f"C{i % 10}" if on_front else "white",
            color=f"C{i % 10}",
            capsize=3,
            lw=1.0,
            label=s.method + _short_label(s.label) + (" *" if on_front else ""),
        )
    fp = sorted(((-p[0], p[1]) for p, f in zip(pts, front, strict=True) if f), key=lambda p: p[0])
    if len(fp) > 1:
        ax.plot([100 * p[0] for p in fp], [p[1] for p in fp], "--", color="0.5", lw=1)
    grid = _grid(v)
    if len(grid) > 1:  # the whole fixed-lambda grid as a curve, in the order of its settings
        settings = ", ".join(s.setting.split("=")[-1] for s in grid)
        ax.plot([100 * s.estimates[xcol].mean for s in grid],
                [s.estimates[ycol].mean for s in grid], "-", marker=".", color="0.3", lw=1.2,
                alpha=0.6, zorder=0, label=f"{grid[0].family} grid: {settings}")  # fmt: skip
    ax.set_xlabel("goal reached in time (% of scenarios)", fontsize=11)
    ax.set_ylabel("collision frames per scenario", fontsize=11)
    ax.set_title(title, fontsize=12)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(
        fontsize=9,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        title="* on the Pareto front (filled)",
        title_fontsize=9,
    )
    # every point named beside it (points that coincide stay readable): Pareto members
    # first and in bold; plotting.labels guarantees no two labels overlap
    from ...io.plotting.labels import place_labels

    order = sorted(range(len(v.shown)), key=lambda i: not front[i])
    place_labels(
        ax,
        [100 * -pts[i][0] for i in order],
        [pts[i][1] for i in order],
        [v.shown[i].method + (" *" if front[i] else "") for i in order],
        fontsize=8,
        colors=[f"C{i % 10}" for i in order],
        weights=["bold" if front[i] else "normal" for i in order],
    )
    fig.savefig(path, dpi=120)
    plt.close(fig)


#: The curves of ``success_vs_epsilon.png``: (family, epsilons, their estimates).
_Curve = tuple[str, list[float], list[Estimate]]


def _epsilon_curves(
    rows: list[dict[str, Any]], seed: int
) -> tuple[list[_Curve], float | None] | None:
    """The success rate against epsilon per epsilon family (nominal shift) and
    ``nolearn``'s rate; None when no row has an epsilon setting."""
    fams: dict[str, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        setting = str(r.get("setting") or "")
        if setting.startswith("eps=") and r["shift"] == "nominal":
            fams[str(r.get("family"))][float(setting[4:])].append(_num(r.get("success")))
    if not fams:
        return None
    curves = []
    for fam, by_eps in sorted(fams.items()):
        eps = sorted(by_eps)
        curves.append((fam, eps, bootstrap_means([by_eps[e] for e in eps], seed=seed)))
    base = [
        _num(r.get("success"))
        for r in rows
        if r.get("method") == "nolearn" and r["shift"] == "nominal"
    ]
    return curves, (float(np.nanmean(base)) if base else None)


def _success_vs_epsilon(curves: list[_Curve], base: float | None, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    for fam, eps, est in curves:
        ax.errorbar(
            eps,
            [100 * e.mean for e in est],
            yerr=[[100 * (e.mean - e.low) for e in est], [100 * (e.high - e.mean) for e in est]],
            marker="o",
            capsize=3,
            label=fam,
        )
    if base is not None:
        ax.axhline(100 * base, color="0.4", ls=":", label="nolearn")
    ax.set_xlabel("epsilon (target average loss)")
    ax.set_ylabel("success rate (%)")
    ax.set_title("Success against epsilon, nominal predictor (95 % CIs)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------ targets
def _targets(
    views: list[_ShiftView],
    totals: Mapping[str, Any],
    bench: Mapping[str, Any] | None,
    tune_wall: float | None,
) -> str:
    lines = ["# Targets", ""]
    wall = (bench or {}).get("wall_s")
    if wall is not None:
        total = float(wall) + (tune_wall or 0.0)
        tw = "not known (shipped values)" if tune_wall is None else f"{tune_wall:.0f} s"
        lines.append(
            f"- Run time: `bench tune` {tw} + `bench run` {float(wall):.0f} s = {total:.0f} s "
            f"({total / 60:.1f} min; target <= 15 min: {'met' if total <= 900 else 'NOT met'})."
        )
    v = next((x for x in views if x.shift == "delay-0.5s"), None)
    tuned = _tuned_names(bench)
    conf = tuned.get("conformal")
    if v is not None and conf is not None:
        by = {s.method: s for s in v.summaries}
        c, base = by.get(conf), by.get("nolearn")
        if c is not None and base is not None:
            cf, bf = c.estimates["collision frames"].mean, base.estimates["collision frames"].mean
            ratio = cf / bf if bf > 0 else math.nan
            d = c.paired["collision frames"].difference
            ok = math.isfinite(ratio) and ratio <= 0.5
            lines.append(
                f"- `delay-0.5s`: `{conf}` has {cf:.2f} collision frames per scenario against "
                f"`nolearn`'s {bf:.2f} ({100 * ratio:.0f} %; paired difference "
                f"{d.format(3)}); target <= 50 %: {'met' if ok else 'NOT met'}."
            )
        if c is not None and c.paired_fixed:
            dc = c.paired_fixed["collision frames"].difference
            ds = c.paired_fixed["success"].difference
            fewer = dc.high < 0
            not_lower = ds.mean >= 0 and ds.high >= 0
            lines.append(
                f"- `delay-0.5s`: `{conf}` against the {_tuned_short(bench)} `{v.fixed}`: "
                "collision frames "
                f"{dc.format(3)} (fewer, CI below 0: {'met' if fewer else 'NOT met'}), "
                f"success {ds.format(3, percent=True)} (not lower: "
                f"{'met' if not_lower else 'NOT met'})."
            )
    elif v is None:
        lines.append("- `delay-0.5s` was not run: its target is not evaluated.")
    lines.append(
        f"- Collision events: {totals['events']} over the shown methods; frames of events "
        f"neither proven avoidable nor unavoidable: {totals['undecided_frames']} of "
        f"{totals['frames']} collision frames"
        + (
            f"; {totals['unknown']} colliding episodes without their run directory"
            if totals["unknown"]
            else ""
        )
        + f" (every event classified: {'met' if totals['undecided_frames'] == 0 else 'NOT met'})."
    )
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ no regret
def _grid(v: _ShiftView) -> list[MethodSummary]:
    """The reference family's members that ran under this shift, by setting."""
    from .methods import FAMILIES

    fam = next((f for f in FAMILIES.values() if f.reference), None)
    if fam is None:
        return []
    # (a view drawn without its summaries, e.g. a figure test's, has no grid)
    members = [s for s in getattr(v, "summaries", ()) if s.family == fam.name]
    return sorted(members, key=lambda s: _num(s.setting.split("=")[-1].rstrip("/s")))


def _adaptive(v: _ShiftView) -> list[str]:
    """The shown methods whose family learns lambda (the grid's own family aside)."""
    from .methods import FAMILIES

    out = []
    for s in v.shown:
        fam = FAMILIES.get(s.family)
        if fam is not None and fam.learn and not fam.reference and s.method not in out:
            out.append(s.method)
    return out


def _no_regret(
    views: list[_ShiftView], out: Path, bench: Mapping[str, Any] | None
) -> dict[str, list[GridComparison]]:
    """Write ``no_regret.md`` / ``.csv``; return the comparisons per shift."""
    tuned = set(_tuned_names(bench).values())
    comps: dict[str, list[GridComparison]] = {}
    md = [
        "# Adaptive methods against every fixed lambda",
        "",
        "Per shift, each adaptive method against the whole fixed-lambda grid this folder ran "
        "(means over the same scenarios). *Dominated by*: grid members at least as good on "
        "success, reached and collision frames, and better on one. *Regret*: the best grid "
        "member on that figure minus the method (collision frames: the method minus the "
        "best), positive when the grid did better; the best member is named. *Re-tuned*: "
        "the method minus the grid member the tuning rule picks on this split (which knows "
        "the shift), positive when the method did better (collision frames: fewer).",
        "",
    ]
    header = ["shift", "method", _tuned_short(bench), "dominated by"]
    for f in ("success", "reached", "collision frames"):
        header += [f, f"regret {f}", f"best {f}", f"vs re-tuned {f}"]
    table: list[list[Any]] = []
    for v in views:
        grid = [s.method for s in _grid(v)]
        comps[v.shift] = c = compare_with_grid(
            v.shift, v.summaries, grid, _adaptive(v), v.reference
        )
        if not c:
            continue
        md += [
            f"## Shift `{v.shift}` ({v.n_scenarios} scenarios, {len(grid)} fixed settings; "
            f"re-tuned: `{v.reference}`)",
            "",
            "| method | success | reached | collision frames | dominated by | regret success "
            "| regret reached | regret collision frames | vs re-tuned (success, reached, "
            "collision frames) |",
            "|---|---:|---:|---:|---|---|---|---|---|",
        ]
        for x in c:
            fg, rg, bg, tg = x.figures, x.regret, x.best, x.to_reference
            dom = ", ".join(f"`{m}`" for m in x.dominated_by) or "none"
            name = f"`{x.method}`" + (f" ({_tuned_short(bench)})" if x.method in tuned else "")
            vs = (
                f"{100 * tg['success']:+.1f}, {100 * tg['reached']:+.1f}, "
                f"{tg['collision frames']:+.2f}"
                if tg
                else "-"
            )
            md.append(
                f"| {name} | {100 * fg['success']:.1f} % | {100 * fg['reached']:.1f} % | "
                f"{fg['collision frames']:.2f} | {dom} | {100 * rg['success']:+.1f} "
                f"(`{bg['success']}`) | {100 * rg['reached']:+.1f} (`{bg['reached']}`) | "
                f"{rg['collision frames']:+.2f} (`{bg['collision frames']}`) | {vs} |"
            )
            row: list[Any] = [v.shift, x.method, x.method in tuned, ";".join(x.dominated_by)]
            for fig in ("success", "reached", "collision frames"):
                row += [fg[fig], rg.get(fig), bg.get(fig), tg.get(fig)]
            table.append(row)
        md.append("")
    _write_csv(out / "no_regret.csv", header, table)
    (out / "no_regret.md").write_text("\n".join(md) + "\n")
    return comps


def _issue_targets(
    views: list[_ShiftView],
    comps: Mapping[str, list[GridComparison]],
    bench: Mapping[str, Any] | None,
) -> str:
    """The per-agent issue's targets
    (:func:`~conformal_control.experiments.bench.regret.issue_targets`)
    for the dev-tuned adaptive methods."""
    tuned = set(_tuned_names(bench).values())
    methods = [m for v in views for m in _adaptive(v) if m in tuned]
    methods = list(dict.fromkeys(methods))
    if not methods:
        return ""
    checks = issue_targets({v.shift: v.summaries for v in views}, comps, methods)
    lines = [
        "",
        "## Adaptation without the reach penalty",
        "",
        "Under `delay-0.5s` and `noise-0.25m`: at most 50 % of `nolearn`'s collision frames, "
        "the goal reached in time within 5 points of `nolearn`, dominated by no fixed lambda "
        "of the grid; under `nominal`: success within 2 points of `nolearn`'s.",
        "",
        "| method | delay-0.5s (collision share, reached, dominated) | noise-0.25m (same) | "
        "nominal success | all met |",
        "|---|---|---|---|---|",
    ]
    for c in checks:
        cells = []
        for sh in ("delay-0.5s", "noise-0.25m"):
            x = c.shifts.get(sh)
            cells.append(
                "not run"
                if x is None
                else f"{100 * x[0]:.0f} %, {x[1]:+.1f} pts, {'dominated' if x[2] else 'not'}: "
                f"{'met' if x[3] else 'NOT met'}"
            )
        nom = (
            "not run"
            if c.nominal is None
            else f"{c.nominal[0]:+.1f} pts: {'met' if c.nominal[1] else 'NOT met'}"
        )
        lines.append(
            f"| `{c.method}` | {cells[0]} | {cells[1]} | {nom} | {'met' if c.met else 'NOT met'} |"
        )
    some = any(c.met for c in checks)
    lines += [
        "",
        f"- Some {_tuned_short(bench)} adaptive method meets them all: "
        f"{'met' if some else 'NOT met'}.",
    ]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ agents
def _agent_data(row: Mapping[str, Any]) -> dict[str, Any] | None:
    """A row's per-agent figures (from its run's ``metrics.json``), None if unknown."""
    rd = row.get("run_dir")
    if not rd:
        return None
    try:
        data = json.loads((Path(str(rd)) / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    agents = data.get("agents")
    return agents if isinstance(agents, dict) else None


def _agents(views: list[_ShiftView], rows: list[dict[str, Any]], out: Path) -> bool:
    """Write ``agents.md`` for the methods run with lambda per agent; False if none."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if _num(r.get("n_agents")) >= 0:
            groups[(r["shift"], str(r["method"]))].append(r)
    if not groups:
        return False
    md = [
        "# lambda per agent: each agent's average loss",
        "",
        "Agents with at least 10 losses (checked one by one), pooled over the scenarios: "
        "the distribution of their average loss minus epsilon (the fixed-step identity "
        "makes it (lambda_j,1 - lambda_j,end) / (eta K_j) exactly while lambda_j is not "
        "clipped; a floor that binds keeps the agent's loss above epsilon meanwhile), and "
        "how many meet their own bound where the run had one (Theorem 2 with lambda_safe, "
        "or a long-run bound). Episodes whose run folder is missing are counted apart.",
        "",
        "Where the run had a `lambda_safe` (the per-pedestrian methods: `lambda_safe=auto`, "
        "derived from the CBF gap bound, see the Benchmark page), Theorem 2's premise "
        "(lambda_j <= lambda_safe keeps agent j's loss <= epsilon) is checked two ways: "
        "*tested* counts the agents with an update at lambda_j <= lambda_safe and, of "
        "those, the agents with a loss above epsilon there; *every interval* re-evaluates "
        "each agent's loss at lambda_safe at every interval (with the decision the robot "
        "took) and counts the losses above epsilon. *Assumption* counts the episodes where "
        "Theorem 2's lambda_1 >= lambda_safe - eta and lambda_min <= lambda_safe - eta hold "
        "(a floor above lambda_safe - eta breaks it: clipping adds to lambda, and the "
        "bound is then arithmetic only).",
        "",
        "| shift | method | episodes | agents checked | median | 90th percentile | "
        "largest | within 0.01 of epsilon | lambda_safe (1/s) | bound met | assumption | "
        "premise tested: agents failed / tested | premise at every interval: losses above "
        "epsilon / checked |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|---|---|---|",
    ]
    for (shift, method), g in sorted(groups.items()):
        gaps: list[float] = []
        met = with_bound = missing = 0
        for r in g:
            data = _agent_data(r)
            if data is None:
                missing += 1
                continue
            eps = _num(r.get("epsilon"))
            for avg, b in zip(data.get("l_avg", []), data.get("bound", []), strict=False):
                gaps.append(_num(avg) - eps)
                if b is not None:
                    with_bound += 1
                    met += int(_num(avg) <= _num(b) + 1e-12)
        x = np.asarray(gaps, dtype=float)
        if x.size:
            cells = (
                f"{np.median(x):+.4f} | {np.quantile(x, 0.9):+.4f} | {x.max():+.4f} | "
                f"{100 * np.mean(x <= 0.01):.0f} %"
            )
        else:
            cells = "- | - | - | -"
        safe = [r for r in g if math.isfinite(_num(r.get("lambda_safe")))]
        if with_bound:
            bound = f"{met} of {with_bound}"
        elif safe:
            bound = f"no bound (rule {g[0].get('rule') or '?'})"
        else:
            bound = "no bound (no lambda_safe)"
        note = f" ({missing} without run folder)" if missing else ""
        md.append(
            f"| {shift} | `{method}` | {len(g)}{note} | {x.size} | {cells} | "
            f"{_premise_cells(safe)} | {bound} | {_premise_rest(safe)} |"
        )
    (out / "agents.md").write_text("\n".join(md) + "\n")
    return True


def _premise_cells(safe: list[dict[str, Any]]) -> str:
    """The rows' lambda_safe in 1/s (one value, or their range), "-" without one."""
    values = sorted(
        {round(_num(r.get("lambda_safe")) * _num(r.get("lambda_unit_si") or 1.0), 6) for r in safe}
    )
    if not values:
        return "-"
    return f"{values[0]:.1f}" if len(values) == 1 else f"{values[0]:.1f} to {values[-1]:.1f}"


def _premise_rest(safe: list[dict[str, Any]]) -> str:
    """The assumption, the premise tested and the premise at every interval (cells)."""
    if not safe:
        return "- | - | -"

    def total(key: str) -> int:
        return int(sum(v for r in safe if math.isfinite(v := _num(r.get(key)))))

    with_assumption = [r for r in safe if math.isfinite(_num(r.get("theorem2_assumption")))]
    held = sum(int(_num(r.get("theorem2_assumption")) == 1.0) for r in with_assumption)
    assumption = f"holds in {held} of {len(with_assumption)} episodes" if with_assumption else "-"
    tested = f"{total('n_agents_premise_failed')} / {total('n_agents_premise_tested')} agents"
    checks = total("n_premise_checks")
    every = (
        f"{total('n_premise_exceeded')} / {checks} ({total('n_agents_premise_exceeded')} agents)"
        if checks
        else "not checked (the loss cannot re-evaluate)"
    )
    return f"{assumption} | {tested} | {every}"


# ------------------------------------------------------------------ entry point
#: Row keys that describe a run's configuration (the sweep's flat rows: the run's own
#: fields, its ``meta``, and its ``episode.*``, ``predictor_params.*``, ``param.*``).
_CONFIG_KEYS = frozenset(
    {"scene", "predictor", "learn", "seed", "max_frames", "suite", "split", "crowd",
     "tuned_from", "family", "setting", "time_limit", "rule"}
)  # fmt: skip
_CONFIG_PREFIXES = ("episode.", "predictor_params.", "param.")


def _differences(rows: list[dict[str, Any]]) -> list[str]:
    """``key (v1, v2)`` for every configuration key whose value differs between ``rows``."""
    keys = sorted({k for r in rows for k in r})
    out = []
    for k in keys:
        if k not in _CONFIG_KEYS and not k.startswith(_CONFIG_PREFIXES):
            continue
        values = list(dict.fromkeys(json.dumps(r.get(k), default=str) for r in rows))
        if len(values) > 1:
            shown = ", ".join(repr(json.loads(v)) for v in values[:4])
            out.append(f"{k} ({shown}{', ...' if len(values) > 4 else ''})")
    return out


def _check_unique(rows: list[dict[str, Any]]) -> None:
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[(r["shift"], str(r["method"]), str(r["scenario"]))].append(r)
    dup = [k for k, g in groups.items() if len(g) > 1]
    if dup:
        shift, method, scenario = dup[0]
        differ = _differences(groups[dup[0]])
        what = (
            "they differ in " + "; ".join(differ)
            if differ
            else "their stored configurations do not say how they differ"
        )
        raise ValueError(
            f"the rows hold {len(groups[dup[0]])} runs of method {method} on scenario "
            f"{scenario} under shift {shift} ({len(dup)} such triple(s)): {what}; runs of "
            "different conditions are never pooled: report them from separate folders"
        )


def write_report(
    rows: Sequence[Mapping[str, Any]],
    out: str | Path,
    *,
    baseline: str = "nolearn",
    title: str = "Benchmark",
    seed: int = 0,
    bench: Mapping[str, Any] | None = None,
    tune_wall: float | None = None,
    notice: str | None = None,
) -> dict[str, Path]:
    """Write the report (see the module docstring) into ``out``; return the files.

    Parameters
    ----------
    rows : sequence of mapping
        The benchmark's rows (:func:`~conformal_control.experiments.bench.suite.read_rows`).
    out : str or Path
        The report's folder (created).
    baseline : str
        The method every other is paired with.
    title : str
        The title of the Markdown pages.
    seed : int
        Seed of the bootstraps.
    bench : mapping, optional
        The folder's ``bench.json`` (its tuned values name the dev-tuned methods).
    tune_wall : float, optional
        Seconds ``bench tune`` took (for the run-time target).
    notice : str, optional
        The first line of every page (a folder with unfinished episodes:
        :func:`~conformal_control.experiments.bench.suite.incomplete_notice`).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = canonical_order(rows)
    ok, _ = _ok_rows(rows)
    if not ok:
        raise ValueError("no successful episode in the results: nothing to report")
    _check_unique(ok)
    order = {name: i for i, name in enumerate(SHIFTS)}
    shifts = sorted({r["shift"] for r in ok}, key=lambda s: (order.get(s, len(order)), s))
    prepared = [_prepared(r) for r in rows]
    views = [
        _view(sh, [r for r in prepared if r["shift"] == sh], baseline, seed, bench) for sh in shifts
    ]
    files = {
        "leaderboard.md": out / "leaderboard.md",
        "leaderboard.csv": out / "leaderboard.csv",
        "per_scene.csv": out / "per_scene.csv",
        "per_scene.md": out / "per_scene.md",
        "strata.md": out / "strata.md",
        "strata.csv": out / "strata.csv",
        "collisions.md": out / "collisions.md",
        "collisions.csv": out / "collisions.csv",
        "targets.md": out / "targets.md",
    }
    files["leaderboard.md"].write_text(_leaderboard_md(views, baseline, title))
    _leaderboard_csv(files["leaderboard.csv"], views)
    _per_scene(ok, out)
    _strata(views, ok, out)
    totals = _collisions(views, ok, out)
    comparisons = _no_regret(views, out, bench)
    files["no_regret.md"], files["no_regret.csv"] = out / "no_regret.md", out / "no_regret.csv"
    files["targets.md"].write_text(
        _targets(views, totals, bench, tune_wall) + _issue_targets(views, comparisons, bench)
    )
    if _agents(views, ok, out):
        files["agents.md"] = out / "agents.md"
    jobs: list[FigureJob] = []
    for v in views:
        name = "frontier.png" if len(views) == 1 else f"frontier-{v.shift}.png"
        files[name] = out / name
        title_v = f"{title}: shift {v.shift} ({v.n_scenarios} scenarios)"
        jobs.append((_frontier, (v, files[name], title_v), {}))
    curves = _epsilon_curves(ok, seed)
    if curves is not None:
        files["success_vs_epsilon.png"] = out / "success_vs_epsilon.png"
        jobs.append((_success_vs_epsilon, (*curves, files["success_vs_epsilon.png"]), {}))
    draw_all(jobs)  # a third of a second each: split between two cores where possible
    if notice:  # an incomplete folder says so on the first line of every page
        for path in files.values():
            if path.suffix == ".md" and path.exists():
                path.write_text(f"{notice}\n\n{path.read_text()}")
    return files
