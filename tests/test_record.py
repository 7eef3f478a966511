"""The guided recording session: prompts -> dataset, labels that match real presses, interruption
and resume, force logs.

On the simulated device the simulated sensors report where the finger really was (``x_cm``/``y_cm``
of touch rows) and the measured force, so every labelled chirp can be checked against the truth.
"""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from cli_helpers import reseal

from sonicskin.cli import main
from sonicskin.dataset import Dataset
from sonicskin.record import CsvForce, location_counts, recorded_locations
from sonicskin.selection import press_ids
from sonicskin.sim import Scenario


def location_presses(out) -> dict[int, int]:
    """Presses per pressed location (``record --resume``'s count)."""
    return {v: c[2] for v, c in location_counts(out).items() if c[2]}


# Short prompts keep a session at ~120 chirps (3 s of hands-off: Alg. 2's beta for relative features).
FAST = ["--fast", "--calibration-s", "3", "--moving-s", "0", "--touch-s", "1.2", "--gap-s", "0.3"]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The stationary CFRP link with six markers (ids 0..5, 1.2 cm apart) instead of 31."""
    d = Scenario.load("stationary").to_dict()
    d.update(name="small", layout={"kind": "grid", "nx": 3, "ny": 2, "spacing_cm": 1.2, "x0_cm": 2.4, "y0_cm": 11.9})
    path = tmp_path_factory.mktemp("scenario") / "small.yaml"
    path.write_text(yaml.safe_dump(d))
    return str(path)


def label_truth(out) -> dict[int, dict[str, int]]:
    """Per labelled location: chirps, chirps whose true contact is not at that marker, chirps at >= 0.5 N."""
    ds = Dataset(out)
    ids = np.array(ds.layout.ids)
    res: dict[int, dict[str, int]] = {}
    for s in ds.sessions:
        _, lab = ds.read_session(s)
        m = lab["location"] >= 0
        xy = np.column_stack([lab["x_cm"][m], lab["y_cm"][m]])
        d = ds.layout.distance_cm(xy[:, None, :], ds.layout.xy_cm[None])
        nearest = ids[np.argmin(np.nan_to_num(d, nan=np.inf), axis=1)]
        wrong = ~np.isfinite(xy).all(axis=1) | (nearest != lab["location"][m])
        for loc, bad, f in zip(lab["location"][m], wrong, lab["force_n"][m]):
            r = res.setdefault(int(loc), {"chirps": 0, "wrong": 0, "pressed": 0})
            r["chirps"] += 1
            r["wrong"] += int(bad)
            r["pressed"] += int(f >= 0.5)
    return res


def assert_real_presses(out, locations) -> None:
    """Every labelled touch chirp is a press at that marker; each location mostly at >= 0.5 N."""
    truth = label_truth(out)
    assert set(truth) == set(locations)
    for loc, r in truth.items():
        assert r["wrong"] == 0, f"location {loc}: {r['wrong']} of {r['chirps']} labelled chirps pressed elsewhere"
        assert r["pressed"] >= 0.7 * r["chirps"], f"location {loc}: only {r['pressed']} of {r['chirps']} chirps at >= 0.5 N"


def test_record_on_the_simulated_device_then_fit_svm(tmp_path):
    out = tmp_path / "rec"
    assert main(["record", "--out", str(out), "--fast", "--scenario", "two-points", "--moving-s", "1"]) == 0
    ds = Dataset(out)
    frames, lab = ds.read_session("s000")
    assert (ds.root / "s000" / "session.json").exists()
    assert set(lab["segment"]) == {"calibration", "moving", "touch", "gap"}
    assert recorded_locations(out) == {0, 1}
    assert_real_presses(out, [0, 1])
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


@pytest.mark.parametrize("locations", [[3, 4, 5], [0, 4, 5], [5, 1]])
def test_subsets_label_only_real_presses(tmp_path, small, locations):
    """Skipped locations leave no gap: the person presses the prompted marker, in the prompted order."""
    out = tmp_path / "rec"
    assert main(["record", "--out", str(out), "--scenario", small, "--locations", *map(str, locations), *FAST]) == 0
    assert_real_presses(out, locations)
    _, lab = Dataset(out).read_session("s000")
    loc = lab["location"][lab["location"] >= 0]
    assert list(dict.fromkeys(loc.tolist())) == locations  # prompted order
    assert np.array_equal(lab["chirp"], np.arange(lab["chirp"].size))  # one row per chirp, in stream order
    assert np.allclose(np.diff(lab["t_s"]), Dataset(out).rig.period_s)  # no chirp skipped or doubled


def _interrupt_after(monkeypatch, n_blocks: int) -> None:
    """Ctrl-C after ``n_blocks`` audio blocks have been read (anywhere in a prompt)."""
    from sonicskin.acquire import SimulatedSource

    real_read = SimulatedSource.read
    count = {"n": 0}

    def read(self, timeout=1.0):
        count["n"] += 1
        if count["n"] > n_blocks:
            raise KeyboardInterrupt
        return real_read(self, timeout)

    monkeypatch.setattr(SimulatedSource, "read", read)


@pytest.mark.parametrize("seed", [1, 2])
def test_interrupt_at_a_random_moment_then_resume(tmp_path, small, monkeypatch, capsys, seed):
    out = tmp_path / "rec"
    want = [0, 1, 2, 3, 4, 5]
    args = ["record", "--out", str(out), "--scenario", small, *FAST]
    # A full session is ~120 chirps x 20 blocks; stop somewhere in its touch prompts.
    n_blocks = int(np.random.default_rng(seed).integers(600, 2200))
    _interrupt_after(monkeypatch, n_blocks)
    assert main(args) == 130
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert "interrupted" in err and "finished prompts" in err
    ds = Dataset(out)
    assert ds.sessions == ["s000"] and not (out / "s000" / "session.json").exists()
    before = recorded_locations(out)
    assert before < set(want)
    if before:  # what was kept before the interruption is intact and true
        assert_real_presses(out, sorted(before))
    n_before = ds.read_session("s000")[0].shape[0]
    # Resume records exactly the missing presses of the three passes (record's default) and says which.
    have = location_presses(out)
    short = {v: 3 - have.get(v, 0) for v in want if have.get(v, 0) < 3}
    assert main([*args, "--resume"]) == 0
    assert (f"resuming: recording {sum(short.values())} missing press(es) at {len(short)} location(s): "
            f"{next(iter(short))} (") in capsys.readouterr().err
    _, lab1 = Dataset(out).read_session("s001")
    got = press_ids(lab1["location"], np.zeros(len(lab1["location"]), int))
    pressed = [int(lab1["location"][got == k][0]) for k in np.unique(got[got >= 0])]
    assert sorted(pressed) == sorted(v for v, k in short.items() for _ in range(k))
    assert Dataset(out).read_session("s000")[0].shape[0] == n_before  # nothing recorded before is lost
    assert_real_presses(out, want)
    assert recorded_locations(out) == set(want) and location_presses(out) == dict.fromkeys(want, 3)
    assert main([*args, "--resume"]) == 0
    assert "all 6 requested locations have 3 presses; nothing to record" in capsys.readouterr().err
    # The two sessions together train an SVM over every location.
    art = tmp_path / "art"
    assert main(["fit-svm", "--data", str(out), "--out", str(art), "--n-bins", "40"]) == 0
    skin = json.loads((art / "skin.json").read_text())
    assert skin["models"]["svm"]["n_locations"] == len(want)
    assert set(skin["training"]["split"]["train"]) == {"s000", "s001"}


def test_resume_records_a_location_that_was_labelled_but_not_pressed(tmp_path, small, capsys):
    out = tmp_path / "rec"
    args = ["record", "--out", str(out), "--scenario", small, "--locations", "1", "2", *FAST]
    assert main(args) == 0
    # The user did not press location 2 (the force sensor read ~0 N throughout its prompt).
    for csv in sorted((out / "s000").glob("part-*.csv")):
        text = csv.read_text().splitlines()
        head = text[0].split(",")
        rows = [r.split(",") for r in text[1:]]
        for r in rows:
            if r[head.index("location")] == "2":
                r[head.index("force_n")] = "0.01"
        csv.write_text("\n".join([text[0], *(",".join(r) for r in rows)]) + "\n")
    reseal(out / "s000")  # a recording in which location 2 was not pressed, not a damaged one
    assert location_counts(out)[2][1] == 0 and recorded_locations(out) == {1}
    capsys.readouterr()
    assert main([*args, "--resume"]) == 0
    assert "2 (labelled but only 0 of " in capsys.readouterr().err
    _, lab1 = Dataset(out).read_session("s001")
    assert set(lab1["location"][lab1["location"] >= 0]) == {2}
    assert recorded_locations(out) == {1, 2}


def test_sigint_at_a_random_moment_keeps_every_finished_prompt(tmp_path, small):
    """A real Ctrl-C (SIGINT to the process), wherever it lands; then --resume completes the set."""
    out = tmp_path / "rec"
    args = [sys.executable, "-m", "sonicskin", "record", "--out", str(out), "--scenario", small, *FAST]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [os.getcwd(), os.environ.get("PYTHONPATH")])),
           "OMP_NUM_THREADS": "1"}
    # Ctrl-C as a terminal delivers it, whatever this test runner inherited (a background job starts with
    # SIGINT ignored, and so would the child)
    p = subprocess.Popen(args, env=env, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # Interrupt somewhere in the k-th touch prompt (k random), a random moment after it is shown.
    rng = np.random.default_rng()
    k, seen = int(rng.integers(1, 5)), 0  # not the last of the six: the run is still going when SIGINT comes
    for line in p.stderr:
        seen += "touch location" in line
        if seen == k:
            break
    time.sleep(float(rng.uniform(0.0, 0.2)))
    p.send_signal(signal.SIGINT)
    err = p.communicate(timeout=60)[1]
    # 130: stopped by the Ctrl-C (exit code of an interrupted run).  Under load the prompt lines reach this test
    # late, and the run may already have written everything and be exiting when SIGINT lands: then the shell's
    # default (killed by SIGINT, -2) is fine as long as the run said it finished.
    finished = "wrote " in err and "interrupted" not in err
    assert p.returncode in (0, 130) or (p.returncode == -signal.SIGINT and finished), err
    assert "Traceback" not in err, err
    before = recorded_locations(out)
    if before:
        assert_real_presses(out, sorted(before))
    assert main([*args[3:], "--resume"]) == 0
    assert recorded_locations(out) == {0, 1, 2, 3, 4, 5}
    assert_real_presses(out, [0, 1, 2, 3, 4, 5])


def test_bad_locations_are_one_line_errors(tmp_path, small, capsys):
    assert main(["record", "--out", str(tmp_path / "r"), "--scenario", small, "--locations", "2", "9", *FAST]) == 2
    err = capsys.readouterr().err
    assert "--locations 9: not a marker of the small layout (ids 0..5)" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()


def test_force_log(tmp_path):
    p = tmp_path / "f.csv"
    p.write_text("t_s,force_n\n0,0\n1,2\n2,4\n")
    f = CsvForce(p)
    assert f.force(1.5) == pytest.approx(3.0) and np.isnan(f.force(5.0))
    p.write_text("time,newton\n0,0\n")
    with pytest.raises(ValueError, match="t_s,force_n"):
        CsvForce(p)


def test_ctrl_c_while_a_part_is_written_keeps_that_part_whole(tmp_path, small, monkeypatch):
    """SIGINT inside the FLAC encoder (cffi callbacks swallow exceptions) must neither be lost nor cut the part."""
    from sonicskin.dataset import DatasetWriter

    real_write = DatasetWriter.write_part
    calls = []

    def write_part(self, session, part, audio, labels):
        calls.append(part)
        if len(calls) == 2:  # Ctrl-C as the first touch prompt's part starts to be written
            os.kill(os.getpid(), signal.SIGINT)
        return real_write(self, session, part, audio, labels)

    monkeypatch.setattr(DatasetWriter, "write_part", write_part)
    # Python's Ctrl-C handler, as in a terminal (a runner started in the background inherits SIGINT ignored,
    # and then a recording rightly keeps going)
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    out = tmp_path / "rec"
    try:
        code = main(["record", "--out", str(out), "--scenario", small, "--locations", "1", "2", "3", *FAST])
    finally:
        signal.signal(signal.SIGINT, old)
    assert code == 130
    assert calls == [0, 1]  # stopped right after the part that was being written
    assert Dataset(out).parts("s000") == [0, 1]
    assert recorded_locations(out) == {1}
    assert_real_presses(out, [1])


def test_a_run_that_records_nothing_leaves_nothing_behind(tmp_path, small, monkeypatch, capsys):
    """A device that does not open, or Ctrl-C before the first prompt is done: no lone dataset.json
    that would block the retry (the issue's `record --device 0` without PortAudio)."""
    import sonicskin.acquire as acquire

    def no_device(*a, **k):
        raise ValueError("no audio device matches 'Fireface'")

    out = tmp_path / "rec"
    monkeypatch.setattr(acquire, "SoundDeviceSource", no_device)
    assert main(["record", "--out", str(out), "--device", "Fireface", "--scenario", small, *FAST]) == 2
    assert "no audio device matches" in capsys.readouterr().err and not out.exists()
    monkeypatch.undo()
    _interrupt_after(monkeypatch, 5)
    assert main(["record", "--out", str(out), "--scenario", small, "--locations", "1", *FAST]) == 130
    assert "nothing was recorded" in capsys.readouterr().err and not out.exists()
    monkeypatch.undo()
    assert main(["record", "--out", str(out), "--scenario", small, "--locations", "1", *FAST]) == 0
    assert recorded_locations(out) == {1}


def test_a_device_that_stops_delivering_ends_the_recording_with_one_line(tmp_path, small, monkeypatch, capsys):
    """The recorder reads its device through acquire.blocks, as the live loop does: an interface that opens and then
    delivers nothing (the audio server died) read for ever; now the watchdog ends it in one line, and the dataset
    it could not record anything into is removed."""
    import sonicskin.acquire as acquire

    class Dead(acquire._QueueSource):
        def __init__(self, rig, device=None, **kw):
            super().__init__(rig, 1024)

        def start(self):
            pass

        def stop(self):
            pass

    monkeypatch.setattr(acquire, "SoundDeviceSource", Dead)
    out = tmp_path / "rec"
    t0 = time.perf_counter()
    assert main(["record", "--out", str(out), "--device", "0", "--scenario", small, *FAST]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("sonicskin record: error: no audio from the device for 3 s") and not out.exists()
    assert time.perf_counter() - t0 >= 3.0  # the watchdog's time (no upper bound: the suite runs at load 5)


def test_record_writes_the_deployable_artifact_then_live_runs_it(tmp_path, small, capsys):
    """Issue 27.4: `record` then `live` is the whole bring-up: three passes by default, and once every marker is pressed
    the artifact fit-svm would write, with the validated choices and the learning curve printed on stdout."""
    from sonicskin.runtime import SkinRuntime

    part = tmp_path / "part"
    assert main(["record", "--out", str(part), "--scenario", small, "--locations", "1", *FAST]) == 0
    out = capsys.readouterr().out
    assert "no artifact yet: location(s) 0, 2, 3, 4, 5 of the layout have no press yet; `--resume` records them" in out
    assert not (tmp_path / "part-artifact").exists()
    # Prompts shorter than the press's force ramp never count: --resume alone repeated them for ever; it says so.
    assert main(["record", "--out", str(tmp_path / "short"), "--scenario", small, "--locations", "1", *FAST[:-4],
                 "--touch-s", "0.3", "--gap-s", "0.3"]) == 0
    assert ("have no press yet; 1 of them were prompted in this run but gave fewer than 3 chirps at >= 0.5 N: press "
            "longer (--touch-s, now 0.3 s)") in capsys.readouterr().out
    rec = tmp_path / "rec"
    assert main(["record", "--out", str(rec), "--scenario", small, *FAST]) == 0
    out = capsys.readouterr().out
    _, lab = Dataset(rec).read_session("s000")
    presses = lab["location"][np.r_[True, lab["location"][1:] != lab["location"][:-1]]]
    assert sorted(presses[presses >= 0].tolist()) == sorted([0, 1, 2, 3, 4, 5] * 3)  # three passes over six markers
    art = tmp_path / "rec-artifact"
    assert f"wrote {art}/svm.onnx" in out and "learning curve (presses per location: accuracy) 1:" in out
    assert f"deploy it: sonicskin live --artifact {art}" in out and (art / "learning_curve.png").is_file()
    rt = SkinRuntime(art, "svm")
    assert rt.layout.ids == Dataset(rec).layout.ids and "drift" in rt.meta
    assert main(["live", "--artifact", str(art), "--scenario", small, "--fast", "--duration", "8"]) == 0
    assert '"kind": "touch"' in capsys.readouterr().out  # the scripted presses become touch events


def test_a_run_stopped_while_writing_its_artifact_is_resumed_by_writing_it(tmp_path, small, capsys, monkeypatch):
    """Interrupted after the last prompt, while fitting: no artifact, and --resume said "nothing to do" for ever."""
    import sonicskin.record as record

    rec, art = tmp_path / "rec", tmp_path / "rec-artifact"

    def stopped(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(record, "build_svm_artifact", stopped)
    assert main(["record", "--out", str(rec), "--scenario", small, *FAST]) == 130
    monkeypatch.undo()
    assert not art.exists() and location_presses(rec) == dict.fromkeys(range(6), 3)
    capsys.readouterr()
    assert main(["record", "--out", str(rec), "--scenario", small, *FAST, "--resume"]) == 0
    err, out = capsys.readouterr()[::-1]
    assert "all 6 requested locations have 3 presses; nothing to record" in err
    assert (art / "skin.json").is_file() and f"deploy it: sonicskin live --artifact {art}" in out
    assert Dataset(rec).sessions == ["s000"]  # nothing recorded again
