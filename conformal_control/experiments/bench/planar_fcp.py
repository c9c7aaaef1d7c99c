"""FCP-MPC's offline calibration on an ETH/UCY recording, for the planar protocol.

The published FCP-MPC runs (``planar/sims/sim_func_cp.py``, read, not used) calibrate their
envelopes before a scenario from the dataset's prediction file: for every time step of the
file (every time step at which a pedestrian has a history), the positions predicted 1..12
steps ahead are paired with the positions then observed, for the pedestrians predicted and
observed; the residual distance fields of those pairs on a 128 x 128 grid calibrate the
envelopes (:func:`~conformal_control.families.mpc.fieldcp.fit_envelope`, alpha = 0.1, 5 principal
components, 7 mixture components, 30 % held out). The grid covers the scenario: the robot's
start and goal, and the pedestrians' current and predicted positions over the scenario's
first ``min(max_steps, 200)`` time steps, with 2 m of margin.

Two calibration sets (:data:`~conformal_control.experiments.bench.planar.CALIBRATIONS`):

* ``recording``: every time step of the recording, the published runs' (which includes the
  scenario's own time steps: the envelopes have seen the test window's prediction errors);
* ``held_out``: every time step whose predictions do not reach into the scenario's window
  (from its start to its last step, plus the plan's horizon before it): ours.

The published runs cache one calibration per dataset (their cache file's name has no
scenario), so the second and third scenarios of a dataset reuse the first scenario's grid
geometry under their own centre and side; in ``fcp-planar`` each scenario is calibrated on
its own grid. In ``fcp-planar-dense`` a task carries its part of the recording
(:attr:`~conformal_control.experiments.bench.planar.PlanarTask.part`): one grid covers the part, one
calibration serves all its scenarios, and ``held_out`` calibrates on the *other* part
(test scenarios on the dev part and back, each without the plan's horizon at the boundary).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...families.mpc.fcp import FieldCalibration
from ...families.mpc.fieldcp import FieldGrid, FunctionalEnvelope, fit_envelope
from ...predictors.base import PredictionQuery, Predictor

__all__ = ["PlanarPredictions", "calibrate", "predictions_on", "scenario_samples"]


@dataclass(frozen=True)
class PlanarPredictions:
    """A predictor's forecasts at every time step of a recording.

    Attributes
    ----------
    samples : int ndarray of shape (T,)
        The recording's samples (time steps) with a pedestrian that has a history.
    columns : list of int ndarrays
        Per sample, the recording's columns of those pedestrians.
    forecasts : list of ndarrays of shape (M, H, 2)
        Per sample, their predicted positions 1..H samples ahead (m).
    """

    samples: np.ndarray
    columns: list[np.ndarray]
    forecasts: list[np.ndarray]

    def at(self, sample: int) -> tuple[np.ndarray, np.ndarray] | None:
        """``(columns, forecast)`` at a sample (None without a pedestrian)."""
        k = int(np.searchsorted(self.samples, sample))
        if k < self.samples.size and self.samples[k] == sample:
            return self.columns[k], self.forecasts[k]
        return None


def predictions_on(
    recording: Any,
    predictor: Predictor,
    horizon: int,
    dt: float,
    frame_of: Callable[[int], int],
    scene: str,
) -> PlanarPredictions:
    """Ask ``predictor`` at every sample of ``recording`` with a pedestrian with a history.

    Parameters
    ----------
    recording : PlanarRecording
        The recording (``positions``, ``ids``, ``pedestrians``, ``history``).
    predictor : Predictor
        The run's predictor (reset here).
    horizon : int
        Samples ahead.
    dt : float
        Seconds per sample.
    frame_of : callable
        The query's ``frame`` of a sample.
    scene : str
        The query's ``scene``.
    """
    predictor.reset()
    samples, columns, forecasts = [], [], []
    for i in range(1, recording.positions.shape[0]):
        cols = recording.pedestrians(i)
        if cols.size == 0:
            continue
        query = PredictionQuery(
            ids=recording.ids[cols],
            history=recording.history(i, cols),
            dt=dt,
            horizon=horizon,
            t=0.0,
            frame=frame_of(i),
            scene=scene,
        )
        samples.append(i)
        columns.append(cols)
        forecasts.append(np.asarray(predictor.predict(query).positions, dtype=float)[:, :horizon])
    return PlanarPredictions(np.array(samples, dtype=np.int64), columns, forecasts)


def scenario_samples(recording: Any, first: int, max_steps: int) -> tuple[int, int]:
    """The scenario's first and last sample: from ``first``, ``max_steps`` samples with a
    pedestrian that has a history (the protocol's steps), or the recording's end."""
    i, count = int(first), 0
    last = recording.positions.shape[0] - 1
    while i <= last and count < max_steps:
        if recording.pedestrians(i).size:
            count += 1
        i += 1
    return int(first), min(i - 1, last)


def calibrate(
    recording: Any,
    predictions: PlanarPredictions,
    span: tuple[int, int],
    corners: Sequence[Sequence[float]],
    exclude: tuple[int, int] | None,
    settings: FieldCalibration,
) -> FunctionalEnvelope:
    """Envelopes on the grid covering ``span`` (see the module docstring).

    Parameters
    ----------
    recording : PlanarRecording
        The scenario's recording.
    predictions : PlanarPredictions
        The run's predictor at every sample (:func:`predictions_on`).
    span : (int, int)
        First and last sample whose pedestrians (current and predicted) the grid covers.
    corners : sequence of (x, y)
        The robot's start and goal (m), inside the grid.
    exclude : (int, int) or None
        Prediction times left out of the calibration (inclusive), None: none.
    settings : FieldCalibration
        Grid size, margin, alpha, components, share, seed and slack.
    """
    horizon = predictions.forecasts[0].shape[1] if predictions.forecasts else 12
    pts = [np.asarray(corners, dtype=float).reshape(-1, 2)]
    for i in range(span[0], span[1] + 1):
        got = predictions.at(i)
        if got is not None:
            cols, fc = got
            pts.append(recording.at(i, cols))
            pts.append(fc.reshape(-1, 2))
    grid = FieldGrid.around(
        np.concatenate(pts), margin=float(settings.grid_margin), size=int(settings.grid_size)
    )
    pairs: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(horizon)]
    rows = zip(predictions.samples, predictions.columns, predictions.forecasts, strict=True)
    for i, cols, fc in rows:
        if exclude is not None and exclude[0] <= i <= exclude[1]:
            continue
        for h in range(1, horizon + 1):
            true = recording.at(int(i) + h, cols)
            ok = np.isfinite(true).all(axis=1) & np.isfinite(fc[:, h - 1]).all(axis=1)
            if ok.any():
                pairs[h - 1].append((fc[ok, h - 1], true[ok]))
    return fit_envelope(
        pairs,
        grid,
        settings.miscoverage,
        int(settings.n_components),
        int(settings.n_mixtures),
        settings.calibration_share,
        int(settings.random_state),
        settings.slack,
    )
