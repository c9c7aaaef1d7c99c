"""lambda run per agent in the CBF family: row j's slack is lambda_j, learned from agent
j's own gap loss; one agent is the scalar controller bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.data.scene import scene_from_tracks
from conformal_control.data.tracks import Tracks
from conformal_control.data.units import SI
from conformal_control.runs.episode import run_episode

FPS = 10.0
DEFAULTS = {
    "a": 2.0,
    "K_acc": 10.0,
    "K_rep": 0.5,
    "K_att": 1.0,
    "rho0": 8.0,
    "tau": 0.4,
    "eta": 2.0,
    "epsilon": 0.0,
    "loss_scale": 1.0,
}


def _scene(tracks: dict[int, np.ndarray]):
    n = next(iter(tracks.values())).shape[0]
    data = Tracks(FPS, {k: (np.arange(n), xy) for k, xy in tracks.items()}, source="made")
    return scene_from_tracks(
        data,
        name="made",
        start=np.array([0.0, 0.0]),
        goals=np.array([[30.0, 0.0]]),
        start_frame=20,
        v_max=1.0,
        history_frames=20,
        units=SI,
        defaults=DEFAULTS,
        robot_radius=0.3,
        agent_radius=0.3,
    )


def _straight(p0, v, n=260):
    t = np.arange(n)[:, None] / FPS
    return np.asarray(p0, dtype=float) + t * np.asarray(v, dtype=float)


def _circling(centre, radius, omega, n=260):
    t = np.arange(n) / FPS
    return np.column_stack(
        [centre[0] + radius * np.cos(omega * t), centre[1] + radius * np.sin(omega * t)]
    )


def _run(scene, loss=None, **params):
    return run_episode(scene, params=params, loss=loss, engine="loop", max_frames=200)


def test_one_agent_per_agent_is_the_scalar_controller_bit_for_bit():
    # one pedestrian curving across the robot's path: the constant-velocity predictor errs
    scene = _scene({1: _circling((8.0, 0.5), 2.0, 0.8)})
    runs = {per: _run(scene, lambda_per=per, epsilon=-0.05) for per in ("run", "agent")}
    a, b = runs["run"], runs["agent"]
    ia, ib = a.loop.intervals, b.loop.intervals
    assert len(ia) == len(ib) > 30
    assert sum(iv.loss is not None for iv in ia) > 20
    for x, y in zip(ia, ib, strict=True):
        assert (x.lam, x.loss, x.n_steps) == (y.lam, y.loss, y.n_steps)
        assert x.diagnostics == y.diagnostics
    assert np.array_equal(a.steps["x"], b.steps["x"])
    assert np.array_equal(a.steps["cmd"], b.steps["cmd"])
    lams = [iv.lam for iv in ia]
    assert max(lams) - min(lams) > 0.1  # lambda did move
    assert a.metrics.l_avg == b.metrics.l_avg
    assert b.loop.monitor.summary()["n_agents"] == 1


def test_only_the_badly_predicted_agents_lambda_moves():
    # agent 1 walks straight (constant velocity: predicted exactly, to round-off), agent 2
    # circles (the constant-velocity prediction is wrong); both within sensing range
    scene = _scene({1: _straight((6.0, 3.0), (-0.3, 0.0)), 2: _circling((6.0, -2.5), 1.5, 1.2)})
    res = _run(scene, lambda_per="agent", epsilon=0.0, eta=5.0)
    mon = res.loop.monitor
    good, bad = mon.entries[1], mon.entries[2]
    assert good.n > 20 and bad.n > 20
    assert max(abs(x) for x in good.lambdas) < 1e-9  # loss s(0 + 0) = epsilon: no step
    assert max(good.lambdas) - min(good.lambdas) < 1e-9
    assert max(bad.lambdas) - min(bad.lambdas) > 0.5
    # the interval's loss is the largest agent term; the monitor's average is per agent
    for iv in res.loop.intervals:
        if iv.loss is not None:
            assert iv.loss == np.nanmax(iv.agent_losses)
            assert iv.lam == iv.lams.min()


def test_per_agent_needs_a_family_and_a_loss_that_split_by_agent():
    scene = _scene({1: _straight((6.0, 3.0), (-0.3, 0.0))})
    with pytest.raises(ValueError, match="does not split by agent"):
        _run(scene, loss="collision", lambda_per="agent")
    with pytest.raises(ValueError, match="lambda_per must be one of run, agent"):
        _run(scene, lambda_per="pedestrian")
    with pytest.raises(ValueError, match="lambda_prior must be a quantile"):
        _run(scene, lambda_per="agent", lambda_prior=2.0)
