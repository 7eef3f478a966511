import numpy as np
import pytest
from sklearn.svm import SVC

from sonicskin.baseline import SVMLocalizer, ovr_scores_from_ovo


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


def test_localizer_learns_clusters_and_keeps_ids(rng):
    X, y = _clusters(rng)
    Xm = rng.normal(0, 0.1, (50, X.shape[1])).astype(np.float32)
    m = SVMLocalizer(n_bins=20).fit(X, y, X_moving=Xm)
    Xt, yt = _clusters(np.random.default_rng(12345), spread=0.3)
    assert set(m.classes_) == {1, 3, 5, 7, 9}
    assert np.mean(m.predict(Xt) == yt) > 0.95
    assert m.decision_function(Xt).shape == (len(yt), 5)
    assert len(m.selected_) == 20


def test_localizer_errors(rng):
    X, y = _clusters(rng)
    with pytest.raises(ValueError, match="single touch location"):
        SVMLocalizer(n_bins=5).fit(X[:10], np.zeros(10))
    with pytest.raises(ValueError, match="150 feature rows but 10 location labels"):
        SVMLocalizer(n_bins=5).fit(X, y[:10])
    Xn = X.copy(); Xn[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        SVMLocalizer(n_bins=5).fit(Xn, y)
    with pytest.raises(ValueError, match="gamma=500 is larger than the 40 bins"):
        SVMLocalizer(n_bins=500).fit(X, y)


def test_two_locations_through_onnx(rng, tmp_path):
    """skl2onnx's binary SVM output has its own layout; the scores must still match scikit-learn."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from sonicskin.artifact import export_svm

    X, y = _clusters(rng, k=2, spread=1.5)
    pipe = make_pipeline(StandardScaler(), SVC(decision_function_shape="ovo")).fit(X, y)
    parity = export_svm(pipe, 2, tmp_path / "svm.onnx", X)
    assert parity["labels_equal"] and parity["max_abs_scores"] <= parity["scores_tol"] < 0.01
