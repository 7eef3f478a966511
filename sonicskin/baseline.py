"""The paper's localizer: OSPA bins -> standard scaling -> RBF SVM, one class per location."""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC
from sklearn.utils.validation import check_is_fitted

from .head.heads import ovr_scores_from_ovo
from .ospa import OSPA

__all__ = ["SVMLocalizer", "ovr_scores_from_ovo"]


class SVMLocalizer(ClassifierMixin, BaseEstimator):
    """OSPA + StandardScaler + ``SVC(kernel="rbf")`` over the touch locations (paper Sec. III-A/B).

    Parameters
    ----------
    n_bins : int, default=300
        OSPA's gamma.
    C : float, default=10.0
        SVM regularisation.
    kernel_gamma : float or "scale", default="scale"
        RBF kernel width (``SVC(gamma=...)``).
    allowed : bool array, optional
        Matched-filter mask over the input features (``rig.allowed_mask``).

    Attributes
    ----------
    pipeline_ : sklearn Pipeline ``ospa -> scale -> svc`` (the SVC uses ``ovo`` decision values).
    classes_ : location ids.
    selected_ : feature indices kept by OSPA.
    """

    def __init__(self, n_bins: int = 300, C: float = 10.0, kernel_gamma="scale", allowed=None):
        self.n_bins = n_bins
        self.C = C
        self.kernel_gamma = kernel_gamma
        self.allowed = allowed

    def fit(self, X, y, X_moving=None):
        X = np.asarray(X, dtype=np.float32)
        y = np.asarray(y)
        if X.ndim != 2:
            raise ValueError(f"X must be (n_chirps, n_bins), got shape {X.shape}")
        if y.shape != (X.shape[0],):
            raise ValueError(f"got {X.shape[0]} feature rows but {y.size} location labels; they must match")
        if not np.isfinite(X).all():
            raise ValueError("X contains NaN or inf; check the frames with sonicskin.dsp.check_frames")
        if np.unique(y).size < 2:
            raise ValueError("training data holds a single touch location; record at least two locations")
        self.pipeline_ = Pipeline([
            ("ospa", OSPA(gamma=self.n_bins, allowed=self.allowed)),
            ("scale", StandardScaler()),
            ("svc", SVC(kernel="rbf", C=self.C, gamma=self.kernel_gamma, decision_function_shape="ovo")),
        ])
        self.pipeline_.fit(X, y, ospa__X_moving=X_moving)
        self.classes_ = self.pipeline_.classes_
        self.selected_ = self.pipeline_.named_steps["ospa"].selected_
        return self

    def pairwise_scores(self, X) -> np.ndarray:
        check_is_fitted(self, "pipeline_")
        return self.pipeline_.decision_function(np.asarray(X, dtype=np.float32))

    def decision_function(self, X) -> np.ndarray:
        """Per-location scores S (paper Alg. 2), shape (n, n_locations)."""
        return ovr_scores_from_ovo(self.pairwise_scores(X), len(self.classes_))

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(self.decision_function(X), axis=1)]
