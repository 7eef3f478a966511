"""sonicskin.nuisance: shrinkage LDA (= scikit-learn's, fast), the metric head, level removal, nuisance directions, ONNX."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.covariance import ledoit_wolf_shrinkage
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
from sklearn.pipeline import make_pipeline
from sklearn.utils.estimator_checks import parametrize_with_checks

from sonicskin.nuisance import LevelRemoval, ShrinkageLDA, ledoit_wolf_shrinkage_gram, make_candidates, nuisance_directions


def _blobs(K=5, n=60, d=200, seed=0):
    rng = np.random.default_rng(seed)
    y = np.arange(n) % K
    X = rng.normal(size=(n, d)) * rng.uniform(0.5, 3.0, d)
    X[:, :4] += 2.0 * y[:, None]
    return X, y


@parametrize_with_checks([ShrinkageLDA(), ShrinkageLDA(shrinkage=0.2), LevelRemoval()])
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


def test_nuisance_direction_is_ignored():
    """Two markers differ along e0; a later press moves every chirp far along a nuisance direction v the training
    press never showed.  Plain LDA is thrown off by it, the metric head told about v is not (a known answer)."""
    rng = np.random.default_rng(1)
    d, n = 50, 80
    y = np.arange(n) % 2
    X = 0.05 * rng.normal(size=(n, d))
    X[:, 0] += 1.0 * y
    v = np.zeros(d)
    v[1:3] = [1.0, -1.0]
    X[:, 1] += 0.3 * y  # the markers' patterns also differ a little along the nuisance's bins
    Xt = X + 3.0 * v * np.where(y == 0, 1, -1)[:, None]  # marker 0 drifts +v, marker 1 -v
    plain = ShrinkageLDA().fit(X, y)
    head = ShrinkageLDA(nuisance=v[None, :] * 3.0).fit(X, y)
    assert np.mean(plain.predict(Xt) == y) < 0.2
    assert np.mean(head.predict(Xt) == y) == 1.0
    # weight 0 is plain LDA, bit for bit
    np.testing.assert_array_equal(ShrinkageLDA(nuisance=v[None, :], nuisance_weight=0.0).fit(X, y).coef_, plain.coef_)


def test_metric_head_is_nearest_mean_under_its_metric():
    X, y = _blobs(4, 80, 20, seed=2)
    V = np.random.default_rng(0).normal(size=(3, 20))
    m = ShrinkageLDA(nuisance=V, priors=np.full(4, 0.25)).fit(X, y)
    # reconstruct the covariance densely and compare with the Mahalanobis nearest mean
    lam_U = []
    for k in range(4):
        Xk = X[y == k] - X[y == k].mean(0)
        sc = Xk.std(0)
        sc[sc == 0] = 1
        s = m.shrinkage_[k]
        Z = Xk / sc
        mu = np.sum(Z * Z) / Z.size
        lam_U.append(0.25 * (s * mu * np.diag(sc ** 2) + (1 - s) * Xk.T @ Xk / len(Xk)))
    S = sum(lam_U) + V.T @ V
    Si = np.linalg.inv(S)
    diff = X[:, None, :] - m.means_[None]
    maha = np.einsum("nkd,de,nke->nk", diff, Si, diff)
    np.testing.assert_array_equal(m.predict(X), m.classes_[maha.argmin(1)])


def test_level_removal():
    rng = np.random.default_rng(0)
    f = rng.uniform(20e3, 80e3, 40)  # any column order, as OSPA's
    X = rng.normal(size=(7, 40))
    lr = LevelRemoval().fit(X)
    np.testing.assert_allclose(lr.transform(X).mean(axis=1), 0, atol=1e-12)
    np.testing.assert_allclose(lr.transform(X + 5.0), lr.transform(X), atol=1e-12)  # a gain change is gone
    lt = LevelRemoval(tilt=True, freqs_hz=f).fit(X)
    shifted = X + 2.0 + 3e-4 * (f - 50e3)[None, :]  # gain and tilt
    np.testing.assert_allclose(lt.transform(shifted), lt.transform(X), atol=1e-10)
    np.testing.assert_allclose(lt.transform(lt.transform(X)), lt.transform(X), atol=1e-10)  # a projection
    assert np.abs(lt.transform(X) @ (f - f.mean())).max() < 1e-8


def test_bad_inputs_one_line():
    X, y = _blobs(3, 30, 10)
    with pytest.raises(ValueError, match=r"^nuisance must be \(k, 10\) directions over the same 10 inputs, got shape \(2, 9\)$"):
        ShrinkageLDA(nuisance=np.ones((2, 9))).fit(X, y)
    with pytest.raises(ValueError, match=r"^shrinkage must be 'auto' or a number in \[0, 1\], got 1.5$"):
        ShrinkageLDA(shrinkage=1.5).fit(X, y)
    with pytest.raises(ValueError, match=r"^nuisance_weight must be a number >= 0, got -1$"):
        ShrinkageLDA(nuisance=np.ones((1, 10)), nuisance_weight=-1).fit(X, y)
    with pytest.raises(ValueError, match=r"^tilt removal needs freqs_hz, the frequency of each of the 10 input columns, got None$"):
        LevelRemoval(tilt=True).fit(X)
    with pytest.raises(ValueError, match=r"^ShrinkageLDA needs at least 2 classes, got 1: record at least two locations$"):
        ShrinkageLDA().fit(X, np.zeros(len(X)))
    with pytest.raises(ValueError, match=r"^unknown nuisance kinds \['wind'\]; choose from"):
        nuisance_directions(X, y, kinds=["wind"])


def test_nuisance_directions_known_answers():
    f = np.linspace(20e3, 80e3, 3001)
    P = 2e3  # a pattern with a 2 kHz period
    K = 2
    means = np.stack([np.sin(2 * np.pi * f / P), 0.5 * np.cos(2 * np.pi * f / P)])
    X = np.repeat(means, 3, axis=0)
    y = np.repeat(np.arange(K), 3)
    V = nuisance_directions(X, y, freqs_hz=f, positions_cm=np.array([[0.0, 0.0], [2.0, 0.0]]), stretch=1e-3, gain_db=0.5,
                            tilt_db=0.4, aim_cm=0.2, strength=0.3)
    # stretch: s f dmu/df / sqrt(K), the analytic derivative away from the ends
    want = 1e-3 * f * (2 * np.pi / P) * np.stack([np.cos(2 * np.pi * f / P), -0.5 * np.sin(2 * np.pi * f / P)]) / np.sqrt(K)
    np.testing.assert_allclose(V["stretch"][:, 5:-5], want[:, 5:-5], atol=2e-3 * np.abs(want).max())
    np.testing.assert_allclose(V["gain"], 0.5)
    assert np.ptp(V["tilt"]) == pytest.approx(0.4) and V["tilt"].mean() == pytest.approx(0.0, abs=1e-12)
    # aim: 0.2 cm of the 2 cm toward the other marker, pooled over the 2 markers with one neighbour each
    np.testing.assert_allclose(V["aim"][0], (means[1] - means[0]) * 0.1 / np.sqrt(2), atol=1e-12)
    np.testing.assert_allclose(V["strength"], 0.3 * means / np.sqrt(2), atol=1e-12)
    assert "motion" not in V  # no hands-off chirps given


def test_aim_wraps_around_a_tube():
    X = np.eye(3).repeat(2, axis=0)
    y = np.repeat(np.arange(3), 2)
    pos = np.array([[0.5, 0.0], [5.0, 0.0], [9.5, 0.0]])  # circumference 10: marker 0 and 2 are 1 cm apart
    V = nuisance_directions(X, y, positions_cm=pos, circumference_cm=10.0, aim_cm=0.1, kinds=["aim"])["aim"]
    # marker 0's nearest neighbour is marker 2 (across the seam), at 1 cm: 0.1 of the difference
    np.testing.assert_allclose(V[0], (np.eye(3)[2] - np.eye(3)[0]) * 0.1 / np.sqrt(3), atol=1e-12)


def test_candidates_fit_and_predict():
    X, y = _blobs(4, 80, 60)
    V = nuisance_directions(X, y, kinds=["gain", "strength"])
    for name, est in make_candidates(nuisance=np.vstack(list(V.values()))).items():
        acc = np.mean(est.fit(X, y).predict(X) == y)
        assert acc > 0.9, name


@pytest.mark.parametrize("binary", [False, True])
def test_onnx_export_matches(binary):
    import onnxruntime as ort
    from skl2onnx import to_onnx

    from sonicskin.nuisance import register_onnx_converters

    register_onnx_converters()
    X, y = _blobs(2 if binary else 5, 80, 120, seed=4)
    f = np.linspace(20e3, 80e3, 120)
    lda = ShrinkageLDA(nuisance=nuisance_directions(X, y, kinds=["strength"])["strength"])
    pipe = make_pipeline(LevelRemoval(tilt=True, freqs_hz=f), lda).fit(X, y)
    onx = to_onnx(pipe, X[:1].astype(np.float32), options={id(lda): {"zipmap": False, "raw_scores": True}},
                  target_opset=17)
    sess = ort.InferenceSession(onx.SerializeToString(), providers=["CPUExecutionProvider"])
    labels, scores = sess.run(None, {sess.get_inputs()[0].name: X.astype(np.float32)})
    np.testing.assert_array_equal(labels, pipe.predict(X))
    want = pipe.decision_function(X)
    if binary:
        want = np.column_stack([-want, want])
    np.testing.assert_allclose(scores, want, rtol=1e-3, atol=1e-3 * np.abs(want).max())
