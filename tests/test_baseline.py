import numpy as np
import pytest
from sklearn.svm import SVC

from sonicskin.kinds.svm import export_pipeline, ovr_scores_from_ovo


def _clusters(rng, k=5, n=30, f=40, spread=0.3):
    centers = rng.normal(0, 1, (k, f))
    y = np.repeat(np.arange(k), n)
    X = centers[y] + rng.normal(0, spread, (y.size, f))
    return X.astype(np.float32), y * 2 + 1  # non-contiguous ids


def test_ovr_from_ovo_matches_sklearn(rng):
    X, y = _clusters(rng, k=6, spread=1.0)
    ovo = SVC(decision_function_shape="ovo").fit(X, y).decision_function(X)
    ovr = SVC(decision_function_shape="ovr").fit(X, y).decision_function(X)
    np.testing.assert_allclose(ovr_scores_from_ovo(ovo, 6), ovr, atol=1e-9)
    with pytest.raises(ValueError, match=r"expected \(n, 15\) pairwise scores"):
        ovr_scores_from_ovo(ovo[:, :3], 6)


def test_two_locations(rng):
    X, y = _clusters(rng, k=2, spread=1.5)
    svc = SVC(decision_function_shape="ovo").fit(X, y)
    S = ovr_scores_from_ovo(svc.decision_function(X), 2)
    np.testing.assert_array_equal(svc.classes_[S.argmax(1)], svc.predict(X))


def test_two_locations_through_onnx(rng, tmp_path):
    """skl2onnx's binary SVM output has its own layout; the scores must still match scikit-learn."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    X, y = _clusters(rng, k=2, spread=1.5)
    pipe = make_pipeline(StandardScaler(), SVC(decision_function_shape="ovo")).fit(X, y)
    parity = export_pipeline(pipe, tmp_path / "svm.onnx", X)
    assert parity["labels_equal"] and parity["max_abs_scores"] <= parity["scores_tol"] < 0.01
