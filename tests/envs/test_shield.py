"""ConformalShield: what it returns meets the constraints it reports; it prevents contact."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from conformal_control.data.synthetic import SYNTHETIC_DEFAULTS
from conformal_control.envs import ConformalCrowdEnv, ConformalShield


def _check_step(shield: ConformalShield, action: np.ndarray, info: dict) -> int:
    """The returned velocity against rows rebuilt from the shield's own prediction;
    returns the number of constraints that were enforced."""
    v = np.asarray(info["shield_action"], dtype=float)
    v_max = shield.env.unwrapped.core.v_max
    assert np.hypot(*v) <= v_max * (1 + 1e-9)
    assert info["shield_delta"] == pytest.approx(np.hypot(*(v - action)), abs=1e-12)
    assert info["shield_modified"] == (info["shield_delta"] > 1e-9)
    last = shield.last_
    x = shield.last_state_
    x_pred, v_pred = shield.last_prediction_
    A, b = shield.constraint.rows(x[:2], x_pred, v_pred)
    np.testing.assert_allclose(A, last.A, rtol=0, atol=0)
    np.testing.assert_allclose(b, last.b, rtol=0, atol=0)
    assert info["shield_n_constraints"] == A.shape[0]
    if not A.shape[0]:
        assert not info["shield_modified"] or np.hypot(*action) > v_max
        return 0
    lam = info["shield_lambda_applied"]
    assert np.isfinite(lam), "the default lambda_search fallback always meets every row"
    assert lam >= info["shield_lambda"]
    slack = A @ v + b + lam
    tol = 1e-6 * max(1.0, abs(lam))
    assert slack.min() >= -tol, (slack, info["shield_status"])
    ids = list(shield.last_ids_)
    for a in info["shield_active"]:
        assert abs(slack[ids.index(a)]) <= tol
    if info["shield_status"] == "unconstrained":
        np.testing.assert_array_equal(v, action)
    return int(A.shape[0])


@pytest.fixture(scope="module")
def shield(crossing):
    return ConformalShield(ConformalCrowdEnv(crossing, crowd="social_force"))


@settings(
    max_examples=12,
    deadline=None,
    # an example is a whole episode: shrinking one takes minutes, the seed reproduces it
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    seed=st.integers(0, 2**16),
    toward_goal=st.floats(0.0, 1.0),
    noise=st.floats(0.0, 3.0),
    burst=st.floats(1.0, 4.0),
)
def test_the_shield_never_returns_an_action_that_violates_its_constraints(
    shield, seed, toward_goal, noise, burst
):
    rng = np.random.default_rng(seed)
    obs, _ = shield.reset(seed=seed)
    v_max = shield.env.unwrapped.core.v_max
    for _ in range(int(rng.integers(40, 120))):
        g = obs["robot"][4:6].astype(float)
        a = toward_goal * v_max * g / max(np.hypot(*g), 1e-9) + rng.normal(0.0, noise, 2)
        if rng.random() < 0.1:
            a *= burst  # now and then beyond v_max
        obs, _, term, trunc, info = shield.step(a)
        _check_step(shield, a, info)
        _check_cause(shield, a, info)
        if term or trunc:
            break


def test_the_property_is_exercised_with_binding_constraints(shield):
    # the scripted policy on this seed meets pedestrians: binding rows are checked above
    obs, _ = shield.reset(seed=1)
    n_active = n_rows = 0
    for _ in range(600):
        g = obs["robot"][4:6].astype(float)
        a = 2.0 * g / np.hypot(*g)
        obs, _, term, trunc, info = shield.step(a)
        n_rows += _check_step(shield, a, info)
        n_active += len(info["shield_active"])
        if term or trunc:
            break
    assert n_rows > 100 and n_active > 10


def _head_on(line_scene, straight):
    # a pedestrian walks straight at the robot along its path
    scene = line_scene([straight((0.0, 12.0), (0.0, -1.2), n=300)], start_index=5)
    return dataclasses.replace(scene, defaults=dict(SYNTHETIC_DEFAULTS), v_max=2.0)


def test_shield_prevents_the_contact_a_straight_policy_makes(line_scene, straight):
    scene = _head_on(line_scene, straight)
    results = {}
    for shielded in (False, True):
        env = ConformalCrowdEnv(scene, max_frames=120)
        if shielded:
            env = ConformalShield(env)
        env.reset(seed=0)
        for _ in range(480):
            _, _, term, trunc, info = env.step(np.array([0.0, 1.5]))
            if term or trunc:
                break
        results[shielded] = info
    assert results[False]["n_collision_steps"] > 0
    assert results[True]["n_collision_steps"] == 0
    assert results[True]["shield_interventions"] > 0
    assert results[True]["shield_lambda"] != 0.0  # lambda learned online


def test_shield_needs_the_crowd_environment():
    import gymnasium as gym

    with pytest.raises(TypeError, match="ConformalCrowd-v0"):
        ConformalShield(gym.make("CartPole-v1"))


def test_shield_runs_at_the_environments_rate(crossing):
    env = ConformalCrowdEnv(crossing, max_frames=5)
    with pytest.raises(ValueError, match="rate"):
        ConformalShield(env, {"substeps": 2})


def test_gymnasium_check_env_accepts_the_shield(crossing):
    """check_env re-creates the wrapper from its recorded arguments: it refused it before."""
    import warnings

    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = ConformalShield(
        gym.make("ConformalCrowd-v0", scene=crossing, max_frames=30), {"epsilon": -0.1}
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=True)
    # the advice to check the raw environment is what this test does not want to follow
    benign = ("infinity", "symmetric and normalized", "recommend using the raw environment")
    assert [str(w.message) for w in caught if not any(b in str(w.message) for b in benign)] == []
    assert env._saved_kwargs["params"] == {"epsilon": -0.1}


# ---------------------------------------------------------------- why an action changed
def _unconstrained_answer(shield: ConformalShield, action: np.ndarray, lam: float) -> np.ndarray:
    """What a fresh copy of the shield's filter returns for ``action`` without any row."""
    inner = shield.filter.inner
    fresh = type(inner)(**inner.get_params())
    fresh.reset()
    return fresh.solve(action, np.zeros((0, 2)), np.zeros(0), lam).decision


def _check_cause(shield: ConformalShield, action: np.ndarray, info: dict) -> str:
    cause = info["shield_cause"]
    assert (cause == "none") == (not info["shield_modified"])
    if cause == "speed_limit":
        # no row binds and no fallback: the answer is the speed set's alone
        assert not info["shield_active"]
        assert info["shield_status"] == "optimal"
        v = np.asarray(info["shield_action"], dtype=float)
        np.testing.assert_allclose(
            v, _unconstrained_answer(shield, action, info["shield_lambda"]), atol=1e-6
        )
    elif cause == "constraint":
        assert info["shield_active"] or info["shield_status"] not in ("optimal", "unconstrained")
    return cause


def test_speed_clipping_is_not_counted_as_an_intervention(line_scene, straight):
    # one pedestrian far off the robot's path: an action beyond v_max is clipped, never
    # constrained
    scene = line_scene([straight((40.0, 0.0), (0.0, 0.1), n=300)], start_index=5)
    scene = dataclasses.replace(scene, defaults=dict(SYNTHETIC_DEFAULTS), v_max=2.0)
    shield = ConformalShield(ConformalCrowdEnv(scene, max_frames=20))
    _, info = shield.reset(seed=0)
    assert info["shield_interventions"] == info["shield_speed_clips"] == 0
    for k in range(40):
        a = np.array([0.0, 3.0]) if k % 2 else np.array([0.0, 1.0])
        _, _, term, trunc, info = shield.step(a)
        assert not (term or trunc)
        assert _check_cause(shield, a, info) == ("speed_limit" if k % 2 else "none")
        if k % 2:  # onto the 16-gon inscribed in the speed disc: within 2 % of v_max
            assert 0.98 * 2.0 <= np.hypot(*info["shield_action"]) <= 2.0 + 1e-9
    assert info["shield_speed_clips"] == 20
    assert info["shield_interventions"] == 0


def test_interventions_and_speed_clips_are_told_apart(shield):
    # a random policy in the action box through a reactive crowd: both causes occur, every
    # step's cause is consistent with what the filter did, and the counters add up
    rng = np.random.default_rng(0)
    shield.reset(seed=0)
    v_max = shield.env.unwrapped.core.v_max
    counts = {"none": 0, "constraint": 0, "speed_limit": 0}
    for k in range(800):
        if k % 40 == 0:
            a = rng.uniform(-v_max, v_max, 2)
        _, _, term, trunc, info = shield.step(a)
        counts[_check_cause(shield, a, info)] += 1
        if term or trunc:
            break
    assert counts["constraint"] > 20 and counts["speed_limit"] > 20
    assert info["shield_interventions"] == counts["constraint"]
    assert info["shield_speed_clips"] == counts["speed_limit"]
