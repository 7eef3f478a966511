"""`sonicskin check`: known answers on synthetic captures, a healthy simulated rig passes, and each
simulated fault fails with its fix line; the command writes check.png and check.json."""

import json

import numpy as np
import pytest

from sonicskin.check import Capture, SimulatedDevice, analyse, capture
from sonicskin.cli import main
from sonicskin.dsp import rig_chirp
from sonicskin.errors import SonicskinError
from sonicskin.rig import Rig
from sonicskin.sim import Scenario

LAYOUT = {"kind": "grid", "nx": 3, "ny": 1, "spacing_cm": 2.4, "x0_cm": 6, "y0_cm": 12}
SC = Scenario(sessions=1, layout=LAYOUT, seed=21)


@pytest.fixture(scope="module")
def device(rig):
    return SimulatedDevice(rig, SC)


def _run(device, fault="none", **kw):
    device.fault = fault
    device.rates = (44_100.0, 48_000.0) if fault == "rate" else SimulatedDevice.RATES
    try:
        return analyse(capture(device.rig, device, **kw), device.rig)
    finally:
        device.fault, device.rates = "none", SimulatedDevice.RATES


def test_known_answer_chirp_through_a_flat_channel(rig):
    """H = 1 plus white noise sigma: single-chirp SNR per bin = A^2 L / (4 n_band sigma^2) (Parseval),
    the delay is where the chirp was put, and the rest-to-rest change is -SNR."""
    L, fs, sigma, d = rig.n_chirp, rig.fs_hz, 1e-3, 1234
    n = 12 * L
    x = np.tile(rig_chirp(rig), 13)[L - d:L - d + n]
    rng = np.random.default_rng(0)
    x = (x + rng.normal(0, sigma, n)).astype(np.float32)[:, None]
    cap = Capture(x, fs, 0, 0, (0, 8 * L), (8 * L, 12 * L), "synthetic")
    rep = analyse(cap, rig)
    expect = 10 * np.log10(rig.amplitude ** 2 * L / (4 * rig.n_band * sigma ** 2))
    m = rep.measurements
    assert m["snr_db_median"] == pytest.approx(expect, abs=1.0)
    assert m["delay_ms"] == pytest.approx(d / fs * 1e3, abs=1e-6) and m["delay_jitter_samples"] == 0
    assert m["rest_to_rest_db"] == pytest.approx(-expect, abs=1.5)
    assert m["pwm_lines_hz"] == []
    # No press in this capture: the "press" changes nothing beyond noise, and the check says so.
    assert rep.status("touch contrast") == "fail" and "press firmly" in rep.line("touch contrast").fix


def test_healthy_simulated_rig_passes(device):
    rep = _run(device)
    assert rep.ok and {x.status for x in rep.lines} == {"pass"}, rep.table()
    m = rep.measurements
    assert m["lock_db"] > 40 and m["touch_contrast_db"] > 20 and m["rest_to_rest_db"] < -40
    assert -12 < m["peak_dbfs"] < -3 and m["clipped_share"] == 0


def test_delay_is_the_interfaces_latency_plus_the_acoustic_path(rig):
    """Two interface latencies 7.1 ms apart measure 7.1 ms apart; the rest is the wave's travel
    between the discs (~21 cm of CFRP at a few hundred m/s: a fraction of a millisecond)."""
    got = []
    for delay_ms in (2.9, 10.0):
        dev = SimulatedDevice(rig, SC, delay_ms=delay_ms)
        got.append(analyse(capture(rig, dev, rest_s=2.0, press_s=1.0), rig).measurements["delay_ms"])
    assert got[1] - got[0] == pytest.approx(7.1, abs=0.02)
    assert 0 < got[0] - 2.9 < 1.0


@pytest.mark.parametrize("fault, line, fix", [
    ("disconnected", "chirp lock", "no chirp on any input: connect output 0 (--tx) to the transmitter disc"),
    ("clipping", "input level", "the input clips: turn the input gain down"),
    ("rate", "sample rate", "set the interface to 192000 Hz"),
    ("weak", "SNR per sub-band", "the chirp is too weak for the noise"),
    ("wrong-channel", "chirp lock", "the chirp arrives on input 1, not on input 0: pass --rx 1"),
])
def test_each_fault_fails_with_its_fix(device, fault, line, fix):
    rep = _run(device, fault)
    assert not rep.ok
    bad = [x for x in rep.lines if x.status == "fail"]
    assert bad[0].name == line and fix in bad[0].fix, rep.table()
    assert len(bad) == 1  # one cause, one line (the lines that need it are skipped, not failed)


def test_motor_pwm_lines_found_and_judged_against_the_rigs_notches(rig):
    dev = SimulatedDevice(rig, SC, motors=0.3)
    rep = analyse(capture(rig, dev, rest_s=3.0, press_s=1.0), rig)
    lines = rep.measurements["pwm_lines_hz"]
    assert lines and all(min(abs(f - c) for c in (30e3, 60e3)) < 2e3 for f in lines)
    assert rep.status("PWM/motor lines") == "pass"  # inside the rig's 30/60 kHz notches
    other = Rig(pwm_hz=(90_000.0,))  # a rig that notches nothing in 20-80 kHz
    rep2 = analyse(capture(other, SimulatedDevice(other, SC, motors=0.3), rest_s=3.0, press_s=1.0), other)
    assert rep2.status("PWM/motor lines") == "warn" and "pwm_hz" in rep2.line("PWM/motor lines").fix


def test_cli_check_writes_png_and_json(tmp_path, capsys):
    assert main(["check", "--out", str(tmp_path), "--rest", "2", "--press", "1.5"]) == 0
    out = capsys.readouterr().out
    assert "rig check: PASS" in out and "touch contrast" in out
    doc = json.loads((tmp_path / "check.json").read_text())
    assert doc["ok"] is True and len(doc["lines"]) == 8 and doc["measurements"]["fs_hz"] == 192000
    png = (tmp_path / "check.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    assert main(["check", "--out", str(tmp_path / "f"), "--rest", "2", "--press", "1", "--sim-fault", "clipping"]) == 1
    assert "the input clips" in capsys.readouterr().out
    assert json.loads((tmp_path / "f" / "check.json").read_text())["ok"] is False


def test_cli_check_usage_errors(capsys):
    assert main(["check", "--device", "3", "--sim-fault", "weak"]) == 2
    assert "--sim-fault is for the simulated device" in capsys.readouterr().err
    with pytest.raises(SonicskinError, match="--rx 5: the device has 2 inputs"):
        capture(Rig.load("jaco"), SimulatedDevice(Rig.load("jaco"), SC), rx=5)


def test_clipping_is_not_also_counted_as_dropouts_with_a_short_rest(device):
    """Clipped rest chirps deviate from the median too; that is the level line's finding, not the delay line's."""
    rep = _run(device, "clipping", rest_s=2.0, press_s=1.5)
    assert [x.name for x in rep.lines if x.status == "fail"] == ["input level"], rep.table()
    assert rep.measurements["dropout_chirps"] == 0
