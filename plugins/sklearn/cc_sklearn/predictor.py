"""A scikit-learn regressor mapping past displacements to future offsets.

Features are the ``obs - 1`` displacements of the observed window and targets the
``horizon`` offsets of the future positions from the last observed one (both flattened,
standardised with ``StandardScaler``). Any regressor of ``sklearn.utils.all_estimators``
can be named; single-output ones are wrapped in ``MultiOutputRegressor``.

The fitted pipeline is saved as ``model.skops`` beside ``config.json`` with ``skops.io``,
which stores the objects' state, not code: loading builds only the types skops trusts by
default (scikit-learn's estimators, numpy and builtin containers) and the few internal
scikit-learn classes listed in :data:`TRUSTED_TYPES`, and refuses a file that names any
other type. Nothing is unpickled: a weights folder from a replayed configuration, a sweep
spec or the cache cannot run code. Folders of older versions (``model.joblib``, a pickle)
are refused with a message saying to train again.

The registry's entry-point cache cannot run code either: the plugin is found as
``sklearn`` through an entry point, and a cached row is used only when the installed
distribution's ``entry_points.txt`` declares exactly it (``conformal_control.core.registry``
checks every row against the installed metadata rather than signing the cache, whose key
would sit beside it in the user's folder); a cache pointing ``sklearn`` elsewhere is
discarded and the entry points are scanned again.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np
import skops.io as sio
from sklearn.compose import TransformedTargetRegressor
from sklearn.multioutput import MultiOutputRegressor
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.utils import all_estimators

from conformal_control.core.exceptions import InputError
from conformal_control.predictors.learned import WindowPredictor, synthetic_windows

__all__ = [
    "MODEL_FILE",
    "TRUSTED_TYPES",
    "UNIT_TEST_WEIGHTS",
    "SklearnPredictor",
    "make_unit_test_weights",
    "regressor_class",
]

#: The fitted pipeline's file in a weights folder.
MODEL_FILE = "model.skops"

#: scikit-learn's internal classes (not functions) that fitted regressors hold and that
#: ``skops.io`` does not trust by default: tree structures (trees, forests, boosting), the
#: neighbour searches and their metrics, the MLP's optimisers, the Gaussian process
#: kernels and the GLM losses. Each is a data-holding class: loading one builds an object,
#: it calls nothing named by the file. Listed by exact name, never by prefix (a prefix
#: would also admit functions, which skops can call while loading).
TRUSTED_TYPES: tuple[str, ...] = (
    "sklearn.tree._tree.Tree",
    "sklearn.ensemble._hist_gradient_boosting.predictor.TreePredictor",
    "sklearn.neighbors._kd_tree.KDTree",
    "sklearn.neighbors._ball_tree.BallTree",
    "sklearn.metrics._dist_metrics.EuclideanDistance64",
    "sklearn.metrics._dist_metrics.ManhattanDistance64",
    "sklearn.metrics._dist_metrics.ChebyshevDistance64",
    "sklearn.metrics._dist_metrics.MinkowskiDistance64",
    "sklearn.neural_network._stochastic_optimizers.AdamOptimizer",
    "sklearn.neural_network._stochastic_optimizers.SGDOptimizer",
    "sklearn.gaussian_process.kernels.ConstantKernel",
    "sklearn.gaussian_process.kernels.DotProduct",
    "sklearn.gaussian_process.kernels.ExpSineSquared",
    "sklearn.gaussian_process.kernels.Matern",
    "sklearn.gaussian_process.kernels.Product",
    "sklearn.gaussian_process.kernels.RBF",
    "sklearn.gaussian_process.kernels.RationalQuadratic",
    "sklearn.gaussian_process.kernels.Sum",
    "sklearn.gaussian_process.kernels.WhiteKernel",
    "sklearn._loss.loss.HalfSquaredError",
    "sklearn._loss.loss.HalfPoissonLoss",
    "sklearn._loss.loss.HalfGammaLoss",
    "sklearn._loss.loss.HalfTweedieLoss",
    "sklearn._loss.loss.HalfTweedieLossIdentity",
)

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


class SklearnPredictor(WindowPredictor, run_values={"random_state": "seed"}):
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
        untrusted = _untrusted(sio.dumps(self.model_))
        if untrusted:  # would be refused on loading: say so now, not after training
            raise InputError(
                f"a fitted {self.estimator} holds types this plugin does not load "
                f"({', '.join(untrusted)}); choose another regressor"
            )
        sio.dump(self.model_, folder / MODEL_FILE)

    def _load_model(self, folder: Path, config: dict[str, Any]) -> None:
        path = folder / MODEL_FILE
        if not path.is_file():
            old = " (it holds a model.joblib, a pickle of an older version, which is not loaded)"
            raise InputError(
                f"no {MODEL_FILE} in {folder}"
                + (old if (folder / "model.joblib").exists() else "")
                + "; train the model again with `conformal-control train-predictor sklearn`"
            )
        data = path.read_bytes()  # checked and loaded from the same bytes
        try:
            needed = sio.get_untrusted_types(data=data)
        except Exception as exc:  # not a skops file: a zip of the wrong layout, garbage
            raise InputError(f"{path}: not a skops model file ({exc})") from None
        untrusted = [t for t in needed if t not in TRUSTED_TYPES]
        if untrusted:
            raise InputError(
                f"{path} names types outside the trusted list ({', '.join(untrusted[:5])}"
                f"{', ...' if len(untrusted) > 5 else ''}), which could run code when "
                "loaded; it is refused (train the model again, or review the types and load "
                "it yourself with skops.io.load(path, trusted=[...]))"
            )
        self.model_ = sio.loads(data, trusted=needed)


def _untrusted(data: bytes) -> list[str]:
    """Types of a skops file that neither skops nor :data:`TRUSTED_TYPES` trust."""
    return [t for t in sio.get_untrusted_types(data=data) if t not in TRUSTED_TYPES]


def make_unit_test_weights(folder: str | Path = UNIT_TEST_WEIGHTS) -> Path:
    """Fit the Ridge of ``_unit_test_params`` on seeded synthetic walks; save to ``folder``.

    The package ships its output; the plugin's tests re-create it in a temporary folder
    and check that it still predicts the same (re-run this after changing the model).
    """
    return SklearnPredictor().fit(*synthetic_windows(), dt=0.4).save(folder)
