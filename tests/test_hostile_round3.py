"""What a third hostile pass found (issue 37, after the first fixes): writers that emptied a folder of the user's own
files, an import that deleted its own input, a recording left unreadable by SIGTERM, scores on another wall reported as
the artifact's, an arm trained on another arm's data, and a --duration that overflowed."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest
from cli_helpers import assert_one_line_error, run

from sonicskin.rig import Rig
from sonicskin.session import MAX_SCRIPTED_S, live_scenario
from sonicskin.sim import Scenario, build_timeline


def test_simulate_refuses_a_folder_of_other_files_so_overwrite_never_empties_it(capsys, tmp_path, cli_files):
    """simulate --out V wrote its dataset beside the user's files; a later --overwrite then deleted them all."""
    v = tmp_path / "V"
    (v / "src").mkdir(parents=True)
    (v / "important.txt").write_text("keep")
    for extra in ([], ["--overwrite"]):
        line = assert_one_line_error(*run(capsys, ["simulate", "--scenario", cli_files["scenario"], "--rig", cli_files["rig"],
                                                   "--out", v, *extra])[::2], "simulate")
        assert line == (f"sonicskin simulate: error: {v} holds files but no dataset; write the dataset into a new or empty "
                        f"folder (choose another --out)")
    assert sorted(p.name for p in v.iterdir()) == ["important.txt", "src"] and (v / "important.txt").read_text() == "keep"


def test_an_import_never_overwrites_the_folder_its_own_table_is_in(capsys, tmp_path):
    from test_cli import _spectra_table

    out = tmp_path / "ds"
    _spectra_table(tmp_path / "t.npz")
    assert run(capsys, ["import-spectra", "--table", tmp_path / "t.npz", "--out", out])[0] == 0
    table = out / "touches.npz"
    table.write_bytes((tmp_path / "t.npz").read_bytes())
    line = assert_one_line_error(*run(capsys, ["import-spectra", "--table", table, "--out", out, "--overwrite"])[::2],
                                 "import-spectra")
    assert line == (f"sonicskin import-spectra: error: {table} lies inside --out {out}: --overwrite would replace the "
                    f"import's own input; choose an --out elsewhere")
    assert table.is_file()


def test_sigterm_ends_live_as_ctrl_c_does(tmp_path, cli_files):
    """A supervisor stopping the sensor (SIGTERM) ended it at once: exit 143, no summary, and an --mcap recording no
    reader opened.  SIGTERM is now a Ctrl-C: the run ends as at the end of its duration, every file closed (the MCAP
    writer is closed on that path: tests/test_mcap_events.py)."""
    p = subprocess.Popen([sys.executable, "-m", "sonicskin", "live", "--artifact", str(cli_files["artifact"]), "--rig",
                          str(cli_files["rig"]), "--scenario", str(cli_files["scenario"]), "--duration", "60", "--no-status"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = p.stdout.readline()  # the first event: the run is under way
        assert json.loads(first)["kind"] in ("touch", "release"), first
        time.sleep(0.5)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert "Traceback" not in err and json.loads(err.strip().splitlines()[-1])["summary"]["chirps"] > 0


def test_compare_says_when_the_data_is_of_another_wall_and_names_no_trained_session(capsys, tmp_path, cli_files):
    """An artifact scored on a dataset of another wall (same size, another link) gave 63 % as its accuracy, with a
    note that the test session had trained it: session names were compared, not datasets."""
    other = tmp_path / "other"
    assert run(capsys, ["simulate", "--scenario", cli_files["scenario"], "--rig", cli_files["rig"], "--out", other,
                        "--set", "link_seed=77", "--set", "seed=77", "--quiet"])[0] == 0
    code, out, err = run(capsys, ["compare", "--data", other, "--artifact", cli_files["artifact"], "--test", "s000",
                                  "--out", tmp_path / "cmp"])
    assert code == 0, err
    assert (f"warning: dataset {other} was recorded on another " in err and "its wall fingerprint differs" in err
            and "not its accuracy" in err)
    assert "trained or validated this artifact" not in out
    code, out, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", cli_files["artifact"], "--test",
                                  "s000", "--out", tmp_path / "cmp2"])
    assert code == 0 and "s000 trained or validated this artifact: not a held-out test" in out
    assert "another" not in err


def test_fit_svm_refuses_an_arm_whose_data_is_of_other_walls(capsys, tmp_path):
    arm = tmp_path / "arm.yaml"
    arm.write_text("name: one\nrig: fast\nlinks:\n  - {name: a, tx: 0, rx: 0, scenario: {base: stationary, sessions: 2, "
                   "train_repeats: 1, touch_s: 1.0, link_seed: 1, layout: {kind: rings, counts: [3], spacing_cm: 1.2}}}\n")
    assert run(capsys, ["simulate", "--links", arm, "--out", tmp_path / "data", "--quiet"])[0] == 0
    arm.write_text(arm.read_text().replace("link_seed: 1", "link_seed: 2"))  # another link: the data is not of its wall
    line = assert_one_line_error(*run(capsys, ["fit-svm", "--links", arm, "--data", tmp_path / "data", "--out",
                                               tmp_path / "art"])[::2], "fit-svm")
    assert line.startswith(f"sonicskin fit-svm: error: link 'a': {tmp_path / 'data' / 'a'} was recorded on another ")
    assert "(its wall fingerprint differs: another link or simulated wall)" in line  # the same material and size
    assert line.endswith(f"simulate this arm's links first (`sonicskin simulate --links {arm} --out DIR`) and train on DIR")
    assert not (tmp_path / "art").exists()


@pytest.mark.parametrize("duration", [1e308, 1e6])
def test_a_huge_duration_scripts_at_most_an_hour(duration, cli_files):
    """--duration 1e308 on the simulated device raised OverflowError while scripting the presses."""
    rig, sc = Rig.load(cli_files["rig"]), Scenario.load(cli_files["scenario"])
    length = len(build_timeline(live_scenario(sc, rig, duration), rig)) / rig.chirps_per_s
    assert MAX_SCRIPTED_S <= length < 1.2 * MAX_SCRIPTED_S


def test_the_process_keeps_no_sigterm_handler_after_a_verb(capsys):
    before = signal.getsignal(signal.SIGTERM)
    run(capsys, ["info"])
    assert signal.getsignal(signal.SIGTERM) is before


def test_the_watchdog_waits_for_two_blocks_of_a_large_blocksize():
    """--blocksize 1048576 (5.5 s a block at 192 kHz) with the 3 s watchdog: a healthy simulated device was called dead
    before its first block could arrive."""
    from sonicskin.acquire import DeviceLost, blocks

    class Silent:  # a source that never delivers: the watchdog must still wait two blocks' time
        rig, blocksize, finished, error = Rig(fs_hz=192000, n_chirp=1024, pwm_hz=()), 57600, None, None
        stall_text = "no audio for {s:g} s"

        def read(self, timeout):
            time.sleep(timeout)

        def producer_cpu_s(self):
            return None

    t0 = time.perf_counter()
    with pytest.raises(DeviceLost, match=r"^no audio for 0\.6 s$"):
        for _ in blocks(Silent(), watchdog_s=0.05, poll_s=0.01):
            pass
    assert time.perf_counter() - t0 >= 0.6


URDF = """<robot name="r">
  <link name="base"/>
  <link name="l1"><collision><origin xyz="0 0 0.1" rpy="0 0 0"/><geometry><cylinder radius="0.04" length="0.3"/></geometry>
  </collision></link>
  <joint name="j1" type="fixed"><parent link="{parent}"/><child link="l1"/><origin xyz="{xyz}" rpy="0 0 0"/></joint>
</robot>"""


@pytest.mark.parametrize("parent, xyz, message", [
    ("base", "0 0 nan", "an <origin xyz='0 0 nan'> is not three finite numbers; fix the URDF"),
    ("base", "0 0", "an <origin xyz='0 0'> is not three finite numbers; fix the URDF"),
    ("base", "0 0 1e999", "an <origin xyz='0 0 1e999'> is not three finite numbers; fix the URDF"),
    ("l1", "0 0 0", "joint 'j1' has link 'l1' as both its parent and its child; a joint connects two links"),
])
def test_a_urdf_with_non_finite_poses_or_a_joint_onto_itself_is_refused(tmp_path, parent, xyz, message):
    """NaN joint origins were accepted and reached /tf_static in the MCAP recording."""
    from sonicskin.surface import LinkSurface, SurfaceError

    path = tmp_path / "r.urdf"
    path.write_text(URDF.format(parent=parent, xyz=xyz))
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_urdf(path, "l1")
    assert str(e.value) == f"{path}: {message}"
    path.write_text(URDF.format(parent="base", xyz="0 0 0.2"))
    assert LinkSurface.from_urdf(path, "l1").kind == "tube"


@pytest.mark.parametrize("layout, message", [
    ("{kind: rings, counts: [100, 100]}", "layout marker 20 at (24, 0) cm lies outside the tube (x 0..23.56 round it, "
                                          "y 0..25 cm); move the layout (x0_cm, y0_cm, spacing_cm) or use fewer markers"),
    ("{kind: rings, counts: [1000, 1000]}", "scenario 'stationary': layout has 2000 markers, more than 1000"),
])
def test_a_layout_off_the_wall_or_too_large_is_refused_at_once(capsys, tmp_path, layout, message):
    """Markers wrapped five times round a tube and coincided (exit 0); a million of them ran for minutes."""
    line = assert_one_line_error(*run(capsys, ["simulate", "--scenario", "stationary", "--out", tmp_path / "d", "--set",
                                               f"layout={layout}"])[::2], "simulate")
    assert line.startswith(f"sonicskin simulate: error: {message}")
    assert not (tmp_path / "d").exists()


def test_a_stopped_listener_says_it_does_not_start_again(cli_files):
    """start() after stop() did nothing, silently: a script waiting for events waited for ever."""
    from sonicskin.api import Listener
    from sonicskin.errors import SonicskinError

    lst = Listener(cli_files["artifact"], rig=cli_files["rig"], scenario=cli_files["scenario"], fast=True, duration_s=2)
    assert lst.start() is lst and lst.start() is lst  # a second start while it runs: nothing more
    lst.stop()
    with pytest.raises(SonicskinError, match="^this Listener was stopped and its source closed; make a new Listener to "
                                             "listen again$"):
        lst.start()
    # A run that ended by itself (its duration) did not start again either, and said nothing: a controller restarting it
    # waited for events for ever.
    lst = Listener(cli_files["artifact"], rig=cli_files["rig"], scenario=cli_files["scenario"], fast=True, duration_s=1)
    lst.start()
    deadline = time.monotonic() + 120
    while lst.running and time.monotonic() < deadline:
        time.sleep(0.05)
    with pytest.raises(SonicskinError, match="^this Listener's run has ended and its source is closed; make a new Listener"):
        lst.start()


@pytest.mark.parametrize("setting, expected", [
    ("seed=-1", "sonicskin simulate: error: scenario seed must be a whole number >= 0, got -1"),
    ("link_seed=-3", "sonicskin simulate: error: scenario link_seed must be a whole number >= 0, got -3"),
    ('touch_s="1e-9"', "sonicskin simulate: error: scenario touch_s must be a finite number, got '1e-9' (YAML reads a "
                       "number without a dot, 1e-9, as text: write 1.0e-9)")])
def test_scenario_settings_are_refused_in_words_that_fit(capsys, tmp_path, setting, expected):
    """numpy's "expected non-negative integer" for a negative seed; "must be a finite number, got '1e-9'" for 1e-9."""
    code, _, err = run(capsys, ["simulate", "--scenario", "stationary", "--set", setting, "--out", tmp_path / "d"])
    assert assert_one_line_error(code, err, "simulate") == expected and not (tmp_path / "d").exists()


def test_a_number_without_a_dot_given_to_set_is_a_number():
    from sonicskin.cli.parser import key_value

    assert key_value("touch_s=1e-9") == ("touch_s", 1e-9) and key_value("gap_s=2E1") == ("gap_s", 20.0)
    assert key_value("name='1e3'") == ("name", "1e3") and key_value("name=abc") == ("name", "abc")
