"""conformal-control plugin: a scikit-learn regressor on past displacements."""

from .predictor import SklearnPredictor

__all__ = ["SklearnPredictor"]
