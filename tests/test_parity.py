"""Export parity judged on what the artifact decides (issue 27.1): the location, the touch decision, and outputs
within a bound relative to their scale; rounding never fails a valid export, a real mismatch is one line."""

import numpy as np
import pytest

from sonicskin.parity import PARITY_TOL, ParityError, decisions_parity, parity_bound


def _logits(seed=0, n=50, K=5, scale=100.0):
    """Log-probability-like logits: winners well ahead (gap >= 1), values down to -scale."""
    rng = np.random.default_rng(seed)
    lg = -rng.uniform(5, scale, (n, K + 1))
    lg[np.arange(n), rng.integers(0, K, n)] = -rng.uniform(0, 1, n)  # the winner, far ahead of the rest
    lg[:, -1] = -rng.uniform(2, 4, n)  # no touch unlikely: touch margin >= 1
    return lg


def _margin(lg):
    from scipy.special import logsumexp

    return logsumexp(lg[:, :-1], axis=1) - lg[:, -1]


def _judge(got, ref, vote_tie=None, f_got=None, f_ref=None):
    f_ref = np.ones((len(ref), ref.shape[1] - 1)) if f_ref is None else f_ref
    f_got = f_ref if f_got is None else f_got
    return decisions_parity({"logits": got, "force_n": f_got}, {"logits": ref, "force_n": f_ref}, label="logits",
                            label_cols=slice(0, -1), touch=(_margin(got), _margin(ref)), vote_tie=vote_tie,
                            every_chirp=("force_n",))


def test_the_bound_is_relative_to_the_scale_of_the_outputs():
    assert parity_bound(np.array([[-100.0, 3.0]])) == pytest.approx(100 * PARITY_TOL)
    assert parity_bound(np.array([0.2, -0.5])) == PARITY_TOL  # at least 1 x PARITY_TOL
    assert parity_bound(np.array([np.nan, -np.inf, 2.0])) == pytest.approx(2 * PARITY_TOL)  # finite values only


def test_float32_rounding_of_large_logits_passes_and_is_reported():
    """The README's WAV walkthrough failed at max |d logits| 1.05e-4 on labels that all agreed (a fixed 1e-4 bound)."""
    ref = _logits()
    got = ref + np.random.default_rng(1).choice([-1.3e-4, 1.3e-4], ref.shape)
    par = _judge(got, ref)
    assert par["ok"] and par["labels_equal"] and par["touch_equal"] and par["near_ties"] == 0
    assert par["max_abs_logits"] == pytest.approx(1.3e-4) and par["logits_tol"] == pytest.approx(PARITY_TOL * np.abs(ref).max())


def test_a_different_label_fails():
    ref = _logits()
    got = ref.copy()
    k = int(np.argmax(ref[3, :-1]))
    got[3, (k + 1) % 5] = ref[3, k] + 0.5  # another location wins by half a logit on chirp 3
    par = _judge(got, ref)
    assert not par["ok"] and par["labels_equal"] is False


def test_a_different_touch_decision_fails():
    ref = _logits()
    got = ref.copy()
    got[7, -1] = 5.0  # no touch wins on chirp 7
    par = _judge(got, ref)
    assert not par["ok"] and par["touch_equal"] is False and par["labels_equal"] is True


def test_a_label_decided_within_rounding_is_a_near_tie_not_a_failure():
    ref = _logits()
    k = int(np.argmax(ref[4, :-1]))
    ref[4, (k + 1) % 5] = ref[4, k] - 1e-5  # the two best locations within rounding
    got = ref.copy()
    got[4, [k, (k + 1) % 5]] = got[4, [(k + 1) % 5, k]]  # onnxruntime picks the other one
    par = _judge(got, ref)
    assert par["ok"] and par["near_ties"] == 1 and par["labels_equal"]


def test_a_flipped_vote_is_accepted_only_where_a_pairwise_decision_was_within_rounding():
    ref = _logits()
    got = ref.copy()
    got[9, :-1] += np.array([2.0, -2.0, 0.0, 0.0, 0.0])  # a whole vote moved between locations 0 and 1
    tie = np.zeros(len(ref), bool)
    assert not _judge(got, ref, vote_tie=tie)["ok"]  # no pairwise decision near zero: a real mismatch
    tie[9] = True
    par = _judge(got, ref, vote_tie=tie)
    assert par["ok"] and par["votes_flipped"] == 1 and par["max_abs_logits"] == 0.0
    par = _judge(ref, ref, vote_tie=tie)  # a potential tie whose vote did not flip is judged as every other chirp
    assert par["ok"] and par["votes_flipped"] == 0


def test_the_force_is_judged_on_every_chirp_against_its_own_scale():
    ref = _logits()
    f_ref = np.full((len(ref), 5), 12.0)
    tie = np.ones(len(ref), bool)
    par = _judge(ref, ref, vote_tie=tie, f_ref=f_ref, f_got=f_ref + 0.011)  # within 12 N x 1e-3
    assert par["ok"] and par["force_n_tol"] == pytest.approx(0.012)
    par = _judge(ref, ref, vote_tie=tie, f_ref=f_ref, f_got=f_ref + np.where(np.arange(5) == 2, 0.5, 0.0))
    assert not par["ok"] and par["max_abs_force_n"] == pytest.approx(0.5)


def test_nan_in_onnxruntime_output_fails():
    ref = _logits()
    got = ref.copy()
    got[0, 0] = np.nan
    assert not _judge(got, ref)["ok"]


def _toy_net():
    pytest.importorskip("torch")
    pytest.importorskip("onnxruntime")
    from sonicskin.training.quick import fit_net
    from test_net import _toy

    X, cls, force = _toy()
    return X, fit_net(X, cls, force, n_locations=4, epochs=1, seed=0)


def _altered(real, change):
    """A stand-in for ``ort_session``: the real session, its outputs passed through ``change`` (an onnxruntime that
    computes otherwise than the exporter's original)."""
    class Altered:
        def __init__(self, path):
            self.s = real(path)

        def get_inputs(self):
            return self.s.get_inputs()

        def run(self, names, feeds):
            return change(*self.s.run(names, feeds))

    return Altered


def test_a_real_network_mismatch_is_one_line_with_the_fix(tmp_path, monkeypatch):
    import onnxruntime
    import torch
    from sonicskin.export import onnx as ex

    X, predict = _toy_net()
    def shifted(lg, f):  # an onnxruntime whose force output is 0.5 N off on one location
        f[:, 2] += 0.5
        return lg, f

    monkeypatch.setattr(ex, "ort_session", _altered(ex.ort_session, shifted))
    tol = parity_bound(predict(X)[1])
    with pytest.raises(ParityError) as e:
        ex.export_net(predict.model, tmp_path / "net.onnx", X)
    assert str(e.value) == (
        f"the exported net.onnx does not decide as the torch network does on its {len(X)} check chirps (max |d force_n| "
        f"0.5 > {tol:.2g}): onnxruntime {onnxruntime.__version__} runs the graph torch {torch.__version__} exported "
        f"differently; reinstall the tested versions (pip install -c constraints.txt -e '.[train]') and export again")


def test_a_real_svm_mismatch_is_one_line_with_the_fix(tmp_path, monkeypatch):
    import onnxruntime
    import sklearn

    from sonicskin.kinds import svm

    rng = np.random.default_rng(0)
    cls = np.repeat(np.arange(3), 20)
    X = (rng.normal(0, 1, (3, 8))[cls] * 3 + rng.normal(0, 0.3, (60, 8))).astype(np.float32)
    pipe = svm.fit_pipeline(X, cls, 3)
    assert svm.export_pipeline(pipe, tmp_path / "ok.onnx", X)["labels_equal"]
    # an onnxruntime whose pairwise decisions come out negated
    monkeypatch.setattr(svm, "ort_session", _altered(svm.ort_session, lambda label, ovo: (label, -ovo)))
    with pytest.raises(ParityError, match=r"^the exported svm\.onnx does not decide as scikit-learn's SVM does on its 60 "
                       r"check chirps \(the location differs; max \|d scores\| [\d.]+ > [\d.e-]+; max \|d decision\| [\d.]+ > "
                       rf"[\d.e-]+\): onnxruntime {onnxruntime.__version__} runs the graph skl2onnx wrote differently from "
                       rf"scikit-learn {sklearn.__version__}; reinstall the package's dependencies \(pip install -c "
                       r"constraints\.txt -e \.\) and fit again$"):
        svm.export_pipeline(pipe, tmp_path / "svm.onnx", X)
