"""The network's kernel layer: it starts as the SVM (same decision values and predictions), trains its
force head without moving the SVM's localization, and exports to ONNX with parity."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sonicskin.models import KernelVotes, SkinNet  # noqa: E402
from sonicskin.training.quick import fit_net  # noqa: E402

from sonicskin.kinds import Fitted  # noqa: E402
from sonicskin.kinds.svm import fit_pipeline, ovr_scores_from_ovo  # noqa: E402


def _toy(n_per=30, K=4, d=12, seed=0):
    """K clusters in d dims (raw scale and offset unlike unit variance, as dB features); force scales the signature."""
    centres = np.random.default_rng(0).normal(0, 1.0, (K, d))  # the same locations for every draw
    rng = np.random.default_rng(100 + seed)
    cls = np.repeat(np.arange(K), n_per)
    force = rng.uniform(1, 10, cls.size)
    X = 5.0 + 3.0 * (centres[cls] * (0.5 + force[:, None] / 10) + rng.normal(0, 0.35, (cls.size, d)))
    return X.astype(np.float32), cls, force.astype(np.float32)


def _kernel_net(X, cls, force, **kw):
    """fit_net with the kernel layer: the SVM of (X, cls), frozen (as the SVM kind fits it)."""
    pipe = fit_pipeline(X[cls < 4], cls[cls < 4], 4)
    return fit_net(X, cls, force, n_locations=4, layer="kernel", fitted={"svm": Fitted(pipe, {}, X.shape[1], {})}, **kw)


def _svm_location(pipe, X):
    return ovr_scores_from_ovo(pipe.decision_function(X), pipe[-1].classes_.size).argmax(1)


@pytest.mark.parametrize("K", [4, 2])
def test_kernel_layer_reproduces_the_svm_decision_values_and_votes(K):
    X, cls, _ = _toy(K=K)
    pipe = fit_pipeline(X, cls, int(cls.max()) + 1)
    layer = KernelVotes.from_svc(pipe[-1], K)
    Xq, _, _ = _toy(K=K, seed=1)
    z = torch.from_numpy(pipe[0].transform(Xq).astype(np.float32))
    with torch.no_grad():
        scores, phi = layer(z)
        d = layer.decision(phi).numpy()
    ref = pipe.decision_function(Xq)  # libsvm order and sign; scikit-learn's binary d is the other way round
    np.testing.assert_allclose(d, ref if K > 2 else -ref[:, None], atol=1e-4)
    # RBF activations are the kernel values exp(-gamma |z - sv|^2)
    sv = pipe[-1].support_vectors_
    k = np.exp(-pipe[-1]._gamma * ((pipe[0].transform(Xq)[:, None, :] - sv[None]) ** 2).sum(-1))
    np.testing.assert_allclose(phi.numpy(), k, atol=1e-5)
    # 2 x (2 x the SVM's one-vs-rest scores (votes, ties broken by confidence) - (K - 1)): the same location, and
    # 4 x the vote count (+ a constant), the runtime's sharpening of the SVM's votes for the continuous position
    np.testing.assert_allclose(scores.numpy(), 2.0 * (2 * ovr_scores_from_ovo(ref, K) - (K - 1)), atol=2e-4)


def test_kernel_layer_rejects_what_it_cannot_copy():
    X, cls, _ = _toy()
    with pytest.raises(ValueError, match="RBF SVC"):
        from sklearn.svm import SVC
        KernelVotes.from_svc(SVC(kernel="linear").fit(X, cls), 4)
    pipe = fit_pipeline(X[cls < 3], cls[cls < 3], 3)
    with pytest.raises(ValueError, match="classes"):
        KernelVotes.from_svc(pipe[-1], 4)
    with pytest.raises(ValueError, match="support vectors"):
        SkinNet(12, 3, n_centres=5).init_from_svm(pipe)


def _net_from_svm(query_seed: int):
    """A SkinNet initialised from an SVM of the toy data, the SVM, and toy queries of another seed."""
    X, cls, _ = _toy()
    pipe = fit_pipeline(X, cls, int(cls.max()) + 1)
    net = SkinNet(X.shape[1], 4, n_centres=pipe[-1].support_vectors_.shape[0]).eval()
    net.init_from_svm(pipe)
    return net, pipe, _toy(seed=query_seed)[0]


def test_skinnet_starts_as_the_svm_on_raw_features():
    net, pipe, Xq = _net_from_svm(2)
    with torch.no_grad():
        logits, force = net(torch.from_numpy(Xq))
    assert logits.shape == (len(Xq), 5) and force.shape == (len(Xq), 4)  # 4 locations + no touch
    np.testing.assert_array_equal(logits[:, :4].numpy().argmax(1), _svm_location(pipe, Xq))


def test_fit_net_keeps_the_svm_localization_and_learns_force():
    X, cls, force = _toy(n_per=40)
    rest = np.random.default_rng(3).normal(5.0, 0.3, (60, X.shape[1])).astype(np.float32)  # no-touch chirps: class K
    Xa = np.vstack([X, rest])
    ca = np.concatenate([cls, np.full(len(rest), 4)])
    fa = np.concatenate([force, np.full(len(rest), np.nan, np.float32)])
    svm = fit_pipeline(X, cls, 4)
    predict = fit_net(Xa, ca, fa, n_locations=4, epochs=60, seed=0, layer="kernel", fitted={"svm": Fitted(svm, {}, 12, {})})
    Xq, cq, fq = _toy(n_per=20, seed=4)
    logits, f_all = predict(Xq)
    np.testing.assert_array_equal(logits[:, :4].argmax(1), _svm_location(svm, Xq))  # frozen kernel layer = the SVM
    assert (logits.argmax(1) < 4).mean() > 0.95  # touches are not called no-touch
    rest_q = np.random.default_rng(5).normal(5.0, 0.3, (50, X.shape[1])).astype(np.float32)
    assert (predict(rest_q)[0].argmax(1) == 4).mean() > 0.95
    f_hat = f_all[np.arange(len(cq)), cq]
    rmse = np.sqrt(np.mean((f_hat - fq) ** 2))
    assert rmse < 0.7 * fq.std()  # the force head learned the force (predicting the mean: 1.0)


def test_kernel_layer_trains_through_its_votes():
    X, cls, _ = _toy()
    pipe = fit_pipeline(X, cls, int(cls.max()) + 1)
    layer = KernelVotes.from_svc(pipe[-1], 4)
    scores, _ = layer(torch.from_numpy(pipe[0].transform(X).astype(np.float32)))
    torch.nn.functional.cross_entropy(scores, torch.from_numpy(cls)).backward()
    assert all(q.grad is not None and torch.isfinite(q.grad).all() and q.grad.abs().sum() > 0 for q in layer.parameters())


def test_kernel_net_exports_to_onnx_with_parity(tmp_path):
    pytest.importorskip("onnxruntime")
    from sonicskin.export.onnx import export_net

    X, cls, force = _toy()
    predict = _kernel_net(X, cls, force, epochs=2, seed=0)
    parity = export_net(predict.model, tmp_path / "net.onnx", X)
    assert parity["labels_equal"] and parity["touch_equal"] and parity["max_abs_logits"] <= parity["logits_tol"]
    assert parity["max_abs_force_n"] <= parity["force_n_tol"]


def _softmax(z):
    e = np.exp(z - z.max(1, keepdims=True))
    return e / e.sum(1, keepdims=True)


def test_touch_and_place_are_factorised_and_weigh_markers_as_the_svm_runtime():
    """p(no touch) is the trunk's sigmoid alone; the location distribution given a touch is the softmax of
    4 x the SVM's vote counts, the weights the SVM runtime gives the continuous-position centroid."""
    net, pipe, Xq = _net_from_svm(3)
    with torch.no_grad():
        logits = net(torch.from_numpy(Xq))[0].numpy().astype(np.float64)
        t = net.location(net.trunk(net.standardize(torch.from_numpy(Xq))))[:, 0].numpy()
    p = _softmax(logits)
    np.testing.assert_allclose(p[:, -1], 1 / (1 + np.exp(t)), rtol=1e-4)
    ovr = ovr_scores_from_ovo(pipe.decision_function(Xq), 4)
    np.testing.assert_allclose(p[:, :4] / p[:, :4].sum(1, keepdims=True), _softmax(4.0 * ovr), atol=1e-4)


@pytest.mark.parametrize("bias", [-60.0, 60.0])
def test_saturated_touch_logit_exports_finite(tmp_path, bias):
    """A trunk sure of touch / no touch: onnxruntime's Sigmoid underflows there, the exported log-probabilities must not."""
    pytest.importorskip("onnxruntime")
    from sonicskin.export.onnx import export_net

    X, cls, force = _toy()
    predict = _kernel_net(X, cls, force, epochs=1, seed=0)
    with torch.no_grad():
        predict.model.location.bias.fill_(bias)
    parity = export_net(predict.model, tmp_path / "net.onnx", X)
    assert parity["labels_equal"] and parity["max_abs_logits"] <= parity["logits_tol"]


def test_rest_mix_adds_rest_deviations_to_touch_chirps_only():
    from sonicskin.training.module import SkinLitModule

    m = SkinLitModule(n_in=6, n_locations=3, kernel=False, noise_db=0.0, rest_mix=1.0)
    seen = []
    forward = m.model.forward
    m.model.forward = lambda x: (seen.append(x.clone()), forward(x))[1]
    g = torch.Generator().manual_seed(0)
    x = torch.randn(40, 6, generator=g)
    cls = torch.tensor([0, 1, 2, 3] * 10)  # class 3: no touch
    force = torch.where(cls < 3, 2.0, float("nan"))
    m.loss_terms(x, cls, force, train=True)
    rest = cls == 3
    assert torch.equal(seen[0][rest], x[rest])  # no-touch chirps are real noise already
    dev = seen[0][~rest] - x[~rest]
    assert dev.abs().sum() > 0
    # every added vector is one of the no-touch chirps' deviations from their mean
    pool = x[rest] - x[rest].mean(0)
    assert all(torch.isclose(pool, d, atol=1e-6).all(1).any() for d in dev)
    m.loss_terms(x, cls, force, train=False)
    assert torch.equal(seen[1], x)  # evaluation sees the inputs as they are


def test_export_parity_holds_at_a_vote_tie(tmp_path):
    """A chirp on the boundary between two locations (pairwise decision ~ 0) may vote either way in float32:
    the export counts it as a near tie instead of failing on a whole vote's difference (seen on multi-person)."""
    pytest.importorskip("onnxruntime")
    from sonicskin.export.onnx import export_net

    X, cls, force = _toy()
    predict = _kernel_net(X, cls, force, epochs=1, seed=0)
    net = predict.model
    a, b = X[cls == 0][0].astype(np.float64), X[cls == 1][0].astype(np.float64)

    def d01(w):  # the (0, 1) pairwise decision value at a + w (b - a)
        x = torch.from_numpy((a + w * (b - a))[None].astype(np.float32))
        with torch.no_grad():
            return float(net.kernel.decision(net.kernel.rbf(net.standardize(x)))[0, 0])

    lo, hi = 0.0, 1.0
    assert d01(lo) > 0 > d01(hi)  # votes for 0 at a, for 1 at b
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if d01(mid) > 0 else (lo, mid)
    edge = (a + lo * (b - a)).astype(np.float32)
    parity = export_net(net, tmp_path / "net.onnx", np.vstack([X, edge[None]]))
    assert parity["labels_equal"] and parity["max_abs_logits"] <= parity["logits_tol"]
