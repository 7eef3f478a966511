"""``import_wav``: a folder of WAV recordings (one continuous recording per file = one session), the transmitted
sweep (a WAV of one period, any sweep; or a linear chirp's parameters) and a label CSV of touch intervals
(:mod:`.labels`) into a dataset."""

from __future__ import annotations

import hashlib
import warnings
from pathlib import Path

import numpy as np
import scipy.fft

from ..dataset import COLUMNS, DatasetWriter, load_json
from ..dsp import frame_faults, frame_stream, rig_chirp
from ..errors import check_memory
from ..rig import Rig
from ._common import ImportDataError, _first_touch, _staged, _write_session
from .labels import _check_intervals, _read_labels, label_layout

SILENT_RMS = 1e-7  # a recording quieter than this (about -140 dBFS) holds no received sweep
LOOPBACK_CORR = 0.98  # a 'received' channel this close to the transmitted sweep is the sweep itself


def sweep_rig(sweep: np.ndarray, fs_hz: float, *, pwm_hz=(), pwm_halfwidth_hz: float = 0.0, band_db: float = -20.0,
              name: str = "imported") -> Rig:
    """A rig for an arbitrary transmitted sweep: its band is where its spectrum is within ``band_db`` of the peak."""
    x = np.asarray(sweep, np.float32)
    if x.ndim != 1 or x.size < 64:
        raise ValueError(f"the sweep must be one period of mono audio (>= 64 samples), got shape {x.shape}")
    S = np.abs(scipy.fft.rfft(x))
    if not S.max() > 0:
        raise ValueError("the sweep is silent (all zeros); pass the WAV of one period of what the transmitter plays")
    n = x.size
    k = _repeats(x)
    if k:
        raise ImportDataError(f"the sweep WAV repeats every {n // k} samples: it holds {k} periods of the sweep, not one; "
                              f"cut it to one period ({n // k} samples)")
    f = np.fft.rfftfreq(x.size, 1 / fs_hz)
    on = np.flatnonzero(20 * np.log10(S / S.max() + 1e-12) >= band_db)
    f_lo, f_hi = float(max(f[on[0]], f[1])), float(f[on[-1]])
    return Rig(fs_hz=float(fs_hz), f_lo_hz=f_lo, f_hi_hz=f_hi, n_chirp=int(x.size), pwm_hz=tuple(pwm_hz),
               pwm_halfwidth_hz=pwm_halfwidth_hz, amplitude=float(min(1.0, np.max(np.abs(x)) or 1.0)), name=name,
               sweep_b64=Rig.encode_sweep(x))


def _sf_info(p: Path):
    import soundfile as sf

    if not p.is_file():
        raise ImportDataError(f"{p}: {'is a folder, not an audio file' if p.is_dir() else 'no such file'}")
    try:
        return sf.info(str(p))
    except (RuntimeError, TypeError, ValueError, OSError) as e:  # soundfile.LibsndfileError is a RuntimeError
        raise ImportDataError(f"{p}: not a readable audio file ({str(e).splitlines()[0][:120] if str(e) else type(e).__name__}); "
                           f"the file is damaged or not WAV/FLAC") from None


def _sf_read(p: Path, what: str = "recording") -> tuple[np.ndarray, int]:
    import soundfile as sf

    info = _sf_info(p)
    check_memory(4.0 * info.frames * max(1, info.channels) * 3, f"reading {p}", f"split the {what} into shorter files")
    try:
        x, sr = sf.read(str(p), dtype="float32", always_2d=True)
    except (RuntimeError, TypeError, ValueError, OSError, AssertionError) as e:
        raise ImportDataError(f"{p}: not a readable audio file ({str(e).splitlines()[0][:120] if str(e) else type(e).__name__}); "
                           f"the file is damaged") from None
    if x.size == 0:
        raise ImportDataError(f"{p}: holds no samples")
    if not np.isfinite(x).all():
        raise ImportDataError(f"{p}: the {what} holds NaN or inf samples (float WAV); it is damaged: export it again")
    return x, sr


def _repeats(x: np.ndarray) -> int | None:
    """How many times a shorter period repeats within the periods ``x`` (16..2, 90 % autocorrelation), or ``None``."""
    x = np.atleast_2d(np.asarray(x, np.float64))
    n = x.shape[1]
    r = scipy.fft.irfft(np.abs(scipy.fft.rfft(x, axis=1)) ** 2, n=n, axis=1)
    for k in range(16, 1, -1):
        if n % k == 0 and np.median(r[:, n // k] / np.maximum(r[:, 0], 1e-300)) > 0.9:
            return k
    return None


def _check_received(frames: np.ndarray, rig: Rig, p: Path, *, offset: int = 0, channel: int = 0, channels: int = 1) -> None:
    """A recording cut into sweep periods holds the sweep (else --period/--sweep/--chirp do not describe the file)."""
    n, L = frames.shape
    fix = "check --period/--chirp or --sweep (and that the file is the receiver's recording)"
    if n < 2:
        raise ImportDataError(f"{p}: holds {n} whole sweep of {L} samples after the first sweep start; a recording needs at "
                              f"least two: record longer, or {fix}")
    pairs = np.unique(np.linspace(0, n - 2, min(n - 1, 256)).astype(int))
    a = frames[pairs].astype(np.float64)
    b = frames[pairs + 1].astype(np.float64)
    a -= a.mean(axis=1, keepdims=True)
    b -= b.mean(axis=1, keepdims=True)
    # Correlation of each period with the next at small shifts: a right period repeats at shift 0; a period a few
    # samples off repeats at that shift (its frames drift); noise or a half period repeats nowhere.
    xc = scipy.fft.irfft(scipy.fft.rfft(b, axis=1) * np.conj(scipy.fft.rfft(a, axis=1)), n=L, axis=1)
    xc /= np.sqrt(np.sum(a * a, 1) * np.sum(b * b, 1))[:, None] + 1e-300
    med = np.median(xc, axis=0)
    lags = np.r_[0:65, L - 64:L]
    k = int(lags[np.argmax(med[lags])])
    lag = k if k < L // 2 else k - L
    if lag and med[k] >= 0.8 and med[k] > med[0] + 0.1:
        raise ImportDataError(f"{p}: the recording repeats every {L + lag} samples, not every {L} (correlation "
                              f"{med[k]:.2f} against {med[0]:.2f}): the sweep period is {(L + lag) / rig.fs_hz:.7g} s; {fix}")
    if med[0] < 0.3:
        raise ImportDataError(f"{p}: consecutive sweep periods of {L} samples do not repeat (median correlation {med[0]:.2f}): "
                              f"the file holds no sweep of this period; {fix}")
    k = _repeats(a)
    if k:
        raise ImportDataError(f"{p}: the recording repeats every {L // k} samples, not every {L}: the sweep period is "
                              f"{L // k / rig.fs_hz:.6g} s; {fix}")
    blocks = [frames[i:i + 8].astype(np.float64).mean(axis=0) for i in np.linspace(0, max(n - 8, 0), min(64, n)).astype(int)]
    P = np.mean([np.abs(scipy.fft.rfft(x - x.mean())) ** 2 for x in blocks], axis=0)
    share = float(P[rig.band_bins].sum() / max(P[1:].sum(), 1e-300))
    if share < 0.01:
        c = np.cumsum(P[1:]) / P[1:].sum()
        lo, hi = rig.freqs_hz[1 + np.searchsorted(c, 0.05)], rig.freqs_hz[1 + min(np.searchsorted(c, 0.95), c.size - 1)]
        raise ImportDataError(f"{p}: {share:.1%} of the repeating signal's power lies in the sweep band "
                              f"{rig.f_lo_hz / 1e3:g}-{rig.f_hi_hz / 1e3:g} kHz (most lies at {lo / 1e3:.3g}-{hi / 1e3:.3g} kHz); {fix}")
    first = frames[: min(8, n)].astype(np.float64).mean(axis=0)
    first -= first.mean()
    ref = rig_chirp(rig).astype(np.float64)
    ref -= ref.mean()
    xc = scipy.fft.irfft(scipy.fft.rfft(first) * np.conj(scipy.fft.rfft(ref)), n=L)
    shape = float(np.abs(xc).max() / np.sqrt(np.sum(first ** 2) * np.sum(ref ** 2) + 1e-300))
    if shape > LOOPBACK_CORR:
        raise ImportDataError(f"{p}: channel {channel} is the transmitted sweep itself (correlation {shape:.3f} with it), not a "
                              f"received one: a loopback or the playback file; pass --channel N for the receiver's channel "
                              f"(the file has {channels})")
    faults = frame_faults(frames)
    if np.any(faults == 2):
        k = int(np.flatnonzero(faults == 2)[0])
        raise ImportDataError(f"{p}: {int(np.sum(faults == 2))} of {n} sweeps are silent (the first is sweep {k}, "
                              f"{(offset + k * L) / rig.fs_hz:.3f} s): a dropout in the recording; cut the file at the "
                              f"dropout or record again")
    if np.any(faults == 3):
        raise ImportDataError(f"{p}: {int(np.sum(faults == 3))} of {n} sweeps are clipped at full scale (the first is sweep "
                              f"{np.flatnonzero(faults == 3)[0]}): their spectra are distorted and the model verbs refuse "
                              f"clipped sweeps; record again with a lower input gain")


def _cut_short(r: dict, t: np.ndarray, n_samples: int, rig, fs: float) -> bool:
    """Whether label row ``r``'s interval holds only the start of the recording's last, incomplete sweep."""
    if not t.size:
        return False
    nxt = t[-1] + rig.period_s  # where the incomplete sweep starts
    return bool(r["start_s"] <= nxt < r["end_s"] and nxt * fs < n_samples)


def import_wav(wav_dir: str | Path, labels: str | Path, out: str | Path, *, sweep_wav: str | Path | None = None,
               chirp_hz: tuple[float, float] | None = None, period_s: float | None = None, amplitude: float = 1.0,
               channel: int = 0, pwm_hz=(), pwm_halfwidth_hz: float = 0.0, mode: str = "create", log=print) -> Path:
    """Import WAV recordings into a dataset folder and return it; a failed import leaves no new dataset behind."""

    wav_dir, labels, out = Path(wav_dir), Path(labels), Path(out)
    if not wav_dir.is_dir():
        raise FileNotFoundError(f"{wav_dir}: no such folder of recordings")
    if sweep_wav is not None and (chirp_hz is not None or period_s is not None):
        raise ImportDataError("give the transmitted sweep one way: --sweep SWEEP.wav, or --chirp F_LO F_HI --period S; not both")
    rows = _read_labels(labels, log=log)
    files = sorted(p for p in wav_dir.iterdir() if p.suffix.lower() in (".wav", ".flac"))
    if not files:
        raise ValueError(f"{wav_dir}: no .wav or .flac recordings")
    unknown = {r["file"] for r in rows} - {p.name for p in files}
    if unknown:
        raise ValueError(f"{labels}: labels name files that are not in {wav_dir}: {sorted(unknown)}")
    infos = {p: _sf_info(p) for p in files}
    rates = {i.samplerate for i in infos.values()}
    if len(rates) != 1:
        raise ValueError(f"{wav_dir}: recordings at different sample rates {sorted(rates)}; resample them to one")
    fs = float(rates.pop())
    if sweep_wav is not None:
        sweep, sr = _sf_read(Path(sweep_wav), "sweep")
        if sr != fs:
            raise ValueError(f"{sweep_wav}: the sweep is at {sr} Hz but the recordings at {fs:g} Hz")
        rig = sweep_rig(sweep[:, 0], fs, pwm_hz=pwm_hz, pwm_halfwidth_hz=pwm_halfwidth_hz)
    elif chirp_hz is not None and period_s is not None:
        if not (np.isfinite(period_s) and 0 < period_s * fs <= 1 << 22):
            raise ImportDataError(f"--period {period_s:g} s is {period_s * fs:.3g} samples at {fs:g} Hz; a sweep period is "
                                  f"64..{1 << 22} samples")
        n = int(round(period_s * fs))
        rig = Rig(fs_hz=fs, f_lo_hz=chirp_hz[0], f_hi_hz=chirp_hz[1], n_chirp=n, pwm_hz=tuple(pwm_hz),
                  pwm_halfwidth_hz=pwm_halfwidth_hz, amplitude=amplitude, name="imported")
    else:
        raise ValueError("give the transmitted sweep: --sweep SWEEP.wav, or --chirp F_LO F_HI --period S for a linear chirp")
    ids, layout, names = label_layout([r["label"] for r in rows], [r["x_cm"] for r in rows], [r["y_cm"] for r in rows],
                                      where=str(labels), log=log)
    for r, i in zip(rows, ids):
        r["location"] = int(i)

    ref = rig_chirp(rig)
    for p in files:
        _check_intervals(rows, labels, p.name, infos[p].frames / fs, rig.period_s)
    # Times in minutes (or ms read as s by a spreadsheet) still fall inside the recordings: a hint, not a refusal.
    ends = [max((r["end_s"] for r in rows if r["file"] == p.name), default=None) for p in files]
    unlabelled = [p.name for p, e in zip(files, ends) if e is None]
    if unlabelled:  # (a hands-off recording is a session without a touch; a forgotten one would read as one)
        warnings.warn(f"{labels} has no row for {', '.join(unlabelled[:5])}{' ...' if len(unlabelled) > 5 else ''}: imported "
                      f"as hands-off (no touch in {'it' if len(unlabelled) == 1 else 'them'}); if a recording holds "
                      f"presses, add their rows", stacklevel=2)
    if all(e is None or e < 0.2 * infos[p].frames / fs for p, e in zip(files, ends)):
        last = max(e for e in ends if e is not None)
        longest = max(files, key=lambda p: infos[p].frames)
        warnings.warn(f"{labels}: every interval ends in the first fifth of its recording (the last at {last:g} s; "
                      f"{longest.name} is {infos[longest].frames / fs:.3g} s long): are the times in seconds?", stacklevel=2)
    # The recordings (in session order) and the label file are bound to the dataset: --resume with another
    # folder content or edited labels would otherwise mix two imports (sessions are numbered in file order).
    source = {"kind": "import-wav", "from": str(wav_dir.resolve()), "labels": {str(k): v for k, v in names.items()},
              "files": [p.name for p in files], "labels_sha256": hashlib.sha256(labels.read_bytes()).hexdigest()}
    if mode == "resume" and (out / "dataset.json").is_file():
        old = load_json(out / "dataset.json").get("source", {})
        if isinstance(old, dict) and "files" not in old:
            raise ImportDataError(f"cannot resume {out}: it was imported by an older sonicskin that did not record which "
                                  f"files it holds; pass --overwrite to import every recording again")
        if isinstance(old, dict) and old.get("files") != source["files"]:
            raise ImportDataError(f"cannot resume {out}: it was imported from the recordings {old.get('files')}, the folder now "
                                  f"holds {source['files']} (sessions are numbered in file order); import into a new --out "
                                  f"or pass --overwrite")
        if isinstance(old, dict) and old.get("labels_sha256") != source["labels_sha256"]:
            raise ImportDataError(f"cannot resume {out}: {labels} changed since the import began; pass --overwrite to import "
                                  f"every recording with the new labels")
    with _staged(out, mode, inputs=[wav_dir, labels, *files]) as (root, wmode):
        w = DatasetWriter(root, rig, layout, source=source, mode=wmode)
        done = 0
        recordings: dict[str, str] = {}  # sha256 of a channel's samples -> file
        for k, p in enumerate(files):
            session = f"s{k:03d}"
            if w.session_done(session):
                continue
            x, _ = _sf_read(p)
            if channel >= x.shape[1]:
                raise ValueError(f"{p}: has {x.shape[1]} channels; --channel {channel} does not exist")
            channels = x.shape[1]
            x = x[:, channel]
            digest = hashlib.sha256(x.tobytes()).hexdigest()
            if digest in recordings:
                raise ImportDataError(f"{p}: holds the same samples as {recordings[digest]}: one recording would be two "
                                      f"sessions (trained and tested on twice); remove the copy")
            recordings[digest] = p.name
            if not np.sqrt(np.mean(np.square(x, dtype=np.float64))) > SILENT_RMS:
                raise ImportDataError(f"{p}: channel {channel} is silent (all zeros or below {SILENT_RMS:g} RMS): no sweep "
                                      f"was received; check the file and --channel")
            peak = float(np.max(np.abs(x)))
            if peak > 1.0:
                raise ImportDataError(f"{p}: samples reach {peak:.3g}, beyond full scale (1.0): the dataset's 24-bit parts would "
                                      f"clip them; scale every recording by one gain (at most {1 / peak:.3g}) and import again")
            if x.size < 2 * rig.n_chirp:
                raise ValueError(f"{p}: {x.size} samples hold less than two sweeps of {rig.n_chirp}; is --sweep/--period right?")
            frames, offset = frame_stream(x, ref)
            _check_received(frames, rig, p, offset=offset, channel=channel, channels=channels)
            starts = offset + np.arange(frames.shape[0]) * rig.n_chirp
            t = starts / fs
            lab = {c: np.zeros(t.size) for c in COLUMNS}
            lab.update(chirp=np.arange(t.size), t_s=t, time_s=t, location=np.full(t.size, -1), x_cm=np.full(t.size, np.nan),
                       y_cm=np.full(t.size, np.nan), force_n=np.zeros(t.size), moving=np.zeros(t.size),
                       temperature_c=np.full(t.size, np.nan), subject=np.zeros(t.size, int))
            seg = np.array(["calibration"] * t.size, dtype=object)
            for r in (r for r in rows if r["file"] == p.name):
                m = slice(*np.searchsorted(t, [r["start_s"], r["end_s"]], side="left"))  # t increases: [start, end)
                if m.start >= m.stop and _cut_short(r, t, x.size, rig, fs):
                    # a recording stopped a moment early: its last sweep began inside the interval but is incomplete
                    tail = (x.size - starts[-1] - rig.n_chirp) / fs if t.size else 0.0
                    warnings.warn(f"{labels} line {r['line']}: the interval {r['start_s']:g}-{r['end_s']:g} s of {p.name} "
                                  f"holds only the sweep starting at {t[-1] + rig.period_s:.4f} s, which the recording cuts "
                                  f"short ({rig.n_chirp - round(tail * fs)} of its {rig.n_chirp} samples missing at the end "
                                  f"of the file): that chirp is left out", stacklevel=2)
                    continue
                if m.start >= m.stop:
                    raise ImportDataError(f"{labels} line {r['line']}: the interval {r['start_s']:g}-{r['end_s']:g} s of {p.name} holds "
                                          f"no sweep start (sweeps start every {rig.period_s * 1e3:.4g} ms from {t[0]:.4g} s); "
                                          f"times are in seconds: fix the interval")
                if r["location"] >= 0:
                    lab["location"][m] = r["location"]
                    lab["x_cm"][m], lab["y_cm"][m] = layout.coords(np.array([r["location"]]))[0]
                    lab["force_n"][m] = r["force_n"]
                    seg[m] = "touch"
                else:
                    seg[m] = "moving" if r["moving"] > 0 else "gap"
                lab["moving"][m] = r["moving"]
                lab["subject"][m] = r["subject"]
            # chirps no interval labels: the leading rest is the boot calibration, later ones are no-touch chirps
            unlabelled = seg == "calibration"
            seg[unlabelled & (np.arange(t.size) >= _first_touch(seg == "touch"))] = "gap"
            lab["segment"] = seg.astype(str)
            _write_session(w, session, x, lab, {"source_file": p.name})
            done += 1
    log(f"imported {done} recordings ({fs:g} Hz, band {rig.f_lo_hz / 1e3:.1f}-{rig.f_hi_hz / 1e3:.1f} kHz, "
        f"{rig.n_chirp} samples per sweep) into {out}" + (f"; {len(files) - done} were there already" if done < len(files) else ""))
    return out
