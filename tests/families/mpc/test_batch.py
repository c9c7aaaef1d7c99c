"""Sampling-MPC episodes in lockstep (one compiled evaluation for every episode's plans)
equal the episodes run one by one, field by field."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conformal_control.experiments.bench import planar
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import Unicycle, VelocityTrackingDoubleIntegrator
from conformal_control.families.mpc import ECPMPC, SamplingMPC
from conformal_control.families.mpc.batch import plan_all
from conformal_control.families.mpc.kernels import evaluate, evaluate_many
from conformal_control.predictors import ConstantVelocityPredictor, PredictionQuery

#: measured times: not part of the equality (a batch shares its joint evaluation's time)
TIMES = ("ctrl_ms", "pred_ms")


def _untimed(res: planar.ScenarioResult) -> dict[str, Any]:
    metrics = {k: v for k, v in res.metrics().items() if k != "ctrl_time_ms"}
    steps = [{k: v for k, v in s.items() if k not in TIMES} for s in res.steps]
    return {
        "metrics": metrics,
        "steps": steps,
        "goal_step": res.goal_step,
        "ended": res.ended,
        "stats": res.stats,
    }


@pytest.mark.parametrize("method", ["mpc", "cc_mpc", "cc_mpc_brake", "acp_mpc", "ecp_mpc"])
def test_lockstep_scenarios_equal_one_by_one(method: str, data_root: Path) -> None:
    task = planar.TASKS["zara1"]
    starts = list(task.start_timesteps)
    m = planar.PLANAR_METHODS[method]
    alone = [planar.run_scenario(task, t, m, data_root=data_root) for t in starts]
    together = planar.run_scenarios(task, starts, m, data_root=data_root)
    assert len(together) == len(alone) == 3
    for a, b in zip(alone, together, strict=True):
        assert _untimed(b) == _untimed(a)
        assert sum(s["recorded"] for s in a.steps) > 20  # the scenarios did decide
        timed = [s["ctrl_ms"] for s in b.steps if s["recorded"]]
        assert all(t is not None and t > 0 for t in timed)
    assert any(s["status"] != "optimal" for r in alone for s in r.steps if s["recorded"])


def test_evaluate_many_equals_evaluate_problem_by_problem() -> None:
    rng = np.random.default_rng(3)
    problems = []
    for n, m in ((40, 5), (1, 0), (17, 3), (25, 1)):
        pos = rng.normal(0.0, 3.0, (n, 6, 2))
        cmds = rng.normal(0.0, 1.0, (n, 6, 2))
        pred = rng.normal(0.0, 3.0, (m, 6, 2))
        y0 = rng.normal(0.0, 3.0, (m, 2))
        radius = rng.uniform(0.5, 2.0, (n, 6)) if n > 20 else rng.uniform(0.5, 2.0, 6)
        problems.append(
            (pos, cmds, rng.normal(size=2), pred, y0, radius, rng.normal(size=2),
             (1.0, 10.0, 0.01, 0.1), rng.normal(size=2), n != 17)
        )  # fmt: skip
    problems[2][0][:] = problems[2][2]  # a robot standing still among frozen agents
    problems[2][3][:] = problems[2][3][:, :1]
    problems[2][4][:] = problems[2][3][:, 0]
    for one, many in zip([evaluate(*p) for p in problems], evaluate_many(problems), strict=True):
        for a, b in zip(one, many, strict=True):
            np.testing.assert_array_equal(a, b)
    assert evaluate_many([]) == []
    with pytest.raises(ValueError, match="one horizon"):
        evaluate_many([problems[0], (np.zeros((2, 3, 2)), *problems[0][1:])])


def _query(rng: np.random.Generator, m: int, t: float) -> PredictionQuery:
    cur = rng.uniform(-4.0, 4.0, (m, 2))
    vel = rng.normal(0.0, 1.0, (m, 2))
    hist = cur[:, None, :] - vel[:, None, :] * 0.4 * np.arange(7, -1, -1)[None, :, None]
    return PredictionQuery(ids=np.arange(m), history=hist, dt=0.4, horizon=1, t=t)


@pytest.mark.parametrize("replan_every", [1, 3])
def test_plan_all_decides_as_each_family_alone(replan_every: int) -> None:
    """Families with different plants, sample counts and crowds, planned together."""

    def families() -> list[SamplingMPC]:
        cv = ConstantVelocityPredictor
        common: dict[str, Any] = {"sampling__horizon": 5, "sampling__dt_plan": 0.4, "substeps": 1}
        out: list[SamplingMPC] = [
            SamplingMPC(
                cv(),
                Unicycle(),
                sampling__n_samples=60,
                sampling__replan_every=replan_every,
                **common,
            ),
            SamplingMPC(
                cv(),
                VelocityTrackingDoubleIntegrator(K_acc=20.0),
                sampling__n_samples=30,
                fallback="least_violation",
                random_state=4,
                **common,
            ),
            ECPMPC(cv(), Unicycle(), sampling__n_samples=40, calibration_size=3, **common),
        ]
        for f in out:
            f.reset()
        return out

    def run(together: bool) -> tuple[list[list[np.ndarray]], list[dict[str, float]]]:
        fams = families()
        plants = [f.dynamics for f in fams]
        xs = [p.initial_state(np.zeros(2), 0.2) for p in plants]
        goal = np.array([8.0, 2.0])
        rng = np.random.default_rng(11)
        cmds: list[list[np.ndarray]] = [[] for _ in fams]
        for k in range(12):
            states = []
            for i, f in enumerate(fams):
                f.begin_interval(_query(rng, 4 + i, t=0.4 * k))
                states.append(ControlState(x=xs[i], t=0.4 * k, step=0, goal=goal))
            if together:
                plan_all([(f, st, -0.1 * i) for i, (f, st) in enumerate(zip(fams, states))])  # noqa: B905
            for i, (f, st) in enumerate(zip(fams, states, strict=True)):
                cmd = f.decide(st, -0.1 * i)
                cmds[i].append(cmd)
                xs[i] = plants[i].step(xs[i], cmd, 0.4)
        return cmds, [f.stats() for f in fams]

    alone, alone_stats = run(False)
    together, together_stats = run(True)
    assert together_stats == alone_stats
    assert sum(s["n_plans"] for s in alone_stats) > 12  # replanned (and replayed) plans
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(np.array(a), np.array(b))
