"""``ConformalCrowdParallel``: several robots in one crowd, a PettingZoo parallel environment.

Agents are the robots, ``"robot_0"`` ... ``"robot_{M-1}"``, each with the observation,
action, reward and ``info`` of ``ConformalCrowd-v0`` (:mod:`conformal_control.envs.core`)
and its own conformal monitor. As in :func:`~conformal_control.runs.fleet.run_multi`, the
robots share nothing but the world: each observes the pedestrians and the other robots
within its own sensing radius (another robot is one more agent in its ``"agents"`` rows).
A robot leaves ``agents`` when it reaches its last goal (terminated; it then stops near
its goal and stays an obstacle) or when the recording runs out (truncated).

Starts and goals: ``robots=M`` with a ``layout`` (:func:`~conformal_control.runs.fleet.robot_tasks`:
the scene's task rotated about its midpoint, or ``"antipodal"`` on a circle), or explicit
``starts`` and ``goals`` (m).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import BaseParallelWrapper

from ..core.loop import ConformalStepper
from ..core.spec import Robots, RunSpec
from ..data.scene import Scene
from ..families.cbf.controller import ConformalCBFController
from ..families.cbf.filters.exact2d import Exact2DSafetyFilter
from ..families.cbf.loss import CBFGapLoss
from ..families.cbf.reciprocal import Reciprocity
from ..runs.fleet import as_tasks, robot_tasks
from .core import CrowdCore, load
from .crowd import observation_space
from .roles import GivenVelocity, RecordingFilter

__all__ = ["ConformalCrowdParallel", "ReciprocalShield", "parallel_env"]


class ConformalCrowdParallel(ParallelEnv[str, dict[str, np.ndarray], np.ndarray]):  # type: ignore[misc]
    """M robots with velocity commands among pedestrians (see the module docstring).

    The parameters not listed below are as for
    :class:`~conformal_control.envs.crowd.ConformalCrowdEnv`.

    Parameters
    ----------
    scene : Scene or str
    robots : int
        Number of robots (with ``layout``); ignored when ``starts`` is given.
    params, spec, max_agents, progress_weight, collision_penalty, goal_bonus
        As for :class:`~conformal_control.envs.crowd.ConformalCrowdEnv`.
    terminate_on_collision, data_root, render_mode
        As for :class:`~conformal_control.envs.crowd.ConformalCrowdEnv`.
    **settings
        Settings of the run, as for :class:`~conformal_control.envs.crowd.ConformalCrowdEnv`,
        and of its robots section: ``starts``, ``goals`` (explicit tasks, m), ``layout``,
        ``radius``, ``center`` (see :func:`~conformal_control.runs.fleet.robot_tasks`).
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
        params: dict[str, Any] | None = None,
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
        run = RunSpec.from_settings(params, base=spec, **settings)
        section = run.robots or Robots()
        if section.starts is not None or section.goals is not None:
            s, tasks = as_tasks(section.starts, section.goals)
        else:
            n = robots if section.robots is None else section.robots
            s, tasks = robot_tasks(
                sc, n, section.layout, radius=section.radius, center=section.center
            )
        self.core = CrowdCore(
            sc,
            s,
            tasks,
            run,
            max_agents=max_agents,
            progress_weight=progress_weight,
            collision_penalty=collision_penalty,
            goal_bonus=goal_bonus,
            terminate_on_collision=terminate_on_collision,
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


class ReciprocalShield(BaseParallelWrapper):  # type: ignore[misc]
    """Filter every robot's action through its own conformal CBF, robots sharing their rows.

    Each robot gets the flagship controller with its action as the reference velocity
    (as :class:`~conformal_control.envs.shield.ConformalShield` does for one robot): its
    pedestrians' rows from its own predictor, with its own lambda learned online from its
    own losses, and **reciprocal rows about the other robots**
    (:mod:`~conformal_control.families.cbf.reciprocal`: each robot takes its share of every pair's
    barrier rate, from what the world lets robots know of each other). Two shielded
    policies can therefore not drive their robots into each other, whatever the policies
    do; a robot whose policy drives at a pedestrian is held back by its own rows.

    Added to each robot's ``info``: ``shield_modified``, ``shield_delta`` (m/s),
    ``shield_action``, ``shield_status`` (``unconstrained``, ``optimal`` or the fallback),
    ``shield_lambda`` (1/s), ``shield_loss`` (when an interval closed) and
    ``shield_interventions`` (steps modified so far).

    Parameters
    ----------
    env : ConformalCrowdParallel
        The environment (unwrapped or wrapped).
    information : {"position", "velocity", "plan"}
        What robots know of each other (the shield's rows); ``"plan"``: each robot's last
        filtered action, broadcast.
    lambda_scope : {"pedestrians", "robots", "both"}
        The rows lambda is the slack of.
    learn : bool
        False keeps every shield's lambda at its initial value.
    """

    def __init__(
        self,
        env: ConformalCrowdParallel,
        information: str = "plan",
        lambda_scope: str = "pedestrians",
        learn: bool = True,
    ) -> None:
        super().__init__(env)
        base = env.unwrapped
        if not isinstance(base, ConformalCrowdParallel):
            raise TypeError(
                "ReciprocalShield wraps a ConformalCrowdParallel environment (it reads the "
                f"robots' sensors from it), got {type(base).__name__}"
            )
        self.information = information
        self.lambda_scope = lambda_scope
        self.learn = learn
        core = base.core
        core.world.information = information  # the world hands each robot its peers
        si = core.fleet[0].params.si
        margin = float(si["robot_radius"] - si["agent_radius"])
        self.controllers: list[ConformalCBFController] = []
        self.filters: list[RecordingFilter] = []
        self.steppers: list[ConformalStepper] = []
        for fl in core.fleet:
            filt = RecordingFilter(
                Exact2DSafetyFilter(v_max=core.v_max, speed_sides=int(si["speed_sides"]))
            )
            self.filters.append(filt)
            ctrl = ConformalCBFController(
                copy.deepcopy(fl.predictor),
                fl.constraint,
                filt,
                GivenVelocity(),
                substeps=int(si["substeps"]),
                reciprocity=Reciprocity("reciprocal", lambda_scope, margin),
            )
            loss = CBFGapLoss(fl.constraint, scale=float(si["loss_scale"]))
            self.controllers.append(ctrl)
            self.steppers.append(
                ConformalStepper(ctrl, loss, copy.deepcopy(fl.rule), learn=bool(learn))
            )
        self._base = base

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, dict[str, Any]]]:
        obs, infos = self.env.reset(seed=seed, options=options)
        core = self._base.core
        self.n_interventions_ = np.zeros(len(self.steppers), dtype=np.int64)
        self._open = np.zeros(len(self.steppers), dtype=bool)
        for i, st in enumerate(self.steppers):
            st.start()
            query = core.query_[i]
            if query is not None:
                st.begin_interval(query)
                self._open[i] = True
        for a, info in infos.items():
            i = self._base.possible_agents.index(a)
            info.update({"shield_lambda": self.steppers[i].lam, "shield_interventions": 0})
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
        core = self._base.core
        world = core.world
        index = {a: i for i, a in enumerate(self._base.possible_agents)}
        filtered: dict[str, np.ndarray] = {}
        extra: dict[str, dict[str, Any]] = {}
        for a, act in actions.items():
            i = index[a]
            v_in, _ = core.clip(act)
            ctrl = self.controllers[i]
            assert isinstance(ctrl.reference, GivenVelocity)
            ctrl.reference.velocity = v_in
            lam = self.steppers[i].lam
            v = np.asarray(self.steppers[i].decide(world.state(i)), dtype=float)
            if self.information == "plan":
                world.broadcast(i, v)
            delta = float(np.hypot(*(v - v_in)))
            self.n_interventions_[i] += delta > 1e-9
            last = self.filters[i].last_
            status = (
                "unconstrained" if last is None else (last.result.fallback or last.result.status)
            )
            filtered[a] = v
            extra[a] = {
                "shield_modified": delta > 1e-9,
                "shield_delta": delta,
                "shield_action": v,
                "shield_status": status,
                "shield_lambda": lam,
                "shield_loss": None,
                "shield_interventions": int(self.n_interventions_[i]),
            }
        obs, rewards, terms, truncs, infos = self.env.step(filtered)
        closed = any(info.get("interval_closed") for info in infos.values())
        if closed:
            for i in map(int, np.flatnonzero(self._open)):
                a = self._base.possible_agents[i]
                truth = core.truth_[i]
                if truth is not None and a in extra:
                    extra[a]["shield_loss"] = self.steppers[i].end_interval(truth).loss
                self._open[i] = False
            if not world.done:
                for i in core.under_way():
                    query = core.query_[i]
                    if query is not None:
                        self.steppers[i].begin_interval(query)
                        self._open[i] = True
        else:  # a robot that left mid-interval: its interval is dropped (reset restarts it)
            for a in actions:
                if terms.get(a) or truncs.get(a):
                    self._open[index[a]] = False
        for a, info in infos.items():
            info.update(extra.get(a, {}))
        return obs, rewards, terms, truncs, infos
