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
from sonicskin.kinds.lda import DEFAULTS, ShrinkageLDA, choose, fit_lda, ledoit_wolf_shrinkage_gram, normalize


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


@pytest.mark.parametrize("norm", ["none", "level", "unit"])
@pytest.mark.parametrize("K", [2, 5])
def test_onnx_graph_decides_as_numpy(tmp_path, norm, K):
    """The LDA's ONNX graph (normalisation, then one Gemm) gives numpy's scores and the LDA's own predictions."""
    import onnxruntime as ort

    X, y = _blobs(K, 80, 120, seed=4)
    lda = fit_lda(X, y, 100, norm)
    kind = kinds.get("lda")
    parity = kind.export(Fitted(lda, {"norm": norm}, 100, {}), tmp_path / "lda.onnx", X[:, :100].astype(np.float32))
    assert parity["labels_equal"] and parity["max_abs_scores"] <= parity["scores_tol"]
    sess = ort.InferenceSession(str(tmp_path / "lda.onnx"), providers=["CPUExecutionProvider"])
    S = sess.run(None, {"inputs": X[:, :100].astype(np.float32)})[0]
    assert S.shape == (len(X), K)
    np.testing.assert_array_equal(lda.classes_[S.argmax(1)], lda.predict(normalize(X[:, :100], norm)))


def _data(X, y, folds, mode="relative"):
    return SimpleNamespace(X=X, cls=y, n_locations=int(y.max()) + 1, spec=SimpleNamespace(mode=mode),
                           folds=lambda: (folds, "test folds"))


def test_choice_finds_the_normalisation_a_gain_needs_and_defaults_without_folds():
    """Markers differ in shape; the second half of the chirps carries another gain (a constant 8 dB offset): the LDA of the
    chirps as measured is thrown off, the level-removed one sees through it (a known answer), and the choice is a
    normalised one at the best validation score (ties to the default).  Without folds the measured default is taken."""
    rng = np.random.default_rng(2)
    K, n, d = 4, 240, 60
    y = np.arange(n) % K
    half = np.arange(n) < n // 2
    X = rng.normal(size=(K, d))[y] + 0.2 * rng.normal(size=(n, d)) + np.where(half, 0.0, 8.0)[:, None]
    got = choose(_data(X, y, [(half, ~half), (~half, half)]))
    assert got["scores"]["every bin, level removed"] > 0.95 and got["scores"]["every bin, as measured"] < 0.8
    assert got["status"] == "validated" and got["norm"] != "none" and got["accuracy"] >= got["scores"]["every bin, level removed"] - 0.005
    assert choose(_data(X, y, [])) | {"how": ""} == {"status": "default", "k": d, "norm": DEFAULTS["relative"][1],
                                                     "name": "every bin, unit length", "how": ""}
