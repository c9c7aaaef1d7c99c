"""lambda run per agent in the sampling MPC: agent j's safe distance is d_c + margin -
lambda_j, learned from agent j's own distance shortfall; one agent is the scalar MPC bit
for bit."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.data.scene import scene_from_tracks
from conformal_control.data.tracks import Tracks
from conformal_control.data.units import SI
from conformal_control.families.mpc.kernels import evaluate, evaluate_many
from conformal_control.runs.episode import run_episode

FPS = 10.0


def _scene(tracks):
    n = next(iter(tracks.values())).shape[0]
    data = Tracks(FPS, {k: (np.arange(n), xy) for k, xy in tracks.items()}, source="made")
    defaults = {"a": 2.0, "K_acc": 10.0, "K_rep": 0.5, "K_att": 1.0, "rho0": 8.0, "tau": 0.4}
    return scene_from_tracks(
        data, name="made", start=np.array([0.0, 0.0]), goals=np.array([[30.0, 0.0]]),
        start_frame=20, v_max=1.0, history_frames=20, units=SI,
        defaults={**defaults, "eta": 0.2, "epsilon": 0.1, "loss_scale": 1.0},
        robot_radius=0.3, agent_radius=0.3,
    )  # fmt: skip


def _straight(p0, v, n=260):
    return np.asarray(p0, dtype=float) + np.arange(n)[:, None] / FPS * np.asarray(v, dtype=float)


def _circling(centre, radius, omega, n=260):
    t = np.arange(n) / FPS
    return np.column_stack(
        [centre[0] + radius * np.cos(omega * t), centre[1] + radius * np.sin(omega * t)]
    )


MPC = {
    "family": "mpc",
    "family_params": {"sampling__n_samples": 60, "sampling__horizon": 6},
    "params": {"epsilon": 0.1, "eta": 0.2, "lambda_min": -1.0},
}


def _run(scene, **params):
    kw = {**MPC, "params": {**MPC["params"], **params}}
    return run_episode(scene, engine="loop", max_frames=120, **kw)


def test_one_agent_per_agent_is_the_scalar_mpc_bit_for_bit():
    scene = _scene({1: _circling((5.0, 0.3), 1.5, 0.8)})
    a, b = _run(scene, lambda_per="run"), _run(scene, lambda_per="agent")
    ia, ib = a.loop.intervals, b.loop.intervals
    assert len(ia) == len(ib) > 20 and sum(iv.loss is not None for iv in ia) > 10
    for x, y in zip(ia, ib, strict=True):
        assert (x.lam, x.loss, x.n_steps, x.diagnostics) == (
            y.lam,
            y.loss,
            y.n_steps,
            y.diagnostics,
        )
    assert np.array_equal(a.steps["cmd"], b.steps["cmd"])
    assert len({iv.lam for iv in ia}) > 3  # lambda moved


def test_each_agent_gets_its_own_safe_distance_in_the_kernel():
    rng = np.random.default_rng(0)
    pos = rng.uniform(-3, 3, (40, 5, 2))
    cmds = rng.uniform(-1, 1, (40, 5, 2))
    pred = rng.uniform(-3, 3, (3, 5, 2))
    y0 = rng.uniform(-3, 3, (3, 2))
    args = (np.zeros(2), pred, y0)
    radius = np.full(5, 1.0)
    off = np.array([0.0, -0.4, 0.7])
    got = evaluate(pos, cmds, *args, radius, np.ones(2), (1, 1, 0, 0), np.zeros(2), True, off)
    # reference: each agent's clearance per step with its own radius (the continuous
    # check of evaluate_numpy), then the worst agent per step
    steps = []
    for j in range(3):
        b = pos[:, :, None, :] - pred[j : j + 1].transpose(1, 0, 2)[None]
        start_p = np.concatenate([np.zeros((40, 1, 2)), pos[:, :-1]], 1)
        start_y = np.concatenate([y0[j : j + 1, None], pred[j : j + 1, :-1]], 1)
        a = start_p[:, :, None, :] - start_y.transpose(1, 0, 2)[None]
        d = b - a
        dd = (d**2).sum(-1)
        s = np.where(dd > 0, np.clip(-(a * d).sum(-1) / np.where(dd > 0, dd, 1), 0, 1), 1.0)
        q = a + s[..., None] * d
        steps.append(np.sqrt((q**2).sum(-1))[..., 0] - (radius + off[j]))
    cl = np.min(steps, axis=0)
    assert np.allclose(got[1], cl.min(axis=1), atol=1e-12)
    assert np.allclose(got[2], np.maximum(-cl, 0).sum(axis=1), atol=1e-12)
    # the batched call gives the same numbers, and no offsets is the scalar evaluation
    many = evaluate_many(
        [(pos, cmds, *args, radius, np.ones(2), (1, 1, 0, 0), np.zeros(2), True, off)] * 2
    )
    assert all(np.array_equal(m[k], got[k]) for m in many for k in range(3))
    plain = evaluate(pos, cmds, *args, radius, np.ones(2), (1, 1, 0, 0), np.zeros(2), True)
    zero = evaluate(pos, cmds, *args, radius, np.ones(2), (1, 1, 0, 0), np.zeros(2), True, off * 0)
    assert all(np.array_equal(plain[k], zero[k]) for k in range(3))


def test_two_agents_learn_their_own_distance():
    # agent 1 walks away from the robot's path, agent 2 circles close to it
    scene = _scene({1: _straight((4.0, 4.0), (0.0, 0.3)), 2: _circling((5.0, -0.5), 1.2, 1.0)})
    # (lambda_max: the default ceiling, margin = 0, would stop lambda at 0; issue 30)
    res = _run(scene, lambda_per="agent", lambda_max=1.0)
    mon = res.loop.monitor
    assert mon.entries[1].n > 5 and mon.entries[2].n > 5
    # the far agent's shortfall is 0: its lambda only grows (a smaller safe distance)
    far = mon.entries[1]
    assert max(far.losses) == 0.0 and far.lam > far.lambda_1
    with pytest.raises(ValueError, match="cannot be run per agent"):
        run_episode(
            scene, family="ecp_mpc", rule="aci", loss=None, params={"lambda_per": "agent"},
            engine="loop", max_frames=20,
        )  # fmt: skip


def test_one_agent_margin_loss_per_agent_is_the_scalar_margin_loss_bit_for_bit():
    """cc_mpc_margin_agent's loss (margin_miscoverage_agent, lambda per pedestrian) with one
    pedestrian is cc_mpc_margin (margin_miscoverage, one lambda) bit for bit."""
    scene = _scene({1: _circling((5.0, 0.3), 1.5, 0.8)})
    kw = {**MPC, "params": {**MPC["params"], "lambda_max": 1.0, "eta": 0.1}}
    a = run_episode(scene, engine="loop", max_frames=120, loss="margin_miscoverage", **kw)
    kw["params"] = {**kw["params"], "lambda_per": "agent"}
    b = run_episode(scene, engine="loop", max_frames=120, loss="margin_miscoverage_agent", **kw)
    ia, ib = a.loop.intervals, b.loop.intervals
    assert len(ia) == len(ib) > 20 and sum(iv.loss == 1.0 for iv in ia) >= 1
    for x, y in zip(ia, ib, strict=True):
        assert (x.lam, x.loss, x.n_steps, x.diagnostics) == (
            y.lam,
            y.loss,
            y.n_steps,
            y.diagnostics,
        )
    assert np.array_equal(a.steps["cmd"], b.steps["cmd"])
    assert len({iv.lam for iv in ia}) > 3  # lambda moved


def test_the_floored_method_keeps_each_lambda_above_its_floor() -> None:
    """``cc_mpc_margin_agent_floor``: each pedestrian's lambda stops at -0.2 m (at most
    0.2 m of safe distance added) where the floorless method's goes lower."""
    from conformal_control.experiments.bench.methods import expand_methods

    # a pedestrian circling across the robot's path: the constant-velocity forecast misses
    scene = _scene({1: _circling((3.0, 0.2), 1.0, 1.5)})
    lows = {}
    for name in ("cc_mpc_margin_agent", "cc_mpc_margin_agent_floor"):
        kw = expand_methods([name])[0].run_kwargs()
        kw["family_params"] = {**kw["family_params"], "sampling__n_samples": 60}
        res = run_episode(scene, engine="loop", max_frames=200, **kw)
        lam = [x for e in res.loop.monitor.entries.values() for x in e.lambdas]
        assert len(lam) >= 4
        lows[name] = min(lam)
    assert lows["cc_mpc_margin_agent"] < -0.2 - 1e-9  # the floor binds in this case
    assert lows["cc_mpc_margin_agent_floor"] == pytest.approx(-0.2)
