"""A scikit-learn regressor mapping past displacements to future offsets.

Features are the ``obs - 1`` displacements of the observed window and targets the
``horizon`` offsets of the future positions from the last observed one (both flattened,
standardised with ``StandardScaler``). Any regressor of ``sklearn.utils.all_estimators``
can be named; single-output ones are wrapped in ``MultiOutputRegressor``. The fitted
pipeline is saved with joblib beside ``config.json``.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import joblib
import numpy as np
from sklearn.compose import TransformedTargetRegressor
from sklearn.multioutput import MultiOutputRegressor
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.utils import all_estimators

from conformal_control.predictors.learned import WindowPredictor, synthetic_windows

__all__ = ["UNIT_TEST_WEIGHTS", "SklearnPredictor", "make_unit_test_weights", "regressor_class"]

#: A Ridge fitted on 256 seeded synthetic walks, shipped with the package for the contract
#: kit, so that ``_unit_test_params`` never fits anything.
UNIT_TEST_WEIGHTS = Path(__file__).resolve().parent / "unit_test_weights"


@functools.cache
def _regressors() -> dict[str, type]:
    return dict(all_estimators(type_filter="regressor"))


def regressor_class(name: str) -> type:
    """The scikit-learn regressor class called ``name`` (clear error otherwise)."""
    try:
        return _regressors()[name]
    except KeyError:
        raise ValueError(
            f"unknown scikit-learn regressor {name!r} (e.g. Ridge, KNeighborsRegressor, "
            "RandomForestRegressor, MLPRegressor)"
        ) from None


class SklearnPredictor(WindowPredictor):
    """Any scikit-learn regressor on past displacements (default Ridge).

    Parameters
    ----------
    estimator : str
        Regressor class name in scikit-learn (``Ridge``, ``KNeighborsRegressor``, ...).
    estimator_params : dict or None
        Its constructor arguments (``random_state`` is filled in if it takes one).
    obs, horizon : int
        Observed and predicted samples of the training windows.
    model_dt : float
        Spacing of the training windows (s); queries at another spacing are resampled.
    weights : str or None
        Folder written by ``save`` / ``conformal-control train-predictor``.
    random_state : int
        Seed of stochastic regressors.
    """

    def __init__(
        self,
        estimator: str = "Ridge",
        estimator_params: dict[str, Any] | None = None,
        obs: int = 8,
        horizon: int = 12,
        model_dt: float = 0.4,
        weights: str | None = None,
        random_state: int = 0,
    ) -> None:
        self.estimator = estimator
        self.estimator_params = estimator_params
        self.obs = obs
        self.horizon = horizon
        self.model_dt = model_dt
        self.weights = weights
        self.random_state = random_state

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        """The Ridge shipped in the package (see :func:`make_unit_test_weights`)."""
        return [{"weights": str(UNIT_TEST_WEIGHTS)}]

    def _make(self) -> Any:
        cls = regressor_class(self.estimator)
        params = dict(self.estimator_params or {})
        if "random_state" in cls().get_params():
            params.setdefault("random_state", self.random_state)
        reg = cls(**params)
        try:
            from sklearn.utils import get_tags

            multi = get_tags(reg).target_tags.multi_output
        except Exception:  # older scikit-learn
            multi = reg._get_tags().get("multioutput", False)
        if not multi:
            reg = MultiOutputRegressor(reg)
        return TransformedTargetRegressor(
            regressor=make_pipeline(StandardScaler(), reg), transformer=StandardScaler()
        )

    def _fit_arrays(self, disp: np.ndarray, target: np.ndarray) -> None:
        model = self._make()
        model.fit(disp.reshape(len(disp), -1), target.reshape(len(target), -1))
        self.model_ = model

    def _predict_offsets(self, disp: np.ndarray) -> np.ndarray:
        y = self.model_.predict(disp.reshape(len(disp), -1))
        return np.asarray(y, dtype=float).reshape(len(disp), self.horizon, 2)

    def _save_model(self, folder: Path) -> None:
        joblib.dump(self.model_, folder / "model.joblib")

    def _load_model(self, folder: Path, config: dict[str, Any]) -> None:
        self.model_ = joblib.load(folder / "model.joblib")


def make_unit_test_weights(folder: str | Path = UNIT_TEST_WEIGHTS) -> Path:
    """Fit the Ridge of ``_unit_test_params`` on seeded synthetic walks; save to ``folder``.

    The package ships its output; the plugin's tests re-create it in a temporary folder
    and check that it still predicts the same (re-run this after changing the model).
    """
    return SklearnPredictor().fit(*synthetic_windows(), dt=0.4).save(folder)
