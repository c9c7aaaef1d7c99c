"""The engine of the RL environments: robots in a crowd, each with a conformal monitor.

:class:`CrowdCore` runs a :class:`~conformal_control.world.multi.MultiRobotWorld` one
control instant per call and computes, for every robot, what an RL environment returns:
its observation, reward and information. The gymnasium environment is a core with one
robot; the PettingZoo environment a core with several.

**Observation** (a ``gymnasium.spaces.Dict``; all lengths in m, velocities in m/s):

* ``"robot"`` -- ``(6,)``: ``x, y, vx, vy`` of the robot and ``gx - x, gy - y`` to its
  current goal;
* ``"agents"`` -- ``(max_agents, 4)``: for the agents within the sensing radius, nearest
  first, their position and velocity *relative to the robot* ``dx, dy, dvx, dvy``
  (pedestrians as of the current frame, their velocity over the last frame; other
  robots as they are now); rows past the sensed agents are 0;
* ``"mask"`` -- ``(max_agents,)`` int8: 1 for a row that holds an agent.

``gymnasium.wrappers.FlattenObservation`` turns it into one float Box (keys in sorted
order: the agents' rows, then the mask, then the robot).

**Action**: the velocity command (m/s), a ``Box(-v_max, v_max, (2,))``; a command longer
than ``v_max`` is scaled back to ``v_max`` (``info["action_clipped"]``). It is held for
one control instant, ``1 / (fps * substeps)`` s.

**Reward** at each step::

    r = progress_weight * (D_before - D_after)
        - collision_penalty * [in contact with a pedestrian or a robot after the step]
        + goal_bonus * [the last goal was reached during the step]

with D the remaining path (distance to the current goal plus the legs after it) and
contact a centre distance below robot + pedestrian radius (pedestrians) or two robot
radii (robots).

**The conformal monitor.** Each robot carries the flagship's predictor, constraint, loss
and update rule with a :class:`~conformal_control.envs.roles.MonitorFilter` in place of the
safety filter: it never changes an action, it scores it. ``info`` holds

* ``lambda`` -- the monitor's lambda_k during the step (1/s), and ``loss`` -- the loss of
  the interval that closed at this step (``None`` otherwise or when nothing was sensed):
  the values the flagship would learn from these actions;
* ``constraint_status`` -- ``"none"`` (no agent sensed), ``"satisfied"`` (the action meets
  every conformal constraint at lambda_k) or ``"violated"``; ``n_constraints``,
  ``n_violated`` and ``min_slack`` (the smallest ``A v + b + lambda``, 1/s; ``inf`` without
  constraints);
* ``collision_pedestrian``, ``collision_robot`` -- contact after the step;
  ``n_collision_steps`` -- steps in contact so far; ``goal_reached``; ``action_clipped``;
  ``interval_closed``; ``t`` (s).

Episodes end (``terminated``) when the robot reaches its last goal -- or at a contact with
``terminate_on_collision`` -- and are cut (``truncated``) when the recording runs out or
after ``max_frames`` frames.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..core.loop import ConformalStepper
from ..core.spec import RunSpec
from ..data.scene import Scene
from ..predictors.base import PredictionQuery
from ..runs.build import Flagship, build_flagship
from ..world.multi import MultiRobotWorld
from .roles import GivenVelocity, MonitorFilter

__all__ = ["CrowdCore", "StepOutcome"]


@dataclasses.dataclass
class StepOutcome:
    """What one robot gets back from a step."""

    observation: dict[str, np.ndarray]
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any]


def load(scene: Scene | str, data_root: str | None = None, seed: int = 0) -> Scene:
    """A scene given by name (``load_scene``) or as it is."""
    if isinstance(scene, Scene):
        return scene
    from ..data import load_scene

    return load_scene(scene, data_root, seed=seed)


class CrowdCore:
    """Robots with conformal monitors in a world, stepped one control instant at a time.

    Parameters
    ----------
    scene : Scene
    starts : ndarray of shape (R, 2)
    goals : list of R arrays of shape (G, 2)
    spec : RunSpec
        The run (:class:`~conformal_control.core.spec.RunSpec`): parameters in its ``units``,
        the crowd, the monitors' predictor and update rule, ``max_frames``; robot ``i``
        is built with seed ``i``.
    max_agents : int
        Agents in an observation (nearest first).
    progress_weight, collision_penalty, goal_bonus : float
        Reward weights (see the module docstring).
    terminate_on_collision : bool
    """

    def __init__(
        self,
        scene: Scene,
        starts: np.ndarray,
        goals: list[np.ndarray],
        spec: RunSpec,
        *,
        max_agents: int = 8,
        progress_weight: float = 1.0,
        collision_penalty: float = 1.0,
        goal_bonus: float = 10.0,
        terminate_on_collision: bool = False,
    ) -> None:
        if isinstance(max_agents, bool) or not isinstance(max_agents, int) or max_agents < 1:
            raise ValueError(f"max_agents must be an integer >= 1, got {max_agents!r}")
        for name, v in (
            ("progress_weight", progress_weight),
            ("collision_penalty", collision_penalty),
            ("goal_bonus", goal_bonus),
        ):
            if not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        self.max_agents = max_agents
        self.progress_weight = float(progress_weight)
        self.collision_penalty = float(collision_penalty)
        self.goal_bonus = float(goal_bonus)
        self.terminate_on_collision = bool(terminate_on_collision)
        self.spec = spec
        max_frames = spec.max_frames
        n = len(starts)
        self.fleet: list[Flagship] = []
        for i in range(n):
            scene_i = scene.replace(start=np.asarray(starts[i]), goals=goals[i])
            robot_run = dataclasses.replace(
                spec,
                predictor=_copy_role(spec.predictor),
                rule=_copy_role(spec.rule),
                reference=GivenVelocity(),
                safety_filter=MonitorFilter(),
                crowd=spec.crowd if i == 0 else "replay",
                seed=i,
                robots=None,
            )
            self.fleet.append(build_flagship(scene_i, robot_run))
        fl0 = self.fleet[0]
        env0 = fl0.env
        self.scene = fl0.scene
        self.v_max = float(fl0.params.si["v_max"])
        self.world = MultiRobotWorld(
            fl0.scene,
            np.asarray(starts, dtype=float),
            goals,
            [fl.dynamics for fl in self.fleet],
            tau_frames=env0.tau_frames,
            substeps=env0.substeps,
            sensing_radius=env0.sensing_radius,
            history_frames=env0.history_frames,
            max_frames=max_frames,
            crowd=getattr(env0, "crowd", None),
        )
        self.monitors = [ConformalStepper(fl.family, fl.loss, fl.rule) for fl in self.fleet]
        self.n_robots = n

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None) -> list[StepOutcome]:
        """Start an episode; a reactive crowd is seeded with ``seed`` when given."""
        w = self.world
        if seed is not None and w.crowd is not None:
            w.crowd.seed = int(seed)
        w.reset()
        n = self.n_robots
        for m in self.monitors:
            m.start()
        self.query_: list[PredictionQuery | None] = [None] * n
        self.truth_: list[Any] = [None] * n
        self.retired_ = np.zeros(n, dtype=bool)
        self.n_contact_ = np.zeros(n, dtype=np.int64)
        self.n_clipped_ = np.zeros(n, dtype=np.int64)
        self._open = np.zeros(n, dtype=bool)
        self._open_interval()
        return [
            StepOutcome(self.observe(i), 0.0, False, False, self._base_info(i)) for i in range(n)
        ]

    def _open_interval(self) -> None:
        w = self.world
        for i in w.active():
            if self.retired_[i]:
                continue
            q = w.sense(int(i))
            self.query_[i] = q
            self.monitors[i].begin_interval(q)
            self._open[i] = True
        self._length = w.control_instants()
        self._count = 0

    def clip(self, action: Any) -> tuple[np.ndarray, bool]:
        """The action as a float velocity within the disc of radius v_max."""
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (2,) or not np.isfinite(a).all():
            raise ValueError(f"an action is a finite velocity (vx, vy) in m/s, got {action!r}")
        speed = math.hypot(a[0], a[1])
        if speed > self.v_max:
            return a * (self.v_max / speed), True
        return a, False

    def under_way(self) -> list[int]:
        """Robots that take actions now."""
        return [int(i) for i in self.world.active() if not self.retired_[i]]

    def step(self, actions: dict[int, Any]) -> dict[int, StepOutcome]:
        """One control instant; ``actions`` maps each robot under way to its command."""
        w = self.world
        if w.done:
            raise RuntimeError("the episode is over: call reset()")
        movers = self.under_way()
        missing = [i for i in movers if i not in actions]
        if missing:
            raise ValueError(f"no action for robot(s) {missing}")
        cmds = np.zeros((self.n_robots, 2))
        before = {i: w.remaining_path(i) for i in movers}
        lam_used = {}
        checks = {}
        clipped = {}
        for i in movers:
            a, clipped[i] = self.clip(actions[i])
            self.n_clipped_[i] += clipped[i]
            fl = self.fleet[i]
            ref = fl.reference
            assert isinstance(ref, GivenVelocity)
            ref.velocity = a
            lam_used[i] = self.monitors[i].lam
            cmds[i] = self.monitors[i].decide(w.state(i))
            filt = fl.safety_filter
            assert isinstance(filt, MonitorFilter)
            checks[i] = _status(filt)
        w.apply(cmds)
        self._count += 1
        closed = w.done or self._count >= self._length
        losses: dict[int, float | None] = {}
        if closed:
            for i in map(int, np.flatnonzero(self._open)):
                truth = w.reveal(i)
                self.truth_[i] = truth
                losses[i] = self.monitors[i].end_interval(truth).loss
                self._open[i] = False
            if not w.done:
                self._open_interval()
        out = {}
        for i in movers:
            ped, rob = w.contacts(i)
            self.n_contact_[i] += ped or rob
            reached = w.goal_reached(i)
            r = self.progress_weight * (before[i] - w.remaining_path(i))
            r -= self.collision_penalty * float(ped or rob)
            r += self.goal_bonus * float(reached)
            terminated = reached or (self.terminate_on_collision and (ped or rob))
            truncated = not terminated and w.done
            if terminated or truncated:
                self.retired_[i] = True
                if self._open[i]:  # a robot stopped by a collision: its interval is dropped
                    self._open[i] = False
            info = self._base_info(i)
            info.update(
                {
                    "lambda": lam_used[i],
                    "lambda_next": self.monitors[i].lam,
                    "loss": losses.get(i),
                    "interval_closed": closed,
                    **checks[i],
                    "collision_pedestrian": ped,
                    "collision_robot": rob,
                    "action_clipped": clipped[i],
                }
            )
            out[i] = StepOutcome(self.observe(i), float(r), bool(terminated), truncated, info)
        return out

    # ------------------------------------------------------------------ outputs
    def observe(self, i: int) -> dict[str, np.ndarray]:
        """Robot ``i``'s observation (see the module docstring)."""
        w = self.world
        x = w.state(i).x
        g = w.current_goal(i)
        robot = np.array([x[0], x[1], x[2], x[3], g[0] - x[0], g[1] - x[1]], dtype=np.float32)
        nb = w.neighbours(i, self.max_agents)
        k = nb.ids.size
        agents = np.zeros((self.max_agents, 4), dtype=np.float32)
        agents[:k, :2] = nb.rel_pos
        agents[:k, 2:] = nb.rel_vel
        mask = np.zeros(self.max_agents, dtype=np.int8)
        mask[:k] = 1
        return {"robot": robot, "agents": agents, "mask": mask}

    def _base_info(self, i: int) -> dict[str, Any]:
        w = self.world
        return {
            "lambda": self.monitors[i].lam,
            "goal_reached": w.goal_reached(i),
            "n_collision_steps": int(self.n_contact_[i]),
            "distance_to_goal": w.remaining_path(i),
            "t": w.t,
        }


def _status(filt: MonitorFilter) -> dict[str, Any]:
    last = filt.last_
    if last is None or last.A.shape[0] == 0:
        return {
            "constraint_status": "none",
            "n_constraints": 0,
            "n_violated": 0,
            # no constraint: unbounded slack (inf compares equal to itself, NaN does not,
            # and PettingZoo's and gymnasium's determinism checks compare infos)
            "min_slack": math.inf,
        }
    slack = last.A @ last.nominal + last.b + last.lam
    n_bad = int((slack < 0).sum())
    return {
        "constraint_status": "violated" if n_bad else "satisfied",
        "n_constraints": int(slack.size),
        "n_violated": n_bad,
        "min_slack": float(slack.min()),
    }


def _copy_role(role: Any) -> Any:
    """A name, ``(name, params)`` or None as is; an instance deep-copied (each robot its
    own)."""
    if role is None or isinstance(role, (str, tuple)):
        return role
    import copy

    return copy.deepcopy(role)
