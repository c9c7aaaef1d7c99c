"""Several robots in one scene: the world they share, stepped one control instant at a time.

:class:`MultiRobotWorld` is :class:`~conformal_control.world.replay.ReplayEnvironment`
for ``R`` robots: the same clock (frames of the scene, ``substeps`` control instants per
frame, intervals of ``tau_frames`` frames), the same sensor, the same reveal of the truth,
the same frame log with ``d_min``, the same goals -- per robot. With one robot it computes
exactly what the replay (or reactive) environment computes, number for number.

**What a robot knows.** The world hands robot ``i`` only what its own sensor returns and,
with an ``information`` option, what the robots tell each other. At a sampling time
:meth:`MultiRobotWorld.sense` lists the agents within robot ``i``'s sensing radius --
pedestrians *and other robots*, the latter with ids of their own
(:attr:`MultiRobotWorld.robot_ids`, after the largest pedestrian id) and typed as robots
(the query's ``robot`` flags) -- and their histories; at the end of the interval
:meth:`MultiRobotWorld.reveal` gives the true trajectories of those agents. The histories
are, by default, what the single-robot sensor gives (``sensor_history="tracked"``: the
agent's positions over the last ``history_frames`` frames, as a tracker that had it in view
would report them); with ``sensor_history="observed"`` only the frames at which the agent
was within robot ``i``'s own sensing radius are kept (NaN elsewhere).

With ``information`` set, :meth:`MultiRobotWorld.state` also gives robot ``i``, at every
control instant, a :class:`~conformal_control.families.cbf.reciprocal.PeerView` of the robots it
sensed at the sampling time (what a reciprocal controller builds its rows from): their
positions now and robot ``i``'s share of each pair, plus, by option,

* ``"position"``: nothing else;
* ``"velocity"``: their velocities now and robot ``i``'s own (a sensor measuring velocity);
* ``"plan"``: the plans they broadcast and robot ``i``'s own -- what each robot passed to
  :meth:`MultiRobotWorld.broadcast` at the previous control instant (every robot sees
  the plans of the same instant, whatever the order robots decide in); zero velocity
  before the first broadcast and once a robot has stopped at its goal.

**Yielding** (``"plan"`` only: it is communication). A robot may broadcast, with its plan,
that it *yields*: its rows about the other robots gave way at its last decision (it is
squeezed, :mod:`~conformal_control.families.cbf.reciprocal`). At the next control instant the
shares of its pairs are then recomputed from the broadcast flags, the same way for both
robots of a pair: a yielding robot's share of a pair with a robot that does not yield is
0 and its partner's 1 (the partner takes the whole pair constraint); two yielding robots,
or two that do not, keep the fleet's shares. The two shares of a pair still add up to 1.

Nothing else about another robot is ever handed out: not its lambda, predictor, goal,
reference or command (except as the broadcast plan).

**Pedestrians** are replayed from the recording, or simulated by a
:class:`~conformal_control.world.crowds.crowd.Crowd` that sees every robot (position, velocity,
the scene's robot radius) at every control instant.

**A robot that reaches its last goal** stops deciding; its plant is then commanded to
zero velocity (it brakes, and is held still once slower than :data:`PARKED_SPEED`), and
it remains an agent the others and the pedestrians see. The others' views mark it
parked (:attr:`~conformal_control.families.cbf.reciprocal.PeerView.parked`): it takes no
share of a pair any more, so a reciprocal CBF robot takes the whole of each pair with it.
Its metrics (frame log, collisions) end at its goal time, as for one robot. The world
ends when every robot has reached its goal, when the data runs out, or after
``max_frames`` frames.

**Collisions.** Each frame (while a robot is under way) the log holds its smallest centre
distance to a pedestrian (``d_min``; a collision below robot radius + pedestrian radius)
and to another robot (``d_min_robot``; a collision below two robot radii), so the two
kinds are counted separately.

Why a world of our own rather than R replay environments: pedestrians and robots must
move together, every robot seeing the others where they are now, and a reactive crowd
must step once per control instant with all robots; the class keeps the arithmetic of
the single-robot environment (so that one robot reproduces it) with the per-frame work
vectorised over robots.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.spec import ROBOT_CHOICES
from ..data.scene import Scene
from ..families.cbf.controller import ControlState
from ..families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from ..families.cbf.loss import CBFTruth
from ..families.cbf.reciprocal import INFORMATION, PeerView, pair_shares
from ..families.cbf.roles import Dynamics
from ..predictors.base import PredictionQuery, TruthUnavailableError
from .crowds.crowd import Crowd
from .replay import FrameLog

__all__ = [
    "PARKED_SPEED",
    "SENSOR_HISTORIES",
    "LockstepArrays",
    "MultiRobotWorld",
    "Neighbours",
    "RobotLog",
]

#: Values of ``sensor_history``.
SENSOR_HISTORIES = ROBOT_CHOICES["sensor_history"]

#: Speed (m/s) under which a robot braking at its goal is taken to have stopped.
PARKED_SPEED = 1e-3


@dataclass
class RobotLog:
    """What the world recorded about one robot (what its metrics are computed from).

    Attributes
    ----------
    log : FrameLog
        One row per frame while the robot is under way (``d_min`` to pedestrians).
    d_min_robot : list of float
        Per logged frame, the smallest centre distance to another robot (NaN if alone).
    n_sensed_ : list of int
        Agents sensed at each of the robot's sampling times.
    t_goal_ : float or None
        Time the last goal was reached.
    steps_t, steps_x, steps_cmd : lists
        Time, state and command at each control instant the robot decided.
    """

    log: FrameLog
    d_min_robot: list[float] = field(default_factory=list)
    n_sensed_: list[int] = field(default_factory=list)
    t_goal_: float | None = None
    steps_t: list[float] = field(default_factory=list)
    steps_x: list[np.ndarray] = field(default_factory=list)
    steps_cmd: list[np.ndarray] = field(default_factory=list)


@dataclass
class Neighbours:
    """Agents within a robot's sensing radius at the current control instant.

    Sorted by distance. Pedestrian positions are those of the current frame (the sensor's
    rate) and their velocities the backward difference over the last frame (0 for an agent
    that just appeared); robots are where they are now, with their current velocity.

    Attributes
    ----------
    ids : ndarray of shape (N,)
    rel_pos, rel_vel : ndarray of shape (N, 2)
        Position and velocity relative to the robot (m, m/s).
    is_robot : ndarray of shape (N,)
        The agent type the sensor reports (True for a robot).
    """

    ids: np.ndarray
    rel_pos: np.ndarray
    rel_vel: np.ndarray
    is_robot: np.ndarray


@dataclass(frozen=True)
class LockstepArrays:
    """A world's arrays as a lockstep engine steps them (:meth:`MultiRobotWorld.lockstep`):
    the world's own, live (the engine writes the robots' states, goals, flags and the
    broadcast plans into them), plus the goals and the plants' constants packed per robot.

    Attributes
    ----------
    x : ndarray (R, 4)
        The robots' states (x, y, vx, vy).
    done, parked : ndarray (R,) of bool
        At the last goal; stopped there.
    step, goal : ndarray (R,) of int64
        Control instants decided in the open interval; the current waypoint's index.
    goals : ndarray (R, G, 2)
        Each robot's waypoints (the first ``n_goals[i]``), m.
    n_goals : ndarray (R,) of int64
        Waypoints per robot.
    plan_v, next_v : ndarray (R, 2)
        The broadcast velocities visible now, and those broadcast at this instant.
    yielding, next_yielding : ndarray (R,) of bool
        The broadcast yielding flags, likewise.
    shares : ndarray (R, R)
        The fleet's shares of each pair.
    plant : ndarray (R, 3)
        Per robot, the velocity-tracking plant's gain ``K``, ``exp(-K dt)`` and
        ``-expm1(-K dt)`` (as its ``step`` computes them).
    dt, goal_radius : float
        The control step (s) and the goal radius (m).
    information : int
        -1 (no peer view), 0, 1, 2: ``"position"``, ``"velocity"``, ``"plan"``.
    """

    x: np.ndarray
    done: np.ndarray
    parked: np.ndarray
    step: np.ndarray
    goal: np.ndarray
    goals: np.ndarray
    n_goals: np.ndarray
    plan_v: np.ndarray
    next_v: np.ndarray
    yielding: np.ndarray
    next_yielding: np.ndarray
    shares: np.ndarray
    plant: np.ndarray
    dt: float
    goal_radius: float
    information: int


class MultiRobotWorld:
    """Pedestrians and ``R`` robots in one scene (see the module docstring).

    Parameters
    ----------
    scene : Scene
        Pedestrians, timing, radii (robot, pedestrian, goal), extent. Its own start and
        goals are not used: each robot has its own.
    starts : array-like of shape (R, 2)
        Start position of each robot (m).
    goals : sequence of R arrays of shape (G_i, 2)
        Goals (waypoints) of each robot, visited in order (m).
    dynamics : Dynamics or sequence of R Dynamics
        Plant of each robot (one instance is used for all: plants hold no state).
    tau_frames, substeps, sensing_radius, history_frames, max_frames
        As for :class:`~conformal_control.world.replay.ReplayEnvironment`.
    crowd : Crowd, optional
        Simulated pedestrians (seeing every robot); None replays the recording.
    sensor_history : {"tracked", "observed"}
        Histories handed to the predictors (see the module docstring).
    information : {"position", "velocity", "plan"}, optional
        What robots know of each other at a control instant (:meth:`state`'s ``peers``);
        None hands out no peer view.
    weights : sequence of R floats, optional
        The fleet's share weights: robot i's share of a pair with robot j is
        ``w_i / (w_i + w_j)`` (default: one half).

    Attributes
    ----------
    robot_ids : ndarray of shape (R,)
        The ids under which the robots appear to each other's sensors.
    robots : list of RobotLog
    """

    def __init__(
        self,
        scene: Scene,
        starts: np.ndarray | Sequence[Sequence[float]],
        goals: Sequence[np.ndarray | Sequence[Sequence[float]]],
        dynamics: Dynamics | Sequence[Dynamics],
        *,
        tau_frames: int,
        substeps: int = 4,
        sensing_radius: float = 10.0,
        history_frames: int = 120,
        max_frames: int | None = None,
        crowd: Crowd | None = None,
        sensor_history: str = "tracked",
        information: str | None = None,
        weights: Sequence[float] | None = None,
    ) -> None:
        self.scene = scene
        self.starts = starts
        self.goals = goals
        self.dynamics = dynamics
        self.tau_frames = tau_frames
        self.substeps = substeps
        self.sensing_radius = sensing_radius
        self.history_frames = history_frames
        self.max_frames = max_frames
        self.crowd = crowd
        self.sensor_history = sensor_history
        self.information = information
        self.weights = weights

    # ------------------------------------------------------------------ set-up
    @property
    def n_robots(self) -> int:
        return int(np.asarray(self.starts, dtype=float).reshape(-1, 2).shape[0])

    def _validate(self) -> None:
        for name in ("tau_frames", "substeps", "history_frames"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not (math.isfinite(self.sensing_radius) and self.sensing_radius > 0):
            raise ValueError(f"sensing_radius must be > 0, got {self.sensing_radius!r}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"max_frames must be >= 1, got {self.max_frames!r}")
        if self.sensor_history not in SENSOR_HISTORIES:
            raise ValueError(
                f"sensor_history must be one of {', '.join(SENSOR_HISTORIES)}, "
                f"got {self.sensor_history!r}"
            )
        if self.information is not None and self.information not in INFORMATION:
            raise ValueError(
                f"information must be one of {', '.join(INFORMATION)} or None, "
                f"got {self.information!r}"
            )
        if self.crowd is not None and not isinstance(self.crowd, Crowd):
            raise ValueError(f"crowd must be a Crowd or None, got {type(self.crowd).__name__}")
        self.scene.validate()
        starts = np.asarray(self.starts, dtype=float)
        if starts.ndim != 2 or starts.shape[1] != 2 or starts.shape[0] < 1:
            raise ValueError(f"starts must have shape (R, 2) with R >= 1, got {starts.shape}")
        if not np.isfinite(starts).all():
            raise ValueError("robot starts must be finite")
        if len(self.goals) != starts.shape[0]:
            raise ValueError(f"{starts.shape[0]} starts but {len(self.goals)} goal lists")
        goals = []
        for i, g in enumerate(self.goals):
            g = np.asarray(g, dtype=float).reshape(-1, 2)
            if g.shape[0] == 0 or not np.isfinite(g).all():
                raise ValueError(f"robot {i}: at least one finite goal (x, y) is needed")
            goals.append(g)
        dyn = self.dynamics
        plants = list(dyn) if isinstance(dyn, Sequence) else [dyn] * starts.shape[0]
        if len(plants) != starts.shape[0]:
            raise ValueError(f"{starts.shape[0]} robots but {len(plants)} dynamics")
        w = np.ones(starts.shape[0]) if self.weights is None else np.asarray(self.weights, float)
        if w.shape != (starts.shape[0],):
            raise ValueError(f"{starts.shape[0]} robots but {w.size} share weights")
        self._shares = pair_shares(w)
        self._starts = starts
        self._goals = goals
        self._goal_xy = [g.tolist() for g in goals]  # the same numbers, as Python floats
        self._plants = plants

    def reset(self) -> None:
        """Start a new episode (validates the parameters)."""
        self._validate()
        sc = self.scene
        r = self._starts.shape[0]
        self._dt_frame = 1.0 / sc.fps
        self._dt = self._dt_frame / self.substeps
        self._fi = sc.start_index
        last = sc.n_frames - 1
        if self.max_frames is not None:
            last = min(last, sc.start_index + int(self.max_frames))
        self._last = last
        self._x = np.zeros((r, 4))
        self._x[:, :2] = self._starts
        self._t = 0.0
        self._n_instants = 0  # control instants since the start (all robots)
        self._goal = np.zeros(r, dtype=np.int64)
        self._done = np.zeros(r, dtype=bool)
        self._parked = np.zeros(r, dtype=bool)
        self._world_done = False
        self._step = np.zeros(r, dtype=np.int64)  # instants decided in the open interval
        self._k_start = np.full(r, self._fi, dtype=np.int64)
        self._sensed: list[tuple[np.ndarray, np.ndarray]] = [
            (np.zeros(0, np.int64), np.zeros(0, np.int64)) for _ in range(r)
        ]
        ids = np.asarray(sc.agent_ids)
        base = int(ids.max()) + 1 if ids.size else 0
        self.robot_ids = np.arange(base, base + r, dtype=np.int64)
        self.robots = [RobotLog(FrameLog([], [], [], [])) for _ in range(r)]
        self._peer_static: list[tuple[np.ndarray, np.ndarray, np.ndarray] | None] = [None] * r
        # broadcast plans: visible (as of this instant) and pending (for the next)
        self._plan_v = np.zeros((r, 2))
        self._next_v = np.zeros((r, 2))
        self._paths: list[tuple[np.ndarray, np.ndarray] | None] = [None] * r
        self._next_paths: list[tuple[np.ndarray, np.ndarray] | None] = [None] * r
        self._yield = np.zeros(r, dtype=bool)  # broadcast yielding flags, as of now
        self._next_yield = np.zeros(r, dtype=bool)
        self._any_yield = False  # whether any flag of _yield is set
        # pedestrians: the recording, or a buffer the crowd fills as it is simulated
        if self.crowd is None:
            self._peds = sc.positions
        else:
            buf = sc.positions  # dense (a sparse scene's is assembled here)
            self.crowd.reset(buf, sc.fps, sc.start_index, self.substeps, sc.robot_radius)
            buf = buf.copy()
            buf[sc.start_index + 1 :] = np.nan
            buf[sc.start_index] = self.crowd.frame_positions(sc.start_index)
            self._peds = buf
            self._crowd_frame = sc.start_index
            self._crowd_sub = 0
        # robots per frame: standing at their starts before the episode, NaN after the
        # last simulated frame
        self._robot_pos = np.full((sc.n_frames, r, 2), np.nan)
        self._robot_pos[: self._fi + 1] = self._starts
        self._log_frame()

    # ------------------------------------------------------------------ state
    @property
    def done(self) -> bool:
        """The world has ended (every robot at its goal, data or time exhausted)."""
        return self._world_done

    def robot_done(self, i: int) -> bool:
        """Robot ``i`` has reached its last goal (or the world has ended)."""
        return bool(self._done[i]) or self._world_done

    def active(self) -> np.ndarray:
        """Indices of the robots still under way."""
        if self._world_done:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(~self._done)

    @property
    def t(self) -> float:
        """Time (s) since the start."""
        return self._t

    @property
    def frame_index(self) -> int:
        """Index into the scene's frames of the current frame."""
        return self._fi

    @property
    def positions(self) -> np.ndarray:
        """Robot states now, shape (R, 4): x, y, vx, vy (a copy)."""
        out: np.ndarray = self._x.copy()
        return out

    def goal_reached(self, i: int) -> bool:
        return self.robots[i].t_goal_ is not None

    def current_goal(self, i: int) -> np.ndarray:
        """Robot ``i``'s current goal (waypoint), m."""
        goal: np.ndarray = self._goals[i][self._goal[i]]
        return goal

    def remaining_path(self, i: int) -> float:
        """Distance (m) from robot ``i`` to its current goal plus the legs after it."""
        goals = self._goals[i]
        g = int(self._goal[i])
        d = math.hypot(*(self._x[i, :2] - goals[g]))
        if g + 1 < len(goals):
            d += float(np.hypot(*np.diff(goals[g:], axis=0).T).sum())
        return d

    def pedestrians(self) -> np.ndarray:
        """Pedestrian positions at every frame so far (F, P, 2), NaN where absent."""
        return self._peds

    def robot_track(self) -> np.ndarray:
        """Robot positions at every frame (F, R, 2): starts before the episode, NaN after
        the last simulated frame (robots that reached their goal included)."""
        return self._robot_pos

    def control_instants(self) -> int:
        """Control instants of the interval that starts now."""
        frames = min(self.tau_frames, self._last - self._fi)
        return max(frames, 0) * self.substeps

    def state(self, i: int) -> ControlState:
        """Decision input of robot ``i`` now (with ``information``: its peer view)."""
        peers = None
        if self.information is not None:
            rob = self._sensed[i][1]
            if rob.size:
                peers = self._peer_view(i, rob)
        return ControlState(
            x=self._x[i].copy(),
            t=self._t,
            step=int(self._step[i]),
            goal=self.current_goal(i),
            peers=peers,
        )

    def yielding(self) -> np.ndarray:
        """The yielding flags the robots broadcast at the last control instant, shape (R,)
        (a copy; all False without ``information="plan"``)."""
        out: np.ndarray = self._yield.copy()
        return out

    def _yield_shares(self, i: int, robots: np.ndarray, shares: np.ndarray) -> np.ndarray:
        """Robot ``i``'s shares of its pairs with ``robots`` given the broadcast yielding
        flags (see the module docstring): ``shares`` itself when no flag changes them."""
        if not self._any_yield:
            return shares
        me = bool(self._yield[i])
        them = self._yield.take(robots)
        if not me and not them.any():
            return shares
        out: np.ndarray = np.where(them == me, shares, 0.0 if me else 1.0)
        return out

    def _peer_view(self, i: int, robots: np.ndarray) -> PeerView:
        """What robot ``i`` knows now of ``robots`` (the robots it sensed at the sampling
        time), by the information option (their ids and shares computed once per
        interval)."""
        cached = self._peer_static[i]
        if cached is None or cached[0] is not robots:
            ids, shares = self.robot_ids[robots], self._shares[i, robots]
            ids.setflags(write=False)  # shared by the interval's views: read-only
            shares.setflags(write=False)
            cached = (robots, ids, shares)
            self._peer_static[i] = cached
        return self._make_view(i, robots, cached[1], cached[2])

    def _make_view(
        self, i: int, robots: np.ndarray, ids: np.ndarray, shares: np.ndarray
    ) -> PeerView:
        info = self.information or "position"
        if info == "plan":
            shares = self._yield_shares(i, robots, shares)
        sub = self._x.take(robots, axis=0)  # a copy: positions and velocities now
        ref = own = None
        plans = own_plan = None
        if info == "velocity":
            ref = sub[:, 2:]
            own = self._x[i, 2:].copy()
        elif info == "plan":
            ref = self._plan_v.take(robots, axis=0)
            own = self._plan_v[i].copy()
            paths = self._paths
            plans = tuple([paths[j] for j in robots.tolist()])
            own_plan = paths[i]
        parked = None
        if self._done.any():
            taken = self._done.take(robots)
            parked = taken if taken.any() else None
        return PeerView(
            ids, sub[:, :2], shares, info, ref, own, plans, own_plan, int(self.robot_ids[i]), parked
        )

    def broadcast(
        self,
        i: int,
        velocity: np.ndarray,
        path: tuple[np.ndarray, np.ndarray] | None = None,
        *,
        yielding: bool = False,
    ) -> None:
        """Robot ``i`` broadcasts its plan (see the module docstring); the others see it
        from the next control instant on (``information="plan"``).

        Parameters
        ----------
        i : int
            The robot's index.
        velocity : array (2,)
            The velocity it intends (m/s).
        path : (times (H,), positions (H, 2)), optional
            Its planned path: times in s since the start, positions in m.
        yielding : bool
            Whether it yields to the others.
        """
        v = np.asarray(velocity, dtype=float).reshape(-1)
        if v.shape != (2,) or not (math.isfinite(v[0]) and math.isfinite(v[1])):
            raise ValueError(f"a broadcast velocity is a finite (vx, vy), got {velocity!r}")
        self._next_v[i] = v
        self._next_paths[i] = path
        self._next_yield[i] = bool(yielding)

    # ------------------------------------------------------------------ lockstep
    def lockstep_reason(self) -> str | None:
        """Why a lockstep engine cannot step this world's plants and clock itself (None:
        it can, after :meth:`reset`): a simulated crowd, a plant other than the
        velocity-tracking double integrator."""
        if self.crowd is not None:
            return "a simulated crowd (it steps with the robots at every control instant)"
        dyn = self.dynamics
        for p in list(dyn) if isinstance(dyn, Sequence) else [dyn]:
            if type(p) is not VelocityTrackingDoubleIntegrator:
                return f"the plant {type(p).__name__} (only the velocity-tracking one)"
        return None

    def lockstep(self) -> LockstepArrays:
        """The world's arrays for a lockstep engine (after :meth:`reset`; see
        :meth:`lockstep_reason`). The engine then runs a control instant as
        :meth:`apply` does up to the plan broadcast (plants, goals, per-instant record
        kept by the engine and handed over with :meth:`add_steps`), and calls
        :meth:`close_instants` for the rest."""
        r = self._x.shape[0]
        g = max(len(x) for x in self._goals)
        goals = np.zeros((r, g, 2))
        for i, x in enumerate(self._goals):
            goals[i, : len(x)] = x
        plant = np.zeros((r, 3))
        for i, p in enumerate(self._plants):
            assert isinstance(p, VelocityTrackingDoubleIntegrator)  # lockstep_reason
            k = float(p.compiled_state().K_acc)
            plant[i] = (k, math.exp(-k * self._dt), -math.expm1(-k * self._dt))
        info = -1 if self.information is None else INFORMATION.index(self.information)
        return LockstepArrays(
            self._x,
            self._done,
            self._parked,
            self._step,
            self._goal,
            goals,
            np.array([len(x) for x in self._goals], dtype=np.int64),
            self._plan_v,
            self._next_v,
            self._yield,
            self._next_yield,
            self._shares,
            plant,
            self._dt,
            float(self.scene.goal_radius),
            info,
        )

    def control_budget(self) -> int:
        """Control instants left before the episode's last frame (after :meth:`reset`: all
        of the episode's at most)."""
        return max(self._last - self._fi, 0) * int(self.substeps)

    def sensed_robots(self, i: int) -> np.ndarray:
        """The robots robot ``i`` sensed at its last sampling time (indices, the order of
        its peer view)."""
        return self._sensed[i][1]

    @property
    def instants(self) -> int:
        """Control instants run since the start (all robots)."""
        return self._n_instants

    def close_instants(
        self, k: int, t: float, t_goal: np.ndarray | None = None, *, tick: bool = True
    ) -> None:
        """The end of ``k`` control instants a lockstep engine ran (:meth:`lockstep`): the
        clock (``t``: the time the last one ended at, s, computed as :meth:`apply` adds
        the step), the goal times of the robots that reached their last goal (``t_goal``
        (R,), NaN for the others), the broadcast paths, and with ``tick`` the frame clock
        and log of the last one -- the rest of :meth:`apply` (the engine stops at an
        instant whose frame clock does anything: the earlier ones' does nothing).

        Parameters
        ----------
        k : int
            Instants run.
        t : float
            Time at the end of the last one (s).
        t_goal : ndarray of shape (R,), optional
            Goal times (s), NaN where none (None: no robot reached its goal).
        tick : bool
            Run the frame clock (False: the last instant was not finished deciding yet,
            only the ones before it ended).
        """
        self._t = float(t)
        self._n_instants += int(k)
        if t_goal is not None:
            for i in np.flatnonzero(np.isfinite(t_goal)).tolist():
                self.robots[i].t_goal_ = float(t_goal[i])
        if self.information == "plan":
            done, nxt = self._done, self._next_paths
            self._paths = [None if d else p for d, p in zip(done, nxt, strict=True)]
            self._any_yield = bool(self._yield.any())
        if tick:
            self._tick()

    def add_steps(self, i: int, t: np.ndarray, x: np.ndarray, cmd: np.ndarray) -> None:
        """Robot ``i``'s per-instant record of control instants a lockstep engine ran
        (times (S,), states (S, 4), commands (S, 2)), appended to its log.

        Parameters
        ----------
        i : int
            The robot.
        t, x, cmd : ndarray
            Times (s), states after the step and commands (m/s).
        """
        rec = self.robots[i]
        rec.steps_t.extend(t.tolist())
        rec.steps_x.extend(x.copy())
        rec.steps_cmd.extend(cmd.copy())

    # ------------------------------------------------------------------ logging
    def _log_frame(self) -> None:
        fi = self._fi
        pos = self._peds[fi]
        present = np.isfinite(pos[:, 0])
        p = pos[present]
        x = self._x
        r = x.shape[0]
        if p.size:
            d_ped = np.hypot(p[None, :, 0] - x[:, None, 0], p[None, :, 1] - x[:, None, 1])
            d_min = d_ped.min(axis=1)
        else:
            d_min = np.full(r, math.nan)
        d_rob = self._robot_distances()
        frame = self.scene.first_frame + fi
        for i in range(r):
            if self._done[i]:
                continue
            rec = self.robots[i]
            rec.log.frame.append(frame)
            rec.log.t.append(self._t)
            rec.log.state.append(x[i].copy())
            rec.log.d_min.append(float(d_min[i]))
            rec.d_min_robot.append(float(d_rob[i]) if r > 1 else math.nan)

    def _robot_distances(self) -> np.ndarray:
        """Smallest centre distance from each robot to another robot now, shape (R,)."""
        x = self._x
        if x.shape[0] < 2:
            return np.full(x.shape[0], math.nan)
        d = np.hypot(x[:, None, 0] - x[None, :, 0], x[:, None, 1] - x[None, :, 1])
        np.fill_diagonal(d, np.inf)
        out: np.ndarray = d.min(axis=1)
        return out

    # ------------------------------------------------------------------ sensor
    def _ped_window(self, lo: int, hi: int, idx: np.ndarray) -> np.ndarray:
        out = np.full((idx.size, hi - lo, 2), np.nan)
        a, b = max(lo, 0), min(hi, self.scene.n_frames)
        if b > a and idx.size:
            out[:, a - lo : b - lo] = self._peds[a:b, idx].transpose(1, 0, 2)
        return out

    def _robot_window(self, lo: int, hi: int, idx: np.ndarray) -> np.ndarray:
        out = np.full((idx.size, hi - lo, 2), np.nan)
        a, b = max(lo, 0), min(hi, self.scene.n_frames)
        if b > a and idx.size:
            out[:, a - lo : b - lo] = self._robot_pos[a:b, idx].transpose(1, 0, 2)
        return out

    def _window(self, lo: int, hi: int, sensed: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        ped, rob = sensed
        if rob.size == 0:
            return self._ped_window(lo, hi, ped)
        return np.concatenate([self._ped_window(lo, hi, ped), self._robot_window(lo, hi, rob)])

    def _seen_by(self, i: int, lo: int, hi: int, hist: np.ndarray) -> np.ndarray:
        """``hist`` with the samples robot ``i`` did not have within its radius set to NaN."""
        a, b = max(lo, 0), min(hi, self.scene.n_frames)
        me = np.full((hi - lo, 2), np.nan)
        me[a - lo : b - lo] = self._robot_pos[a:b, i]
        with np.errstate(invalid="ignore"):
            far = ~(np.hypot(*(hist - me[None]).transpose(2, 0, 1)) <= self.sensing_radius)
        out: np.ndarray = hist.copy()
        out[far] = np.nan
        return out

    def sense(self, i: int) -> PredictionQuery:
        """Robot ``i``'s sensor at a sampling time: the agents within its radius."""
        if self._done[i] or self._world_done:
            raise RuntimeError(f"robot {i} has finished; it senses no more")
        sc, fi = self.scene, self._fi
        me = self._x[i, :2]
        pos = self._peds[fi]
        present = np.isfinite(pos[:, 0])
        d = np.full(pos.shape[0], np.inf)
        d[present] = np.hypot(*(pos[present] - me).T)
        ped = np.flatnonzero(d <= self.sensing_radius)
        rob = np.zeros(0, dtype=np.int64)
        if self._x.shape[0] > 1:
            dr = np.hypot(*(self._x[:, :2] - me).T)
            dr[i] = np.inf
            rob = np.flatnonzero(dr <= self.sensing_radius)
        sensed = (ped, rob)
        self._sensed[i] = sensed
        self._k_start[i] = fi
        self._step[i] = 0
        self.robots[i].n_sensed_.append(int(ped.size + rob.size))
        lo, hi = fi - self.history_frames + 1, fi + 1
        history = self._window(lo, hi, sensed)
        if self.sensor_history == "observed" and history.shape[0]:
            history = self._seen_by(i, lo, hi, history)
        ids = np.concatenate([np.asarray(sc.agent_ids)[ped], self.robot_ids[rob]])
        tau = self.tau_frames
        if self.crowd is None:

            def future(horizon: int) -> np.ndarray:
                # the robots' futures are not known at the sampling time: NaN (the
                # oracle's convention for an unknown future)
                out = np.full((ped.size + rob.size, horizon, 2), np.nan)
                out[: ped.size] = self._ped_window(fi + 1, fi + 1 + horizon, ped)
                return out

        else:
            future = _no_future
        return PredictionQuery(
            ids=ids,
            history=history,
            dt=self._dt_frame,
            horizon=tau,
            t=self._t,
            frame=sc.first_frame + fi,
            scene=sc.name,
            truth_provider=future,
            robot=np.r_[np.zeros(ped.size, bool), np.ones(rob.size, bool)],
        )

    def reveal(self, i: int) -> CBFTruth:
        """The true trajectories of the agents robot ``i`` sensed at its last sampling time."""
        n_frames = -(-int(self._step[i]) // self.substeps)  # ceil
        need = int(self._k_start[i]) + n_frames
        while self._crowd_behind(need):
            self._advance_crowd(finish=True)
        samples = self._window(int(self._k_start[i]), need + 1, self._sensed[i])
        return CBFTruth(samples=samples, dt=self._dt_frame, substeps=self.substeps)

    def neighbours(self, i: int, max_count: int | None = None) -> Neighbours:
        """The agents within robot ``i``'s sensing radius now (for observations)."""
        fi = self._fi
        me = self._x[i]
        pos = self._peds[fi]
        prev = self._peds[fi - 1] if fi > 0 else pos
        present = np.flatnonzero(np.isfinite(pos[:, 0]))
        rel = pos[present] - me[:2]
        vel = (pos[present] - prev[present]) * self.scene.fps
        vel[~np.isfinite(vel)] = 0.0
        rrel = self._x[:, :2] - me[:2]
        rvel = self._x[:, 2:]
        others = np.flatnonzero(np.arange(self._x.shape[0]) != i)
        ids = np.concatenate([np.asarray(self.scene.agent_ids)[present], self.robot_ids[others]])
        rel = np.concatenate([rel, rrel[others]])
        vel = np.concatenate([vel, rvel[others]]) - me[2:]
        is_robot = np.r_[np.zeros(present.size, bool), np.ones(others.size, bool)]
        dist = np.hypot(rel[:, 0], rel[:, 1])
        keep = np.flatnonzero(dist <= self.sensing_radius)
        keep = keep[np.argsort(dist[keep], kind="stable")]
        if max_count is not None:
            keep = keep[:max_count]
        return Neighbours(ids[keep], rel[keep], vel[keep], is_robot[keep])

    def contacts(self, i: int) -> tuple[bool, bool]:
        """(pedestrian contact, robot contact) of robot ``i`` now: centre distance below
        robot + pedestrian radius (pedestrians at the current frame) or two robot radii."""
        sc = self.scene
        me = self._x[i, :2]
        pos = self._peds[self._fi]
        ok = np.isfinite(pos[:, 0])
        ped = bool(ok.any() and np.hypot(*(pos[ok] - me).T).min() < sc.collision_distance)
        rob = False
        if self._x.shape[0] > 1:
            d = np.hypot(*(self._x[:, :2] - me).T)
            d[i] = np.inf
            rob = bool(d.min() < 2.0 * sc.robot_radius)
        return ped, rob

    # ------------------------------------------------------------------ plant
    def _crowd_behind(self, frame: int) -> bool:
        return self.crowd is not None and self._crowd_frame < frame

    def _advance_crowd(self, finish: bool = False) -> None:
        """One crowd step with every robot's current state; store a frame when complete."""
        assert self.crowd is not None
        x = self._x
        self.crowd.step(self._crowd_frame, self._crowd_sub, x[:, :2], x[:, 2:4])
        self._crowd_sub += 1
        if self._crowd_sub == self.substeps:
            self._crowd_frame += 1
            self._crowd_sub = 0
            f = self._crowd_frame
            self._peds[f] = self.crowd.frame_positions(f)
            if finish and f < self._robot_pos.shape[0]:
                self._robot_pos[f] = x[:, :2]  # the robots held their last states

    def apply(self, commands: np.ndarray) -> None:
        """One control instant: every robot under way applies its command (m/s).

        ``commands`` has shape (R, 2); rows of robots that have finished are ignored
        (their plants are commanded to stop).
        """
        if self._world_done:
            raise RuntimeError("apply() called on a finished world")
        cmd = np.asarray(commands, dtype=float)
        r = self._x.shape[0]
        if cmd.shape != (r, 2):
            raise ValueError(f"commands must have shape ({r}, 2), got {cmd.shape}")
        if self.crowd is not None:
            # robots and crowd move together over the control step, each seeing the
            # others' states at its start
            self._advance_crowd()
        self._t += self._dt
        self._n_instants += 1
        t = self._t
        stop = np.zeros(2)
        for i in range(r):
            if self._done[i]:
                if not self._parked[i]:
                    x = self._plants[i].step(self._x[i], stop, self._dt)
                    if math.hypot(x[2], x[3]) < PARKED_SPEED:
                        x[2:] = 0.0  # stopped: no more plant steps
                        self._parked[i] = True
                    self._x[i] = x
                continue
            c = cmd[i]
            self._x[i] = self._plants[i].step(self._x[i], c, self._dt)
            self._step[i] += 1
            rec = self.robots[i]
            rec.steps_t.append(t)
            rec.steps_x.append(self._x[i].copy())
            rec.steps_cmd.append(c.copy())
            goals = self._goal_xy[i]
            g = int(self._goal[i])
            x0, x1 = self._x[i, :2].tolist()
            radius = self.scene.goal_radius
            while g < len(goals) and math.hypot(x0 - goals[g][0], x1 - goals[g][1]) <= radius:
                g += 1
            if g >= len(goals):
                g = len(goals) - 1
                rec.t_goal_ = t
                self._done[i] = True
            self._goal[i] = g
        # the plans broadcast at this instant are what the others see at the next one; a
        # robot at its goal (stopping) broadcasts standing still
        if self.information == "plan":
            self._next_v[self._done] = 0.0
            self._plan_v[:] = self._next_v
            done, nxt = self._done, self._next_paths
            self._paths = [None if d else p for d, p in zip(done, nxt, strict=True)]
            self._yield[:] = self._next_yield & ~done
            self._any_yield = bool(self._yield.any())
        self._tick()

    def _tick(self) -> None:
        """The frame clock after a control instant: a closed frame is stored and logged,
        the world ends at the last frame or once every robot is at its goal."""
        if self._n_instants % self.substeps == 0:
            self._fi += 1
            self._robot_pos[self._fi] = self._x[:, :2]
            if self._fi >= self._last:
                self._world_done = True
            elif self._done.all():
                self._world_done = True
            else:
                self._log_frame()
        elif self._done.all():
            self._world_done = True


def _no_future(horizon: int) -> np.ndarray:
    raise TruthUnavailableError(
        "the future of this query is not known at the sampling time: its pedestrians "
        "react to the robots (the oracle predictor needs crowd='replay')"
    )
