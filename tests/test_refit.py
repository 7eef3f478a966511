"""Every press counts (issue 36): the choices are made on the validation session, then every model is refitted on
the training and validation sessions together; and the network places touches exactly as the closed form it starts
from when that is its layer."""

from __future__ import annotations

import numpy as np
import pytest

from sonicskin import kinds
from sonicskin.dataset import Split
from sonicskin.fit import fit_models, prepare, summary_lines, write_artifact
from sonicskin.runtime import SkinRuntime


def _data(cli_files, val=("s001",)):
    return prepare(cli_files["data"], split=Split(("s000",), tuple(val), ("s002",)), n_bins=60, wide=True, progress=False,
                   log=lambda *_: None)


def test_refit_fits_the_chosen_configuration_on_every_labelled_press(cli_files):
    data = _data(cli_files)
    final, fits = fit_models(data, [kinds.BASELINE, kinds.CLOSED_FORM], log=lambda *_: None)
    # the deployed data: s000 and s001 train, nothing validates, the test session untouched
    assert final.split.train == ("s000", "s001") and final.split.val == () and final.split.test == ("s002",)
    assert final.options["refit_of"] == {"train": ["s000"], "val": ["s001"], "test": ["s002"]}
    touch = final.rows("train") & (final.cls < final.n_locations)
    once = data.rows("train") & (data.cls < data.n_locations)
    assert touch.sum() > once.sum()  # the validation presses joined the training ones
    assert fits[kinds.BASELINE].model[-1].shape_fit_[0] == touch.sum()  # the SVM was fitted on all of them
    # the choices are the first pass's: the LDA's bins and normalisation, the SVM's C and kernel width
    _, first = fit_models(data, [kinds.BASELINE, kinds.CLOSED_FORM], refit=False, log=lambda *_: None)
    assert fits[kinds.CLOSED_FORM].selection == first[kinds.CLOSED_FORM].selection
    assert fits[kinds.BASELINE].selection["svm"]["params"] == first[kinds.BASELINE].selection["svm"]["params"]
    assert first[kinds.BASELINE].model[-1].shape_fit_[0] == once.sum()  # --no-refit: the training session alone


def test_the_artifact_says_it_was_refitted_and_on_what(cli_files, tmp_path):
    final, fits = fit_models(_data(cli_files), [kinds.BASELINE], log=lambda *_: None)
    skin = write_artifact(final, tmp_path / "art", fits, log=lambda *_: None)
    assert skin["training"]["split"] == {"train": ["s000"], "val": ["s001"], "test": ["s002"]} and skin["training"]["refit"]
    assert "deployed models refitted on s000 + s001 (every labelled press; the estimates above are from the held-out pass)" \
        in summary_lines(tmp_path / "art", skin)
    nothing_to_validate, _ = fit_models(_data(cli_files, val=()), [kinds.BASELINE], log=lambda *_: None)
    assert nothing_to_validate.split.train == ("s000",)  # no validation session: nothing to refit


def test_the_network_with_the_lda_layer_places_every_chirp_where_the_lda_does(cli_files, tmp_path):
    """Through the deployed artifact (onnxruntime, both heads): the same marker on every test chirp."""
    pytest.importorskip("torch")
    data = _data(cli_files)
    final, fits = fit_models(data, [kinds.NETWORK], log=lambda *_: None,
                             options={kinds.NETWORK: {"epochs": 2, "layer": {"location_layer": "LDA (closed form)",
                                                                             "layer_how": "test"}}})
    write_artifact(final, tmp_path / "art", fits, log=lambda *_: None)
    t = final.table
    X = t.X[t["session"] == "s002"]
    net, lda = SkinRuntime(tmp_path / "art", kinds.NETWORK), SkinRuntime(tmp_path / "art", kinds.CLOSED_FORM)
    pn, pl = net.replay(X, t["time_s"][t["session"] == "s002"]), lda.replay(X, t["time_s"][t["session"] == "s002"])
    run = ~pn.calibrating
    np.testing.assert_array_equal(pn.location[run], pl.location[run])


def test_the_networks_frozen_kernel_is_the_artifacts_svm(cli_files):
    """One SVM per artifact (issue 34): a kernel-layer network freezes the very SVM svm.onnx holds, before and after
    the refit (its support vectors are the kernel's centres, its scaler the network's normalisation)."""
    pytest.importorskip("torch")
    for refit in (False, True):
        _, fits = fit_models(_data(cli_files), [kinds.NETWORK], refit=refit, log=lambda *_: None,
                             options={kinds.NETWORK: {"epochs": 1, "layer": {"location_layer": "kernel", "layer_how": "test",
                                                                             "hparams": {"layer": "kernel", "n_inputs": 60}}}})
        pipe, net = fits[kinds.BASELINE].model, fits[kinds.NETWORK].model
        np.testing.assert_allclose(net.kernel.centres.detach().numpy(), pipe[-1].support_vectors_, rtol=1e-6)
        np.testing.assert_allclose(net.mean.numpy(), pipe[0].mean_, rtol=1e-6)


def test_the_networks_detector_thresholds_the_svms_statistic_over_the_svms_bins(cli_files, tmp_path):
    """Without a validation session the network reports a touch where the SVM's input-RMS detector does or its own
    logit does.  The SVM's threshold holds for the RMS over the SVM's own bins (here 60 of the network's 250 inputs):
    applied over all 250, the network called every test chirp touched (as on the moving robot at short chirps, where
    the SVM validated 100 bins: stored result ``probe``).  Through onnxruntime, on every test chirp."""
    pytest.importorskip("torch")
    data = _data(cli_files, val=())
    final, fits = fit_models(data, [kinds.NETWORK], log=lambda *_: None, options={kinds.NETWORK: {"epochs": 2}})
    assert fits[kinds.NETWORK].selection[kinds.NETWORK]["detector"] == "either"
    assert fits[kinds.NETWORK].entry["detector"]["bins"] == fits[kinds.BASELINE].entry["detector_bins"] < data.X.shape[1]
    write_artifact(final, tmp_path / "art", fits, log=lambda *_: None)
    t = final.table
    s = t["session"] == "s002"
    pn = SkinRuntime(tmp_path / "art", kinds.NETWORK).replay(t.X[s], t["time_s"][s])
    ps = SkinRuntime(tmp_path / "art", kinds.BASELINE).replay(t.X[s], t["time_s"][s])
    run, rest = ~pn.calibrating, ~pn.calibrating & (t["location"][s] < 0)
    assert run.sum() > 10 and rest.sum() > 10
    assert np.all(pn.touch[run] >= ps.touch[run])  # every touch the SVM reports, the network reports
    assert pn.touch[rest].mean() <= ps.touch[rest].mean() + 0.1  # and its own logit adds few on rest chirps


def test_a_layer_given_by_hand_is_refitted_as_it_is(cli_files):
    """A layer given by hand stands: the first pass and the refit on s000 + s001 both train it (the deployed graph an
    MLP, not the closed form's ``LDASkinNet``)."""
    pytest.importorskip("torch")
    from sonicskin.models import LDASkinNet

    layer = {"location_layer": "MLP, every bin", "layer_how": "test"}
    for refit in (False, True):
        _, fits = fit_models(_data(cli_files), [kinds.NETWORK], refit=refit, log=lambda *_: None,
                             options={kinds.NETWORK: {"epochs": 1, "layer": layer}})
        sel = fits[kinds.NETWORK].selection[kinds.NETWORK]
        assert (sel["location_layer"], sel["layer_how"]) == ("MLP, every bin", "test")
        assert not isinstance(fits[kinds.NETWORK].model, LDASkinNet)


def test_with_a_refit_to_follow_the_network_trains_no_mlp_to_validate(cli_files, monkeypatch):
    """The refit would train the closed form in any case: the validation pass chooses it without training MLP folds,
    so its touch decision is chosen on the layer that is deployed."""
    pytest.importorskip("torch")
    import sonicskin.training.fit as tfit
    from sonicskin.training.quick import UNVALIDATED

    chose = []
    real = tfit.choose_layer
    monkeypatch.setattr(tfit, "choose_layer", lambda *a, **k: chose.append(1) or real(*a, **k))
    for refit in (True, False):
        chose.clear()
        _, fits = fit_models(_data(cli_files), [kinds.NETWORK], refit=refit, log=lambda *_: None,
                             options={kinds.NETWORK: {"epochs": 1}})
        sel = fits[kinds.NETWORK].selection[kinds.NETWORK]
        if refit:
            assert not chose and sel["location_layer"] == UNVALIDATED
            assert sel["layer_how"].startswith("the closed form: a refit on every labelled press follows")
        else:
            assert chose and sel["layer_how"].startswith("validation on s001")


def test_sonicskin_train_knows_whether_export_refits(cli_files):
    """``sonicskin train`` chooses its layer before ``export`` refits: with a validation session the datamodule marks
    that a refit follows (so the layer is the closed form), unless ``--no-refit`` (``--data.refit false``)."""
    pytest.importorskip("lightning")
    from sonicskin.training.data import SkinDataModule

    from sonicskin.cli.parser import build_parser
    from sonicskin.cli.train import lightning_overrides

    for argv, follows in ((["--val", "s001"], True), (["--val", "s001", "--no-refit"], False), (["--val", "none"], False)):
        a, _ = build_parser().parse_known_args(["train", "--data", str(cli_files["data"]), *argv])
        over = lightning_overrides(a, 60)
        assert ("--data.refit" in over) == ("--no-refit" in argv)
        dm = SkinDataModule(str(cli_files["data"]), n_bins=60, train_sessions=["s000"],
                            val_sessions=[] if "none" in argv else ["s001"], refit="--no-refit" not in argv)
        dm.setup("fit")
        assert dm.prepared.refit_follows is follows
