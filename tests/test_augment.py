"""training.augment: each augmentation moves a chirp only along its own nuisance direction; the network's LDA layer
is the LDA it starts from and exports to ONNX."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sonicskin.training.augment import AUGMENTATIONS, Augmenter  # noqa: E402
from sonicskin.training.quick import fit_net  # noqa: E402

F = np.linspace(20e3, 80e3, 601)


def _session(K=3, per=6, seed=0):
    rng = np.random.default_rng(seed)
    pat = rng.normal(size=(K, F.size))
    y = np.repeat(np.arange(K), per)
    press = y.copy()  # one press per marker
    force = np.tile(np.linspace(0.5, 1.5, per), K)
    X = pat[y] * force[:, None] + 0.01 * rng.normal(size=(K * per, F.size))
    return X, y, press, pat


def _only(kind, size):
    return {k: (size if k == kind else 0.0) for k in AUGMENTATIONS}


def test_press_draws_stay_on_the_press_line():
    X, y, press, _ = _session()
    aug = Augmenter(X[:2], y[:2], press[:2], sizes=_only("press", 0.5))  # a press of two chirps
    out = aug.draw(np.random.default_rng(1), np.zeros(200, int))
    lam = (out - X[0]) @ (X[1] - X[0]) / np.sum((X[1] - X[0]) ** 2)
    np.testing.assert_allclose(out, X[0] + lam[:, None] * (X[1] - X[0]), atol=1e-9)
    assert lam.min() >= -0.5 - 1e-12 and lam.max() <= 1.5 + 1e-12 and np.ptp(lam) > 1.0


def test_strength_scales_the_whole_chirp():
    X, y, press, _ = _session()
    out = Augmenter(X, y, press, sizes=_only("strength", 0.3)).draw(np.random.default_rng(2))
    ratio = out / X
    np.testing.assert_allclose(ratio, ratio[:, :1].repeat(X.shape[1], axis=1), rtol=1e-9)
    assert np.std(np.log(ratio[:, 0])) > 0.1


def test_stretch_resamples_the_frequency_axis():
    X = np.sin(2 * np.pi * F / 3e3)[None, :].repeat(4, axis=0)
    y = np.arange(4) % 2
    cols = np.random.default_rng(0).permutation(F.size)  # inputs in any order (OSPA's)
    aug = Augmenter(X[:, cols], y, np.arange(4), freqs_hz=F[cols], sizes=_only("stretch", 2e-3))
    out = aug.draw(np.random.default_rng(3))
    back = np.empty_like(out)
    back[:, cols] = out
    for row in back:  # each row is sin(2 pi f (1 + s) / P) for one s in [-2e-3, 2e-3]
        s = np.linspace(-2e-3, 2e-3, 4001)
        err = [np.abs(row[1:-1] - np.sin(2 * np.pi * F[1:-1] * (1 + v) / 3e3)).max() for v in s]
        bound = (2 * np.pi * (F[1] - F[0]) / 3e3) ** 2 / 8  # linear interpolation's error on this grid
        assert min(err) < 1.05 * bound


def test_gain_and_tilt_are_affine_in_frequency():
    X, y, press, _ = _session()
    out = Augmenter(X, y, press, freqs_hz=F, sizes={**_only("gain", 0.5), "tilt": 0.5}).draw(np.random.default_rng(4))
    D = out - X
    A = np.column_stack([np.ones_like(F), F])
    coef, *_ = np.linalg.lstsq(A, D.T, rcond=None)
    np.testing.assert_allclose(A @ coef, D.T, atol=1e-9)


def test_aim_moves_toward_a_neighbouring_marker():
    X, y, press, _ = _session(K=3)
    pos = np.array([[0.0, 0.0], [1.5, 0.0], [3.0, 0.0]])
    aug = Augmenter(X, y, press, positions_cm=pos, sizes=_only("aim", 0.3))
    out = aug.draw(np.random.default_rng(5))
    for i in np.flatnonzero(y == 0):  # marker 0's only neighbour ring is marker 1 (1.5 cm)
        d = out[i] - X[i]
        step = aug.means[1] - aug.means[0]
        a = d @ step / (step @ step)
        np.testing.assert_allclose(d, a * step, atol=1e-9)
        assert 0 <= a <= 1


def test_motion_adds_recorded_hands_off_deviations():
    X, y, press, _ = _session()
    rest = np.random.default_rng(6).normal(size=(5, F.size))
    out = Augmenter(X, y, press, X_rest=rest, sizes=_only("motion", 1.0)).draw(np.random.default_rng(7))
    dev = rest - rest.mean(0)
    coef, *_ = np.linalg.lstsq(dev.T, (out - X).T, rcond=None)
    np.testing.assert_allclose(dev.T @ coef, (out - X).T, atol=1e-8)


def test_bad_configuration_one_line():
    X, y, press, _ = _session()
    with pytest.raises(ValueError, match=r"^unknown augmentations \['wind'\]; choose from"):
        Augmenter(X, y, press, sizes={"wind": 1.0})
    with pytest.raises(ValueError, match=r"^the stretch augmentation needs freqs_hz$"):
        Augmenter(X, y, press, sizes=_only("stretch", 1e-3))
    with pytest.raises(ValueError, match=r"^X has 18 chirps but y \(17,\) and press \(18,\); give one label and press id per chirp$"):
        Augmenter(X, y[:-1], press)


def _with_rest(X, y, n_rest=20, seed=0):
    rng = np.random.default_rng(seed)
    K = int(y.max()) + 1
    Xa = np.vstack([X, 0.05 * rng.normal(size=(n_rest, X.shape[1]))])
    cls = np.r_[y, np.full(n_rest, K)]
    force = np.r_[np.ones(len(y)) * 3.0, np.zeros(n_rest)]
    return Xa, cls, force, K


@pytest.mark.parametrize("views", [[(None, "none")], [(None, "level")], [(None, "unit")], [(None, "none"), (12, "level"), (None, "unit")]])
def test_lda_net_places_touches_exactly_as_its_lda_and_exports(tmp_path, views):
    """The network's closed-form layer is the artifact's LDA, frozen: after training its place is the LDA's on
    chirps the LDA is not sure of, and the export keeps it."""
    from sonicskin.models import LDASkinNet

    from sonicskin.kinds import Fitted
    from sonicskin.kinds.lda import LDAViews

    X, y, press, _ = _session(K=4, per=8, seed=1)
    X = X[:, ::10]
    Xa, cls, force, K = _with_rest(X, y)
    lda = LDAViews([(k or X.shape[1], norm) for k, norm in views]).fit(X, y)
    pred = fit_net(Xa, cls, force, n_locations=K, layer="lda", epochs=3, n_trunk=20,
                   fitted={"lda": Fitted(lda, {"views": lda.views}, X.shape[1], {})})
    assert isinstance(pred.model, LDASkinNet) and pred.model.n_trunk == 20
    Xq = X + 0.3 * np.random.default_rng(9).normal(size=X.shape)
    np.testing.assert_array_equal(pred(Xq)[0][:, :K].argmax(1), lda.predict(Xq))
    from sonicskin.export.onnx import export_net

    parity = export_net(pred.model, tmp_path / "net.onnx", Xa.astype(np.float32))
    assert parity["labels_equal"] and parity["max_abs_logits"] <= parity["logits_tol"]


def test_mlp_layer_learns_separable_markers():
    X, y, press, _ = _session(K=3, per=10, seed=3)
    X = X[:, ::20]
    Xa, cls, force, K = _with_rest(X, y)
    aug = Augmenter(X, y, press, freqs_hz=F[::20], sizes={"press": 0.3, "strength": 0.1})
    pred = fit_net(Xa, cls, force, n_locations=K, layer="mlp", augment=True, augmenter=(aug, np.r_[np.arange(len(y)), -np.ones(20, int)]),
                   epochs=30)
    logits, _ = pred(X)
    assert np.mean(logits[:, :K].argmax(1) == y) == 1.0


def test_the_network_deploys_the_svms_force_model_reports_both_and_its_head_applies_it():
    """Force is linear in the first 5 inputs; the network's head (one epoch) knows nothing of it: on presses neither
    was fitted on, the SVM's pooled ridge scores better (a known answer, reported), it is the network's force, and the
    network's head then gives exactly its force; without an SVM force model the head's own force output is the force."""
    from sonicskin.training.fit import SVM_FORCE, score_force, svm_force

    from sonicskin.force import PooledForce
    from sonicskin.kinds import Fitted
    from sonicskin.kinds.net import NetHead
    from sonicskin.rig import Layout

    rng = np.random.default_rng(5)
    K, n = 3, 240
    y = np.arange(n) % K
    F_true = rng.uniform(1, 8, n)
    X = np.column_stack([np.outer(F_true, [1.0, 0.5, -0.3, 0.8, 0.2]) + 0.05 * rng.normal(size=(n, 5)), 3.0 * rng.normal(size=(n, 20))])
    fit, val = np.arange(n) < 40, np.arange(n) >= 120
    ridge = PooledForce(1.0).fit(X[fit][:, :5], F_true[fit], y[fit])
    svm = Fitted(None, {"force": ridge.to_dict(), "energy_ref_db": 0.0}, 5, {})
    Xa, cls, force, _ = _with_rest(X[:40], y[:40])
    pred = fit_net(Xa, cls, np.r_[F_true[:40], np.zeros(20)], n_locations=K, layer="mlp", epochs=1)
    res = score_force(pred.model, X, y, F_true, val_rows=val, location_ids=np.arange(K), svm=svm, how="validation on s001")
    assert res["force"] == SVM_FORCE and res["force_rmse"][SVM_FORCE] < 0.5 * res["force_rmse"]["head"]
    assert res["force_how"].startswith("validation on s001: the SVM's ") and "head " in res["force_how"]
    unvalidated = score_force(pred.model, X, y, F_true, val_rows=val, location_ids=np.arange(K), svm=svm)
    assert unvalidated["force"] == SVM_FORCE and "force_rmse" not in unvalidated
    no_sensor = score_force(pred.model, X, y, F_true, val_rows=val, location_ids=np.arange(K), svm=None, how="validation")
    assert no_sensor["force"] == "head" and "no SVM force model" in no_sensor["force_how"]
    head = NetHead({"force": ridge.to_dict(), "force_bins": 5, "energy_ref_db": 0.0}, Layout.grid(3, 1, 1.0))
    lg, f_all = pred(X[val])
    p = head.decide([lg, f_all], X[val].astype(np.float32))
    want = svm_force(svm, X[val], p.location)
    np.testing.assert_allclose(p.force_n[p.touch], np.clip(want, 0, None)[p.touch], rtol=1e-6)
