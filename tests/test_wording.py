"""Output in the user's words (issue 20.4): record prompts say where the marker is, the live status
says why blocks were dropped at start-up, the shipped links configs are listed and usable."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
from cli_helpers import run

from sonicskin.rig import Layout


def test_record_prompt_names_the_marker_and_where_it_is(rig):
    from sonicskin.record import make_schedule

    layout = Layout(ids=(3, 7), xy_cm=np.array([[1.2, 0.0], [8.4, 2.4]]))
    texts = [p[3] for p in make_schedule(layout, [7, 3], rig) if p[0] == "touch"]
    assert texts == ["touch location 7 (marker at x 8.4 cm, y 2.4 cm) with varying force for 3 s",
                     "touch location 3 (marker at x 1.2 cm, y 0.0 cm) with varying force for 3 s"]


def test_live_status_explains_start_up_drops():
    from sonicskin.live import LiveLoop

    assert LiveLoop._startup_note(SimpleNamespace(startup_dropped=0), 0) == ""
    note = LiveLoop._startup_note(SimpleNamespace(startup_dropped=327), 330)
    assert note.startswith(" (327 at start-up, before the first chirp was framed")


def test_info_lists_the_links_configs(capsys):
    code, out, _ = run(capsys, ["info"])
    assert code == 0 and "links: two-links-frequency, two-links-time" in out


def test_live_links_needs_a_device_and_one_artifact_per_link(capsys, cli_files):
    code, _, err = run(capsys, ["live", "--links", "two-links-time"])
    assert code == 2 and ("--links two-links-time lists links of a real audio interface (no simulated scenario per "
                          "link); pass --device NAME|INDEX") in err
    code, _, err = run(capsys, ["live", "--links", "two-links-time", "--device", "0", "--link-artifact", cli_files["artifact"]])
    assert code == 2 and ("--links two-links-time has 2 links (upper-arm, forearm); pass --link-artifact DIR once per "
                          "link, in that order (got 1)") in err


def test_live_links_runs_one_loop_per_link(capsys, cli_files, monkeypatch):
    """The command line wires a links config to one loop per link on one source (audio device replaced by a
    replay of two silent-but-noisy channels: the loops run, nothing is touched, each link reports)."""
    from sonicskin import acquire
    from sonicskin.rig import Rig

    small = Rig.load(cli_files["rig"])

    class Replay(acquire._QueueSource):
        def __init__(self, rig, device=None, *, links=None, blocksize=1024, **_):
            super().__init__(rig, blocksize, max_queued_s=60)
            self.links = links
            self.finished = SimpleNamespace(is_set=lambda: True)

        def start(self):
            x = np.random.default_rng(0).normal(0, 1e-3, (small.n_chirp * 40, 2)).astype(np.float32)
            for k in range(0, len(x), self.blocksize):
                self._deliver(x[k:k + self.blocksize])

        def stop(self):
            pass

    monkeypatch.setattr(acquire, "SoundDeviceSource", Replay)
    art = str(cli_files["artifact"])
    code, _, err = run(capsys, ["live", "--links", "two-links-time", "--device", "0", "--rig", cli_files["rig"],
                                "--link-artifact", art, "--link-artifact", art, "--no-status"])
    assert code == 0, err
    summary = json.loads(err.strip().splitlines()[-1])["summary"]
    assert set(summary) == {"upper-arm", "forearm"}
    assert all(s["touch_events"] == 0 for s in summary.values())
    assert all(s["chirps"] > 0 for s in summary.values()), summary  # both loops framed their own chirp slots


def test_training_report_says_force_is_not_measurable_without_a_force_sensor(capsys):
    from sonicskin.cli.train import _report_training

    res = {"epochs": 3, "train_time_s": 1.0, "val_loss": 0.5, "val_acc": 0.9, "val_force_rmse": 0.0}
    for force, want in ((np.full(4, np.nan), "val_force_rmse n/a (no force sensor)"), (np.array([1.0, np.nan]), "val_force_rmse 0.000")):
        cli = SimpleNamespace(epoch_bar=SimpleNamespace(results=res), datamodule=SimpleNamespace(prepared=SimpleNamespace(force=force)))
        _report_training(cli)
        out = capsys.readouterr().out
        assert want in out and "val_acc 0.900" in out


def test_epoch_bar_shows_force_as_na_without_a_force_sensor():
    import pytest

    pytest.importorskip("lightning")
    from sonicskin.training.cli import EpochBar

    for force, want in ((np.full(3, np.nan), "n/a"), (np.array([2.0, np.nan]), "0")):
        shown: dict = {}
        bar = EpochBar()
        bar._bar = SimpleNamespace(set_postfix=lambda d, refresh, shown=shown: shown.update(d), update=lambda n: None)
        trainer = SimpleNamespace(callback_metrics={"val_force_rmse": 0.0, "val_acc": 0.9},
                                  datamodule=SimpleNamespace(prepared=SimpleNamespace(force=force)))
        bar.on_train_epoch_end(trainer, None)
        assert shown == {"val_force_rmse": want, "val_acc": "0.9"}
