"""Online conformal prediction sets for a real time series, through the generic loop.

The series: every (frame, pedestrian) of an ETH/UCY scene, in time order, whose next
position (0.4 s later) is known. At each step a registered predictor (default:
``constant_velocity``) forecasts the next position from the pedestrian's past positions;
the decision is a disc around that forecast; once the truth is revealed the loss is the
miscoverage 1 - covered (:class:`~conformal_control.core.losses.MiscoverageLoss`) and the
score (the displacement error, m) joins the calibration window.

Two parametrisations of the disc radius by lambda (both: larger lambda = smaller disc,
less conservative, the toolkit's convention):

``"level"``  (ACI / DtACI) lambda = nominal miscoverage level alpha_t; radius = the
             conformal quantile of the last ``window`` scores at level 1 - lambda
             (the whole plane for lambda <= 0 or too few scores, empty for lambda >= 1).
``"radius"`` (PID's quantile tracking) lambda = - radius (m): radius = max(-lambda, 0),
             empty for lambda > 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...core import registry
from ...core.base import DecisionFamily, SingleStepEnvironment, UpdateRule, first_test_instance
from ...core.loop import ConformalLoop, LoopResult
from ...core.losses import PARAMETRISATIONS, BallRecord, MiscoverageLoss, conformal_radius
from ...predictors.base import PredictionQuery, Predictor

__all__ = ["ConformalDisc", "PedestrianSeries", "load_series", "run_intervals"]


@dataclass
class _Step:
    frame: int
    ped: int
    history: np.ndarray  # (H, 2), NaN-padded at the front
    target: np.ndarray  # (2,)


def load_series(
    scene: str = "zara1",
    split: str = "test",
    data_root: str | Path | None = None,
    history: int = 8,
    max_steps: int | None = None,
) -> list[_Step]:
    """The (frame, pedestrian) steps of an ETH/UCY file, in time order.

    Parameters
    ----------
    scene : str
        eth, hotel, univ, zara1, zara2 (the leave-one-out folder; ``split="test"`` is that
        scene's own recording).
    split : str
        train / val / test.
    data_root : path, optional
        Data folder (default: ``$CONFORMAL_CONTROL_DATA`` / the shared data).
    history : int
        Past samples handed to the predictor (the current one included).
    max_steps : int, optional
        Keep the first steps only.
    """
    from ...data import ethucy_root

    folder = ethucy_root(data_root) / scene / split
    files = sorted(folder.glob("*.txt"))
    if not files:
        raise FileNotFoundError(f"no ETH/UCY files in {folder}")
    rows = np.loadtxt(files[0], ndmin=2)
    frames = np.unique(rows[:, 0])
    step = float(np.min(np.diff(frames))) if frames.size > 1 else 10.0
    tracks: dict[int, dict[float, np.ndarray]] = {}
    for f, pid, x, y in rows:
        tracks.setdefault(int(pid), {})[float(f)] = np.array([x, y])
    steps: list[_Step] = []
    for pid, tr in tracks.items():
        for f in sorted(tr):
            nxt = f + step
            if nxt not in tr:
                continue
            past = [tr.get(f - i * step) for i in range(history - 1, -1, -1)]
            hist = np.array([p if p is not None else [np.nan, np.nan] for p in past])
            # keep only the trailing run of consecutive samples
            valid = np.isfinite(hist).all(axis=1)
            if not valid[-1]:
                continue
            last_bad = np.where(~valid)[0]
            if last_bad.size:
                hist[: last_bad[-1] + 1] = np.nan
            steps.append(_Step(int(f), pid, hist, tr[nxt]))
    steps.sort(key=lambda s: (s.frame, s.ped))
    return steps[:max_steps] if max_steps is not None else steps


class PedestrianSeries(SingleStepEnvironment[dict[str, Any], float, np.ndarray]):
    """Replays the steps: sense = the pedestrian's history, reveal = its next position.

    ``sense`` also hands over the previous step's revealed position (what a sensor sees),
    so the decision family can score its previous forecast.

    Parameters
    ----------
    steps : list
        The (frame, pedestrian) steps in time order (see :func:`load_series`).
    dt : float
        Sample spacing (s).
    """

    def __init__(self, steps: list[_Step], dt: float = 0.4) -> None:
        self.steps = steps
        self.dt = dt

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        # two pedestrians on wobbly straight lines, 12 steps each, 3 samples of history
        def at(ped: int, j: int) -> np.ndarray:
            return np.array([0.5 * j * ped + 0.1 * np.sin(j + ped), 0.3 * j - 0.1 * np.cos(j)])

        steps = [
            _Step(f, ped, np.array([at(ped, f - 2), at(ped, f - 1), at(ped, f)]), at(ped, f + 1))
            for f in range(12)
            for ped in (1, 2)
        ]
        return [{"steps": steps}]

    @classmethod
    def _unit_test_family(cls) -> ConformalDisc:
        return first_test_instance(ConformalDisc)

    def reset(self) -> None:
        if not self.steps:
            raise ValueError("PedestrianSeries needs at least one step")
        self.i = 0
        self._applied = False

    @property
    def done(self) -> bool:
        return self.i >= len(self.steps)

    def observe(self) -> dict[str, Any]:
        s = self.steps[self.i]
        query = PredictionQuery(
            ids=np.array([s.ped]),
            history=s.history[None].copy(),
            dt=self.dt,
            horizon=1,
            t=s.frame * self.dt / 10.0,
            frame=s.frame,
            scene="ethucy",
            ground_truth=s.target[None, None].copy(),
        )
        previous = self.steps[self.i - 1].target.copy() if self.i > 0 else None
        return {"query": query, "previous_truth": previous}

    def apply(self, decision: Any) -> None:
        if self.done:
            raise RuntimeError("apply() called on a finished series")
        self.i += 1

    def reveal(self) -> np.ndarray:
        target: np.ndarray = self.steps[self.i - 1].target.copy()
        return target


class ConformalDisc(DecisionFamily[dict[str, Any], dict[str, Any], float, BallRecord]):
    """D^lambda = disc around the forecast; radius from lambda and past scores.

    Parameters
    ----------
    predictor : Predictor
        Forecasts the next position from the pedestrian's history.
    window : int
        Number of most recent scores used (the calibration window).
    parametrisation : str
        ``"level"`` or ``"radius"`` (see the module docstring).
    """

    def __init__(
        self, predictor: Predictor, window: int = 200, parametrisation: str = "level"
    ) -> None:
        self.predictor = predictor
        self.window = window
        self.parametrisation = parametrisation

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        from ...predictors.constant_velocity import ConstantVelocityPredictor

        return [
            {"predictor": ConstantVelocityPredictor(), "window": 5},
            {"predictor": ConstantVelocityPredictor(), "parametrisation": "radius"},
        ]

    @classmethod
    def _unit_test_environment(cls) -> PedestrianSeries:
        return first_test_instance(PedestrianSeries)

    def reset(self) -> None:
        if self.parametrisation not in PARAMETRISATIONS:
            raise ValueError(
                f"parametrisation must be one of {PARAMETRISATIONS}, got {self.parametrisation!r}"
            )
        if int(self.window) != self.window or self.window < 1:
            raise ValueError(f"window must be an integer >= 1, got {self.window!r}")
        self.scores_: list[float] = []
        self._center: np.ndarray | None = None
        self._sorted = np.empty(0)
        self.radii_: list[float] = []
        self.n_nonfinite_forecasts_ = 0
        self.predictor.reset()

    def begin_interval(self, observation: dict[str, Any]) -> None:
        prediction = self.predictor.predict(observation["query"])
        prev = observation.get("previous_truth")
        if prev is not None and self._center is not None:
            self.scores_.append(float(np.linalg.norm(prev - self._center)))
        center = np.asarray(prediction.positions, dtype=float)[0, 0]
        if not np.isfinite(center).all():  # counted fallback: stand still
            self.n_nonfinite_forecasts_ += 1
            center = observation["query"].current[0]
        self._center = center
        recent = self.scores_[-int(self.window) :]
        self._sorted = np.sort(np.asarray(recent, dtype=float))

    def decide(self, state: dict[str, Any], lam: float) -> float:
        r = conformal_radius(self._sorted, lam, self.parametrisation)
        self.radii_.append(r)
        return r

    def interval_record(self) -> BallRecord:
        assert self._center is not None
        return BallRecord(self._center.copy(), self._sorted, self.parametrisation)


def run_intervals(
    rule: UpdateRule,
    steps: list[_Step],
    *,
    predictor: str | Predictor = "constant_velocity",
    predictor_params: dict[str, Any] | None = None,
    window: int = 200,
    parametrisation: str = "level",
) -> tuple[LoopResult, dict[str, Any]]:
    """Run the online prediction discs on ``steps``; return the result and its figures.

    Figures: ``coverage`` (long-run fraction covered), ``miscoverage``, ``radius_median``
    and ``radius_mean`` over finite radii (m), ``share_infinite`` (whole-plane sets),
    ``share_empty``, and the monitor's guarantee figures.

    Parameters
    ----------
    rule : UpdateRule
        The update rule of the discs' lambda.
    steps : list
        The (frame, pedestrian) steps, from :func:`load_series`.
    predictor : Predictor or str
        Forecasts the next position (an instance or a registered name).
    predictor_params : dict, optional
        Its parameters, for a registered name.
    window : int
        Number of most recent scores used (the calibration window).
    parametrisation : {"level", "radius"}
        See the module docstring.
    """
    pred: Predictor = (
        registry.create("predictor", predictor, **(predictor_params or {}))
        if isinstance(predictor, str)
        else predictor
    )
    family = ConformalDisc(pred, window=window, parametrisation=parametrisation)
    loop = ConformalLoop(PedestrianSeries(steps), family, MiscoverageLoss(), rule)
    result = loop.run()
    radii = np.asarray(family.radii_, dtype=float)
    finite = radii[np.isfinite(radii)]
    figures = {
        "n_steps": int(radii.size),
        "coverage": 1.0 - result.l_avg,
        "miscoverage": result.l_avg,
        "radius_median": float(np.median(finite)) if finite.size else None,
        "radius_mean": float(np.mean(finite)) if finite.size else None,
        "share_infinite": float(np.mean(radii == np.inf)),
        "share_empty": float(np.mean(radii == -np.inf)),
        **result.guarantee,
    }
    return result, figures
