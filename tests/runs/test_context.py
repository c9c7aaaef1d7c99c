"""The run context: a plugin receives the run values its class declares, nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.core.spec import RUN_VALUES, RunContext
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor
from conformal_control.runs.build import build_flagship


class CappedWalker(Predictor):
    """Walks on at the last velocity, capped at the pedestrians' own speed limit.

    Parameters
    ----------
    v_max : float
        The pedestrians' speed cap (m/s), not the robot's.
    random_state : int
        Unused seed.
    """

    def __init__(self, v_max: float = 2.5, random_state: int = 7) -> None:
        self.v_max = v_max
        self.random_state = random_state

    def predict(self, query: PredictionQuery) -> Forecast:
        last = query.history[:, -1]
        return Forecast(np.repeat(last[:, None], query.horizon, axis=1))


class SeededWalker(CappedWalker, run_values={"random_state": "seed", "v_max": "v_max"}):
    """The same, asking for the run's seed and the robot's speed limit.

    Parameters
    ----------
    v_max : float
        Speed cap (m/s).
    random_state : int
        Seed.
    """


@pytest.fixture
def walkers():
    registry.register("predictor", "capped_walker", CappedWalker)
    registry.register("predictor", "seeded_walker", SeededWalker)
    yield
    registry.unregister("predictor", "capped_walker")
    registry.unregister("predictor", "seeded_walker")


def test_a_plugins_own_default_is_never_replaced_by_a_run_value_it_did_not_ask_for(
    crossing, walkers
) -> None:
    fl = build_flagship(crossing, predictor="capped_walker", seed=3, units="si")
    assert fl.params.si["v_max"] == 2.0  # the robot's speed limit
    assert fl.predictor.v_max == 2.5 and fl.predictor.random_state == 7
    declared = build_flagship(crossing, predictor="seeded_walker", seed=3, units="si")
    assert declared.predictor.v_max == 2.0 and declared.predictor.random_state == 3
    given = build_flagship(
        crossing, predictor="seeded_walker", predictor_params={"v_max": 1.5}, seed=3, units="si"
    )
    assert given.predictor.v_max == 1.5  # the caller's value wins


def test_the_flagships_parts_receive_what_they_declare(crossing) -> None:
    fl = build_flagship(crossing, {"barrier_margin": 0.1, "v_max": 1.7}, units="si")
    si = fl.params.si
    d_c = si["robot_radius"] + si["agent_radius"]
    assert fl.barrier.d_c == pytest.approx(d_c + 0.1)
    assert fl.safety_filter.v_max == fl.reference.v_max == 1.7
    assert fl.loss.constraint is fl.constraint is fl.family.constraint
    assert fl.family.predictor is fl.predictor and fl.family.safety_filter is fl.safety_filter


def test_arguments_pass_only_declared_values_a_run_fixes() -> None:
    ctx = RunContext(v_max=2.0, seed=4)
    assert ctx.arguments(CappedWalker) == {}
    assert ctx.arguments(SeededWalker) == {"v_max": 2.0, "random_state": 4}
    assert ctx.arguments(SeededWalker, {"random_state": 1}) == {"v_max": 2.0, "random_state": 1}
    assert RunContext().arguments(SeededWalker) == {}  # a value the run does not fix


def test_run_values_are_the_context_fields() -> None:
    assert list(RUN_VALUES) == [f for f in RunContext.__dataclass_fields__]
