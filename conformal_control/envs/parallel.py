"""``ConformalCrowdParallel``: several robots in one crowd, a PettingZoo parallel environment.

Agents are the robots, ``"robot_0"`` ... ``"robot_{M-1}"``, each with the observation,
action, reward and ``info`` of ``ConformalCrowd-v0`` (:mod:`conformal_control.envs.core`)
and its own conformal monitor. As in :func:`~conformal_control.sim.multi.run_multi`, the
robots share nothing but the world: each observes the pedestrians and the other robots
within its own sensing radius (another robot is one more agent in its ``"agents"`` rows).
A robot leaves ``agents`` when it reaches its last goal (terminated; it then stops near
its goal and stays an obstacle) or when the recording runs out (truncated).

Starts and goals: ``robots=M`` with a ``layout`` (:func:`~conformal_control.sim.multi.robot_tasks`:
the scene's task rotated about its midpoint, or ``"antipodal"`` on a circle), or explicit
``starts`` and ``goals`` (m).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from ..data.scene import Scene
from ..flagship.build import RoleSpec
from ..sim.multi import as_tasks, robot_tasks
from .core import CrowdCore, load
from .crowd import observation_space

__all__ = ["ConformalCrowdParallel", "parallel_env"]


class ConformalCrowdParallel(ParallelEnv[str, dict[str, np.ndarray], np.ndarray]):  # type: ignore[misc]
    """M robots with velocity commands among pedestrians (see the module docstring).

    The parameters not listed below are as for
    :class:`~conformal_control.envs.crowd.ConformalCrowdEnv`.

    Parameters
    ----------
    scene : Scene or str
    robots : int
        Number of robots (with ``layout``); ignored when ``starts`` is given.
    starts, goals : array-like, optional
        Explicit tasks (m).
    layout, radius, center
        See :func:`~conformal_control.sim.multi.robot_tasks`.
    """

    metadata: dict[str, Any] = {  # noqa: RUF012 - PettingZoo's attribute, replaced per instance
        "render_modes": ["rgb_array"],
        "name": "conformal_crowd_parallel_v0",
        "is_parallelizable": True,
        "render_fps": 10,
    }

    def __init__(
        self,
        scene: Scene | str = "crossing",
        robots: int = 2,
        *,
        starts: Any = None,
        goals: Any = None,
        layout: str = "scene",
        radius: float | None = None,
        center: Sequence[float] | None = None,
        params: dict[str, Any] | None = None,
        units: str = "scene",
        crowd: str = "replay",
        crowd_params: dict[str, Any] | None = None,
        max_agents: int = 8,
        predictor: RoleSpec = "constant_velocity",
        predictor_params: dict[str, Any] | None = None,
        rule: RoleSpec = "fixed_eta",
        rule_params: dict[str, Any] | None = None,
        progress_weight: float = 1.0,
        collision_penalty: float = 1.0,
        goal_bonus: float = 10.0,
        terminate_on_collision: bool = False,
        max_frames: int | None = None,
        data_root: str | None = None,
        render_mode: str | None = None,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        sc = load(scene, data_root)
        if starts is not None or goals is not None:
            s, tasks = as_tasks(starts, goals)
        else:
            s, tasks = robot_tasks(sc, robots, layout, radius=radius, center=center)
        self.core = CrowdCore(
            sc,
            s,
            tasks,
            params=params,
            units=units,
            crowd=crowd,
            crowd_params=crowd_params,
            max_agents=max_agents,
            predictor=predictor,
            predictor_params=predictor_params,
            rule=rule,
            rule_params=rule_params,
            progress_weight=progress_weight,
            collision_penalty=collision_penalty,
            goal_bonus=goal_bonus,
            terminate_on_collision=terminate_on_collision,
            max_frames=max_frames,
        )
        self.possible_agents = [f"robot_{i}" for i in range(s.shape[0])]
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        v = np.float32(self.core.v_max)
        # one space object per agent (seeding one agent's space leaves the others alone)
        self._obs_spaces = {a: observation_space(max_agents) for a in self.possible_agents}
        self._act_spaces = {
            a: spaces.Box(-v, v, shape=(2,), dtype=np.float32) for a in self.possible_agents
        }
        self.metadata = {**self.metadata, "render_fps": round(self.core.scene.fps)}

    def observation_space(self, agent: str) -> spaces.Dict:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self._act_spaces[agent]

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, dict[str, Any]]]:
        first = self.core.reset(seed)
        self.agents = list(self.possible_agents)
        obs = {a: first[i].observation for i, a in enumerate(self.possible_agents)}
        infos = {a: first[i].info for i, a in enumerate(self.possible_agents)}
        return obs, infos

    def step(
        self, actions: dict[str, np.ndarray]
    ) -> tuple[
        dict[str, dict[str, np.ndarray]],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        if not self.agents:
            raise RuntimeError("every robot is done: call reset()")
        unknown = sorted(set(actions) - set(self.agents))
        if unknown:
            raise ValueError(f"actions for agents that are not acting: {unknown}")
        out = self.core.step({self._index[a]: actions[a] for a in self.agents if a in actions})
        obs, rewards, terms, truncs, infos = {}, {}, {}, {}, {}
        for i, o in out.items():
            a = self.possible_agents[i]
            obs[a], rewards[a] = o.observation, o.reward
            terms[a], truncs[a], infos[a] = o.terminated, o.truncated, o.info
        self.agents = [a for a in self.agents if not (terms[a] or truncs[a])]
        return obs, rewards, terms, truncs, infos

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from .render import render_world

        return render_world(self.core.world)

    def close(self) -> None:
        pass

    def state(self) -> np.ndarray:
        """The world's state: every robot's ``x, y, vx, vy`` (M, 4)."""
        return self.core.world.positions


def parallel_env(**kwargs: Any) -> ConformalCrowdParallel:
    """PettingZoo-style constructor: ``parallel_env(scene="crossing", robots=4)``."""
    return ConformalCrowdParallel(**kwargs)
