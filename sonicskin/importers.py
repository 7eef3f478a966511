"""Bring recordings from other rigs into the dataset format, so they train and compare like
simulated data.

``import_wav``: a folder of WAV recordings (one continuous recording per file = one session),
the transmitted sweep (a WAV of one period, any sweep; or a linear chirp's parameters), any
sample rate, and a label CSV of touch intervals::

    file,start_s,end_s,location,x_cm,y_cm,force_n,moving,subject
    run1.wav,3.2,5.9,7,8.4,1.2,3.5,0,0

Chirps starting inside an interval carry its label; the others are no-touch.  ``force_n`` may
be empty (no sensor), ``moving`` marks robot motion (use ``location`` -1 for a moving, hands-off
interval).  Marker coordinates come from the ``x_cm``/``y_cm`` columns.

``import_spectra``: a table of precomputed channel magnitudes with labels (``.npz`` with arrays
``freqs_hz`` (F,), ``magnitude_db`` (n, F) and one array per label column), e.g. from another
group's pipeline.  Each row becomes one received chirp of the given rig with exactly that
magnitude response in band (zero phase), so every tool of this package runs on it unchanged.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import scipy.fft

from .dataset import COLUMNS, DatasetWriter
from .dsp import chirp_spectrum, frame_stream
from .rig import Layout, Rig

__all__ = ["import_wav", "import_spectra", "sweep_rig"]

_LABEL_COLS = ("file", "start_s", "end_s", "location")


def sweep_rig(sweep: np.ndarray, fs_hz: float, *, pwm_hz=(), pwm_halfwidth_hz: float = 0.0, band_db: float = -20.0,
              name: str = "imported") -> Rig:
    """A rig for an arbitrary transmitted sweep: its band is where its spectrum is within ``band_db`` of the peak."""
    x = np.asarray(sweep, np.float32)
    if x.ndim != 1 or x.size < 64:
        raise ValueError(f"the sweep must be one period of mono audio (>= 64 samples), got shape {x.shape}")
    S = np.abs(scipy.fft.rfft(x))
    f = np.fft.rfftfreq(x.size, 1 / fs_hz)
    on = np.flatnonzero(20 * np.log10(S / S.max() + 1e-12) >= band_db)
    f_lo, f_hi = float(max(f[on[0]], f[1])), float(f[on[-1]])
    return Rig(fs_hz=float(fs_hz), f_lo_hz=f_lo, f_hi_hz=f_hi, n_chirp=int(x.size), pwm_hz=tuple(pwm_hz),
               pwm_halfwidth_hz=pwm_halfwidth_hz, amplitude=float(min(1.0, np.max(np.abs(x)) or 1.0)), name=name,
               sweep_b64=Rig.encode_sweep(x))


def _read_labels(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ValueError(f"{path}: no label rows")
    missing = [c for c in _LABEL_COLS if c not in rows[0]]
    if missing:
        raise ValueError(f"{path}: label CSV lacks columns {missing}; need file,start_s,end_s,location "
                         f"(and x_cm,y_cm for each location; optional force_n,moving,subject)")
    out = []
    for i, r in enumerate(rows, start=2):
        try:
            d = {"file": r["file"], "start_s": float(r["start_s"]), "end_s": float(r["end_s"]), "location": int(r["location"]),
                 "x_cm": float(r["x_cm"]) if r.get("x_cm") not in (None, "") else np.nan,
                 "y_cm": float(r["y_cm"]) if r.get("y_cm") not in (None, "") else np.nan,
                 "force_n": float(r["force_n"]) if r.get("force_n") not in (None, "") else np.nan,
                 "moving": float(r["moving"]) if r.get("moving") not in (None, "") else 0.0,
                 "subject": int(r["subject"]) if r.get("subject") not in (None, "") else 0}
        except ValueError as e:
            raise ValueError(f"{path} line {i}: {e}") from None
        if d["end_s"] <= d["start_s"]:
            raise ValueError(f"{path} line {i}: end_s must be after start_s")
        out.append(d)
    return out


def _layout_from(rows: list[dict], path: Path) -> Layout:
    pos: dict[int, tuple[float, float]] = {}
    for r in rows:
        if r["location"] >= 0 and r["location"] not in pos:
            if not (np.isfinite(r["x_cm"]) and np.isfinite(r["y_cm"])):
                raise ValueError(f"{path}: location {r['location']} has no x_cm,y_cm; give marker coordinates in cm")
            pos[r["location"]] = (r["x_cm"], r["y_cm"])
    if len(pos) < 2:
        raise ValueError(f"{path}: labels name {len(pos)} touch locations; need at least two")
    ids = sorted(pos)
    return Layout(ids=tuple(ids), xy_cm=np.array([pos[i] for i in ids]))


def import_wav(wav_dir: str | Path, labels: str | Path, out: str | Path, *, sweep_wav: str | Path | None = None,
               chirp_hz: tuple[float, float] | None = None, period_s: float | None = None, amplitude: float = 1.0,
               channel: int = 0,
               pwm_hz=(), pwm_halfwidth_hz: float = 0.0, mode: str = "create", log=print) -> Path:
    """Import WAV recordings into a dataset folder; returns it."""
    import soundfile as sf

    wav_dir, labels, out = Path(wav_dir), Path(labels), Path(out)
    rows = _read_labels(labels)
    files = sorted(p for p in wav_dir.iterdir() if p.suffix.lower() in (".wav", ".flac"))
    if not files:
        raise ValueError(f"{wav_dir}: no .wav or .flac recordings")
    unknown = {r["file"] for r in rows} - {p.name for p in files}
    if unknown:
        raise ValueError(f"{labels}: labels name files that are not in {wav_dir}: {sorted(unknown)}")
    rates = {sf.info(p).samplerate for p in files}
    if len(rates) != 1:
        raise ValueError(f"{wav_dir}: recordings at different sample rates {sorted(rates)}; resample them to one")
    fs = float(rates.pop())
    if sweep_wav is not None:
        sweep, sr = sf.read(sweep_wav, dtype="float32", always_2d=True)
        if sr != fs:
            raise ValueError(f"{sweep_wav}: the sweep is at {sr} Hz but the recordings at {fs:g} Hz")
        rig = sweep_rig(sweep[:, 0], fs, pwm_hz=pwm_hz, pwm_halfwidth_hz=pwm_halfwidth_hz)
    elif chirp_hz is not None and period_s is not None:
        n = int(round(period_s * fs))
        rig = Rig(fs_hz=fs, f_lo_hz=chirp_hz[0], f_hi_hz=chirp_hz[1], n_chirp=n, pwm_hz=tuple(pwm_hz),
                  pwm_halfwidth_hz=pwm_halfwidth_hz, amplitude=amplitude, name="imported")
    else:
        raise ValueError("give the transmitted sweep: --sweep SWEEP.wav, or --chirp F_LO F_HI --period S for a linear chirp")
    layout = _layout_from(rows, labels)
    w = DatasetWriter(out, rig, layout, source={"kind": "import-wav", "from": str(wav_dir.resolve())}, mode=mode)
    from .dsp import rig_chirp

    ref = rig_chirp(rig)
    for k, p in enumerate(files):
        x, _ = sf.read(p, dtype="float32", always_2d=True)
        if channel >= x.shape[1]:
            raise ValueError(f"{p}: has {x.shape[1]} channels; --channel {channel} does not exist")
        x = x[:, channel]
        frames, offset = frame_stream(x, ref)
        starts = offset + np.arange(frames.shape[0]) * rig.n_chirp
        t = starts / fs
        lab = {c: np.zeros(t.size) for c in COLUMNS}
        lab.update(chirp=np.arange(t.size), t_s=t, time_s=t, location=np.full(t.size, -1), x_cm=np.full(t.size, np.nan),
                   y_cm=np.full(t.size, np.nan), force_n=np.zeros(t.size), moving=np.zeros(t.size),
                   temperature_c=np.full(t.size, np.nan), subject=np.zeros(t.size, int))
        seg = np.array(["calibration"] * t.size, dtype=object)
        for r in (r for r in rows if r["file"] == p.name):
            m = (t >= r["start_s"]) & (t < r["end_s"])
            if r["location"] >= 0:
                lab["location"][m] = r["location"]
                lab["x_cm"][m], lab["y_cm"][m] = layout.coords(np.array([r["location"]]))[0]
                lab["force_n"][m] = r["force_n"]
                seg[m] = "touch"
            else:
                seg[m] = "moving" if r["moving"] > 0 else "gap"
            lab["moving"][m] = r["moving"]
            lab["subject"][m] = r["subject"]
        lab["segment"] = seg.astype(str)
        session = f"s{k:03d}"
        w.write_part(session, 0, x, lab)
        w.finish_session(session, {"source_file": p.name})
    log(f"imported {len(files)} recordings ({fs:g} Hz, band {rig.f_lo_hz / 1e3:.1f}-{rig.f_hi_hz / 1e3:.1f} kHz, "
        f"{rig.n_chirp} samples per sweep) into {out}")
    return out


def import_spectra(table: str | Path, out: str | Path, *, rig: Rig | None = None, mode: str = "create",
                   log=print) -> Path:
    """Import a table of magnitude spectra (dB) with labels (see module docstring); returns the dataset."""
    table = Path(table)
    rig = rig or Rig.load("jaco")
    try:
        z = dict(np.load(table, allow_pickle=False))
    except (OSError, ValueError) as e:
        raise ValueError(f"{table}: not a readable .npz table ({e})") from None
    need = ("freqs_hz", "magnitude_db", "location", "x_cm", "y_cm", "session")
    missing = [k for k in need if k not in z]
    if missing:
        raise ValueError(f"{table}: missing arrays {missing}; need {', '.join(need)} (optional force_n, moving, subject)")
    f, M = np.asarray(z["freqs_hz"], float), np.asarray(z["magnitude_db"], float)
    n = M.shape[0]
    if M.ndim != 2 or M.shape[1] != f.size:
        raise ValueError(f"{table}: magnitude_db must be (n, {f.size}) for {f.size} frequencies, got {M.shape}")
    if not np.all(np.diff(f) > 0):
        raise ValueError(f"{table}: freqs_hz must increase")
    if not np.isfinite(M).all():
        raise ValueError(f"{table}: magnitude_db has NaN or inf")
    fb = rig.freqs_hz[rig.band_bins]
    if f[0] > fb[0] or f[-1] < fb[-1]:
        raise ValueError(f"{table}: spectra cover {f[0]:g}-{f[-1]:g} Hz but the rig's band is {fb[0]:g}-{fb[-1]:g} Hz; "
                         f"pass a rig whose chirp band lies inside the table")
    loc = np.asarray(z["location"], int)
    rows = [{"location": int(i), "x_cm": float(x), "y_cm": float(y)} for i, x, y in zip(loc, z["x_cm"], z["y_cm"])]
    layout = _layout_from(rows, table)
    w = DatasetWriter(out, rig, layout, source={"kind": "import-spectra", "from": str(table.resolve())}, mode=mode)
    S = chirp_spectrum(rig)
    sessions = np.asarray(z["session"]).astype(str)
    for s in sorted(set(sessions)):
        idx = np.flatnonzero(sessions == s)
        H = np.zeros((idx.size, rig.n_chirp // 2 + 1), complex)
        for j, i in enumerate(idx):
            H[j, rig.band_bins] = 10 ** (np.interp(fb, f, M[i]) / 20)
        frames = scipy.fft.irfft(H * S, n=rig.n_chirp, axis=-1).astype(np.float32)
        peak = float(np.abs(frames).max())
        if peak >= 1.0:
            raise ValueError(f"{table}: session {s} would clip (peak {peak:.2f}); scale magnitude_db down by "
                             f"{20 * np.log10(peak) + 1:.0f} dB")
        L = rig.n_chirp
        audio = np.concatenate([frames[0, L // 2:], frames.ravel(), frames[-1, : L // 2]])  # starts mid-sweep
        t = (L // 2 + np.arange(idx.size) * L) / rig.fs_hz
        lab = {"chirp": np.arange(idx.size), "t_s": t, "time_s": t,
               "segment": np.where(loc[idx] >= 0, "touch", "calibration"), "location": loc[idx],
               "x_cm": np.where(loc[idx] >= 0, z["x_cm"][idx], np.nan), "y_cm": np.where(loc[idx] >= 0, z["y_cm"][idx], np.nan),
               "force_n": np.asarray(z.get("force_n", np.full(n, np.nan)), float)[idx],
               "moving": np.asarray(z.get("moving", np.zeros(n)), float)[idx],
               "temperature_c": np.full(idx.size, np.nan), "subject": np.asarray(z.get("subject", np.zeros(n)), int)[idx]}
        w.write_part(s, 0, audio, lab)
        w.finish_session(s, {"rows": int(idx.size)})
    log(f"imported {n} spectra in {len(set(sessions))} sessions into {out}")
    return Path(out)
