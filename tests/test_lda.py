"""sonicskin.kinds.lda: the shrinkage LDA (= scikit-learn's, fast), its normalisations, its ONNX graph and its choice."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from sklearn.covariance import ledoit_wolf_shrinkage
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
from sklearn.utils.estimator_checks import parametrize_with_checks

from sonicskin import kinds
from sonicskin.kinds import Fitted
from sonicskin.kinds.lda import ENSEMBLE, LDAViews, ShrinkageLDA, choose, fit_lda, ledoit_wolf_shrinkage_gram, normalize


def _blobs(K=5, n=60, d=200, seed=0):
    rng = np.random.default_rng(seed)
    y = np.arange(n) % K
    X = rng.normal(size=(n, d)) * rng.uniform(0.5, 3.0, d)
    X[:, :4] += 2.0 * y[:, None]
    return X, y


@parametrize_with_checks([ShrinkageLDA(), ShrinkageLDA(shrinkage=0.2)])
def test_sklearn_compatible(estimator, check):
    check(estimator)


@pytest.mark.parametrize("K,n,d", [(2, 40, 30), (5, 60, 200), (6, 150, 400)])
@pytest.mark.parametrize("shrinkage", ["auto", 0.3])
def test_equals_sklearn_lda(K, n, d, shrinkage):
    X, y = _blobs(K, n, d)
    ref = LinearDiscriminantAnalysis(solver="lsqr", shrinkage=shrinkage).fit(X, y)
    ours = ShrinkageLDA(shrinkage=shrinkage).fit(X, y)
    assert ours.coef_.shape == ref.coef_.shape
    np.testing.assert_allclose(ours.coef_, ref.coef_, rtol=1e-9, atol=1e-12 * np.abs(ref.coef_).max())
    np.testing.assert_allclose(ours.intercept_, ref.intercept_, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(ours.predict(X), ref.predict(X))


def test_ledoit_wolf_from_gram_equals_sklearn():
    rng = np.random.default_rng(3)
    Z = rng.normal(size=(30, 500)) * rng.uniform(0.1, 2, 500)
    Z -= Z.mean(axis=0)
    assert ledoit_wolf_shrinkage_gram(Z) == pytest.approx(ledoit_wolf_shrinkage(Z, assume_centered=True), rel=1e-10)


def test_bad_inputs_one_line():
    X, y = _blobs(3, 30, 10)
    with pytest.raises(ValueError, match=r"^shrinkage must be 'auto' or a number in \[0, 1\], got 1.5$"):
        ShrinkageLDA(shrinkage=1.5).fit(X, y)
    with pytest.raises(ValueError, match=r"^ShrinkageLDA needs at least 2 classes, got 1: record at least two locations$"):
        ShrinkageLDA().fit(X, np.zeros(len(X)))


def test_normalisations():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(7, 40))
    np.testing.assert_allclose(normalize(X, "level").mean(axis=1), 0, atol=1e-12)
    np.testing.assert_allclose(normalize(X + 5.0, "level"), normalize(X, "level"), atol=1e-12)  # a gain change is gone
    np.testing.assert_allclose(np.linalg.norm(normalize(X, "unit"), axis=1), 1.0)
    np.testing.assert_allclose(normalize(3.0 * X, "unit"), normalize(X, "unit"))  # a stronger touch of one shape
    np.testing.assert_array_equal(normalize(X, "none"), X)


@pytest.mark.parametrize("views", [[(100, "none")], [(100, "level")], [(60, "unit")], [(100, "none"), (60, "level"), (100, "unit")]])
@pytest.mark.parametrize("K", [2, 5])
def test_onnx_graph_decides_as_numpy(tmp_path, views, K):
    """The LDA's ONNX graph (per view its first bins, normalisation and one MatMul; the views summed) gives numpy's
    scores and the LDA's own predictions."""
    import onnxruntime as ort

    X, y = _blobs(K, 80, 120, seed=4)
    lda = LDAViews(views).fit(X[:, :100], y)
    kind = kinds.get("lda")
    parity = kind.export(Fitted(lda, {"views": views}, 100, {}), tmp_path / "lda.onnx", X[:, :100].astype(np.float32))
    assert parity["labels_equal"] and parity["max_abs_scores"] <= parity["scores_tol"]
    sess = ort.InferenceSession(str(tmp_path / "lda.onnx"), providers=["CPUExecutionProvider"])
    S = sess.run(None, {"inputs": X[:, :100].astype(np.float32)})[0]
    assert S.shape == (len(X), K)
    np.testing.assert_array_equal(lda.classes_[S.argmax(1)], lda.predict(X[:, :100]))


def test_the_ensemble_sums_its_views_posteriors():
    """The ensemble's scores are the sum of its views' scores (the product of their posteriors): a known answer from
    scikit-learn's LDA of each view; one view alone is that view's LDA."""
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis

    X, y = _blobs(4, 80, 120, seed=5)
    views = [(120, "none"), (50, "unit")]
    want = sum(LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto").fit(normalize(X[:, :k], nm), y)
               .decision_function(normalize(X[:, :k], nm)) for k, nm in views)
    np.testing.assert_allclose(LDAViews(views).fit(X, y).decision_function(X), want, rtol=1e-6, atol=1e-6)
    one = LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto").fit(X[:, :50], y)
    np.testing.assert_array_equal(fit_lda(X, y, 50, "none").predict(X), one.predict(X[:, :50]))


def _data(X, y, folds, mode="relative"):
    return SimpleNamespace(X=X, cls=y, n_locations=int(y.max()) + 1, spec=SimpleNamespace(mode=mode),
                           folds=lambda: (folds, "test folds"))


def test_the_ensemble_sees_through_a_gain_its_as_measured_view_does_not():
    """Markers differ in shape; the second half of the chirps carries another gain (a constant 8 dB offset): the LDA of
    the chirps as measured is thrown off, the level-removed one sees through it (a known answer), and so does the
    ensemble, whose validated accuracy is reported.  Without folds: the same views, not validated.  Absolute inputs:
    every bin at unit length."""
    rng = np.random.default_rng(2)
    K, n, d = 4, 240, 60
    y = np.arange(n) % K
    half = np.arange(n) < n // 2
    X = rng.normal(size=(K, d))[y] + 0.2 * rng.normal(size=(n, d)) + np.where(half, 0.0, 8.0)[:, None]
    assert np.mean(fit_lda(X[half], y[half], d, "none").predict(X[~half]) == y[~half]) < 0.8
    assert np.mean(fit_lda(X[half], y[half], d, "level").predict(X[~half]) == y[~half]) > 0.95
    got = choose(_data(X, y, [(half, ~half), (~half, half)]))
    assert got["status"] == "validated" and got["name"] == ENSEMBLE and got["accuracy"] > 0.95
    assert got["views"] == [(d, "none"), (d, "level"), (d, "unit")]
    assert choose(_data(X, y, [])) | {"how": ""} == {"status": "default", "name": ENSEMBLE, "how": "", "views": got["views"]}
    assert choose(_data(X, y, [], mode="absolute"))["views"] == [(d, "unit")]
