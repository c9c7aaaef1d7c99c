"""``ConformalCrowd-v0``: one robot crossing a crowd, a gymnasium environment.

The robot drives through the pedestrians of a scene (replayed from the recording or
reacting to it: ``crowd="social_force"``, ``"orca"``, ``"mixed"``) from the scene's start
to its goals. Observation, action, reward, termination and the conformal monitor's
``info`` are described in :mod:`conformal_control.envs.core`. Time advances one control
instant per step (``1 / (fps * substeps)`` s: 0.025 s on the built-in ``crossing`` scene).

Make it with ``gymnasium.make("conformal_control.envs:ConformalCrowd-v0", scene="crossing",
crowd="orca")`` in a fresh interpreter (gymnasium imports the module before the colon,
which registers the id), or with the short id ``"ConformalCrowd-v0"`` once
:mod:`conformal_control.envs` is imported.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..core.spec import RunSpec
from ..data.scene import Scene
from .core import CrowdCore, load

__all__ = ["ConformalCrowdEnv", "observation_space"]


def observation_space(max_agents: int) -> spaces.Dict:
    """The observation space of one robot (see :mod:`conformal_control.envs.core`)."""
    inf = np.float32(np.inf)
    return spaces.Dict(
        {
            "robot": spaces.Box(-inf, inf, shape=(6,), dtype=np.float32),
            "agents": spaces.Box(-inf, inf, shape=(max_agents, 4), dtype=np.float32),
            "mask": spaces.MultiBinary(max_agents),
        }
    )


class ConformalCrowdEnv(gym.Env[dict[str, Any], np.ndarray]):
    """One robot among pedestrians; the action is its velocity command (m/s).

    Parameters
    ----------
    scene : Scene or str
        A scene or a name for :func:`~conformal_control.data.load_scene` (``"crossing"``,
        the built-in scene, needs no data; SDD scenes need ``data_root``).
    params : dict, optional
        Run parameters in ``units`` (``v_max``, radii, ``tau``, ``substeps``, the
        monitor's ``epsilon``, ``eta``, ...; see ``conformal-control params``).
    spec : RunSpec, optional
        The run (:class:`~conformal_control.core.spec.RunSpec`); ``params`` and the settings
        below are applied on it.
    max_agents : int
        Agents in an observation.
    progress_weight, collision_penalty, goal_bonus : float
        Reward weights.
    terminate_on_collision : bool
        End the episode at the first contact.
    data_root : str, optional
        Where SDD data lives (for scene names).
    render_mode : {"rgb_array"}, optional
    **settings
        Settings of the run (:meth:`RunSpec.from_settings
        <conformal_control.core.spec.RunSpec.from_settings>`): ``units`` ({"scene", "si"}),
        ``crowd`` ({"replay", "social_force", "orca", "mixed"}) and ``crowd_params``
        (SI), the conformal monitor's ``predictor``, ``predictor_params``, ``rule`` and
        ``rule_params``, ``max_frames`` (cut the episode after this many frames).
    """

    # gymnasium's attribute (an instance's copy carries the scene's frame rate)
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(
        self,
        scene: Scene | str = "crossing",
        params: dict[str, Any] | None = None,
        *,
        spec: RunSpec | None = None,
        max_agents: int = 8,
        progress_weight: float = 1.0,
        collision_penalty: float = 1.0,
        goal_bonus: float = 10.0,
        terminate_on_collision: bool = False,
        data_root: str | None = None,
        render_mode: str | None = None,
        **settings: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        sc = load(scene, data_root)
        self.core = CrowdCore(
            sc,
            np.asarray(sc.start, dtype=float).reshape(1, 2),
            [np.asarray(sc.goals, dtype=float).reshape(-1, 2)],
            RunSpec.from_settings(params, base=spec, **settings),
            max_agents=max_agents,
            progress_weight=progress_weight,
            collision_penalty=collision_penalty,
            goal_bonus=goal_bonus,
            terminate_on_collision=terminate_on_collision,
        )
        v = np.float32(self.core.v_max)
        self.action_space = spaces.Box(-v, v, shape=(2,), dtype=np.float32)
        self.observation_space = observation_space(max_agents)
        self.metadata = {**self.metadata, "render_fps": round(self.core.scene.fps)}
        self._over = True

    @property
    def scene(self) -> Scene:
        """The scene as run (resolved radii, v_max)."""
        return self.core.scene

    @property
    def dt(self) -> float:
        """Duration of one step (s)."""
        w = self.core.world
        return 1.0 / (self.core.scene.fps * w.substeps)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        (first,) = self.core.reset(seed)
        self._over = False
        return first.observation, first.info

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        if self._over:
            raise RuntimeError("the episode is over (or never started): call reset()")
        out = self.core.step({0: action})[0]
        self._over = out.terminated or out.truncated
        return out.observation, out.reward, out.terminated, out.truncated, out.info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from .render import render_world

        return render_world(self.core.world)
