"""Several robots, two multi-agent policies, with and without the reciprocal shield.

Six robots on a circle of 5 m through the built-in ``crossing`` scene, each to the
opposite point, in the PettingZoo parallel environment; every robot runs the same policy:

* ``scripted``: straight to its goal at 1.5 m/s;
* ``random``: that plus a uniform random velocity in [-2, 2] m/s per axis (an untrained
  multi-agent RL policy).

Each policy runs bare and through :class:`~conformal_control.envs.ReciprocalShield`, which
filters every robot's action with its own conformal CBF, the robots' rows shared. Printed:
steps with a robot in contact with another robot, with a pedestrian, robots that reached
their goals, and actions the shield changed.

Usage::

    python examples/parallel_shield.py
"""

from __future__ import annotations

import numpy as np

from conformal_control.envs import ConformalCrowdParallel, ReciprocalShield


def scripted(obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
    g = obs["robot"][4:6]
    return 1.5 * g / max(float(np.hypot(*g)), 1e-9)


def random(obs: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(-2.0, 2.0, 2) + 0.8 * scripted(obs, rng)


def episode(policy, shield: bool, seed: int = 0) -> tuple[int, int, int, int]:
    env = ConformalCrowdParallel(
        "crossing", robots=6, layout="antipodal", radius=5.0, center=(15.0, 8.0), max_frames=300
    )
    if shield:
        env = ReciprocalShield(env)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    robot = pedestrian = goals = modified = 0
    while env.agents:
        actions = {a: policy(obs[a], rng) for a in env.agents}
        obs, _, terminated, _, infos = env.step(actions)
        for a, info in infos.items():
            robot += info["collision_robot"]
            pedestrian += info["collision_pedestrian"]
            goals += bool(terminated[a] and info["goal_reached"])
            modified += bool(info.get("shield_modified"))
    return robot, pedestrian, goals, modified


def main() -> None:
    print(f"{'policy':<9} {'shield':<7} {'robot contacts':>14} {'pedestrian':>10} "
          f"{'goals':>5} {'modified':>8}")  # fmt: skip
    for policy in (scripted, random):
        for shield in (False, True):
            robot, ped, goals, mod = episode(policy, shield)
            print(
                f"{policy.__name__:<9} {'on' if shield else 'off':<7} {robot:>14} {ped:>10} "
                f"{goals:>5} {mod:>8}"
            )


if __name__ == "__main__":
    main()
