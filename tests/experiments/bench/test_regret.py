"""Adaptive methods against the whole fixed-lambda grid: domination, regret, the targets."""

from __future__ import annotations

import json

import pytest

from conformal_control.experiments.bench.regret import compare_with_grid, issue_targets
from conformal_control.experiments.bench.report import write_report

#: (success, reached, collision frames) per method, per shift: a fixed grid of three, an
#: adaptive method that no member dominates under delay, one that fixed[-30] dominates.
FIGURES = {
    "nominal": {
        "nolearn": (0.70, 0.78, 3.0),
        "fixed[lambda=-10/s]": (0.71, 0.77, 2.8),
        "fixed[lambda=-30/s]": (0.66, 0.69, 2.5),
        "fixed[lambda=-45/s]": (0.50, 0.52, 0.5),
        "conformal_agent[eps=-0.05]": (0.69, 0.78, 2.6),
        "conformal[eps=-0.05]": (0.72, 0.78, 2.4),
    },
    "delay-0.5s": {
        "nolearn": (0.20, 0.80, 50.0),
        "fixed[lambda=-10/s]": (0.22, 0.77, 48.0),
        "fixed[lambda=-30/s]": (0.37, 0.68, 26.0),
        "fixed[lambda=-45/s]": (0.38, 0.40, 2.5),
        "conformal_agent[eps=-0.05]": (0.38, 0.78, 20.0),
        "conformal[eps=-0.05]": (0.36, 0.60, 27.0),
    },
}


class _Est:
    def __init__(self, mean: float) -> None:
        self.mean = mean


class _Sum:
    def __init__(self, method: str, figs: tuple[float, float, float]) -> None:
        self.method, self.family = method, method.split("[")[0]
        self.setting = method.split("[")[1].rstrip("]") if "[" in method else ""
        self.estimates = {
            "success": _Est(figs[0]),
            "reached": _Est(figs[1]),
            "collision frames": _Est(figs[2]),
        }


def _summaries(shift: str) -> list[_Sum]:
    return [_Sum(m, f) for m, f in FIGURES[shift].items()]


GRID = ["fixed[lambda=-10/s]", "fixed[lambda=-30/s]", "fixed[lambda=-45/s]"]
ADAPTIVE = ["conformal_agent[eps=-0.05]", "conformal[eps=-0.05]"]


def test_domination_and_regret_against_the_grid():
    comps = compare_with_grid(
        "delay-0.5s", _summaries("delay-0.5s"), GRID, ADAPTIVE, reference="fixed[lambda=-45/s]"
    )
    agent, scalar = comps
    assert not agent.dominated
    assert scalar.dominated_by == ["fixed[lambda=-30/s]"]  # better on all three figures
    # regret per figure to the best member in hindsight (positive: the grid did better)
    assert agent.regret["success"] == pytest.approx(0.0)  # -45 has 0.38 too
    assert agent.regret["reached"] == pytest.approx(-0.01)  # better than every member
    assert agent.regret["collision frames"] == pytest.approx(20.0 - 2.5)
    assert agent.best["collision frames"] == "fixed[lambda=-45/s]"
    # against the re-tuned member: positive = the method did better
    assert agent.to_reference["reached"] == pytest.approx(0.38)
    assert agent.to_reference["collision frames"] == pytest.approx(2.5 - 20.0)


def test_the_issue_targets():
    views = {sh: _summaries(sh) for sh in FIGURES}
    comps = {sh: compare_with_grid(sh, views[sh], GRID, ADAPTIVE) for sh in FIGURES}
    agent, scalar = issue_targets(views, comps, ADAPTIVE)
    ratio, reach, dominated, ok = agent.shifts["delay-0.5s"]
    assert ratio == pytest.approx(0.4) and reach == pytest.approx(-2.0) and not dominated
    assert ok and agent.shifts["noise-0.25m"] is None  # not run: not met
    assert agent.nominal == (pytest.approx(-1.0), True) and not agent.met
    assert scalar.shifts["delay-0.5s"][3] is False  # dominated, reach 20 points short


def _rows() -> list[dict]:
    out = []
    for shift, figs in FIGURES.items():
        for method, (succ, reach, coll) in figs.items():
            for i in range(100):  # scenario i: success / reached for the first shares
                fam = method.split("[")[0]
                out.append(
                    {
                        "scenario": f"s{i}",
                        "shift": shift,
                        "method": method,
                        "family": fam,
                        "setting": method.split("[")[1].rstrip("]") if "[" in method else "",
                        "status": "ok",
                        "success": str(i < 100 * succ).lower(),
                        "goal_reached": str(i < 100 * reach).lower(),
                        "n_collide": coll,
                        "any_collision": str(coll > 0).lower(),
                        "time_limit": 10.0,
                        "t_goal": 8.0,
                    }
                )
    return out


def test_the_report_writes_the_no_regret_tables_and_the_targets(tmp_path):
    bench = {
        "tuned": {
            "split": "dev",
            "values": {"fixed": -10.0, "conformal_agent": -0.05, "conformal": -0.05},
        }
    }
    files = write_report(_rows(), tmp_path, bench=bench)
    md = files["no_regret.md"].read_text().split("## Shift `delay-0.5s`")[1]
    line = next(x for x in md.splitlines() if x.startswith("| `conformal[eps=-0.05]`"))
    assert "`fixed[lambda=-30/s]`" in line.split("|")[5]  # dominated by
    line = next(x for x in md.splitlines() if x.startswith("| `conformal_agent[eps=-0.05]`"))
    assert line.split("|")[5].strip() == "none"
    targets = files["targets.md"].read_text()
    assert "## Adaptation without the reach penalty" in targets
    assert "| `conformal_agent[eps=-0.05]` | 40 %, -2.0 pts, not: met | not run |" in targets
    assert "Some dev-tuned adaptive method meets them all: NOT met" in targets
    assert files["frontier-delay-0.5s.png"].stat().st_size > 10_000


def test_agents_md_reads_each_runs_agents(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    agents = {"min_intervals": 10, "n": [12, 30], "l_avg": [-0.04, -0.05], "bound": [None, None]}
    (run / "metrics.json").write_text(json.dumps({"agents": agents}))
    rows = [
        {
            "scenario": "s0",
            "method": "conformal_agent[eps=-0.05]",
            "family": "conformal_agent",
            "status": "ok",
            "success": "true",
            "goal_reached": "true",
            "n_collide": 0,
            "any_collision": "false",
            "t_goal": 8.0,
            "time_limit": 10.0,
            "n_agents": 2,
            "epsilon": -0.05,
            "run_dir": str(run),
        }
    ]
    files = write_report(rows, tmp_path / "report")
    md = files["agents.md"].read_text()
    # gaps to epsilon: +0.01 and 0 -> median +0.005, 90th percentile +0.009
    assert "| nominal | `conformal_agent[eps=-0.05]` | 1 | 2 | +0.0050 | +0.0090 | +0.0100 |" in md


def test_agents_md_reports_the_bound_and_the_premise_per_row(tmp_path):
    rows = []
    # two episodes of a fixed-step method with a derived lambda_safe (-4.2/frame at 30 fps:
    # -126/s): 2 of 4 agents meet their bound; one episode's premise exceeded once
    bounds = [([-0.04, 0.2], [0.1, 0.1]), ([-0.05, -0.05], [0.0, -0.06])]
    for i, (avg, bnd) in enumerate(bounds):
        run = tmp_path / f"run{i}"
        run.mkdir()
        agents = {"min_intervals": 10, "n": [12, 30], "l_avg": avg, "bound": bnd}
        (run / "metrics.json").write_text(json.dumps({"agents": agents}))
        rows.append(
            {
                "scenario": f"s{i}",
                "method": "conformal_agent[eps=-0.05]",
                "family": "conformal_agent",
                "status": "ok",
                "success": "true",
                "goal_reached": "true",
                "n_collide": 0,
                "any_collision": "false",
                "t_goal": 8.0,
                "time_limit": 10.0,
                "n_agents": 2,
                "epsilon": -0.05,
                "run_dir": str(run),
                "rule": "fixed_eta",
                "lambda_safe": -4.2,
                "lambda_unit_si": 30.0,
                "theorem2_assumption": "false" if i else "true",
                "n_agents_premise_tested": 1 - i,
                "n_agents_premise_failed": 0,
                "n_premise_checks": 50,
                "n_premise_exceeded": i,
                "n_agents_premise_exceeded": i,
            }
        )
    # the same under DtACI: lambda_safe but no Theorem-2 bound
    dt = [dict(r, method="conformal_agent_dtaci[eps=-0.05]", rule="dtaci") for r in rows]
    for r in dt:
        r["run_dir"] = ""
    files = write_report(rows + dt, tmp_path / "report")
    md = files["agents.md"].read_text()
    line = next(x for x in md.splitlines() if "`conformal_agent[eps=-0.05]`" in x)
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[8:] == [
        "-126.0",
        "2 of 4",
        "holds in 1 of 2 episodes",
        "0 / 1 agents",
        "1 / 100 (1 agents)",
    ]
    line = next(x for x in md.splitlines() if "`conformal_agent_dtaci" in x)
    assert "no bound (rule dtaci)" in line and "2 without run folder" in line
