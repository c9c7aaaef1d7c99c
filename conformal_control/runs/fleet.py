"""Decentralized multi-robot runs: M robots, each its own conformal CBF controller.

Every robot is the flagship of :func:`~conformal_control.runs.build.build_flagship` -- its
own predictor, barrier, safety filter, reference controller, loss, update rule and lambda
-- built from the same parameters (role instances are deep-copied per robot, so no state
is shared) and driven by its own :class:`~conformal_control.core.loop.ConformalStepper`. Each
senses the pedestrians and the other robots through its own sensor in the shared world
(:class:`~conformal_control.world.multi.MultiRobotWorld`), which types the robots as
robots, and learns its own lambda from its own losses.

How a robot treats the others (:mod:`conformal_control.families.cbf.reciprocal`): by default each
pair shares one constraint, each robot taking its share of the pair's barrier rate
(``reciprocity="reciprocal"``), from what the ``information`` option lets robots know of
each other (positions, velocities, or the commands they broadcast: ``"plan"``, the
default, the only communication); ``reciprocity="none"`` predicts the other robots like
pedestrians (each taking the whole constraint for its prediction), and robots listed in
``ignoring`` take no robot into account. ``lambda_scope`` says which rows lambda is the
slack of, ``hard_rows`` how the lambda search treats the others, ``sidestep`` how a robot
held back by another turns. Nothing else of another robot is ever read.

Starts and goals (:func:`robot_tasks`):

* ``layout="scene"`` (default): robot 0 does the scene's own task (its start and goals);
  robot ``i`` does the same task rotated by ``2 pi i / M`` about the midpoint of the start
  and the last goal. With two robots they swap ends; with one, it is the single-robot
  episode exactly (:func:`run_multi` then reproduces
  :func:`~conformal_control.runs.episode.run_episode`, metric for metric);
* ``layout="antipodal"``: the robots evenly spaced on a circle of ``radius`` (m) about
  ``center`` (m), each going to the opposite point (robot 0 starts left of the centre);
* ``starts=`` and ``goals=``: an explicit list (goals ``(M, 2)``, or one list of waypoints
  per robot).

Robot ``i``'s named plugins receive ``random_state = seed + i``; a reactive crowd's seed
is ``seed`` (unless ``crowd_params`` sets one).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.loop import ConformalStepper
from ..core.spec import (
    FLOOR_CORE_DEFAULT,
    FLOOR_MARGIN_M,
    MAX_ROBOTS,
    PEER_HORIZON_S,
    ROBOT_CHOICES,
    Robots,
    RunSpec,
)
from ..data.scene import Scene
from ..families.cbf.feasibility import feasibility_floor
from ..families.cbf.reciprocal import RECIPROCITY, Reciprocity
from ..world.multi import MultiRobotWorld
from .build import Flagship, build_flagship
from .engines.batch.fleet import drive_lockstep, lockstep_reason
from .results.episode import RobotResult
from .results.measure import derived_lambda_safe, episode_config, jsonable, measure
from .results.multi_metrics import (
    DeadlockRule,
    FleetMetrics,
    deadlocks,
    fleet_metrics,
    remaining_paths,
    robot_contacts,
)
from .results.multi_record import multi_record
from .results.rundir import csv_cell, finite_or_none

__all__ = [
    "LAYOUTS",
    "MAX_ROBOTS",
    "MultiResult",
    "RobotResult",
    "as_tasks",
    "check_tasks",
    "drive",
    "load_robots_file",
    "prepare_fleet",
    "robot_tasks",
    "run_multi",
    "write_multi_run_dir",
]

#: Built-in layouts of :func:`robot_tasks`.
LAYOUTS = ROBOT_CHOICES["layout"]


# ---------------------------------------------------------------------------- tasks
def _rotate(p: np.ndarray, c: np.ndarray, angle: float) -> np.ndarray:
    cs, sn = math.cos(angle), math.sin(angle)
    d = np.asarray(p, dtype=float) - c
    out: np.ndarray = c + np.stack(
        [cs * d[..., 0] - sn * d[..., 1], sn * d[..., 0] + cs * d[..., 1]], -1
    )
    return out


def robot_tasks(
    scene: Scene,
    n: int,
    layout: str = "scene",
    *,
    radius: float | None = None,
    center: Sequence[float] | None = None,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Starts ``(n, 2)`` and goals (one ``(G, 2)`` array per robot), in metres.

    Parameters
    ----------
    scene : Scene
    n : int
        Number of robots (1 to :data:`MAX_ROBOTS`).
    layout : {"scene", "antipodal"}
        See the module docstring.
    radius : float, optional
        ``antipodal``: radius of the circle (m); default half the distance from the
        scene's start to its last goal.
    center : (x, y), optional
        ``antipodal``: centre of the circle (m); default the midpoint of the scene's start
        and last goal.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_ROBOTS:
        raise ValueError(
            f"the number of robots must be an integer from 1 to {MAX_ROBOTS}, got {n!r}"
        )
    start = np.asarray(scene.start, dtype=float)
    goals = np.asarray(scene.goals, dtype=float).reshape(-1, 2)
    mid = 0.5 * (start + goals[-1])
    if layout == "scene":
        if radius is not None or center is not None:
            raise ValueError("radius and center apply to layout='antipodal'")
        starts = [start] + [_rotate(start, mid, 2 * math.pi * i / n) for i in range(1, n)]
        tasks = [goals] + [_rotate(goals, mid, 2 * math.pi * i / n) for i in range(1, n)]
        return np.array(starts), tasks
    if layout != "antipodal":
        raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    c = mid if center is None else np.asarray(center, dtype=float).reshape(2)
    r = 0.5 * float(np.hypot(*(goals[-1] - start))) if radius is None else float(radius)
    if not (math.isfinite(r) and r > 0) or not np.isfinite(c).all():
        raise ValueError(f"antipodal layout needs a finite radius > 0 and centre, got {r!r}, {c}")
    ang = math.pi + 2 * math.pi * np.arange(n) / n
    unit = np.column_stack([np.cos(ang), np.sin(ang)])
    return c + r * unit, [(c - r * u).reshape(1, 2) for u in unit]


def as_tasks(starts: Any, goals: Any) -> tuple[np.ndarray, list[np.ndarray]]:
    s = np.asarray(starts, dtype=float)
    if s.ndim != 2 or s.shape[1] != 2 or not 1 <= s.shape[0] <= MAX_ROBOTS:
        raise ValueError(
            f"starts must have shape (M, 2) with 1 <= M <= {MAX_ROBOTS}, got {s.shape}"
        )
    if goals is None or len(goals) != s.shape[0]:
        raise ValueError(f"{s.shape[0]} starts need {s.shape[0]} goals (or lists of waypoints)")
    tasks = []
    for i, g in enumerate(goals):
        g = np.asarray(g, dtype=float)
        if g.size == 0 or g.size % 2 or not np.isfinite(g).all():
            raise ValueError(f"robot {i}: goals must be finite (x, y) pairs, got {g.tolist()}")
        tasks.append(g.reshape(-1, 2))
    if not np.isfinite(s).all():
        raise ValueError("robot starts must be finite")
    return s, tasks


#: The largest robots file read (bytes): twenty robots take a few hundred bytes.
MAX_ROBOTS_FILE_BYTES = 1 << 20
#: The largest coordinate of a robots file (m, or a fraction): 1000 km.
MAX_COORDINATE = 1e6


def _json_point(value: Any) -> bool:
    """Whether ``value`` is ``[x, y]`` of JSON numbers (not booleans, not text) within
    :data:`MAX_COORDINATE`."""
    return (
        isinstance(value, list)
        and len(value) == 2
        and all(
            isinstance(v, (int, float))
            and not isinstance(v, bool)
            and math.isfinite(v)
            and abs(v) <= MAX_COORDINATE
            for v in value
        )
    )


def load_robots_file(path: str | Path, scene: Scene) -> tuple[np.ndarray, list[np.ndarray]]:
    """Starts and goals (m) from a JSON file.

    The file holds ``{"units": "m", "robots": [{"start": [x, y], "goals": [[x, y], ...]},
    ...]}``; with ``"units": "fraction"`` the coordinates are fractions of the scene's
    frame, its image or its walkable box (as ``--start`` and ``--goal``). A robot's
    ``"goal": [x, y]`` may stand for a single goal.
    """
    import difflib

    from ..core.exceptions import InputError
    from ..core.fileio import read_limited

    p = Path(path)
    try:
        # capped, never a FIFO or a device (/dev/zero read until memory ran out)
        raw = read_limited(p, MAX_ROBOTS_FILE_BYTES, what="robots file")
        spec = json.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise FileNotFoundError(f"robots file {p} does not exist") from None
    except UnicodeDecodeError:
        raise InputError(f"robots file {p} is not a text file (not UTF-8)") from None
    except json.JSONDecodeError as exc:
        raise ValueError(
            f"robots file {p} is not valid JSON ({exc.msg}, line {exc.lineno})"
        ) from None
    except RecursionError:
        raise InputError(f"robots file {p} is nested too deeply to be a robots file") from None

    def no_unknown(keys: Any, known: tuple[str, ...], where: str) -> None:
        for key in keys:
            if key not in known:
                close = difflib.get_close_matches(str(key), known, n=1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                raise InputError(
                    f"robots file {p}: unknown key {key!r} {where}; {hint}the keys are "
                    f"{', '.join(known)}"
                )

    robots = spec.get("robots") if isinstance(spec, dict) else None
    if not isinstance(robots, list) or not robots:
        raise ValueError(f'robots file {p} needs a non-empty list "robots"')
    no_unknown(spec, ("units", "robots"), "at the top level")
    units = spec.get("units", "m")
    if units not in ("m", "fraction"):
        raise ValueError(f'robots file {p}: "units" must be "m" or "fraction", got {units!r}')
    origin, scale = np.zeros(2), np.ones(2)
    if units == "fraction":  # of the scene's frame: its image, or its walkable box (ETH/UCY)
        from ..data.positions import scene_frame

        frame = scene_frame(scene)
        if frame is None:
            raise ValueError(f"scene {scene.name} has no frame for fractions: use units 'm'")
        origin, scale = frame
    starts, goals = [], []
    for i, r in enumerate(robots):
        if not isinstance(r, dict) or "start" not in r or not ("goals" in r or "goal" in r):
            raise ValueError(f'robots file {p}: robot {i} needs "start" and "goals" (or "goal")')
        no_unknown(r, ("start", "goals", "goal"), f"in robot {i}")
        if "goals" in r and "goal" in r:
            raise InputError(f'robots file {p}: robot {i} has both "goal" and "goals"; give one')
        listed = r["goals"] if "goals" in r else [r["goal"]]
        if not isinstance(listed, list) or not all(_json_point(q) for q in [r["start"], *listed]):
            raise InputError(
                f"robots file {p}: robot {i} has a start or goal that is not two numbers "
                f"[x, y] within {MAX_COORDINATE:g} (JSON numbers: not text, not true/false)"
            )
        try:
            st = np.asarray(r["start"], dtype=float).reshape(2)
            g = np.asarray(r["goals"] if "goals" in r else [r["goal"]], dtype=float).reshape(-1, 2)
        except (TypeError, ValueError):
            raise ValueError(
                f"robots file {p}: robot {i} has a start or goal that is not (x, y)"
            ) from None
        if g.shape[0] == 0 or not (np.isfinite(st).all() and np.isfinite(g).all()):
            raise InputError(f"robots file {p}: robot {i} needs a finite start and goal")
        if units == "fraction" and not (
            ((st >= 0) & (st <= 1)).all() and ((g >= 0) & (g <= 1)).all()
        ):
            raise InputError(
                f"robots file {p}: robot {i} has a fraction outside [0, 1] (units "
                '"fraction" are fractions of the scene\'s width and height)'
            )
        starts.append(origin + st * scale)
        goals.append(origin + g * scale)
    first = np.array(starts)
    gap = 2.0 * float(scene.robot_radius)
    for i in range(len(first)):
        d = np.hypot(*(first[i + 1 :] - first[i]).T) if i + 1 < len(first) else np.zeros(0)
        if d.size and d.min() < gap:
            j = i + 1 + int(np.argmin(d))
            raise InputError(
                f"robots file {p}: robots {i} and {j} start {d.min():.3g} m apart, less than "
                f"two robot radii ({gap:.3g} m): they would start in collision"
            )
    return as_tasks(first, goals)


def prepare_fleet(
    scene: str | Scene,
    spec: RunSpec,
    *,
    data_root: str | Path | None = None,
    start: Any = None,
    goal: Any = None,
    start_frame: int | None = None,
    robots_file: str | Path | None = None,
    center: Any = None,
    **robots: Any,
) -> tuple[Scene, RunSpec]:
    """A fleet's run made ready: the scene loaded, a trainable predictor's weights found
    or trained, and the robots' section (their tasks from ``robots_file``, else from the
    layout) on ``spec``.

    Parameters
    ----------
    scene : str or Scene
        A registered scene name (loaded with ``data_root``, ``start``, ``goal``,
        ``start_frame`` and the spec's seed) or a scene.
    spec : RunSpec
        The run every robot shares.
    data_root : path, optional
        Data folder for scenes read from data and a trainable predictor's weights.
    start, goal, start_frame :
        The scene's task, as :func:`~conformal_control.data.load_scene` takes it.
    robots_file : path, optional
        The robots' starts and goals (:func:`load_robots_file`); then no ``layout``
        (other than ``"scene"``), ``radius`` or ``center``.
    center : position, optional
        The layout's centre as typed (a fraction of the scene's frame, metres, pixels).
    **robots :
        Fields of the robots section (:class:`~conformal_control.core.spec.Robots`):
        ``robots``, ``layout``, ``radius``, ``sensor_history``, ``reciprocity``, ...

    Raises
    ------
    ValueError
        For a robots file given with a layout, a radius or a centre.
    """
    from ..predictors.training import with_weights

    if isinstance(scene, str):
        from ..data import load_scene

        scene = load_scene(
            scene, data_root, start=start, goals=goal, start_frame=start_frame, seed=spec.seed
        )
    spec = with_weights(spec, scene, None if data_root is None else str(data_root))
    if robots_file is not None:
        layout, radius = robots.pop("layout", "scene"), robots.pop("radius", None)
        if layout != "scene" or radius is not None or center is not None:
            raise ValueError(
                "--robots-file gives the tasks: drop --robot-layout, --radius, --center"
            )
        robots["starts"], robots["goals"] = load_robots_file(robots_file, scene)
    elif center is not None:
        from ..data.positions import scene_position

        robots["center"] = tuple(scene_position(scene, center, "--center").tolist())
    else:
        robots["center"] = None
    return scene, RunSpec.from_settings(None, base=spec, **robots)


def check_tasks(starts: np.ndarray, goals: Sequence[np.ndarray], robot_radius: float) -> None:
    """Refuse tasks no fleet can do (a one-line ``ValueError``): two robots that start, or
    end at their last goals, closer than two robot radii."""
    d_c = 2.0 * float(robot_radius)
    for what, pts in (
        ("start", np.asarray(starts)),
        ("end at goals", np.array([g[-1] for g in goals])),
    ):
        d = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
        d[np.tril_indices(d.shape[0])] = np.inf
        if d.size and d.min() < d_c:
            i, j = np.unravel_index(int(np.argmin(d)), d.shape)
            raise ValueError(
                f"robots {i} and {j} {what} {d[i, j]:.3g} m apart, closer than two robot radii "
                f"({d_c:.3g} m): no fleet can do these tasks"
            )


# ---------------------------------------------------------------------------- results
@dataclass
class MultiResult:
    """Everything a multi-robot run produced (what its run directory is written from).

    Attributes
    ----------
    scene : Scene
        The scene as run (resolved radii and v_max).
    config : dict
        The full configuration (``config.json``).
    metrics : FleetMetrics
        The aggregate; per robot see ``robots[i].metrics``.
    robots : list of RobotResult
    track : dict of arrays
        The world per frame: ``frame (F,)``, ``t (F,)``, ``robots (F, M, 2)`` positions
        (robots that reached their goal included), ``active (F, M)``.
    animation : dict or None
        The record :func:`~conformal_control.io.plotting.animation.render_animation`
        renders.
    """

    scene: Scene
    config: dict[str, Any]
    metrics: FleetMetrics
    robots: list[RobotResult]
    track: dict[str, np.ndarray]
    animation: dict[str, Any] | None = None

    def summary_table(self) -> str:
        """One line per robot: goal, time, collisions (pedestrians, robots), d_min, lambda."""
        head = f"{'robot':>5} {'goal':>5} {'t_goal':>7} {'n_ped':>5} {'n_rob':>5} "
        head += f"{'d_min':>6} {'d_rob':>6} {'lambda':>8}"
        lines = [head]
        for r in self.robots:
            m, c = r.metrics, r.contacts

            def f(v: float | None, spec: str) -> str:
                return "-" if v is None else format(v, spec)

            lines.append(
                f"{r.index:>5} {('yes' if m.goal_reached else 'no'):>5} {f(m.t_goal, '7.2f')} "
                f"{m.n_collide:>5} {c.n_collide_robot:>5} {f(m.d_min, '6.2f')} "
                f"{f(c.d_min_robot, '6.2f')} {f(m.lambda_final, '8.3g')}"
            )
        return "\n".join(lines)

    def save(self, out: str | Path) -> Path:
        """Write the run directory (see :func:`write_multi_run_dir`)."""
        return write_multi_run_dir(self, out)


# ---------------------------------------------------------------------------- running
def _copy_role(spec: Any) -> Any:
    """A name, ``(name, params)`` or None as is; an instance deep-copied (no state shared
    between robots)."""
    if spec is None or isinstance(spec, (str, tuple)):
        return spec
    return copy.deepcopy(spec)


def run_multi(
    scene: Scene,
    robots: int | RunSpec | None = None,
    *,
    extra_config: dict[str, Any] | None = None,
    deadlock: DeadlockRule | None = None,
    engine: str = "auto",
    **settings: Any,
) -> MultiResult:
    """Run M robots, each with its own conformal CBF controller, in one scene.

    The parameters not listed below are as for
    :func:`~conformal_control.runs.episode.run_episode`, applied to every robot.

    Parameters
    ----------
    scene : Scene
    robots : int or RunSpec, optional
        Number of robots (1 to :data:`MAX_ROBOTS`), placed by ``layout``; or give
        ``starts`` and ``goals``. Or the run (:class:`~conformal_control.core.spec.RunSpec`,
        its ``robots`` section saying where they go; the settings below apply on it).
    extra_config : dict, optional
        Merged into the configuration (``config.json``).
    deadlock : DeadlockRule, optional
        When a robot counts as deadlocked (default 5 s without 0.25 m of progress).
    engine : {"auto", "loop"}
        ``"auto"``: each control instant's robots stepped together in compiled calls
        (:func:`~conformal_control.runs.engines.batch.fleet.drive_lockstep`) when
        :func:`~conformal_control.runs.engines.batch.fleet.lockstep_reason` allows, else the
        per-fleet loop (:func:`drive`); ``"loop"``: the loop. The results are the same.
    **settings
        Settings of the run (:meth:`RunSpec.from_settings
        <conformal_control.core.spec.RunSpec.from_settings>`), the robots section's included:

        - ``starts``, ``goals`` (array-like, optional):
          Explicit tasks (m): starts ``(M, 2)``; goals ``(M, 2)`` or one ``(G, 2)`` list of
          waypoints per robot.
        - ``layout``, ``radius``, ``center``:
          See :func:`robot_tasks`.
        - ``sensor_history`` ({"tracked", "observed"}):
          Histories handed to each robot's predictor (see
          :class:`~conformal_control.world.multi.MultiRobotWorld`).
        - ``reciprocity`` ({"reciprocal", "none"}):
          Robots share each pair's constraint, or predict each other like pedestrians.
        - ``information`` ({"position", "velocity", "plan"}):
          What reciprocal robots know of each other (``"plan"``: they broadcast commands).
        - ``lambda_scope`` ({"pedestrians", "robots", "both"}, optional):
          The rows lambda is the slack of (default: ``"pedestrians"`` with reciprocity,
          ``"both"`` without).
        - ``weights`` (sequence of float, optional):
          The fleet's share weights (robot i's share of a pair: ``w_i / (w_i + w_j)``).
        - ``ignoring`` (sequence of int):
          Robots that take no other robot into account (a robot that does not comply).
        - ``sidestep`` (float):
          Angle (rad) a reciprocal robot held back by another turns its nominal velocity by.
        - ``hard_rows`` ({"last", "level"}):
          How the lambda search treats the rows lambda is not the slack of.
        - ``peer_horizon`` (float, optional):
          Planning families: how far ahead (s) the peers' lines bind a plan (default
          1.2 s).
        - ``priority`` ({"pedestrians", "robots"}):
          The rows kept longest when not every row can be met (default
          ``"pedestrians"``: the robot rows give way first).
        - ``coordination`` ({"none", "yield"}):
          ``"yield"``: a robot whose robot rows gave way says so, and its partners take
          the whole pair (needs ``information="plan"``).
        - ``floor_margin`` (float):
          CBF family, people first: how far (m) beyond the robots' collision distance
          their floor rows aim (default 0.1 m; 0: the collision distance).
        - ``floor_core`` ({"always", "inside", "calm", "ahead", "none"}):
          CBF family, people first: which pairs' floor rows keep their cores before the
          pedestrians' rows give way (every pair's, only those already closer than the
          collision distance, only those with no pedestrian inside its collision
          distance of either robot, only those with none inside nor predicted inside
          within 1 s and those within the floor distance, or none).

    Returns
    -------
    MultiResult
    """
    if engine not in ("auto", "loop"):
        raise ValueError(f"engine must be 'auto' or 'loop', got {engine!r}")
    if isinstance(robots, RunSpec):
        run = RunSpec.from_settings(None, base=robots, **settings) if settings else robots
    else:
        if robots is not None:
            settings["robots"] = robots
        run = RunSpec.from_settings(settings.pop("params", None), **settings)
    scene = run.on_scene(scene)  # the run's task (start_m, goals_m) is robot 0's
    section = run.robots or Robots()
    robots, starts, goals = section.robots, section.starts, section.goals
    layout, radius, center = section.layout, section.radius, section.center
    sensor_history = section.sensor_history
    reciprocity, information = section.reciprocity, section.information
    lambda_scope, weights, ignoring = section.scope, section.weights, section.ignoring
    sidestep, hard_rows = section.sidestep, section.hard_rows
    peer_horizon, coordination = section.peer_horizon, section.coordination
    priority, floor_margin = section.priority, section.floor_margin
    floor_core = section.floor_core
    if coordination != "none" and information != "plan":
        raise ValueError(
            f"robots coordination={coordination!r} needs information='plan' (robots tell "
            f"each other that they yield), got information={information!r}"
        )
    learn, seed, max_frames = run.learn, run.seed, run.max_frames
    if starts is not None or goals is not None:
        if robots is not None and np.asarray(starts).reshape(-1, 2).shape[0] != robots:
            raise ValueError(f"robots={robots} but {len(starts)} starts were given")
        if layout != "scene" or radius is not None or center is not None:
            raise ValueError("give either explicit starts and goals or a layout, not both")
        s, tasks = as_tasks(starts, goals)
    else:
        s, tasks = robot_tasks(
            scene, 1 if robots is None else robots, layout, radius=radius, center=center
        )
    n = s.shape[0]
    roles = ("predictor", "barrier", "safety_filter", "fallback", "reference", "dynamics")
    fleet: list[Flagship] = []
    for i in range(n):
        scene_i = scene.replace(start=s[i], goals=tasks[i])
        copies: dict[str, Any] = {r: _copy_role(getattr(run, r)) for r in (*roles, "loss", "rule")}
        robot_run = dataclasses.replace(
            run,
            seed=seed + i,
            # the world's crowd is robot 0's (the others' environments are not used)
            crowd=run.crowd if i == 0 else "replay",
            robots=None,
            **copies,
        )
        fleet.append(build_flagship(scene_i, robot_run))
    check_tasks(s, tasks, fleet[0].params.si["robot_radius"])
    modes = robot_modes(n, reciprocity, ignoring)
    radii = fleet[0].params.si
    for fl, mode in zip(fleet, modes, strict=True):
        # robot rows keep two robot radii apart; the barrier was built for robot + agent
        set_reciprocity(
            fl.family,
            mode,
            lambda_scope,
            radii["robot_radius"] - radii["agent_radius"],
            sidestep,
            hard_rows,
            peer_horizon,
            coordination,
            priority,
            floor_margin,
            floor_core,
        )
    fl0 = fleet[0]
    env0 = fl0.env
    world = MultiRobotWorld(
        fl0.scene,
        s,
        tasks,
        [fl.dynamics for fl in fleet],
        tau_frames=env0.tau_frames,
        substeps=env0.substeps,
        sensing_radius=env0.sensing_radius,
        history_frames=env0.history_frames,
        max_frames=max_frames,
        crowd=getattr(env0, "crowd", None),
        sensor_history=sensor_history,
        information=information if "reciprocal" in modes else None,
        weights=weights,
    )
    run_scene = fl0.scene
    si = fl0.params.si
    lam_unit = run_scene.units.factor("lambda_init")
    lambda_safe = run.lambda_safe
    if isinstance(lambda_safe, str):  # "auto": derived from the built run, SI
        lambda_safe = derived_lambda_safe(fl0).value / lam_unit
    elif lambda_safe is not None and run.units == "si":
        lambda_safe = lambda_safe / lam_unit
    lam_safe_si = None if lambda_safe is None else float(lambda_safe) * lam_unit
    steppers = [
        ConformalStepper(
            fl.family,
            fl.loss,
            fl.rule,
            learn=learn,
            lambda_safe=lam_safe_si,
            lambda_safe_source=run.lambda_safe_source,
        )
        for fl in fleet
    ]

    t0, c0 = time.perf_counter(), time.process_time()
    why = "asked" if engine == "loop" else lockstep_reason(world, steppers)
    if why is None:
        own = drive_lockstep(world, steppers, broadcast=information == "plan").own
    else:
        own = drive(world, steppers, broadcast=information == "plan")
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0

    h_max = fl0.barrier.upper_bound
    floor = feasibility_floor(
        si["a"], math.inf if h_max is None else h_max, si["epsilon"], si["loss_scale"]
    )
    stuck = _deadlocks(world, tasks, deadlock or DeadlockRule())
    results: list[RobotResult] = []
    for i, (fl, st) in enumerate(zip(fleet, steppers, strict=True)):
        rec = world.robots[i]
        # the robot's record is what the single-robot measurement reads of an environment
        view = dataclasses.replace(fl, env=rec)  # type: ignore[arg-type]
        m, intervals, traj = measure(
            view, st.result(), learn, lambda_safe, floor, own[i], world.pedestrians()
        )
        contacts = robot_contacts(
            rec.d_min_robot,
            run_scene.robot_radius,
            stuck[i],
            d_min_pedestrian=traj["d_min"],
            collision_distance=run_scene.collision_distance,
        )
        m = dataclasses.replace(
            m, success=bool(m.goal_reached and m.n_collide == 0 and contacts.n_collide_robot == 0)
        )
        traj["d_min_robot"] = np.array(rec.d_min_robot, dtype=float)
        results.append(
            RobotResult(
                index=i,
                id=int(world.robot_ids[i]),
                start=s[i],
                goals=tasks[i],
                metrics=m,
                contacts=contacts,
                intervals=intervals,
                trajectory=traj,
                steps={
                    "t": np.array(rec.steps_t),
                    "x": np.array(rec.steps_x).reshape(-1, 4),
                    "cmd": np.array(rec.steps_cmd).reshape(-1, 2),
                },
                loop=st.result(),
            )
        )
    track = _track(world, results)
    metrics = fleet_metrics(
        [r.metrics for r in results],
        [r.contacts for r in results],
        robot_track=track["robots"],
        active=track["active"],
        robot_radius=run_scene.robot_radius,
        frames=track["frame"].size,
        wall_s=wall,
        lam_unit_name=results[0].metrics.unit("lambda_final"),
        cpu_s=cpu,
    )
    config = episode_config(fl0, run, lambda_safe)
    config["kind"] = "multi"
    config["n_robots"] = n
    for key in ("start_m", "goals_m"):
        config["scene"].pop(key, None)
    config["robots"] = [
        {
            "robot": i,
            "id": int(world.robot_ids[i]),
            "start_m": s[i].tolist(),
            "goals_m": tasks[i].tolist(),
            "seed": seed + i,
        }
        for i in range(n)
    ]
    config["layout"] = (
        {"layout": "explicit"}
        if starts is not None
        else {
            "layout": layout,
            "radius": radius,
            "center": None if center is None else list(center),
        }
    )
    config["sensor_history"] = sensor_history
    config["reciprocity"] = {
        "reciprocity": reciprocity,
        "information": information,
        "lambda_scope": lambda_scope,
        "weights": None if weights is None else [float(w) for w in weights],
        "ignoring": [int(i) for i in ignoring],
        "sidestep": float(sidestep),
        "hard_rows": hard_rows,
        "peer_horizon": peer_horizon,
        "coordination": coordination,
        "priority": priority,
        "floor_margin": float(floor_margin),
        "floor_core": floor_core,
        "modes": modes,
    }
    config["max_frames"] = max_frames
    config["feasibility"] = jsonable(floor.as_dict())
    crowd_config = getattr(env0, "crowd_config", None)
    config["crowd"] = crowd_config() if crowd_config is not None else {"crowd": "replay"}
    config.update(extra_config or {})
    animation = None
    if run.record_animation:
        animation = multi_record(world, results, track, epsilon=si["epsilon"])
    return MultiResult(run_scene, jsonable(config), metrics, results, track, animation)


def robot_modes(n: int, reciprocity: str, ignoring: Sequence[int] = ()) -> list[str]:
    """Each robot's treatment of the others: ``reciprocity`` for all, ``"ignore"`` for the
    robots listed in ``ignoring`` (a robot that does not comply)."""
    if reciprocity not in RECIPROCITY or reciprocity == "ignore":
        raise ValueError(f"reciprocity must be 'reciprocal' or 'none', got {reciprocity!r}")
    bad = [i for i in ignoring if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < n]
    if bad:
        raise ValueError(f"ignoring lists robots that do not exist (0 to {n - 1}): {bad}")
    return ["ignore" if i in set(ignoring) else reciprocity for i in range(n)]


def set_reciprocity(
    family: Any,
    mode: str,
    lambda_scope: str,
    robot_margin: float = 0.0,
    sidestep: float = 0.3,
    hard_rows: str = "last",
    peer_horizon: float | None = PEER_HORIZON_S,
    coordination: str = "none",
    priority: str = "pedestrians",
    floor_margin: float = FLOOR_MARGIN_M,
    floor_core: str = FLOOR_CORE_DEFAULT,
) -> None:
    """Give a robot's decision family its treatment of the other robots (a one-line error
    for a family that cannot have one), a
    :class:`~conformal_control.families.cbf.reciprocal.Reciprocity`.

    Parameters
    ----------
    family : DecisionFamily
        The robot's decision family; it needs a ``reciprocity`` attribute.
    mode : {"reciprocal", "none", "ignore"}
        Reciprocal rows, prediction (as a pedestrian), or no constraint.
    lambda_scope : {"pedestrians", "robots", "both"}
        Rows that get ``+ lambda`` (and agents the loss scores).
    robot_margin : float
        Added to the barrier's collision distance for the robot rows (m).
    sidestep : float
        Angle (rad) a reciprocal robot turns its nominal velocity by, away from another
        robot ahead.
    hard_rows : {"level", "last"}
        How the ``lambda_search`` fallback treats the rows without slack.
    peer_horizon : float, optional
        Planning families: how far ahead (s) the peers' lines bind a plan (default
        :data:`~conformal_control.core.spec.PEER_HORIZON_S`; None: all of it).
    coordination : {"none", "yield"}
        Whether a robot whose robot rows gave way broadcasts that it yields.
    priority : {"pedestrians", "robots"}
        The rows kept longest when not every row can be met.
    floor_margin : float
        How far (m) beyond the robots' collision distance the floor rows aim (CBF
        family, ``priority="pedestrians"``).
    floor_core : {"always", "inside", "calm", "ahead", "none"}
        Which pairs' floor rows keep their cores before the pedestrians' rows give way
        (CBF family, ``priority="pedestrians"``).
    """
    if not hasattr(family, "reciprocity"):
        raise ValueError(
            f"decision family {type(family).__name__} does not handle other robots "
            "(no reciprocity setting)"
        )
    rec = Reciprocity(
        mode,
        lambda_scope,
        robot_margin,
        sidestep,
        hard_rows,
        peer_horizon,
        coordination,
        priority,
        floor_margin,
        floor_core,
    )
    rec.validate()
    family.reciprocity = rec


def drive(
    world: MultiRobotWorld,
    steppers: Sequence[ConformalStepper],
    *,
    broadcast: bool = False,
    clock: Callable[[], float] = time.perf_counter,
) -> list[float]:
    """Run every robot's conformal loop in ``world`` until it ends; returns, per robot, the
    time (s, by ``clock``: wall time by default) spent in its own sensing, deciding and
    learning.

    With ``broadcast`` each robot broadcasts the velocity it decided and, for a family that
    plans ahead (``planned_path``), its plan's path, and for a family that can yield
    (``yielding``), whether it does
    (:meth:`~conformal_control.world.multi.MultiRobotWorld.broadcast`: seen by the others
    at the next control instant).

    The loop of :class:`~conformal_control.core.loop.ConformalLoop` for each robot, all robots
    stepping together: at a sampling time each robot under way senses and begins an
    interval; at each control instant each decides with its own lambda and the world
    applies all the decisions at once; at the next sampling time each scores its interval
    on the truth its own sensor reveals and updates its own lambda.

    Parameters
    ----------
    world : MultiRobotWorld
        The crowd and the robots.
    steppers : sequence of ConformalStepper
        One per robot, in the world's order.
    broadcast : bool
        Each robot broadcasts its decided velocity (and plan) to the others.
    clock : callable
        Gives the time (s) the robots' own work is measured with.
    """
    n = len(steppers)
    own = [0.0] * n
    world.reset()
    for st in steppers:
        st.start()
    cmds = np.zeros((n, 2))
    # what each robot broadcasts besides its command: its plan's path if it plans ahead,
    # whether it yields if it can
    paths = [getattr(st.family, "planned_path", None) for st in steppers]
    yields = [getattr(st.family, "yielding", None) for st in steppers]
    while not world.done:
        active = [int(i) for i in world.active()]
        for i in active:
            t0 = clock()
            steppers[i].begin_interval(world.sense(i))
            own[i] += clock() - t0
        for _ in range(world.control_instants()):
            for i in active:
                if world.robot_done(i):
                    continue
                t0 = clock()
                cmds[i] = steppers[i].decide(world.state(i))
                if broadcast:  # its command, its plan's path if it plans ahead, its yield
                    path, yielding = paths[i], yields[i]
                    world.broadcast(
                        i,
                        cmds[i],
                        None if path is None else path(),
                        yielding=False if yielding is None else bool(yielding()),
                    )
                own[i] += clock() - t0
            world.apply(cmds)
            if world.done:
                break
        for i in active:
            t0 = clock()
            steppers[i].end_interval(world.reveal(i))
            own[i] += clock() - t0
    return own


def _deadlocks(
    world: MultiRobotWorld, tasks: list[np.ndarray], rule: DeadlockRule
) -> list[float | None]:
    """When each robot deadlocked
    (:func:`~conformal_control.runs.results.multi_metrics.deadlocks`)."""
    sc = world.scene
    lo, hi = sc.start_index, world.frame_index
    track = world.robot_track()[lo : hi + 1]
    active = np.zeros(track.shape[:2], dtype=bool)
    first = sc.first_frame + lo
    for i, rec in enumerate(world.robots):
        active[np.asarray(rec.log.frame, dtype=np.int64) - first, i] = True
    remaining = remaining_paths(track, tasks, sc.goal_radius)
    return deadlocks(remaining, active, sc.fps, rule)


def _track(world: MultiRobotWorld, results: list[RobotResult]) -> dict[str, np.ndarray]:
    sc = world.scene
    lo = sc.start_index
    hi = world.frame_index
    pos = world.robot_track()[lo : hi + 1]
    frames = np.arange(lo, hi + 1)
    active = np.zeros((frames.size, len(results)), dtype=bool)
    for r in results:
        logged = np.asarray(r.trajectory["frame"]) - sc.first_frame - lo
        active[logged, r.index] = True
    return {
        "frame": sc.first_frame + frames,
        "t": (frames - lo) / sc.fps,
        "robots": pos,
        "active": active,
    }


# ---------------------------------------------------------------------------- run directory
def write_multi_run_dir(result: MultiResult, out: str | Path) -> Path:
    """Write a multi-robot run directory and return it.

    * ``config.json`` -- the full configuration (every robot's task and seed);
    * ``metrics.json`` -- ``{"fleet": aggregate, "robots": [per robot]}``;
    * ``robots/robot_<i>/metrics.json``, ``intervals.csv``, ``trajectory.csv`` -- each
      robot as a single-robot run writes them (plus ``d_min_robot``);
    * ``trajectories.csv`` -- ``frame,t,robot,x,y,active``: every robot at every frame;
    * ``animation.npz`` -- what ``conformal-control animate`` renders (if recorded).

    Every file is written atomically (temporary name, then rename), the fleet's
    ``metrics.json`` last; a write error names the file.
    """
    from ..core.fileio import atomic_write, atomic_write_json, atomic_write_text
    from .results.rundir import csv_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "config.json", finite_or_none(result.config))
    for r in result.robots:
        d = out / "robots" / f"robot_{r.index:02d}"
        d.mkdir(parents=True, exist_ok=True)
        cols = ["k", "t", "lambda", "loss", "loss_applied", "max_gap", "n_sensed", "n_steps"]
        rows = ([csv_cell(iv.get(c)) for c in cols] for iv in r.intervals)
        atomic_write_text(d / "intervals.csv", csv_text(cols, rows))
        tr = r.trajectory
        keys = ["t", "x", "y", "vx", "vy", "d_min", "d_min_robot"]
        traj = (
            [int(tr["frame"][j]), *(csv_cell(float(tr[c][j])) for c in keys)]
            for j in range(len(tr["frame"]))
        )
        atomic_write_text(d / "trajectory.csv", csv_text(["frame", *keys], traj))
        atomic_write_json(d / "metrics.json", finite_or_none(r.summary()))
    tk = result.track
    track = (
        [
            int(tk["frame"][j]),
            csv_cell(float(tk["t"][j])),
            i,
            csv_cell(float(tk["robots"][j, i][0])),
            csv_cell(float(tk["robots"][j, i][1])),
            int(tk["active"][j, i]),
        ]
        for j in range(tk["frame"].size)
        for i in range(tk["robots"].shape[1])
    )
    atomic_write_text(
        out / "trajectories.csv", csv_text(["frame", "t", "robot", "x", "y", "active"], track)
    )
    animation = result.animation
    if animation is not None:

        def save_npz(tmp: Path) -> None:
            with tmp.open("wb") as fh:  # a file object: numpy would append .npz to a name
                np.savez_compressed(fh, **animation)

        atomic_write(out / "animation.npz", save_npz)
    # last: the fleet's metrics.json marks a complete run directory
    summary = {
        "fleet": result.metrics.as_dict(),
        "robots": [r.summary() for r in result.robots],
    }
    atomic_write_json(out / "metrics.json", finite_or_none(summary))
    return out
