"""Bring recordings from other rigs into the dataset format, so they train and compare like
simulated data.

``import_wav``: a folder of WAV recordings (one continuous recording per file = one session),
the transmitted sweep (a WAV of one period, any sweep; or a linear chirp's parameters), any
sample rate, and a label CSV of touch intervals::

    file,start_s,end_s,location,x_cm,y_cm,force_n,moving,subject
    run1.wav,3.2,5.9,7,8.4,1.2,3.5,0,0

Chirps starting inside an interval carry its label; the others are no-touch.  ``force_n`` may
be empty (no sensor), ``moving`` marks robot motion (use ``location`` -1 for a moving, hands-off
interval).

``import_spectra``: a table of precomputed channel magnitudes with labels (``.npz`` with arrays
``freqs_hz`` (F,), ``magnitude_db`` (n, F), ``location`` and ``session``, optional ``x_cm``,
``y_cm``, ``force_n``, ``moving``, ``subject``), e.g. from another group's pipeline.  The rig is
derived from the frequency axis (bin spacing = fs / samples per frame); each row becomes one
received chirp of that rig with exactly that magnitude response (zero phase), so every tool of
this package runs on it unchanged.  Levels are normalised (the gain is stored in
``dataset.json``, ``source.gain_db``): no dB offset to choose.

Location labels (both importers) may be integers (kept as location ids), numbers such as
positions in cm (``1.5``, ``2.0``) or names (``"wrist"``); numbers and names become ids
0..K-1 in sorted order.  The mapping is printed and stored in ``dataset.json``
(``source.labels``).  Coordinates come from ``x_cm``/``y_cm``; without them a numeric label is
taken as the position in cm along x, and names are placed 1 cm apart.  A negative number, NaN,
an empty cell or ``none``/``no-touch``/``rest`` means no touch.

Writing is all or nothing: a new dataset is built in a hidden folder beside ``out`` and moved
into place when complete; ``mode="resume"`` keeps the sessions already imported and adds the
rest; ``mode="overwrite"`` replaces ``out`` only once the new import succeeded.
"""

from __future__ import annotations

import contextlib
import csv
import difflib
import hashlib
import io
import re
import shutil
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import scipy.fft

from .dataset import (
    COLUMNS,
    MAX_ABS_CM,
    MAX_FORCE_N,
    DatasetWriter,
    check_name,
    read_npz,
    refuse_inside_dataset,
    swap_folders,
    writer_lock,
)
from .dsp import chirp_spectrum, frame_stream
from .errors import SonicskinError
from .limits import check_memory
from .rig import Layout, Rig

__all__ = ["import_wav", "import_spectra", "sweep_rig", "rig_from_axis", "label_layout", "STANDARD_RATES_HZ"]

_LABEL_COLS = ("file", "start_s", "end_s", "location")
_OPTIONAL_COLS = ("x_cm", "y_cm", "force_n", "moving", "subject")
NO_TOUCH_LABELS = frozenset({"", "-1", "nan", "none", "no-touch", "no_touch", "notouch", "rest", "quiet", "idle"})
# Sample rates of common audio interfaces, preferred in this order when the axis fits several equally.
STANDARD_RATES_HZ = (48_000, 96_000, 192_000, 384_000, 44_100, 88_200, 176_400, 352_800, 8_000, 16_000, 32_000,
                     11_025, 22_050, 24_000)
PEAK_LEVEL = 0.5  # imported streams are scaled to this peak (-6 dBFS)
SILENT_RMS = 1e-7  # a recording quieter than this (about -140 dBFS) holds no received sweep
LOOPBACK_CORR = 0.98  # a 'received' channel this close to the transmitted sweep is the sweep itself
MAX_SPAN_DB = 200.0  # dB between the quietest and the loudest value of a table of measured spectra
MAX_LOCATIONS = 100_000  # markers of one layout (dataset.json's bound)
MARKER_SPREAD_CM = 1.0  # rows of one location whose x_cm/y_cm differ by more than this name two places


class ImportDataError(SonicskinError):
    """Input an importer refuses: the message names the file, the row or array, and the fix."""


def _check_values(where: str, *, force=None, moving=None, subject=None, x_cm=None, y_cm=None, rows=None) -> None:
    """Label values at the door: force NaN (no sensor) or finite in [0, MAX_FORCE_N]; moving finite in [0, 1];
    subject a whole number >= 0; coordinates NaN or finite.  ``rows``: names of the rows for the message."""
    def first(mask, col, vals, want):
        mask = np.asarray(mask, bool)
        if mask.any():
            k = int(np.flatnonzero(mask)[0])
            name = rows[k] if rows is not None else f"row {k}"
            v = np.asarray(vals)[k]
            raise ImportDataError(f"{where}: {name}: {col} = {getattr(v, 'item', lambda: v)()!r}, but {want}; fix the value")

    if force is not None:
        f = np.asarray(force, float)
        first(~np.isnan(f) & ~((f >= 0) & (f <= MAX_FORCE_N)), "force_n", force,
              f"a force is empty/NaN (no sensor) or a number in 0..{MAX_FORCE_N:g} N")
    if moving is not None:
        m = np.asarray(moving, float)
        first(~((m >= 0) & (m <= 1)), "moving", moving, "the motion level is a number in [0, 1]")
    if subject is not None:
        v = np.asarray(subject, float)
        first(~(np.isfinite(v) & (v >= 0) & (v < 2**31) & (v == np.round(v))), "subject", subject,
              "a subject is a whole number >= 0")
    for col, c in (("x_cm", x_cm), ("y_cm", y_cm)):
        if c is not None:
            v = np.asarray(c, float)
            first(~np.isnan(v) & ~(np.abs(v) <= MAX_ABS_CM), col, c, "a coordinate is empty/NaN or a finite number of cm")


# -- the rig --------------------------------------------------------------------------

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


def rig_from_axis(freqs_hz: np.ndarray, *, fs_hz: float | None = None, frame: int | None = None,
                  log=print) -> Rig:
    """The rig whose FFT bins are a table's frequency axis.

    The bin spacing is ``fs / frame``.  Give ``fs_hz`` or ``frame`` (samples per FFT frame) when
    you know them; otherwise ``fs`` is the lowest standard audio rate above twice the top frequency
    for which ``fs / spacing`` is a whole number of samples.  The axis may be off the bin grid
    by up to half a bin (bin edges instead of centres, a rounding of a few Hz): each column is
    assigned to its nearest bin.  The rig's band is exactly the table's columns.
    """
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


# -- labels ---------------------------------------------------------------------------

def _as_number(v) -> float | None:
    try:
        return _strict_float(v) if isinstance(v, str) else float(v)
    except (TypeError, ValueError):
        return None


def _is_no_touch(v) -> bool:
    if isinstance(v, str):
        if v.strip().lower() in NO_TOUCH_LABELS:
            return True
        v = _as_number(v.strip())
        return v is not None and (np.isnan(v) or v < 0)
    return bool(np.isnan(v) or v < 0)


def label_layout(labels, x_cm=None, y_cm=None, *, where: str = "labels", log=print) -> tuple[np.ndarray, Layout, dict]:
    """Location ids (``-1`` = no touch) for a column of raw labels, the layout and the id -> label mapping.

    Parameters
    ----------
    labels : (n,) integers, numbers or strings (see the module docstring).
    x_cm, y_cm : (n,) marker coordinates per row (NaN where unknown), optional.
    where : the input's name for messages.

    Returns
    -------
    ids : (n,) int location ids, -1 for no touch.
    layout : one marker per distinct touch label.
    names : ``{id: label}`` as printed.
    """
    raw = np.asarray(labels)
    vals = [v.strip() if isinstance(v, str) else v for v in raw.tolist()]
    touch = np.array([not _is_no_touch(v) for v in vals], bool)
    if not touch.any():
        raise ValueError(f"{where}: no touch labels (every location is empty, negative or a no-touch word)")
    nums = [_as_number(v) for v in np.asarray(vals, dtype=object)[touch]]
    touch_vals = np.asarray(vals, dtype=object)[touch]
    if any(x is not None and not np.isfinite(x) for x in nums):
        k = next(i for i, x in enumerate(nums) if x is not None and not np.isfinite(x))
        raise ImportDataError(f"{where}: location {touch_vals[k]!r} is not a location; use an id, a position in cm, a name, "
                              f"or an empty cell / -1 / 'none' for no touch")
    if any(x is None for x in nums) and any(x is not None for x in nums):
        a = next(v for v, x in zip(touch_vals, nums) if x is not None)
        b = next(v for v, x in zip(touch_vals, nums) if x is None)
        raise ImportDataError(f"{where}: location labels mix numbers ({a!r}) and names ({b!r}); use one kind for every "
                              f"location (a typo such as the letter O for 0?)")
    integer = all(x is not None and float(x).is_integer() for x in nums) and (
        raw.dtype.kind in "iu" or all(isinstance(v, str) and "." not in v and "e" not in v.lower()
                                      for v in np.asarray(vals, dtype=object)[touch]))
    if integer:
        keys = [int(x) for x in nums]
        uniq = sorted(set(keys))
        lut = {k: k for k in uniq}
        names = {k: str(k) for k in uniq}
        kind = "integer ids"
    elif all(x is not None for x in nums):
        keys = [float(x) for x in nums]
        uniq = sorted(set(keys))
        lut = {k: i for i, k in enumerate(uniq)}
        names = {i: f"{k:g}" for k, i in lut.items()}
        kind = "numbers"
    else:
        keys = [str(v) for v in np.asarray(vals, dtype=object)[touch]]
        uniq = sorted(set(keys))
        folded: dict[str, str] = {}
        for k in uniq:
            f = " ".join(k.lower().split())
            if f in folded:
                raise ImportDataError(f"{where}: location names {folded[f]!r} and {k!r} differ only in case or spaces; they "
                                      f"would be two locations: spell each location one way")
            folded[f] = k
        lut = {k: i for i, k in enumerate(uniq)}
        names = {i: k for k, i in lut.items()}
        kind = "names"
    ids = np.full(raw.shape[0], -1, dtype=int)
    ids[touch] = [lut[k] for k in keys]
    if len(uniq) < 2:
        raise ValueError(f"{where}: labels name {len(uniq)} touch location; need at least two")
    if (x_cm is None) != (y_cm is None):
        raise ImportDataError(f"{where}: has {'x_cm' if y_cm is None else 'y_cm'} but not "
                              f"{'y_cm' if y_cm is None else 'x_cm'}; give both coordinates of each marker, or neither")
    xs = np.full(raw.shape[0], np.nan) if x_cm is None else np.asarray(x_cm, float)
    ys = np.full(raw.shape[0], np.nan) if y_cm is None else np.asarray(y_cm, float)
    half = touch & (np.isfinite(xs) != np.isfinite(ys))
    if half.any():
        k = int(np.flatnonzero(half)[0])
        raise ImportDataError(f"{where}: row {k} (location {vals[k]!r}) has x_cm {xs[k]:g} but y_cm {ys[k]:g}; give both "
                              f"coordinates of a marker, or neither")
    if len(uniq) > MAX_LOCATIONS:
        raise ImportDataError(f"{where}: {len(uniq)} distinct touch locations, more than a layout holds ({MAX_LOCATIONS}); is the "
                              f"location column one value per row (an index or a time)?")
    # The rows of each location, grouped in one sort (not one scan per location: quadratic in a big table).
    order = np.flatnonzero(touch)
    order = order[np.argsort(ids[order], kind="stable")]
    bounds = np.searchsorted(ids[order], [lut[k] for k in uniq], side="left").tolist() + [order.size]
    xy, guessed = [], set()
    for j, k in enumerate(uniq):
        i = lut[k]
        rows = order[bounds[j]:bounds[j + 1]]
        ok = rows[np.isfinite(xs[rows]) & np.isfinite(ys[rows])]
        if ok.size:
            # One marker has one position: rows may differ by a finger's aim (mm), not by a different place.
            far = np.hypot(xs[ok] - xs[ok[0]], ys[ok] - ys[ok[0]])
            if far.max() > MARKER_SPREAD_CM:
                r = int(ok[np.argmax(far)])
                raise ImportDataError(f"{where}: location {names[i]!r} is at ({xs[ok[0]]:g}, {ys[ok[0]]:g}) cm in row {ok[0]} but "
                                      f"at ({xs[r]:g}, {ys[r]:g}) cm in row {r}, {far.max():.3g} cm apart; one location is "
                                      f"one marker: fix the coordinates or the label")
            xy.append((float(xs[ok[0]]), float(ys[ok[0]])))
        elif kind != "names":
            xy.append((float(k), 0.0))
            guessed.add(i)
        else:
            xy.append((float(i), 0.0))
            guessed.add(i)
    P = np.array(xy)
    _, first, count = np.unique(np.round(P, 6), axis=0, return_index=True, return_counts=True)
    if np.any(count > 1):
        a = int(first[np.flatnonzero(count > 1)[0]])
        b = next(j for j in range(len(P)) if j != a and np.allclose(np.round(P[j], 6), np.round(P[a], 6)))
        a, b = sorted((a, b))
        raise ImportDataError(f"{where}: locations {names[lut[uniq[a]]]!r} and {names[lut[uniq[b]]]!r} are both at "
                              f"({P[a, 0]:g}, {P[a, 1]:g}) cm; two markers cannot share a place: fix x_cm/y_cm")
    layout = Layout(ids=tuple(lut[k] for k in uniq), xy_cm=P)
    log(f"{len(uniq)} touch locations from {kind} in {where} (label -> id, x/y cm):")
    for k in uniq:
        i = lut[k]
        x, y = layout.coords(np.array([i]))[0]
        note = "" if i not in guessed else "  (x = the label in cm)" if kind != "names" else "  (placed, no x_cm/y_cm)"
        log(f"  {names[i]!s:>12} -> {i:3d}   ({x:g}, {y:g}){note}")
    if guessed and kind == "names":
        warnings.warn(f"{where}: named locations without x_cm,y_cm are placed 1 cm apart in sorted order; "
                      f"distances (< 2 cm, < 3 cm) mean nothing unless you give marker coordinates", stacklevel=2)
    return ids, layout, names


_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?|[+-]?(?:nan|inf|infinity)", re.IGNORECASE)


def _strict_float(text: str) -> float:
    """A plain decimal number (``3.5``, ``-1e-3``, ``nan``); ValueError for anything else (``1_0``, ``3,5``, ``0x1``)."""
    t = str(text).strip()
    if not _NUMBER.fullmatch(t):
        raise ValueError(t)
    return float(t)


def _read_labels(path: Path) -> list[dict]:
    """The label CSV's rows, each checked: known columns (a misspelled optional one is refused, not ignored), one
    value per column, plain numbers, finite times, values in range."""
    try:
        if path.stat().st_size > 256 * 2**20:
            raise ImportDataError(f"{path}: {path.stat().st_size / 2**20:.0f} MB is not a label CSV of touch intervals")
        with open(path, newline="", encoding="utf-8-sig") as fh:  # -sig: a BOM (Excel's "CSV UTF-8") is not a column name
            text = fh.read()
        if "\0" in text:
            raise ImportDataError(f"{path}: holds NUL bytes; it is not a text CSV (save it as UTF-8 text)")
        reader = csv.reader(io.StringIO(text, newline=""))
        lines = [(reader.line_num, r) for r in reader]
    except (UnicodeDecodeError, csv.Error) as e:
        raise ImportDataError(f"{path}: not a readable CSV ({str(e)[:120]}); save it as UTF-8 text") from None
    lines = [(n, r) for n, r in lines if any(c.strip() for c in r)]  # blank lines are skipped
    if not lines:
        raise ValueError(f"{path}: no label rows")
    header = [c.strip() for c in lines[0][1]]
    known = (*_LABEL_COLS, *_OPTIONAL_COLS)
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise ImportDataError(f"{path}: column {dup[0]!r} appears {header.count(dup[0])} times in the header; keep one")
    near = {}
    for c in header:
        if c not in known:
            m = [k for k in known if k.lower() == c.lower()] or difflib.get_close_matches(c.lower(), known, n=1, cutoff=0.75)
            if m:
                near[c] = m[0]
    hint = "".join(f"; is {c!r} meant to be {k!r}?" for c, k in near.items())
    missing = [c for c in _LABEL_COLS if c not in header]
    if missing:
        raise ValueError(f"{path}: label CSV lacks columns {missing}; need file,start_s,end_s,location "
                         f"(optional x_cm,y_cm,force_n,moving,subject){hint}")
    if near:  # a misspelled optional column would be ignored: its values silently lost
        c, k = next(iter(near.items()))
        raise ImportDataError(f"{path}: column {c!r} is not a label column; did you mean {k!r}? "
                              f"(columns: {','.join(known)})")
    ignored = [c for c in header if c not in known]
    if ignored:
        warnings.warn(f"{path}: columns {ignored} are not label columns and are ignored", stacklevel=3)
    if len(lines) < 2:
        raise ValueError(f"{path}: no label rows")

    out = []
    for i, row in lines[1:]:
        if len(row) != len(header):
            raise ImportDataError(f"{path} line {i}: {len(row)} values for {len(header)} columns; a missing value, or a "
                                  f"decimal comma (write 3.5, not 3,5)? fix the row")
        r = dict(zip(header, row))

        def num(k, default, r=r, i=i):
            v = r.get(k, "")
            if v is None or not v.strip():
                return default
            try:
                return _strict_float(v)
            except ValueError:
                raise ImportDataError(f"{path} line {i}: {k} = {v!r} is not a number; write plain numbers "
                                      f"(a dot for decimals, e.g. 3.5)") from None

        d = {"file": r["file"], "start_s": num("start_s", np.nan), "end_s": num("end_s", np.nan), "label": r["location"].strip(),
             "x_cm": num("x_cm", np.nan), "y_cm": num("y_cm", np.nan), "force_n": num("force_n", np.nan),
             "moving": num("moving", 0.0), "subject": num("subject", 0.0)}
        if not (np.isfinite(d["start_s"]) and np.isfinite(d["end_s"]) and d["start_s"] >= 0):
            raise ImportDataError(f"{path} line {i}: start_s and end_s must be finite seconds >= 0, got {r['start_s']}, {r['end_s']}")
        if d["end_s"] <= d["start_s"]:
            raise ImportDataError(f"{path} line {i}: end_s must be after start_s")
        d["line"] = i
        out.append(d)
    _check_values(str(path), force=[d["force_n"] for d in out], moving=[d["moving"] for d in out],
                  subject=[d["subject"] for d in out],
                  x_cm=[d["x_cm"] for d in out], y_cm=[d["y_cm"] for d in out], rows=[f"line {d['line']}" for d in out])
    for d in out:
        d["subject"] = int(d["subject"])
    return out


def _check_intervals(rows: list[dict], path: Path, name: str, duration_s: float, period_s: float) -> None:
    """Intervals of one recording: inside it (give or take one sweep period), and overlapping ones agree."""
    mine = sorted((r for r in rows if r["file"] == name), key=lambda r: (r["start_s"], r["end_s"]))
    for r in mine:
        if r["start_s"] >= duration_s or r["end_s"] > duration_s + period_s:
            raise ImportDataError(f"{path} line {r['line']}: the interval {r['start_s']:g}-{r['end_s']:g} s ends past the end of "
                               f"{name} ({duration_s:.3f} s long); fix the times or the file name")
    keys = ("location", "force_n", "moving", "subject")

    def key(r):
        return tuple("nan" if isinstance(r[k], float) and np.isnan(r[k]) else r[k] for k in keys)

    # One sweep in start order (linear, not pairwise: 20 000 identical rows took 74 s): the intervals that overlap
    # form runs; every interval of a run has the label of the one reaching furthest so far, ``a``, which overlaps
    # any later interval that overlaps the run.
    a = None
    for b in mine:
        if a is None or b["start_s"] >= a["end_s"]:
            a = b
            continue
        if key(b) != key(a):
            raise ImportDataError(f"{path} lines {a['line']} and {b['line']}: the intervals {a['start_s']:g}-{a['end_s']:g} s "
                                  f"and {b['start_s']:g}-{b['end_s']:g} s of {name} overlap with different labels "
                                  f"(location {a['label']!r} vs {b['label']!r}); a chirp has one label: fix the times")
        if b["end_s"] > a["end_s"]:
            a = b


def _sf_info(p: Path):
    import soundfile as sf

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
    """How many times a shorter period repeats within the periods ``x`` (n,) or (rows, n): the most repeats k in
    16..2 whose lag ``n / k`` keeps 90 % of the circular autocorrelation (median over rows); ``None`` when none does.
    The most repeats first: a WAV of 4 periods also repeats every 2."""
    x = np.atleast_2d(np.asarray(x, np.float64))
    n = x.shape[1]
    r = scipy.fft.irfft(np.abs(scipy.fft.rfft(x, axis=1)) ** 2, n=n, axis=1)
    for k in range(16, 1, -1):
        if n % k == 0 and np.median(r[:, n // k] / np.maximum(r[:, 0], 1e-300)) > 0.9:
            return k
    return None


def _check_received(frames: np.ndarray, rig: Rig, p: Path, *, offset: int = 0, channel: int = 0, channels: int = 1) -> None:
    """A recording cut into sweep periods holds the sweep: consecutive periods repeat, no shorter period repeats, and
    the repeating part has power in the sweep's band.  Otherwise --period/--sweep/--chirp do not describe the file
    (or the file holds no received sweep) and every feature would be silently meaningless.  No sweep may be clipped."""
    from .dsp import frame_faults, rig_chirp

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


# -- writing all or nothing -----------------------------------------------------------

@contextlib.contextmanager
def _staged(out: Path, mode: str) -> Iterator[tuple[Path, str]]:
    """Where to write and the DatasetWriter mode; moves a finished new dataset into place, removes a failed one.

    ``out`` is locked for the whole import (:func:`sonicskin.dataset.writer_lock`): a second import (or simulate,
    record) into the same folder is refused before it touches the first one's staging folder."""
    if mode not in ("create", "overwrite", "resume"):
        raise ValueError(f"mode must be create, overwrite or resume, got {mode!r}")
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a dataset; choose another --out or remove it")
    refuse_inside_dataset(out, "a dataset")
    created = not out.exists()
    try:
        with writer_lock(out):
            exists = (out / "dataset.json").is_file()
            if exists and mode == "create":
                raise FileExistsError(f"{out} already holds a dataset; pass --resume to continue it or --overwrite to "
                                      f"replace it")
            if not exists and any(out.iterdir()):
                raise FileExistsError(f"{out} exists and is not a dataset; choose another --out or remove it")
            if exists and mode == "resume":
                yield out, "resume"
                return
            tmp = out.parent / f".{out.name}.importing"
            if tmp.exists():
                shutil.rmtree(tmp)
            try:
                yield tmp, "create"
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
            swap_folders(tmp, out)  # out (locked, empty or the old dataset) now holds the new dataset
            created = False
    finally:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # the empty folder the lock made for a refused or failed new import


def _cut_short(r: dict, t: np.ndarray, n_samples: int, rig, fs: float) -> bool:
    """Whether label row ``r``'s interval holds no whole sweep but the start of the recording's last, incomplete one
    (the sweep after the last whole frame, begun before the file ends)."""
    if not t.size:
        return False
    nxt = t[-1] + rig.period_s  # where the incomplete sweep starts
    return bool(r["start_s"] <= nxt < r["end_s"] and nxt * fs < n_samples)


def _write_session(w: DatasetWriter, session: str, audio: np.ndarray, lab: dict, info: dict) -> None:
    """One session, removed again if anything fails half-way (so ``--resume`` starts it afresh)."""
    try:
        w.write_part(session, 0, audio, lab)
        w.finish_session(session, info)
    except BaseException:
        shutil.rmtree(w.root / session, ignore_errors=True)
        raise


# -- WAV recordings -------------------------------------------------------------------

def import_wav(wav_dir: str | Path, labels: str | Path, out: str | Path, *, sweep_wav: str | Path | None = None,
               chirp_hz: tuple[float, float] | None = None, period_s: float | None = None, amplitude: float = 1.0,
               channel: int = 0, pwm_hz=(), pwm_halfwidth_hz: float = 0.0, mode: str = "create", log=print) -> Path:
    """Import WAV recordings into a dataset folder; returns it.

    ``mode``: ``"create"`` (refuses an existing dataset), ``"overwrite"`` or ``"resume"`` (keeps the
    recordings imported already).  A failed import leaves no new dataset behind.
    """

    wav_dir, labels, out = Path(wav_dir), Path(labels), Path(out)
    if not wav_dir.is_dir():
        raise FileNotFoundError(f"{wav_dir}: no such folder of recordings")
    if sweep_wav is not None and (chirp_hz is not None or period_s is not None):
        raise ImportDataError("give the transmitted sweep one way: --sweep SWEEP.wav, or --chirp F_LO F_HI --period S; not both")
    rows = _read_labels(labels)
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
    from .dsp import rig_chirp

    ref = rig_chirp(rig)
    for p in files:
        _check_intervals(rows, labels, p.name, infos[p].frames / fs, rig.period_s)
    # Times in minutes (or ms read as s by a spreadsheet) still fall inside the recordings: a hint, not a refusal.
    ends = [max((r["end_s"] for r in rows if r["file"] == p.name), default=None) for p in files]
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
        from .dataset import load_json

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
    with _staged(out, mode) as (root, wmode):
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


# -- tables of spectra ----------------------------------------------------------------

def _first_touch(touch: np.ndarray) -> int:
    """Index of a session's first touch chirp (its length when it has none)."""
    return int(np.argmax(touch)) if touch.any() else int(touch.size)


def _segments(touch: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Segments of a session's rows: touches, the hands-off rows before the first touch as the boot calibration, the
    later hands-off rows as no-touch chirps ("gap", or "moving" with the robot moving).  Every hands-off row used to be
    "calibration", as if the whole session's rest were the boot reference's."""
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
    """An array whose name is a near miss of one the importer reads (``force`` for ``force_n``, ``X_cm``) would be
    ignored and its values silently lost: refused, naming the array it resembles."""
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
    """Import a table of magnitude spectra with labels (see the module docstring); returns the dataset.

    Parameters
    ----------
    table : ``.npz`` file.
    out : dataset folder to write.
    rig : use this rig (its band must lie inside the table, give or take one table bin); default:
        derived from the frequency axis (:func:`rig_from_axis`, with ``fs_hz``/``frame``).
    linear : the magnitudes are linear (``|H|``), not dB; converted with ``20 log10``.
    mode : ``"create"``, ``"overwrite"`` or ``"resume"``.
    """
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
    elif _looks_linear(M):
        why = "all <= 1" if M.max() <= 1 else "spread over orders of magnitude"
        warnings.warn(f"{table}: magnitude_db looks linear, not dB (all >= 0, {why}); "
                      f"if so, import with --linear (20 log10 |H|)", stacklevel=2)
    lo, hi = np.unravel_index(int(np.argmin(M)), M.shape), np.unravel_index(int(np.argmax(M)), M.shape)
    if not linear and M[hi] - M[lo] > MAX_SPAN_DB and not _looks_linear(M):  # linear-looking: warned above
        raise ImportDataError(f"{table}: magnitude_db spans {M[hi] - M[lo]:.3g} dB (row {lo[0]}: {M[lo]:.3g}, row {hi[0]}: "
                              f"{M[hi]:.3g}); measured spectra span less than {MAX_SPAN_DB:g} dB: fix the damaged rows")
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
    force = np.asarray(z["force_n"], float) if "force_n" in z else np.full(n, np.nan)
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
    with _staged(out, mode) as (root, wmode):
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
