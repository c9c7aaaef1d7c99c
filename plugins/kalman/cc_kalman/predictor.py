"""Linear Kalman filter per agent with a constant-velocity or -acceleration model.

Each agent's history is filtered from its first finite sample (missing samples are
predict-only steps); the filter is then run ``horizon`` steps ahead without updates, and
the position block of the state covariance is returned as ``Forecast.covariance``.
An agent whose current position is not finite (invalid input) gets a NaN forecast,
counted in ``Forecast.info["n_nonfinite_current"]``; one observed once stands still
(``n_short_history``).

Process noise is continuous white noise on the highest derivative (acceleration for
``"cv"``, jerk for ``"ca"``) with spectral density ``process_noise`` (m^2/s^3 or
m^2/s^5), discretised at the query's spacing by filterpy
(``Q_continuous_white_noise``), so one setting serves every frame rate;
``measurement_noise`` is the standard deviation of a position observation in metres.
The defaults are fitted for forecast accuracy on ETH/UCY training windows
(``benchmarks/fit_kalman_noise.py``; figures in ``docs/predictors.md``): the ratio of the
two noises, which alone shapes the mean forecast, minimises the worst training scene's
8 -> 12 ADE relative to constant velocity; their scale then maximises the one-step-ahead
likelihood (calibrating the covariance). The noise that maximises the likelihood alone
follows the last displacement almost exactly and forecasts worse than constant velocity
on slow, sparse scenes (ETH/UCY hotel: ADE 0.36 m against 0.24 m).

Why the filter loop is ours: filterpy's ``KalmanFilter`` filters one track at a time (a
Python call per agent per sample, ~50 us each), and has no batched form. The x and y
axes of these models are independent with the same covariance, so the same equations
(filterpy's predict and Joseph-form update) run here for every agent at once with numpy;
``build_filter`` still builds the equivalent filterpy filter, which the tests use as the
reference.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter

from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

__all__ = ["FITTED_DEFAULTS", "KalmanPredictor", "axis_model", "build_filter"]

#: Fitted on ETH/UCY ``eth/train`` (hotel, zara, students/uni files) with the default
#: anchor (``benchmarks/fit_kalman_noise.py``): the ratio q / r^2 minimising the worst
#: file's 8 -> 12 ADE relative to constant velocity, then the scale maximising the
#: one-step likelihood. model -> (process_noise, measurement_noise).
FITTED_DEFAULTS: dict[str, tuple[float, float]] = {"cv": (0.00375, 0.05), "ca": (0.0027, 0.03)}

_ORDER = {"cv": 2, "ca": 3}


def axis_model(model: str, dt: float, process_noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition matrix and discretised process noise of one axis (pos, vel[, acc])."""
    order = _ORDER[model]
    f1 = np.eye(order)
    f1[0, 1] = dt
    if order == 3:
        f1[0, 2] = 0.5 * dt * dt
        f1[1, 2] = dt
    q1 = Q_continuous_white_noise(dim=order, dt=dt, spectral_density=process_noise)
    return f1, np.asarray(q1, dtype=float)


def _prior(model: str, measurement_noise: float, velocity_std: float) -> np.ndarray:
    return np.diag([measurement_noise**2, velocity_std**2, 1.0][: _ORDER[model]])


def build_filter(
    model: str, dt: float, process_noise: float, measurement_noise: float, velocity_std: float
) -> KalmanFilter:
    """A filterpy ``KalmanFilter`` for one planar agent (state per axis: pos, vel[, acc])."""
    order = _ORDER[model]
    f1, q1 = axis_model(model, dt, process_noise)
    kf = KalmanFilter(dim_x=2 * order, dim_z=2)
    kf.F = np.kron(np.eye(2), f1)  # state [x, vx(, ax), y, vy(, ay)]
    kf.Q = np.kron(np.eye(2), q1)
    kf.H = np.zeros((2, 2 * order))
    kf.H[0, 0] = kf.H[1, order] = 1.0
    kf.R = np.eye(2) * measurement_noise**2
    kf.P = np.kron(np.eye(2), _prior(model, measurement_noise, velocity_std))
    return kf


class KalmanPredictor(Predictor):
    """Kalman filter per agent, constant velocity or acceleration; covariance too.

    Parameters
    ----------
    model : {"cv", "ca"}
        Constant velocity (white-noise acceleration) or constant acceleration
        (white-noise jerk).
    process_noise : float or None
        Spectral density of the process noise; None uses the fitted default of ``model``.
    measurement_noise : float or None
        Position measurement standard deviation (m); None uses the fitted default.
    velocity_std : float
        Prior standard deviation of the initial velocity (m/s; the prior mean is 0).
    anchor : {"observation", "filter"}
        Where the forecast starts: the last observed position, moving at the filtered
        velocity (and acceleration), or the filtered position (the textbook forecast).
        Recorded positions are accurate to centimetres; what the filter is for is a
        smoothed velocity, and its position estimate lags behind a walker by the
        smoothing. ``"observation"`` forecasts better on every ETH/UCY training scene
        (``docs/predictors.md``); the covariance is the filter's either way.
    """

    def __init__(
        self,
        model: str = "cv",
        process_noise: float | None = None,
        measurement_noise: float | None = None,
        velocity_std: float = 2.0,
        anchor: str = "observation",
    ) -> None:
        self.model = model
        self.process_noise = process_noise
        self.measurement_noise = measurement_noise
        self.velocity_std = velocity_std
        self.anchor = anchor

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [
            {},
            {"model": "ca", "process_noise": 1.0, "measurement_noise": 0.1, "anchor": "filter"},
        ]

    def noise(self) -> tuple[float, float]:
        """(process_noise, measurement_noise) in use, after validation."""
        if self.model not in FITTED_DEFAULTS:
            raise ValueError(f"model must be 'cv' or 'ca', got {self.model!r}")
        q0, r0 = FITTED_DEFAULTS[self.model]
        q = q0 if self.process_noise is None else float(self.process_noise)
        r = r0 if self.measurement_noise is None else float(self.measurement_noise)
        for name, v in (("process_noise", q), ("measurement_noise", r)):
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if not np.isfinite(self.velocity_std) or self.velocity_std <= 0:
            raise ValueError(f"velocity_std must be > 0, got {self.velocity_std!r}")
        if self.anchor not in ("observation", "filter"):
            raise ValueError(f"anchor must be 'observation' or 'filter', got {self.anchor!r}")
        return q, r

    def filter(self, query: PredictionQuery) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Filter every agent's history.

        Returns
        -------
        x : ndarray of shape (N, 2, order)
            Filtered state per axis (position, velocity[, acceleration]) at the sampling
            time; NaN for an agent never observed.
        p : ndarray of shape (N, order, order)
            Its covariance (the same for both axes).
        loglik : ndarray of shape (N,)
            Summed one-step-ahead predictive log-likelihood of each agent's observations
            after its first (used to fit the noise).
        """
        q, r = self.noise()
        f1, q1 = axis_model(self.model, query.dt, q)
        order = f1.shape[0]
        r2 = r * r
        hist = np.asarray(query.history, dtype=float)
        n, t = hist.shape[:2]
        ok = np.isfinite(hist).all(axis=-1)
        x = np.zeros((n, 2, order))
        p = np.zeros((n, order, order))
        loglik = np.zeros(n)
        started = np.zeros(n, dtype=bool)
        p0 = _prior(self.model, r, float(self.velocity_std))
        eye = np.eye(order)
        for k in range(t):
            s = np.flatnonzero(started)
            if s.size:  # predict: x = F x, P = F P F' + Q
                x[s] = x[s] @ f1.T
                p[s] = f1 @ p[s] @ f1.T + q1
            new = ok[:, k] & ~started
            if new.any():
                x[new] = 0.0
                x[new, :, 0] = hist[new, k]
                p[new] = p0
                started |= new
            u = np.flatnonzero(ok[:, k] & ~new & started)
            if u.size:  # update with the position of both axes (Joseph form)
                pu = p[u]
                var = pu[:, 0, 0] + r2  # innovation variance, per axis
                gain = pu[:, :, 0] / var[:, None]  # (U, order)
                resid = hist[u, k] - x[u, :, 0]  # (U, 2)
                x[u] += resid[:, :, None] * gain[:, None, :]
                ikh = eye - gain[:, :, None] * eye[0][None, None, :]
                p[u] = (
                    ikh @ pu @ np.swapaxes(ikh, -1, -2) + r2 * gain[:, :, None] * gain[:, None, :]
                )
                loglik[u] += -np.log(2 * np.pi * var) - 0.5 * (resid**2).sum(axis=1) / var
        x[~started] = np.nan
        return x, p, loglik

    def predict(self, query: PredictionQuery) -> Forecast:
        hist = np.asarray(query.history, dtype=float)
        n, h = hist.shape[0], int(query.horizon)
        pos = np.full((n, h, 2), np.nan)
        cov = np.full((n, h, 2, 2), np.nan)
        x, p, _ = self.filter(query)
        bad_current = ~np.isfinite(hist[:, -1]).all(axis=1) if n else np.zeros(0, bool)
        good = ~bad_current & np.isfinite(x).all(axis=(1, 2))
        n_short = int((good & (np.isfinite(hist).all(axis=-1).sum(axis=1) < 2)).sum())
        if good.any():
            f1, q1 = axis_model(self.model, query.dt, self.noise()[0])
            xg, pg = x[good], p[good]
            if self.anchor == "observation":
                xg[:, :, 0] = hist[good, -1]
            for k in range(h):
                xg = xg @ f1.T
                pg = f1 @ pg @ f1.T + q1
                pos[good, k] = xg[:, :, 0]
                cov[good, k] = pg[:, 0, 0][:, None, None] * np.eye(2)
        info = {"n_short_history": n_short, "n_nonfinite_current": int(bad_current.sum())}
        return Forecast(pos, covariance=cov, info=info)
