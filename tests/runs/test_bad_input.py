"""Bad input gets a clear error or a documented, counted fallback - never a crash."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.data.scene import Scene
from conformal_control.predictors import ConstantVelocityPredictor
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor
from conformal_control.runs.episode import run_episode


class Corrupting(Predictor):
    """Constant velocity, with every other agent's forecast replaced by ``value``."""

    def __init__(self, value: float = np.nan) -> None:
        self.value = value

    def predict(self, query: PredictionQuery) -> Forecast:
        fc = ConstantVelocityPredictor().predict(query)
        fc.positions[::2, query.horizon // 2 :] = self.value
        return fc


class WrongShape(Predictor):
    def predict(self, query: PredictionQuery) -> Forecast:
        return Forecast(np.zeros((query.n_agents, 1, 3)))


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_predictions_are_held_and_counted(crossing, value) -> None:
    # the default lambda floor opened, so that the identity holds exactly (no clipped update)
    res = run_episode(crossing, Corrupting(value), {"lambda_min": -math.inf})
    m = res.metrics
    assert m["n_nonfinite_predictions"] > 0
    assert m["goal_reached"] and m["identity_residual"] < 1e-9
    assert all(np.isfinite(iv.loss) for iv in res.loop.updates)


def test_wrong_forecast_shape_is_a_clear_error(crossing) -> None:
    with pytest.raises(ValueError, match=r"predictor returned positions of shape .* expected"):
        run_episode(crossing, WrongShape())


def tiny_scene(positions: np.ndarray, **kw) -> Scene:
    return Scene(
        name="tiny",
        fps=10.0,
        first_frame=0,
        start_index=kw.pop("start_index", 2),
        positions=positions,
        agent_ids=np.arange(positions.shape[1]),
        start=np.array([0.0, 0.0]),
        goals=np.array([[20.0, 0.0]]),
        v_max=2.0,
        defaults={
            "a": 2.0,
            "K_acc": 10.0,
            "K_rep": 0.5,
            "K_att": 1.0,
            "rho0": 5.0,
            "tau": 0.4,
            "eta": 1.0,
            "epsilon": -0.1,
            "loss_scale": 1.0,
        },
        robot_radius=0.4,
        agent_radius=0.3,
        **kw,
    )


def test_empty_scene_runs_without_updates() -> None:
    res = run_episode(tiny_scene(np.zeros((200, 0, 2))), "constant_velocity")
    m = res.metrics
    assert m["goal_reached"] and m["n_updates"] == 0 and m["d_min"] is None
    assert m["n_collide"] == 0 and m["l_avg"] is None
    assert m["n_unscored"] == m["n_intervals"] > 0


def test_agents_vanishing_mid_interval() -> None:
    f = 200
    pos = np.full((f, 2, 2), np.nan)
    t = np.arange(f) / 10.0
    pos[:, 0, 0] = 6.0 + 0.0 * t  # standing beside the path
    pos[:, 0, 1] = 1.5
    pos[:, 1, 0] = 3.0 + 0.5 * t  # walking ahead of the robot ...
    pos[:, 1, 1] = -1.5
    pos[35:, 1] = np.nan  # ... and vanishing at frame 35 (mid-interval: 4-frame intervals from 2)
    res = run_episode(tiny_scene(pos), "constant_velocity")
    m = res.metrics
    assert m["n_truth_missing"] > 0
    assert m["n_updates"] > 0 and m["goal_reached"]


def test_zero_distance_and_overlap_fall_back_without_crashing() -> None:
    f = 200
    pos = np.full((f, 1, 2), np.nan)
    pos[:, 0] = [0.0, 0.0]  # a pedestrian standing exactly on the robot's start
    res = run_episode(tiny_scene(pos), "constant_velocity", fallback="lambda_search")
    m = res.metrics
    assert m["n_fallback"] > 0 and m["n_fallback"] == m["n_infeasible"]
    assert np.isfinite(res.trajectory["x"]).all()
    assert m["d_min"] == pytest.approx(0.0)


def test_scene_validation_messages() -> None:
    with pytest.raises(ValueError, match="leaves no data"):
        run_episode(tiny_scene(np.zeros((3, 0, 2)), start_index=2), "constant_velocity")
    bad = np.zeros((50, 1, 2))
    bad[5, 0, 0] = np.inf
    with pytest.raises(ValueError, match="positions contain inf"):
        run_episode(tiny_scene(bad), "constant_velocity")
