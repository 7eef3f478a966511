"""The guided recording session: prompts -> dataset, interruption and resume, force logs."""

import numpy as np
import pytest

from sonicskin.cli import main
from sonicskin.dataset import Dataset
from sonicskin.record import CsvForce, recorded_locations


def test_record_on_the_simulated_device_then_fit_svm(tmp_path):
    out = tmp_path / "rec"
    assert main(["record", "--out", str(out), "--fast", "--scenario", "two-points", "--moving-s", "1"]) == 0
    ds = Dataset(out)
    frames, lab = ds.read_session("s000")
    assert (ds.root / "s000" / "session.json").exists()
    assert set(lab["segment"]) == {"calibration", "moving", "touch", "gap"}
    assert recorded_locations(out) == {0, 1}
    # Labels follow the prompts; the simulated sensor's force rises inside each touch prompt only.
    touch = lab["location"] >= 0
    assert np.all(lab["segment"][touch] == "touch") and lab["force_n"][touch].max() > 1.0
    assert np.all(lab["force_n"][lab["segment"] == "calibration"] == 0)
    assert (lab["moving"] > 0).sum() == (lab["segment"] == "moving").sum() > 0
    # The recording trains the paper's system (torch-free); a partial one says what is missing.
    assert main(["fit-svm", "--data", str(out), "--out", str(tmp_path / "art"), "--n-bins", "50"]) == 0
    part = tmp_path / "part"
    assert main(["record", "--out", str(part), "--fast", "--locations", "3", "--moving-s", "0"]) == 0
    assert main(["fit-svm", "--data", str(part), "--out", str(tmp_path / "art2")]) == 2


def test_interrupted_recording_keeps_parts_and_resumes(tmp_path, monkeypatch):
    import sonicskin.record as rec

    out = tmp_path / "rec"
    real_run = rec.Recorder.run

    def interrupted(self):  # Ctrl-C after the third prompt (calibration, location 0, release)
        orig_write = self.w.write_part

        def write_part(session, part, audio, labels):
            orig_write(session, part, audio, labels)
            if part == 2:
                raise KeyboardInterrupt

        self.w.write_part = write_part
        return real_run(self)

    monkeypatch.setattr(rec.Recorder, "run", interrupted)
    assert main(["record", "--out", str(out), "--fast", "--locations", "0", "1", "2", "--moving-s", "0"]) == 130
    monkeypatch.undo()
    assert recorded_locations(out) == {0}
    assert not (out / "s000" / "session.json").exists()
    assert main(["record", "--out", str(out), "--fast", "--locations", "0", "1", "2", "--moving-s", "0", "--resume"]) == 0
    assert recorded_locations(out) == {0, 1, 2}
    assert Dataset(out).sessions == ["s000", "s001"]
    # Everything recorded before the interruption is still readable.
    assert Dataset(out).read_session("s000")[0].shape[0] > 28


def test_force_log(tmp_path):
    p = tmp_path / "f.csv"
    p.write_text("t_s,force_n\n0,0\n1,2\n2,4\n")
    f = CsvForce(p)
    assert f.force(1.5) == pytest.approx(3.0) and np.isnan(f.force(5.0))
    p.write_text("time,newton\n0,0\n")
    with pytest.raises(ValueError, match="t_s,force_n"):
        CsvForce(p)
