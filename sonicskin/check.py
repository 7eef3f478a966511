"""``sonicskin check``: is this rig fit to learn touches from?  One table, each line pass/warn/fail with its fix.

The check plays the rig's chirp for a few seconds of rest, then asks for a firm press, records every input channel,
and measures what docs/bring-up.md lists.  :func:`capture` records; :func:`analyse` returns a :class:`CheckReport`."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import scipy.fft
import scipy.ndimage
import scipy.signal

from .acquire import AudioError, AudioSource, Link, blocks, check_blocksize, check_device_rate, list_devices, resolve_device
from .dsp import chirp_spectrum, find_chirp_offset, rig_chirp
from .errors import SonicskinError, UsageError, is_number
from .jsonio import json_safe
from .plots import pyplot
from .rig import Rig
from .session import SIM, open_source, simulated
from .sim import Scenario, Simulator
from .sim.finger import press_profile
from .sim.scenario import SEGMENTS, Timeline

__all__ = ["Capture", "CheckLine", "CheckReport", "SimulatedDevice", "capture", "analyse", "FAULTS", "THRESHOLDS"]

FAULTS = ("none", "disconnected", "clipping", "weak", "wrong-channel", "rate")
MIN_REST_CHIRPS = 9   # the lock offset takes up to one period; the delay, SNR and repeatability lines need 8 whole chirps
MIN_PRESS_CHIRPS = 3  # the touch contrast takes the pressed half of the whole chirps after the lock offset: 2 at least
MAX_WINDOW_S = 600.0  # a window of the check is held in memory as float32 on every input


def check_windows(rig: Rig, rest_s: float, press_s: float) -> None:
    """The rest and press windows: long enough for the measurements, short enough to hold in memory."""
    for name, v, n, what in (("--rest", rest_s, MIN_REST_CHIRPS, "at rest"),
                             ("--press", press_s, MIN_PRESS_CHIRPS, "to measure the touch contrast")):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0 and v <= MAX_WINDOW_S):
            raise SonicskinError(f"{name} {v:g}: give seconds in (0, {MAX_WINDOW_S:g}]")
        need = n * rig.period_s
        if v < need:
            raise SonicskinError(f"{name} {v:g} s holds fewer than the {n} chirp periods the check needs {what} "
                                 f"({rig.period_s * 1e3:.1f} ms each): give {name} {math.ceil(need * 10) / 10:g} or more")


# pass at or above the first value, warn at or above the second, fail below (lower-is-better rows say so)
THRESHOLDS = {
    "lock_db": (20.0, 10.0),
    "snr_db": (20.0, 10.0),         # median over the sub-bands
    "contrast_db": (10.0, 6.0),
    "rest_db": (-30.0, -20.0),      # lower is better: rest-to-rest change re. the response, dB
    "jitter_samples": (2, 256),     # lower is better; 256 = the live framer's re-lock tolerance
    "peak_dbfs_low": -40.0,         # warn below: raise the input gain
}


@dataclasses.dataclass
class Capture:
    """What the check recorded: every input channel, and where rest and press were asked for."""

    audio: np.ndarray            # (n, n_inputs) float32
    fs_hz: float
    rx: int
    tx: int
    rest: tuple[int, int]        # sample range of the hands-off part
    press: tuple[int, int]       # sample range in which the press was asked for
    device: str
    rate_ok: bool = True
    rate_detail: str = ""
    overflows: int = 0


@dataclasses.dataclass
class CheckLine:
    name: str
    value: str
    status: str                  # "pass" | "warn" | "fail" | "skip"
    fix: str = ""


@dataclasses.dataclass
class CheckReport:
    lines: list[CheckLine]
    measurements: dict
    spectra: dict                # arrays for the plot (freqs, rest/press/noise dB), empty when not measured
    rig: Rig

    @property
    def ok(self) -> bool:
        return not any(x.status == "fail" for x in self.lines)

    def status(self, name: str) -> str:
        return next(x.status for x in self.lines if x.name == name)

    def line(self, name: str) -> CheckLine:
        return next(x for x in self.lines if x.name == name)

    def table(self) -> str:
        w0 = max(len(x.name) for x in self.lines)
        w1 = max(len(x.value) for x in self.lines)
        out = [f"{'check':{w0}}  {'measured':{w1}}  status  fix", "-" * (w0 + w1 + 14)]
        for x in self.lines:
            out.append(f"{x.name:{w0}}  {x.value:{w1}}  {x.status:6}  {x.fix}".rstrip())
        n_fail = sum(x.status == "fail" for x in self.lines)
        n_warn = sum(x.status == "warn" for x in self.lines)
        out.append(f"rig check: {'PASS' if not n_fail else 'FAIL'} ({n_fail} fail, {n_warn} warn)")
        return "\n".join(out)

    def to_json(self) -> str:
        doc = {"ok": self.ok, "rig": self.rig.to_dict(), "lines": [dataclasses.asdict(x) for x in self.lines],
               "measurements": self.measurements}
        doc["rig"].pop("sweep_b64", None)
        return json.dumps(json_safe(doc), indent=1, allow_nan=False)

    def plot(self, path: str | Path) -> Path:
        """check.png: |H(f)| at rest and pressed, the noise floor, PWM notches and lines, the band used."""
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(10, 4.5), constrained_layout=True)
        rig = self.rig
        ax.axvspan(rig.f_lo_hz / 1e3, rig.f_hi_hz / 1e3, color="tab:green", alpha=0.07, label="chirp band (used)")
        for i, f in enumerate(rig.pwm_hz):
            ax.axvspan((f - rig.pwm_halfwidth_hz) / 1e3, (f + rig.pwm_halfwidth_hz) / 1e3, color="tab:red", alpha=0.12,
                       label="rig's PWM notches (dropped)" if i == 0 else None)
        s = self.spectra
        if s:
            f = s["f_hz"] / 1e3
            ax.plot(f, s["rest_db"], lw=0.7, color="tab:blue", label="|H| at rest")
            if s.get("press_db") is not None:
                ax.plot(f, s["press_db"], lw=0.7, color="tab:orange", alpha=0.8, label="|H| pressed")
            ax.plot(f, s["noise_db"], lw=0.7, color="0.45", label="noise floor (chirp-to-chirp)")
            for j, line in enumerate(self.measurements.get("pwm_lines_hz", [])):
                ax.axvline(line / 1e3, color="tab:red", lw=0.8, ls=":", label="motor/PWM line found" if j == 0 else None)
            lo = np.nanpercentile(s["noise_db"], 1) - 10
            hi = np.nanmax(s["rest_db"]) + 10
            ax.set_ylim(lo, hi)
        else:
            ax.text(0.5, 0.5, "no chirp lock: nothing to show", transform=ax.transAxes, ha="center")
        ax.set_xlim(0, rig.fs_hz / 2e3 if not s else max(rig.f_hi_hz, *rig.pwm_hz) / 1e3 + 8)
        ax.set_xlabel("frequency (kHz)")
        ax.set_ylabel("dB (re. transmitted chirp)")
        verdict = "PASS" if self.ok else "FAIL: " + ", ".join(x.name for x in self.lines if x.status == "fail")
        ax.set_title(f"sonicskin check, {self.measurements.get('device', '')}: {verdict}", fontsize=10)
        ax.legend(loc="upper right", fontsize=7, ncol=2)
        ax.grid(alpha=0.3)
        path = Path(path)
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path


# -- capture ----------------------------------------------------------------------------------------------------
class SimulatedDevice:
    """The simulated rig as the audio interface the check records from (``n_inputs``, ``delay_ms``, ``motors``),
    with a ``fault`` to inject: ``disconnected``, ``clipping`` (gain 40 x), ``weak`` (40 dB), ``wrong-channel``
    (the receiver on input 1) or ``rate`` (44.1/48 kHz only)."""

    RATES = (44_100.0, 48_000.0, 96_000.0, 192_000.0)
    GAIN = {"disconnected": 0.0, "clipping": 40.0, "weak": 1e-2}  # of the received chirp, per fault
    prompts = False  # the press is scripted

    def __init__(self, rig: Rig, scenario="stationary", *, fault: str = "none", n_inputs: int = 2, motors: float = 0.0,
                 delay_ms: float = 2.9, seed: int = 0):
        if fault not in FAULTS:
            raise SonicskinError(f"unknown simulated fault {fault!r}; choose one of {', '.join(FAULTS)}")
        if not (is_number(motors) and 0.0 <= motors <= 1.0):
            raise SonicskinError(f"--sim-motors {motors}: motor activity is a number from 0 (robot still) to 1 (full)")
        self.rig, self.fault = rig, fault
        sc = scenario if isinstance(scenario, Scenario) else Scenario.load(scenario)
        self.scenario = sc.replace(seed=sc.seed + 2000 + seed, sessions=1)
        self.sim = Simulator(self.scenario, rig)
        self.n_inputs = self.n_outputs = int(n_inputs)
        self.motors, self.delay_ms = float(motors), float(delay_ms)
        self.rates = (44_100.0, 48_000.0) if fault == "rate" else self.RATES
        self.name = f"simulated ({self.scenario.name}{'' if fault == 'none' else ', fault: ' + fault})"

    def timeline(self, n_rest: int, n_press: int, n_tail: int) -> Timeline:
        rig, sc = self.rig, self.scenario
        layout = sc.make_layout()
        n = n_rest + n_press + n_tail
        k = len(layout) // 2
        F = np.zeros(n)
        F[n_rest:n_rest + n_press] = press_profile(n_press, peak_n=4.0, rng=np.random.default_rng(sc.seed), ramp_frac=0.1)
        touch = F > 0
        t = sc.start_s + np.arange(n) / rig.chirps_per_s
        seg = np.where(touch, SEGMENTS.index("touch"), SEGMENTS.index("gap"))
        return Timeline(session=np.zeros(n, int), chirp=np.arange(n), time_s=t, segment=seg,
                        event=np.where(touch, 0, -1), location=np.where(touch, layout.ids[k], -1),
                        x_cm=np.where(touch, layout.xy_cm[k, 0], np.nan), y_cm=np.where(touch, layout.xy_cm[k, 1], np.nan),
                        force_n=F, moving=np.full(n, self.motors), temperature_c=sc.temperature_c(t),
                        subject=np.full(n, sc.subjects[0]))

    def refused(self, rig: Rig, tx: int) -> str | None:
        """Why the interface does not run the rig's rate (``None``: it does)."""
        return None if rig.fs_hz in self.rates else f"the device runs {', '.join(f'{r:g}' for r in self.rates)} Hz"

    def source(self, *, settle_s: float, rest_s: float, press_s: float, tail_s: float, blocksize: int = 1024) -> AudioSource:
        """The receiver's output: the chirp train at rest, the press, a tail, through the interface's delay and fault."""
        rig = self.rig
        d = int(round(self.delay_ms * 1e-3 * rig.fs_hz)) % rig.n_chirp
        tl = self.timeline(rig.seconds_to_chirps(settle_s + rest_s) + (d > 0), rig.seconds_to_chirps(press_s),
                           rig.seconds_to_chirps(tail_s))
        sim = copy.copy(self.sim)  # the fault's gain on this capture's copy (the simulator's arrays are shared)
        sim.gain = np.float32(sim.gain * self.GAIN.get(self.fault, 1.0))
        return open_source(rig, SIM, [Link()], play=lambda _: (sim, tl), realtime=False, offset=rig.n_chirp - d, blocksize=blocksize)

    def open(self, rig: Rig, *, rx: int, n: int, blocksize: int, settle_s: float, rest_s: float, press_s: float,
             tail_s: float, **_) -> tuple[np.ndarray, list[int], AudioSource]:
        """``n`` samples of every input to record into, the column the receiver fills and its :meth:`source`."""
        rng, q = np.random.default_rng([self.scenario.seed, 17]), float(2 ** 23 - 1)
        noise = (np.round(rng.normal(0, self.sim.noise.sensor_rms, (n, self.n_inputs)) * q) / q).astype(np.float32)
        column = min(1 if self.fault == "wrong-channel" else rx, self.n_inputs - 1)
        return noise, [column], self.source(settle_s=settle_s, rest_s=rest_s, press_s=press_s, tail_s=tail_s, blocksize=blocksize)


class _Interface:
    """An audio interface as the check records from it: every input (at most ``max_inputs``), the chirp on ``tx``."""

    prompts = True  # a person presses when asked

    def __init__(self, device, max_inputs: int):
        self.idx = resolve_device(device)
        d = list_devices()[self.idx]
        self.name, self.n_inputs, self.n_outputs = d["name"], min(int(d["inputs"]), max_inputs), int(d["outputs"])

    def refused(self, rig: Rig, tx: int) -> str | None:
        try:
            check_device_rate(self.idx, rig, self.n_inputs, tx + 1)
        except AudioError as e:
            return str(e)
        return None

    def open(self, rig: Rig, *, tx: int, rx: int, n: int, blocksize: int, playback, **_):
        src = open_source(rig, self.idx, [Link(tx=tx, rx=rx)], rx_channels=list(range(self.n_inputs)), blocksize=blocksize,
                          playback=playback)
        return np.zeros((n, self.n_inputs), np.float32), slice(None), src


def capture(rig: Rig, device=SIM, *, tx: int = 0, rx: int = 0, settle_s: float = 0.5, rest_s: float = 4.0,
            press_s: float = 3.0, tail_s: float = 0.5, blocksize: int = 1024, scenario="stationary", fault: str = "none",
            motors: float = 0.0, prompt=None, playback: np.ndarray | None = None, on_start=None, watchdog_s: float = 3.0,
            max_inputs: int = 8) -> Capture:
    """Play the chirp on ``tx`` and record every input of ``device`` (an interface, ``"sim"`` or a
    :class:`SimulatedDevice`), asking for a press after ``rest_s``; a rate the device refuses is a capture that says so.
    ``playback`` replaces what is played, ``on_start()`` runs once the stream runs (tests: a JACK loopback)."""
    check_windows(rig, rest_s, press_s)
    check_blocksize(blocksize, "--blocksize")
    if not (isinstance(device, SimulatedDevice) or simulated(device)) and fault != "none":
        raise UsageError("--sim-fault is for the simulated device (--device sim)")
    if simulated(device):
        device = SimulatedDevice(rig, scenario, fault=fault, motors=motors)
    elif not isinstance(device, SimulatedDevice):
        device = _Interface(device, max_inputs)
    if prompt is None:  # a person presses on an interface when asked; the simulated press is scripted
        prompt = (lambda msg: print(msg, file=sys.stderr, flush=True)) if device.prompts else (lambda msg: None)
    fs = rig.fs_hz
    rest = (int(settle_s * fs), int((settle_s + rest_s) * fs))
    press = (rest[1], int((settle_s + rest_s + press_s) * fs))
    n_total = press[1] + int(tail_s * fs)
    for opt, channel, n, what in (("--rx", rx, device.n_inputs, "inputs"), ("--tx", tx, device.n_outputs, "outputs")):
        if channel >= n:
            raise SonicskinError(f"{opt} {channel}: the device has {n} {what} (0-{n - 1})")
    refused = device.refused(rig, tx)
    if refused is not None:
        return Capture(np.zeros((0, device.n_inputs), np.float32), fs, rx, tx, rest, press, device.name, rate_ok=False, rate_detail=refused)
    audio, columns, src = device.open(rig, tx=tx, rx=rx, n=n_total, blocksize=blocksize, playback=playback,
                                      settle_s=settle_s, rest_s=rest_s, press_s=press_s, tail_s=tail_s)
    asked = released = False
    with src:
        if on_start is not None:
            on_start()
        prompt(f"check: playing the chirp; hands off the skin for {settle_s + rest_s:.0f} s")
        for b in blocks(src, watchdog_s=watchdog_s):
            if b is None:
                continue
            a, n = b.start, len(b.samples)
            m = min(n, n_total - a)
            if m <= 0:
                break
            audio[a:a + m, columns] = b.samples[:m].reshape(m, -1)
            if not asked and a + m >= rest[1] - int(0.3 * fs):
                asked = True
                prompt(f"check: PRESS NOW: one finger, firmly (~5 N), anywhere on the skin, hold for {press_s:.0f} s")
            if asked and not released and a + m >= press[1]:
                released = True
                prompt("check: release")
            if a + m >= n_total:
                break
    return Capture(audio, fs, rx, tx, rest, press, device.name, overflows=src.overflows + src.dropped_blocks)


# -- analysis ---------------------------------------------------------------------------------------
def _lock(x: np.ndarray, ref: np.ndarray) -> tuple[float, int]:
    """Matched-filter lock over whole periods of ``x``: (peak over median of the mean envelope in dB, offset)."""
    L = ref.size
    n = x.size // L
    if n < 1:
        return 0.0, 0
    X = scipy.fft.fft(x[: n * L].reshape(n, L).astype(np.float64), axis=-1)
    S = scipy.fft.fft(ref)
    H = np.zeros(L)
    H[1:(L + 1) // 2] = 2.0
    H[0] = 1.0
    env = np.abs(scipy.fft.ifft(X * np.conj(S) * H, axis=-1)).mean(axis=0)
    med = np.median(env)
    return float(20 * np.log10(max(env.max(), 1e-30) / max(med, 1e-30))), int(np.argmax(env))


def _grade(value: float, good: float, ok: float, *, lower_is_better: bool = False) -> str:
    if lower_is_better:
        return "pass" if value <= good else "warn" if value <= ok else "fail"
    return "pass" if value >= good else "warn" if value >= ok else "fail"


def _find_lines(noise_db: np.ndarray, f_hz: np.ndarray, *, prominence_db: float = 12.0, cluster_hz: float = 1500.0) -> list[float]:
    """Narrow lines of a noise spectrum (dB per bin): bins above the running median by ``prominence_db``."""
    base = scipy.ndimage.median_filter(noise_db, size=401, mode="nearest")
    peaks, _ = scipy.signal.find_peaks(noise_db - base, height=prominence_db, distance=3)
    lines: list[list[float]] = []
    for p in peaks:
        if lines and f_hz[p] - lines[-1][-1] < cluster_hz:
            lines[-1].append(f_hz[p])
        else:
            lines.append([f_hz[p]])
    return [float(np.mean(c)) for c in lines]


def analyse(cap: Capture, rig: Rig, *, n_subbands: int = 6) -> CheckReport:
    """Measure a capture; every line with its verdict and fix (see the module docstring)."""
    lines: list[CheckLine] = []
    meas: dict = {"device": cap.device, "rx": cap.rx, "tx": cap.tx, "fs_hz": rig.fs_hz}
    spectra: dict = {}

    def skip(*names):
        for nm in names:
            lines.append(CheckLine(nm, "-", "skip", "fix the failed line above first"))

    later = ("chirp lock", "output-to-input delay", "input level", "SNR per sub-band", "PWM/motor lines",
             "rest-to-rest repeatability", "touch contrast")
    # 1. sample rate
    if not cap.rate_ok:
        lines.append(CheckLine("sample rate", f"{rig.fs_hz:g} Hz refused", "fail",
                               f"set the interface to {rig.fs_hz:g} Hz in its control panel (or the audio server: "
                               f"jackd -r {rig.fs_hz:g}), or use a rig config with a rate it runs ({cap.rate_detail})"))
        skip(*later)
        meas["sample_rate_ok"] = False
        return CheckReport(lines, meas, spectra, rig)
    meas["sample_rate_ok"] = True
    lines.append(CheckLine("sample rate", f"{rig.fs_hz:g} Hz accepted", "pass"))
    fs, L = rig.fs_hz, rig.n_chirp
    ref = rig_chirp(rig)
    rest = cap.audio[cap.rest[0]:cap.rest[1]]
    # 2. chirp lock on every input
    locks = [_lock(rest[:, c], ref) for c in range(cap.audio.shape[1])]
    meas["lock_db_per_input"] = [round(lk[0], 1) for lk in locks]
    lock_db, off = locks[cap.rx]
    meas["lock_db"] = lock_db
    good, ok = THRESHOLDS["lock_db"]
    status = _grade(lock_db, good, ok)
    fix = ""
    best = int(np.argmax([lk[0] for lk in locks]))
    if status == "fail":
        if best != cap.rx and locks[best][0] >= good:
            fix = (f"the chirp arrives on input {best}, not on input {cap.rx}: pass --rx {best} "
                   f"(or move the receiver cable to input {cap.rx})")
            meas["chirp_on_input"] = best
        else:
            fix = (f"no chirp on any input: connect output {cap.tx} (--tx) to the transmitter disc (amplifier on, "
                   f"volume up, output not muted) and the receiver disc to input {cap.rx} (--rx)")
    elif status == "warn":
        fix = "the chirp is barely found: raise the transmit level or the input gain, shorten the cables"
    lines.append(CheckLine("chirp lock", f"{lock_db:.1f} dB peak/median on input {cap.rx}", status, fix))
    if status == "fail":
        skip(*later[1:])
        return CheckReport(lines, meas, spectra, rig)
    # 3. delay and its stability (rest periods, cut on the lock).  A chirp hit by a dropout (an xrun:
    #    the audio path repeated or lost a block) is counted and left out of the spectral statistics.
    n_rest = (rest.shape[0] - off) // L
    frames = rest[off:off + n_rest * L, cap.rx].reshape(n_rest, L)
    S = chirp_spectrum(rig)
    bb, allowed = rig.band_bins, rig.allowed_mask
    R = scipy.fft.rfft(frames.astype(np.float64), axis=-1)
    Hb = (R[:, bb] / S[bb])[:, allowed]
    centre = np.median(Hb.real, axis=0) + 1j * np.median(Hb.imag, axis=0)
    dev_db = 10 * np.log10(np.sum(np.abs(Hb - centre) ** 2, axis=1) / np.sum(np.abs(centre) ** 2) + 1e-30)
    # A clipped chirp also deviates, but that is the level line's finding, not a dropout.
    clipped_frame = np.max(np.abs(frames), axis=1) >= 0.999
    glitch = (dev_db > np.median(dev_db) + 10.0) & ~clipped_frame
    clean = ~glitch
    frames, R = frames[clean], R[clean]
    n_rest = len(frames)
    per = np.array([find_chirp_offset(f, ref, max_periods=1) for f in frames])
    per = (per + L // 2) % L - L // 2
    jitter = int(np.ptp(per))
    delay_ms = ((cap.rest[0] + off) % L) / fs * 1e3
    n_glitch = int(glitch.sum())
    meas.update(delay_ms=delay_ms, delay_jitter_samples=jitter, dropout_chirps=n_glitch, rest_chirps=int(glitch.size))
    good, ok = THRESHOLDS["jitter_samples"]
    status = _grade(jitter, good, ok, lower_is_better=True)
    if n_glitch:
        status = "fail" if n_glitch > 0.25 * glitch.size else "warn" if status == "pass" else status
    value = f"{delay_ms:.2f} ms (mod {rig.period_s * 1e3:.1f} ms), wander {jitter} samples"
    if n_glitch:
        value += f", {n_glitch} of {glitch.size} chirps hit by dropouts"
    lines.append(CheckLine("output-to-input delay", value, status, "" if status == "pass" else
                           "the audio path drops or repeats blocks / the delay moves: play and record on ONE interface (one "
                           "clock), raise --blocksize, close other audio programs, use real-time scheduling for the audio server"))
    # 4. level and clipping (the receive channel, the whole capture)
    x = cap.audio[cap.rest[0]:cap.press[1], cap.rx]
    peak = float(np.max(np.abs(x)))
    rms = float(np.sqrt(np.mean(np.square(x, dtype=np.float64))))
    clipped = float(np.mean(np.abs(x) >= 0.999))
    peak_db, rms_db = 20 * np.log10(max(peak, 1e-12)), 20 * np.log10(max(rms, 1e-12))
    meas.update(peak_dbfs=peak_db, rms_dbfs=rms_db, clipped_share=clipped)
    if clipped > 1e-4 or peak >= 0.999:
        lines.append(CheckLine("input level", f"peak {peak_db:.1f} dBFS, {clipped:.2%} of samples clipped", "fail",
                               "the input clips: turn the input gain down (or the transmit amplitude: the rig's "
                               "`amplitude`) until the peak sits near -6 dBFS"))
    elif peak_db < THRESHOLDS["peak_dbfs_low"]:
        lines.append(CheckLine("input level", f"peak {peak_db:.1f} dBFS, rms {rms_db:.1f} dBFS", "warn",
                               "the input is very low: raise the input gain (the piezo wants a Hi-Z / instrument input)"))
    else:
        lines.append(CheckLine("input level", f"peak {peak_db:.1f} dBFS, rms {rms_db:.1f} dBFS, no clipping", "pass"))
    # 5. spectra: coherent mean and chirp-to-chirp variance of the rest chirps
    f_all = np.arange(R.shape[1]) * fs / L
    mean = R.mean(axis=0)
    var = np.mean(np.abs(R - mean) ** 2, axis=0) * n_rest / max(n_rest - 1, 1)
    snr_db = 10 * np.log10(np.abs(mean[bb]) ** 2 / np.maximum(var[bb], 1e-30))
    edges = np.linspace(rig.f_lo_hz, rig.f_hi_hz, n_subbands + 1)
    fb = f_all[bb]
    sub = []
    for a, b in zip(edges[:-1], edges[1:]):
        m = allowed & (fb >= a) & (fb < b)
        sub.append((a, b, float(np.median(snr_db[m])) if m.any() else float("nan")))
    meas["snr_db_per_subband"] = [{"f_lo_hz": a, "f_hi_hz": b, "snr_db": s} for a, b, s in sub]
    med = float(np.nanmedian([s for *_, s in sub]))
    meas["snr_db_median"] = med
    good, ok = THRESHOLDS["snr_db"]
    status = _grade(med, good, ok)
    txt = " ".join(f"{a / 1e3:.0f}-{b / 1e3:.0f}k:{s:.0f}" for a, b, s in sub)
    lines.append(CheckLine("SNR per sub-band", f"{txt} dB (median {med:.0f})", status, "" if status == "pass" else
                           "the chirp is too weak for the noise: raise the transmit level (amplifier gain, rig `amplitude`), "
                           "the input gain, check the glue under the discs; keep the cables away from motor wires"))
    # 6. PWM / motor lines in the noise spectrum
    noise_db_all = 10 * np.log10(np.maximum(var, 1e-30))
    found = [f for f in _find_lines(noise_db_all, f_all) if rig.f_lo_hz <= f <= rig.f_hi_hz]
    covered = [f for f in found if any(abs(f - c) <= rig.pwm_halfwidth_hz for c in rig.pwm_hz)]
    uncovered = [f for f in found if f not in covered]
    meas.update(pwm_lines_hz=found, pwm_lines_uncovered_hz=uncovered)
    if uncovered:
        lines.append(CheckLine("PWM/motor lines", f"{len(found)} in band, {len(uncovered)} outside the notches: "
                               + ", ".join(f"{f / 1e3:.1f}k" for f in uncovered), "warn",
                               "add these frequencies to the rig's pwm_hz (a rig YAML) so the features drop them, "
                               "or route the motor cables away from the discs"))
    else:
        lines.append(CheckLine("PWM/motor lines", f"{len(found)} in band" + (", all inside the rig's PWM notches" if found else ""),
                               "pass"))
    # 7. rest-to-rest repeatability and touch contrast: the change of H over the usable bins, energy-weighted
    #    (10 log10 sum |H_k - H_rest|^2 / sum |H_rest|^2), so bins deep in a notch do not dominate
    H = (R[:, bb] / S[bb])[:, allowed]
    H_rest = H.mean(axis=0)
    e_ref = float(np.sum(np.abs(H_rest) ** 2))

    def change_db(Hk):
        return 10 * np.log10(np.sum(np.abs(Hk - H_rest) ** 2, axis=1) / e_ref + 1e-30)

    rest_db = float(np.median(change_db(H)))
    meas["rest_to_rest_db"] = rest_db
    good, ok = THRESHOLDS["rest_db"]
    status = _grade(rest_db, good, ok, lower_is_better=True)
    lines.append(CheckLine("rest-to-rest repeatability", f"{rest_db:.1f} dB change between rest chirps", status,
                           "" if status == "pass" else "the untouched response moves: re-glue loose discs, fix the cables, "
                           "keep the robot still for the check; raise the SNR"))
    p0 = cap.press[0] + (off - (cap.press[0] - cap.rest[0])) % L
    n_press = max(0, (cap.press[1] - p0) // L)
    press_db = None
    if n_press < 2:
        lines.append(CheckLine("touch contrast", "no press window recorded", "fail", "record longer (--press)"))
    else:
        P = scipy.fft.rfft(cap.audio[p0:p0 + n_press * L, cap.rx].astype(np.float64).reshape(n_press, L), axis=-1)
        HP = (P[:, bb] / S[bb])[:, allowed]
        change = change_db(HP)
        sel = np.argsort(change)[n_press // 2:]  # the pressed half (a person presses late, lets go early)
        press_change = float(np.median(change[sel]))
        contrast = press_change - rest_db
        meas.update(press_change_db=press_change, touch_contrast_db=contrast)
        good, ok = THRESHOLDS["contrast_db"]
        status = _grade(contrast, good, ok)
        lines.append(CheckLine("touch contrast", f"{contrast:.1f} dB (press {press_change:.1f} dB vs rest {rest_db:.1f} dB)", status,
                               "" if status == "pass" else "a press barely changes the response: press firmly during the "
                               "check; glue the discs with a thin hard layer (cyanoacrylate/epoxy, not foam tape)"))
        press_db = 20 * np.log10(np.abs(P[sel][:, bb] / S[bb]).mean(axis=0) + 1e-12)
    spectra.update(f_hz=fb, rest_db=20 * np.log10(np.abs(mean[bb] / S[bb]) + 1e-12), press_db=press_db,
                   noise_db=10 * np.log10(np.maximum(var[bb], 1e-30)) - 20 * np.log10(np.abs(S[bb]) + 1e-12))
    if cap.overflows:
        meas["overflows"] = cap.overflows
    return CheckReport(lines, meas, spectra, rig)
