"""Per-agent linear Kalman filter (filterpy) with a constant-velocity or -acceleration model.

Each agent's history is filtered from its first finite sample (missing samples are
predict-only steps); the filter is then run ``horizon`` steps ahead without updates, and
the position block of the state covariance is returned as ``Forecast.covariance``.
An agent whose current position is not finite (invalid input) gets a NaN forecast,
counted in ``Forecast.info["n_nonfinite_current"]``; one observed once stands still
(``n_short_history``).

Process noise is continuous white noise on the highest derivative (acceleration for
``"cv"``, jerk for ``"ca"``) with spectral density ``process_noise`` (m^2/s^3 or
m^2/s^5), discretised at the query's spacing, so one setting serves every frame rate;
``measurement_noise`` is the standard deviation of a position observation in metres.
The defaults were fitted on ETH/UCY by maximising the one-step-ahead predictive
likelihood (``benchmarks/fit_kalman_noise.py``; figures in ``docs/predictors.md``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter

from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

__all__ = ["FITTED_DEFAULTS", "KalmanPredictor", "build_filter"]

#: Maximum-likelihood noise on 500 seeded windows of ETH/UCY ``eth/train`` (hotel, univ, zara)
#: (see ``benchmarks/fit_kalman_noise.py``): model -> (process_noise, measurement_noise).
FITTED_DEFAULTS: dict[str, tuple[float, float]] = {"cv": (0.02, 0.003), "ca": (0.1, 0.01)}


def build_filter(
    model: str, dt: float, process_noise: float, measurement_noise: float, velocity_std: float
) -> KalmanFilter:
    """A filterpy ``KalmanFilter`` for one planar agent (state per axis: pos, vel[, acc])."""
    order = {"cv": 2, "ca": 3}[model]
    f1 = np.eye(order)
    f1[0, 1] = dt
    if order == 3:
        f1[0, 2] = 0.5 * dt * dt
        f1[1, 2] = dt
    q1 = Q_continuous_white_noise(dim=order, dt=dt, spectral_density=process_noise)
    kf = KalmanFilter(dim_x=2 * order, dim_z=2)
    kf.F = np.kron(np.eye(2), f1)  # state [x, vx(, ax), y, vy(, ay)]
    kf.Q = np.kron(np.eye(2), q1)
    kf.H = np.zeros((2, 2 * order))
    kf.H[0, 0] = kf.H[1, order] = 1.0
    kf.R = np.eye(2) * measurement_noise**2
    p1 = np.diag([measurement_noise**2, velocity_std**2, 1.0][:order])
    kf.P = np.kron(np.eye(2), p1)
    return kf


class KalmanPredictor(Predictor):
    """Kalman filter per agent (filterpy), constant velocity or acceleration; covariance too.

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
        Prior standard deviation of the initial velocity (m/s).
    """

    def __init__(
        self,
        model: str = "cv",
        process_noise: float | None = None,
        measurement_noise: float | None = None,
        velocity_std: float = 2.0,
    ) -> None:
        self.model = model
        self.process_noise = process_noise
        self.measurement_noise = measurement_noise
        self.velocity_std = velocity_std

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"model": "ca", "process_noise": 1.0, "measurement_noise": 0.1}]

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
        return q, r

    def filter(self, query: PredictionQuery) -> tuple[list[KalmanFilter | None], float]:
        """Filtered state of every agent at the sampling time and the summed log-likelihood
        of its observations (used to fit the noise)."""
        q, r = self.noise()
        hist = np.asarray(query.history, dtype=float)
        filters: list[KalmanFilter | None] = []
        loglik = 0.0
        for i in range(hist.shape[0]):
            ok = np.isfinite(hist[i]).all(axis=1)
            if not ok.any():
                filters.append(None)
                continue
            first = int(np.argmax(ok))
            kf = build_filter(self.model, query.dt, q, r, self.velocity_std)
            order = kf.dim_x // 2
            kf.x = np.zeros(kf.dim_x)
            kf.x[0], kf.x[order] = hist[i, first]
            for k in range(first + 1, hist.shape[1]):
                kf.predict()
                if ok[k]:
                    kf.update(hist[i, k])
                    loglik += float(kf.log_likelihood)
            filters.append(kf)
        return filters, loglik

    def predict(self, query: PredictionQuery) -> Forecast:
        hist = np.asarray(query.history, dtype=float)
        n, h = hist.shape[0], int(query.horizon)
        pos = np.full((n, h, 2), np.nan)
        cov = np.full((n, h, 2, 2), np.nan)
        filters, _ = self.filter(query)
        n_short = 0
        bad_current = ~np.isfinite(hist[:, -1]).all(axis=1) if n else np.zeros(0, bool)
        for i, kf in enumerate(filters):
            if kf is None or bad_current[i]:
                continue  # no forecast (NaN) for an agent without a current position
            n_short += int(np.isfinite(hist[i]).all(axis=1).sum() < 2)
            order = kf.dim_x // 2
            idx = [0, order]
            x, p = kf.x.copy(), kf.P.copy()
            for k in range(h):
                x = kf.F @ x
                p = kf.F @ p @ kf.F.T + kf.Q
                pos[i, k] = x[idx]
                cov[i, k] = p[np.ix_(idx, idx)]
        info = {"n_short_history": n_short, "n_nonfinite_current": int(bad_current.sum())}
        return Forecast(pos, covariance=cov, info=info)
