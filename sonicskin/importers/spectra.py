"""``import_spectra``: a table of precomputed channel magnitudes with labels (``.npz``) into a dataset; the rig is
derived from the table's frequency axis (:func:`rig_from_axis`)."""

from __future__ import annotations

import difflib
import hashlib
import warnings
from pathlib import Path

import numpy as np
import scipy.fft

from ..dataset import DatasetWriter, check_name, read_npz
from ..dsp import chirp_spectrum
from ..errors import check_memory
from ..rig import Rig
from ._common import PEAK_LEVEL, ImportDataError, _first_touch, _staged, _write_session
from .labels import _check_values, label_layout, touch_forces

# Sample rates of common audio interfaces, preferred in this order when the axis fits several equally.
STANDARD_RATES_HZ = (48_000, 96_000, 192_000, 384_000, 44_100, 88_200, 176_400, 352_800, 8_000, 16_000, 32_000, 11_025, 22_050, 24_000)
MAX_SPAN_DB = 200.0  # dB between the quietest and the loudest value of a table of measured spectra


def rig_from_axis(freqs_hz: np.ndarray, *, fs_hz: float | None = None, frame: int | None = None,
                  log=print) -> Rig:
    """The rig whose FFT bins are a table's frequency axis (without ``fs_hz``/``frame``: the lowest standard rate that fits)."""
    f = np.asarray(freqs_hz, float)
    if f.ndim != 1 or f.size < 2:
        raise ValueError(f"freqs_hz must list at least two frequencies, got shape {f.shape}")
    if not np.all(np.diff(f) > 0):
        raise ValueError("freqs_hz must increase")
    if not f[0] > 0:
        raise ImportDataError(f"freqs_hz starts at {f[0]:g} Hz; the table's columns are the sweep band's FFT bins, "
                              f"above 0 Hz (leave out DC and negative frequencies)")
    df = (f[-1] - f[0]) / (f.size - 1)
    if np.max(np.abs(np.diff(f) - df)) > 0.05 * df:
        raise ValueError(f"freqs_hz is not evenly spaced (steps {np.diff(f).min():g}-{np.diff(f).max():g} Hz); "
                         f"the columns must be the FFT bins of one frame size")
    if fs_hz is not None and frame is not None:
        if abs(fs_hz / frame - df) > 0.02 * df:
            raise ValueError(f"--fs {fs_hz:g} / --frame {frame} = {fs_hz / frame:g} Hz per bin, but the table's bins are "
                             f"{df:g} Hz apart; check both")
        fs, n = float(fs_hz), int(frame)
        how = "given"
    elif fs_hz is not None:
        fs, n = float(fs_hz), int(round(fs_hz / df))
        how = "given"
    elif frame is not None:
        n = int(frame)
        fs = n * df
        near = [r for r in STANDARD_RATES_HZ if abs(r - fs) <= 0.01 * fs]
        fs = float(near[0]) if near else float(round(fs))
        how = f"{n} samples x {df:g} Hz"
    else:
        # Standard rates whose whole-sample frames have bins where the columns are, give or take a constant
        # shift (bin edges instead of centres) and a few Hz: the first in STANDARD_RATES_HZ among those that
        # fit within 5 Hz of the best fit.  A near miss (44.1 instead of 48 kHz) maps the same columns to the
        # same bins at a chirp rate within 0.1 %: the features do not change.
        fits = []
        for order, r in enumerate(STANDARD_RATES_HZ):
            m = int(round(r / df))
            if r < 2 * f[-1] * (1 - 1e-3) or m < 64:
                continue
            kk = np.floor(f * m / r + 0.5 + 1e-6)
            d = f - kk * r / m
            if np.all(np.diff(kk) == 1) and np.max(np.abs(d)) <= 0.5 * r / m * (1 + 1e-6):
                fits.append((float(np.max(np.abs(d - d.mean()))), order, r, m))
        if not fits:
            raise ValueError(f"cannot tell the sample rate from the axis alone (bins {df:g} Hz apart up to {f[-1]:g} Hz); "
                             f"pass --fs HZ (the recordings' rate) or --frame N (samples per FFT frame)")
        best = min(e for e, *_ in fits)
        _, _, r, n = min((o, e, r, m) for e, o, r, m in fits if e <= best + min(5.0, 0.25 * df))
        fs = float(r)
        if n > fs:
            raise ImportDataError(f"the axis ({f[0]:g}-{f[-1]:g}, bins {df:g} apart) would mean FFT frames of {n / fs:.3g} s; "
                                  f"freqs_hz must be in Hz (are these kHz? multiply by 1000), or pass --fs and --frame")
        how = f"a standard rate with {n}-sample frames fits the axis; pass --fs or --frame if yours differs"
    if n < 64:
        raise ValueError(f"{n} samples per frame (fs {fs:g} Hz / {df:g} Hz bins) is too short; pass --fs or --frame")
    k = np.floor(f * n / fs + 0.5 + 1e-6).astype(int)
    if np.any(np.diff(k) != 1):
        raise ValueError(f"the axis does not fall on the bins of a {n}-sample frame at {fs:g} Hz "
                         f"(bin spacing {fs / n:g} Hz, table {df:g} Hz); pass the right --fs / --frame")
    if k[-1] > n // 2:
        raise ValueError(f"the table reaches {f[-1]:g} Hz, above the Nyquist frequency of {fs:g} Hz; pass the right --fs")
    step = fs / n
    off = float(np.max(np.abs(f - k * step)))
    rig = Rig(fs_hz=fs, f_lo_hz=max(k[0] - 0.25, 0.25) * step, f_hi_hz=min(k[-1] + 0.25, n / 2) * step, n_chirp=n,
              pwm_hz=(), pwm_halfwidth_hz=0.0, amplitude=PEAK_LEVEL, name="imported")
    log(f"rig from the frequency axis: fs {fs:g} Hz ({how}), {n}-sample frames, {rig.n_band} bins "
        f"{k[0] * step / 1e3:.3g}-{k[-1] * step / 1e3:.4g} kHz" + (f" (axis off the bin grid by up to {off:.1f} Hz)"
                                                                    if off > 1e-6 * step else ""))
    return rig


def _segments(touch: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Segments of a session's rows: touches, the rest before the first touch as the boot, later rest as no-touch."""
    later = np.arange(touch.size) >= _first_touch(touch)
    return np.where(touch, "touch", np.where(~later, "calibration", np.where(moving > 0, "moving", "gap")))


def _looks_linear(M: np.ndarray) -> bool:
    """Magnitudes that are all >= 0 and spread over orders of magnitude (or all <= 1) are linear, not dB."""
    if M.min() < 0:
        return False
    p50, p99 = np.percentile(M, [50, 99])
    return bool(M.max() <= 1.0 or M.max() > 300 or p99 > 10 * max(p50, 1e-12))  # 300 dB would be 1e15


_TABLE_ARRAYS = ("freqs_hz", "magnitude_db", "location", "session", "x_cm", "y_cm", "force_n", "moving", "subject")
def _check_array_names(table: Path) -> None:
    """Refuse an array whose name is a near miss of one the importer reads (``force`` for ``force_n``): it would be lost."""
    import zipfile

    try:
        with zipfile.ZipFile(table) as zf:
            names = [n[:-4] for n in zf.namelist() if n.endswith(".npy")]
    except (OSError, zipfile.BadZipFile, ValueError):
        return  # read_npz reports an unreadable table
    for a in names:
        if a in _TABLE_ARRAYS:
            continue
        near = [k for k in _TABLE_ARRAYS if k.lower() == a.lower()] or difflib.get_close_matches(a.lower(), _TABLE_ARRAYS, 1, 0.75)
        if near and near[0] not in names:
            raise ImportDataError(f"{table}: array {a!r} is not one the importer reads; did you mean {near[0]!r}? "
                                  f"(arrays: {', '.join(_TABLE_ARRAYS)})")


def import_spectra(table: str | Path, out: str | Path, *, rig: Rig | None = None, fs_hz: float | None = None,
                   frame: int | None = None, linear: bool = False, mode: str = "create", log=print) -> Path:
    """Import the ``.npz`` ``table`` of magnitude spectra (``linear``: not dB) into the dataset folder ``out``."""
    table, out = Path(table), Path(out)
    _check_array_names(table)
    # Only the arrays this importer uses are read, each checked from its header first.
    z = read_npz(table, {"freqs_hz": ("fiu", 1), "magnitude_db": ("fiu", 2), "location": ("fiuU", 1),
                         "session": ("iuU", 1), "x_cm": ("fiu", 1), "y_cm": ("fiu", 1), "force_n": ("fiu", 1),
                         "moving": ("fiu", 1), "subject": ("fiu", 1)},
                 optional=("x_cm", "y_cm", "force_n", "moving", "subject"), what="table")
    f, M = np.asarray(z["freqs_hz"], float), np.asarray(z["magnitude_db"], float)
    if M.ndim != 2 or M.shape[1] != f.size:
        raise ValueError(f"{table}: magnitude_db must be (n, {f.size}) for {f.size} frequencies, got {M.shape}")
    n = M.shape[0]
    if n == 0:
        raise ImportDataError(f"{table}: magnitude_db has no rows; the table holds no spectra")
    for k in ("location", "session", "x_cm", "y_cm", "force_n", "moving", "subject"):
        if k in z and np.shape(z[k]) != (n,):
            raise ValueError(f"{table}: {k} has shape {np.shape(z[k])}; need one value per row ({n},)")
    if not np.isfinite(f).all():
        raise ImportDataError(f"{table}: freqs_hz has NaN or inf")
    _check_values(str(table), force=z.get("force_n"), moving=z.get("moving"), subject=z.get("subject"),
                  x_cm=z.get("x_cm"), y_cm=z.get("y_cm"))
    for name in sorted(set(np.asarray(z["session"]).astype(str))):
        check_name(name, "session", str(table))
    if not np.all(np.diff(f) > 0):
        raise ValueError(f"{table}: freqs_hz must increase")
    if not np.isfinite(M).all():
        raise ValueError(f"{table}: magnitude_db has NaN or inf")
    if linear:
        if M.min() < 0:
            raise ValueError(f"{table}: --linear magnitudes cannot be negative (min {M.min():g}); are they dB already?")
        M = 20 * np.log10(np.maximum(M, 1e-12 * max(M.max(), 1e-300)))
    lo, hi = np.unravel_index(int(np.argmin(M)), M.shape), np.unravel_index(int(np.argmax(M)), M.shape)
    if not linear and M[hi] - M[lo] > MAX_SPAN_DB:
        fix = ("they look like linear magnitudes: import with --linear (20 log10 |H|)" if _looks_linear(M) else
               "fix the damaged rows")
        raise ImportDataError(f"{table}: magnitude_db spans {M[hi] - M[lo]:.3g} dB (row {lo[0]}: {M[lo]:.3g}, row {hi[0]}: "
                              f"{M[hi]:.3g}); measured spectra span less than {MAX_SPAN_DB:g} dB: {fix}")
    if not linear and _looks_linear(M):
        why = "all <= 1" if M.max() <= 1 else "spread over orders of magnitude"
        warnings.warn(f"{table}: magnitude_db looks linear, not dB (all >= 0, {why}); "
                      f"if so, import with --linear (20 log10 |H|)", stacklevel=2)
    derived = rig is None
    if derived:
        rig = rig_from_axis(f, fs_hz=fs_hz, frame=frame, log=log)
    fb = rig.freqs_hz[rig.band_bins]
    step = f[1] - f[0]
    if f[0] > fb[0] + step or f[-1] < fb[-1] - step:
        raise ValueError(f"{table}: spectra cover {f[0]:g}-{f[-1]:g} Hz but the rig's band is {fb[0]:g}-{fb[-1]:g} Hz; "
                         f"leave out the rig (it is derived from the table) or pass one whose band lies inside the table")
    if n > 1 and not np.ptp(M, axis=0).any():
        raise ImportDataError(f"{table}: every row of magnitude_db is the same spectrum; the table holds no measurements "
                              f"(a fill value or a broadcast?)")
    ids, layout, names = label_layout(z["location"], z.get("x_cm"), z.get("y_cm"), where=str(table), log=log)
    sessions = np.asarray(z["session"]).astype(str)
    force = touch_forces(z["force_n"], ids >= 0, where=str(table), log=log) if "force_n" in z else np.full(n, np.nan)
    if not np.isfinite(force[ids >= 0]).any():
        log("no force values (no force sensor): localization only; force is reported as absent")
    # Each row's magnitude on the rig's bins (rows of the derived rig map one to one; another rig interpolates).
    if derived:
        assert rig.n_band == f.size
        A = M
    else:
        A = np.stack([np.interp(fb, f, m) for m in M])
    sessions_n = max(int(np.sum(sessions == s)) for s in set(sessions))
    seen: dict[bytes, str] = {}
    for s in sorted(set(sessions.tolist())):  # a session pasted twice under two names: its chirps would count twice
        h = hashlib.sha256(np.ascontiguousarray(A[sessions == s]).tobytes()).digest()
        if h in seen:
            raise ImportDataError(f"{table}: sessions {seen[h]!r} and {s!r} hold the same spectra row for row; one recording "
                                  f"would be two sessions (trained and tested on twice): remove the copy")
        seen[h] = s
    # frames_of holds a session's spectra (complex) and its frames (float64) at once, plus the audio.
    check_memory(sessions_n * (rig.n_chirp // 2 + 1) * 16 * 3 + sessions_n * rig.n_chirp * 8 * 3,
                 f"building the longest session of {table} ({sessions_n} rows of {rig.n_chirp}-sample frames)",
                 "pass a smaller --frame or --fs, or split the table's sessions")
    S = chirp_spectrum(rig)

    def frames_of(idx):
        H = np.zeros((idx.size, rig.n_chirp // 2 + 1), complex)
        H[:, rig.band_bins] = 10 ** ((A[idx] - top_db) / 20)
        return scipy.fft.irfft(H * S, n=rig.n_chirp, axis=-1)

    # One gain for the whole table (relative levels between rows are the data): peak at -6 dBFS.
    # Frames are built relative to the loudest bin (no overflow at any level); gain_db is the total.
    top_db = float(A.max())
    peak = max(float(np.abs(frames_of(np.flatnonzero(sessions == s))).max()) for s in set(sessions))
    gain = PEAK_LEVEL / peak
    gain_db = float(20 * np.log10(gain)) - top_db
    source = {"kind": "import-spectra", "from": str(table.resolve()), "gain_db": round(gain_db, 6),
              "labels": {str(k): v for k, v in names.items()}}
    L = rig.n_chirp
    with _staged(out, mode, inputs=[table]) as (root, wmode):
        w = DatasetWriter(root, rig, layout, source=source, mode=wmode)
        for s in sorted(set(sessions)):
            if w.session_done(s):
                continue
            idx = np.flatnonzero(sessions == s)
            frames = (frames_of(idx) * gain).astype(np.float32)
            audio = np.concatenate([frames[0, L // 2:], frames.ravel(), frames[-1, : L // 2]])  # starts mid-sweep
            t = (L // 2 + np.arange(idx.size) * L) / rig.fs_hz
            loc = ids[idx]
            touch = loc >= 0
            lab = {"chirp": np.arange(idx.size), "t_s": t, "time_s": t,
                   "segment": _segments(touch, np.asarray(z.get("moving", np.zeros(n)), float)[idx]), "location": loc,
                   "x_cm": np.where(touch, layout.coords(np.where(touch, loc, layout.ids[0]))[:, 0], np.nan),
                   "y_cm": np.where(touch, layout.coords(np.where(touch, loc, layout.ids[0]))[:, 1], np.nan),
                   "force_n": force[idx], "moving": np.asarray(z.get("moving", np.zeros(n)), float)[idx],
                   "temperature_c": np.full(idx.size, np.nan),
                   "subject": np.asarray(z.get("subject", np.zeros(n)), float).astype(np.int64)[idx]}
            _write_session(w, s, audio, lab, {"rows": int(idx.size)})
    log(f"imported {n} spectra in {len(set(sessions))} sessions into {out} (levels scaled by {gain_db:+.1f} dB, "
        f"stored as source.gain_db)")
    return out
