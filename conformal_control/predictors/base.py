"""The predictor role: a black-box trajectory predictor and what it exchanges.

A :class:`Predictor` receives a :class:`PredictionQuery` (the histories of the sensed
agents at a sampling time, batched) and returns a :class:`Forecast` (their predicted
positions over the horizon). Every length is in metres and every time in seconds.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.base import Plugin

__all__ = ["Forecast", "PredictionQuery", "Predictor", "TruthUnavailableError"]


class TruthUnavailableError(RuntimeError):
    """The environment cannot tell the future (e.g. a crowd that reacts to the robot)."""


@dataclass
class PredictionQuery:
    """What the sensor hands the predictor at a sampling time (batched over agents).

    Attributes
    ----------
    ids : ndarray of shape (N,)
        Identifiers of the sensed agents.
    history : ndarray of shape (N, T, 2)
        Past positions in metres, one row per sample at spacing ``dt``; the last sample
        (``history[:, -1]``) is the position at the sampling time and is always finite.
        Samples where an agent was not observed are NaN (short histories are NaN-padded
        at the front; gaps are NaN in the middle).
    dt : float
        Sample spacing in seconds (1 / the scene's frame rate).
    horizon : int
        Number of future samples requested (positions at ``dt, 2 dt, ..., horizon dt``).
    t : float
        Time of the sampling instant in seconds since the episode started.
    frame : int
        Video frame number of the sampling instant (a cache key for expensive predictors).
    scene : str
        Name of the scene (cache key).
    ground_truth : ndarray of shape (N, horizon, 2) or None
        The true future, when the caller already has it (tests, replayed series).
    truth_provider : callable or None
        ``truth_provider(horizon) -> (N, horizon, 2)``: computes the true future over
        ``horizon`` samples on demand (NaN where an agent is not in the data). An
        environment that replays recorded data attaches one to every query; only the
        oracle baseline calls it (:meth:`future`). It takes the horizon because a
        decision family may ask further ahead than the environment's interval (a plan's
        horizon: ``dataclasses.replace(query, horizon=...)`` keeps the provider).
    robot : ndarray of shape (N,) or None
        The agent type the sensor reports: True for an agent it identifies as a robot (in a
        multi-robot world), False for a pedestrian; None when the sensor does not tell
        (every agent is then treated alike). Predictors may ignore it; a controller that
        handles robots apart (reciprocal constraints) reads it.
    """

    ids: np.ndarray
    history: np.ndarray
    dt: float
    horizon: int
    t: float = 0.0
    frame: int = 0
    scene: str = ""
    ground_truth: np.ndarray | None = None
    truth_provider: Callable[[int], np.ndarray] | None = field(
        default=None, repr=False, compare=False
    )
    robot: np.ndarray | None = None

    @property
    def n_agents(self) -> int:
        return int(self.history.shape[0])

    @property
    def is_robot(self) -> np.ndarray:
        """The agent types as a boolean array of shape (N,) (all False when not told)."""
        if self.robot is None:
            return np.zeros(self.n_agents, dtype=bool)
        out = np.asarray(self.robot, dtype=bool)
        if out.shape != (self.n_agents,):
            raise ValueError(
                f"robot must have one entry per sensed agent ({self.n_agents}), got shape "
                f"{out.shape}"
            )
        return out

    def select(self, keep: np.ndarray) -> PredictionQuery:
        """The query restricted to some agents (a boolean mask or indices), in order.

        The true future is restricted alike (the provider is called for every agent and
        its rows selected).
        """
        idx = np.flatnonzero(keep) if np.asarray(keep).dtype == bool else np.asarray(keep)
        truth = None if self.ground_truth is None else np.asarray(self.ground_truth)[idx]
        provider = self.truth_provider
        sub_provider = None
        if truth is None and provider is not None:

            def sub_provider(horizon: int) -> np.ndarray:
                out: np.ndarray = np.asarray(provider(horizon))[idx]
                return out

        return PredictionQuery(
            ids=np.asarray(self.ids)[idx],
            history=self.history[idx],
            dt=self.dt,
            horizon=self.horizon,
            t=self.t,
            frame=self.frame,
            scene=self.scene,
            ground_truth=truth,
            truth_provider=sub_provider,
            robot=None if self.robot is None else np.asarray(self.robot)[idx],
        )

    @property
    def current(self) -> np.ndarray:
        """Positions at the sampling time, shape (N, 2)."""
        return self.history[:, -1, :]

    def future(self, horizon: int | None = None) -> np.ndarray:
        """The true future positions, shape (N, horizon, 2) (NaN where unobserved).

        Parameters
        ----------
        horizon : int, optional
            Samples wanted (default: the query's ``horizon``). A ``ground_truth`` shorter
            than that is NaN-padded (the future beyond it is unknown).

        Raises
        ------
        TruthUnavailableError
            If the query carries neither ``ground_truth`` nor a ``truth_provider``.
        ValueError
            If ``horizon`` is negative, or the provider returns another shape.
        """
        h = int(self.horizon if horizon is None else horizon)
        if h < 0:
            raise ValueError(f"the horizon of the true future must be >= 0, got {horizon!r}")
        if self.ground_truth is not None:
            gt = np.asarray(self.ground_truth, dtype=float)
            if gt.ndim != 3 or gt.shape[0] != self.n_agents or gt.shape[2] != 2:
                raise ValueError(
                    f"ground_truth has shape {gt.shape}; expected ({self.n_agents}, horizon, 2)"
                )
            if gt.shape[1] >= h:
                return gt[:, :h]
            pad = np.full((gt.shape[0], h - gt.shape[1], 2), np.nan)
            return np.concatenate([gt, pad], axis=1)
        if self.truth_provider is None:
            raise TruthUnavailableError(
                "this environment cannot reveal the future of the sensed agents "
                "(the oracle predictor needs replayed data)"
            )
        out = np.asarray(self.truth_provider(h), dtype=float)
        if out.shape != (self.n_agents, h, 2):
            raise ValueError(
                f"truth_provider({h}) returned shape {out.shape}; expected "
                f"({self.n_agents}, {h}, 2)"
            )
        return out


@dataclass
class Forecast:
    """Output of a predictor.

    Attributes
    ----------
    positions : ndarray of shape (N, H, 2)
        Predicted positions in metres at ``dt, ..., H dt`` after the sampling time.
    covariance : ndarray of shape (N, H, 2, 2) or None
        Optional predictive covariance (m^2), for predictors that have one.
    info : dict
        Counters (e.g. ``{"n_fallback": 2}``, summed over a run) and messages (lists of
        strings, e.g. ``{"fit_errors": [...]}``, concatenated) reported in run metrics.
    """

    positions: np.ndarray
    covariance: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)


class Predictor(Plugin, ABC):
    """Black-box trajectory predictor, batched over the sensed agents.

    Subclasses implement :meth:`predict`. A predictor must not modify the query, must
    return finite positions for every agent whose last history sample is finite (or NaN,
    which the controller replaces by a documented, counted fallback), and must be
    deterministic for a given ``random_state`` if it has one.
    """

    def reset(self) -> None:
        """Forget any state accumulated during an episode (optional)."""

    @abstractmethod
    def predict(self, query: PredictionQuery) -> Forecast:
        """Predict ``query.horizon`` future positions for each of the ``query.n_agents``."""
