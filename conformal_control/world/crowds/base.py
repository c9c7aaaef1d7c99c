"""The crowd-model role: one step of simulated pedestrians among agents they only see.

A :class:`CrowdModel` moves ``N`` simulated pedestrians by one time step. It also sees
``E`` *other* agents that it does not move: the robot (driven by the controller, not by
the model) and, in mixed mode, the pedestrians still replayed from the recording. The
model does not know where the pedestrians are going: the caller hands it each
pedestrian's preferred velocity (towards its next recorded waypoint, see
:mod:`conformal_control.world.crowds.crowd`) and speed bound. Every length is in metres and
every time in seconds.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ...core.base import Plugin

__all__ = ["CrowdModel"]


class CrowdModel(Plugin, ABC):
    """A pedestrian motion model stepped at a given time step (vectorised over agents).

    Subclasses implement :meth:`step`. Parameters are stored unchanged by ``__init__``
    and validated by :meth:`reset`; a model must be deterministic for a given ``rng``
    (models without noise ignore it).
    """

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Validate the parameters and take the random generator (if the model is noisy)."""
        self._validate()
        self.rng_ = rng if rng is not None else np.random.default_rng(0)

    def _validate(self) -> None:
        """Raise ValueError with a one-sentence message for a bad parameter."""

    @staticmethod
    def _check_positive(**values: float) -> None:
        for name, v in values.items():
            if not (isinstance(v, (int, float, np.integer, np.floating)) and np.isfinite(v)):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
            if v <= 0:
                raise ValueError(f"{name} must be > 0, got {v!r}")

    @abstractmethod
    def step(
        self,
        pos: np.ndarray,
        vel: np.ndarray,
        radius: np.ndarray,
        v_pref: np.ndarray,
        v_max: np.ndarray,
        other_pos: np.ndarray,
        other_vel: np.ndarray,
        other_radius: np.ndarray,
        dt: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Advance the simulated pedestrians by ``dt`` seconds.

        Parameters
        ----------
        pos, vel : ndarray of shape (N, 2)
            Positions (m) and velocities (m/s) of the simulated pedestrians.
        radius : ndarray of shape (N,)
            Their body radii (m).
        v_pref : ndarray of shape (N, 2)
            Preferred velocities (m/s): where each would walk if alone.
        v_max : ndarray of shape (N,)
            Speed bounds (m/s).
        other_pos, other_vel : ndarray of shape (E, 2)
            Agents seen but not moved (the robot first).
        other_radius : ndarray of shape (E,)
        dt : float
            Time step (s).

        Returns
        -------
        pos, vel : ndarray of shape (N, 2)
            New positions and velocities (new arrays; the inputs are not modified).
        """
