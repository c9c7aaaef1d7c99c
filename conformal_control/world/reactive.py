"""Pedestrians who react to the robot: the reactive environment and the factory by name.

:class:`ReactiveEnvironment` has the interface and the timing of
:class:`~conformal_control.world.replay.ReplayEnvironment` (same sensor, histories,
reveal of the true trajectories over each interval, frame log with ``d_min``, goals,
collision counting), but after the robot's start frame the pedestrians' positions are
simulated online by a :class:`~conformal_control.world.crowds.crowd.Crowd`: one model step per
control instant, fed with the robot's position and velocity at that instant. History
before the start frame is the recording. Since the future depends on what the robot will
do, a query's ``truth_provider`` raises
:class:`~conformal_control.predictors.base.TruthUnavailableError` (the oracle predictor
cannot run here); the truth revealed at the end of an interval is the simulated one.

:func:`make_environment` builds either environment from a crowd name: ``replay`` (the
recording), ``social_force``, ``orca`` or ``mixed`` (replayed until the robot comes
close, then reactive).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core import registry
from ..core.base import param_names
from ..data.scene import Scene
from ..families.cbf.loss import CBFTruth
from ..predictors.base import PredictionQuery, TruthUnavailableError
from .crowds.crowd import Crowd, model_names
from .replay import ReplayCursor, ReplayEnvironment

__all__ = [
    "DEFAULT_MIXED_RADIUS",
    "ReactiveCursor",
    "ReactiveEnvironment",
    "make_environment",
    "make_environment_like",
]


#: Crowd names accepted by :func:`make_environment`.


#: Default switching radius (m) of the mixed crowd.
DEFAULT_MIXED_RADIUS = 5.0


def _no_future(horizon: int) -> np.ndarray:
    raise TruthUnavailableError(
        "the pedestrians of a reactive crowd respond to the robot, so their future is not "
        "known at the sampling time (the oracle predictor needs crowd='replay')"
    )


@dataclass(frozen=True)
class ReactiveCursor(ReplayCursor):
    """A :class:`~conformal_control.world.replay.ReplayCursor` with the crowd's clock and
    positions (:meth:`ReactiveEnvironment.compiled_state`,
    :meth:`ReactiveEnvironment.from_compiled`).

    Attributes
    ----------
    buffer : ndarray or None
        The pedestrians' positions per frame, ``(frames, agents, 2)``: the recording
        before the start frame, the simulation after it (read: the environment's own
        array; written: ignored, see ``frames``).
    crowd_frame, crowd_sub : int or None
        The crowd's clock: its frame and the control instant within it.
    frames : (int, ndarray) or None
        Positions simulated elsewhere: ``(first, positions (n, agents, 2))`` are written
        into the buffer at frames ``first .. first + n - 1``.
    """

    kernel = "reactive"
    buffer: np.ndarray | None = None
    crowd_frame: int | None = None
    crowd_sub: int | None = None
    frames: tuple[int, np.ndarray] | None = None


class ReactiveEnvironment(ReplayEnvironment):
    """A :class:`ReplayEnvironment` whose pedestrians are simulated by a crowd model.

    Parameters
    ----------
    scene : Scene
    dynamics : Dynamics
    crowd : Crowd
        The crowd model and its seeding (reset with the scene at every episode).
    tau_frames, substeps, sensing_radius, history_frames, max_frames
        As for :class:`~conformal_control.world.replay.ReplayEnvironment`.

    Attributes
    ----------
    log : FrameLog
        The robot per frame, ``d_min`` measured to the simulated pedestrians.
    """

    def __init__(
        self,
        scene: Scene,
        dynamics: Any,
        *,
        crowd: Crowd,
        tau_frames: int,
        substeps: int = 4,
        sensing_radius: float = 10.0,
        history_frames: int = 120,
        max_frames: int | None = None,
    ) -> None:
        super().__init__(
            scene,
            dynamics,
            tau_frames=tau_frames,
            substeps=substeps,
            sensing_radius=sensing_radius,
            history_frames=history_frames,
            max_frames=max_frames,
        )
        self.crowd = crowd

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [
            {**p, "crowd": Crowd("social_force"), "max_frames": 12}
            for p in super()._unit_test_params()
        ]

    # ------------------------------------------------------------------ episode
    def _init_positions(self) -> np.ndarray:  # a dense buffer, filled as simulated
        if not isinstance(self.crowd, Crowd):
            raise ValueError(f"crowd must be a Crowd, got {type(self.crowd).__name__}")
        sc = self.scene
        recorded: np.ndarray = sc.positions  # dense (a sparse scene's is assembled here)
        self.crowd.reset(recorded, sc.fps, sc.start_index, self.substeps, sc.robot_radius)
        buf: np.ndarray = recorded.copy()
        buf[sc.start_index + 1 :] = np.nan  # filled as the crowd is simulated
        buf[sc.start_index] = self.crowd.frame_positions(sc.start_index)
        self._crowd_frame = sc.start_index
        self._crowd_sub = 0
        self._buffer = buf
        return buf

    def _advance_crowd(self) -> None:
        """One crowd step with the robot's current state; store a frame when complete."""
        x = self._x
        self.crowd.step(self._crowd_frame, self._crowd_sub, x[:2], x[2:4])
        self._crowd_sub += 1
        if self._crowd_sub == self.substeps:
            self._crowd_frame += 1
            self._crowd_sub = 0
            self._buffer[self._crowd_frame] = self.crowd.frame_positions(self._crowd_frame)

    def compiled_state(self) -> ReactiveCursor:
        """Where the environment and its crowd are (its own arrays: read them only)."""
        c = super().compiled_state()
        return ReactiveCursor(
            c.x,
            c.frame,
            c.t,
            c.k_start,
            c.sensed,
            c.step,
            buffer=self._buffer,
            crowd_frame=self._crowd_frame,
            crowd_sub=self._crowd_sub,
        )

    def from_compiled(self, cursor: ReplayCursor) -> None:
        """Put the environment (and, for a :class:`ReactiveCursor`, its crowd's clock and
        the positions simulated elsewhere) where ``cursor`` says.

        Parameters
        ----------
        cursor : ReplayCursor or ReactiveCursor
            The state to take (fields left at None are left as they are).
        """
        super().from_compiled(cursor)
        if not isinstance(cursor, ReactiveCursor):
            return
        if cursor.frames is not None:
            first, xy = cursor.frames
            self._buffer[first : first + len(xy)] = xy
        if cursor.crowd_frame is not None:
            self._crowd_frame = cursor.crowd_frame
        if cursor.crowd_sub is not None:
            self._crowd_sub = cursor.crowd_sub

    def apply(self, decision: np.ndarray) -> None:
        if self._done:
            raise RuntimeError("apply() called on a finished episode")
        # robot and crowd move together over the control step, each seeing the other's
        # state at its start
        self._advance_crowd()
        super().apply(decision)

    def sense(self) -> PredictionQuery:
        query = super().sense()
        query.truth_provider = _no_future
        return query

    def reveal(self) -> CBFTruth:
        # an episode that ended within a frame: finish the frame (the robot holding its
        # last state) so that the interval's truth has its closing sample
        need = self._k_start + -(-self._step // self.substeps)
        while self._crowd_frame < need:
            self._advance_crowd()
        return super().reveal()

    # ------------------------------------------------------------------ outputs
    def simulated_scene(self) -> Scene:
        """The scene with the positions the robot met, for plots and animations.

        The recording before the start frame, the simulation after it, NaN beyond the last
        simulated frame; the positions array is the environment's buffer (not a copy).
        """
        return self.scene.replace(positions=self._buffer)

    def crowd_config(self) -> dict[str, Any]:
        """The crowd's configuration and counters, for the run's config (JSON-ready)."""
        c = self.crowd
        model = getattr(c, "model_", None)
        name = c.model if isinstance(c.model, str) else type(c.model).__name__
        params = {k: v for k, v in c.get_params().items() if k not in ("model", "model_params")}
        out: dict[str, Any] = {
            "crowd": "mixed" if c.mixed else name,
            "model": name,
            "model_params": dict(model.get_params()) if model is not None else {},
            **params,
        }
        if model is not None:
            out.update(c.summary())
        return out


def make_environment(
    scene: Scene,
    crowd: str = "replay",
    crowd_params: dict[str, Any] | None = None,
    **env_kwargs: Any,
) -> ReplayEnvironment:
    """The environment of an episode, with pedestrians replayed or reacting to the robot.

    Parameters
    ----------
    scene : Scene
    crowd : str
        ``"replay"`` (the recording, :class:`ReplayEnvironment`), ``"social_force"``,
        ``"orca"`` (every pedestrian simulated from the start frame) or ``"mixed"``
        (replayed until the robot comes within ``radius``, then simulated).
    crowd_params : dict, optional
        For ``mixed``: ``model`` (``"social_force"`` by default or ``"orca"``) and
        ``radius`` (m, default :data:`DEFAULT_MIXED_RADIUS`). For every reactive crowd:
        the :class:`~conformal_control.world.crowds.crowd.Crowd` parameters (``body_radius``,
        ``waypoint_interval``, ``velocity_window``, ``max_speed_factor``,
        ``min_max_speed``, ``arrival_radius``, ``max_delay``, ``seed``) and the model's
        own parameters (e.g. ``A``, ``tau`` or ``time_horizon``), in SI units.
    **env_kwargs
        The environment's arguments: ``dynamics``, ``tau_frames``, ``substeps``,
        ``sensing_radius``, ``history_frames``, ``max_frames``.

    Returns
    -------
    ReplayEnvironment
        A :class:`ReactiveEnvironment` for a reactive crowd.
    """
    params = dict(crowd_params or {})
    if crowd == "replay":
        if params:
            raise ValueError(
                f"crowd 'replay' takes no crowd_params, got {', '.join(sorted(params))}"
            )
        return ReplayEnvironment(scene, **env_kwargs)
    if crowd != "mixed" and crowd not in model_names():
        raise ValueError(
            f"unknown crowd {crowd!r}; choose one of {', '.join(registry.crowd_names())}"
        )
    if crowd == "mixed":
        model = params.pop("model", "social_force")
        radius = params.pop("radius", DEFAULT_MIXED_RADIUS)
        if model not in model_names():
            raise ValueError(
                f"unknown model {model!r} for the mixed crowd; choose one of "
                f"{', '.join(model_names())}"
            )
        if (
            radius is None
            or not (isinstance(radius, (int, float)) and not isinstance(radius, bool))
            or not (math.isfinite(radius) and radius > 0)
        ):
            raise ValueError(f"radius of the mixed crowd must be a number > 0 (m), got {radius!r}")
    else:
        for key in ("model", "radius"):
            if key in params:
                raise ValueError(
                    f"{key!r} is a parameter of crowd='mixed'; crowd {crowd!r} is itself the "
                    "model and simulates every pedestrian"
                )
        model, radius = crowd, None
    own = set(param_names(Crowd)) - {"model", "model_params", "mixed_radius"}
    crowd_kw = {k: params.pop(k) for k in list(params) if k in own}
    known_model = set(param_names(registry.get("crowd", model)))
    unknown = sorted(set(params) - known_model)
    if unknown:
        raise ValueError(
            f"crowd {crowd!r} has no parameter(s) {', '.join(unknown)}; crowd parameters: "
            f"{', '.join(sorted(own | ({'model', 'radius'} if crowd == 'mixed' else set())))}; "
            f"{model} parameters: {', '.join(sorted(known_model))}"
        )
    c = Crowd(model, params or None, mixed_radius=radius, **crowd_kw)
    c.validate()  # fail at construction on a bad value, not mid-run
    return ReactiveEnvironment(scene, crowd=c, **env_kwargs)


def make_environment_like(
    env: ReplayEnvironment, crowd: str = "replay", crowd_params: dict[str, Any] | None = None
) -> ReplayEnvironment:
    """A new environment with ``env``'s scene, dynamics and timing and the given crowd.

    For swapping the replay environment an episode builder made, e.g.
    ``flagship.env = make_environment_like(flagship.env, crowd="orca")``.
    """
    return make_environment(
        env.scene,
        crowd=crowd,
        crowd_params=crowd_params,
        dynamics=env.dynamics,
        tau_frames=env.tau_frames,
        substeps=env.substeps,
        sensing_radius=env.sensing_radius,
        history_frames=env.history_frames,
        max_frames=env.max_frames,
    )
