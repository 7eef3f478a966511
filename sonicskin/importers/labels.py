"""Labels of imported recordings: the label CSV of touch intervals, the values at the door, and the layout that
raw location labels (ids, numbers, names) make."""

from __future__ import annotations

import csv
import difflib
import io
import re
import warnings
from pathlib import Path

import numpy as np

from ..dataset import MAX_ABS_CM, MAX_FORCE_N
from ..features import light_touches
from ..rig import MAX_LOCATIONS, Layout
from ._common import ImportDataError

_LABEL_COLS = ("file", "start_s", "end_s", "location")
_OPTIONAL_COLS = ("x_cm", "y_cm", "force_n", "moving", "subject")
NO_TOUCH_LABELS = frozenset({"", "-1", "nan", "none", "no-touch", "no_touch", "notouch", "rest", "quiet", "idle"})
MARKER_SPREAD_CM = 1.0  # rows of one location whose x_cm/y_cm differ by more than this name two places


def _check_values(where: str, *, force=None, moving=None, subject=None, x_cm=None, y_cm=None, rows=None) -> None:
    """Label values at the door: force, moving, subject and coordinates in range (``rows``: row names for the message)."""
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
        first(~(np.isfinite(v) & (v >= 0) & (v < 2**31) & (v == np.round(v))), "subject", subject, "a subject is a whole number >= 0")
    for col, c in (("x_cm", x_cm), ("y_cm", y_cm)):
        if c is not None:
            v = np.asarray(c, float)
            first(~np.isnan(v) & ~(np.abs(v) <= MAX_ABS_CM), col, c, "a coordinate is empty/NaN or a finite number of cm")


def touch_forces(force, touched, *, where: str, log=print) -> np.ndarray:
    """The labelled touches' forces as training reads them: one value on every touch is a placeholder (no force sensor:
    NaN), and most touches lighter than a press are reported (a unit other than newtons?)."""
    f = np.array(force, float)
    touched = np.asarray(touched, bool)
    known = f[touched & np.isfinite(f)]
    if known.size >= 2 and np.ptp(known) == 0:
        log(f"{where}: force_n is {known[0]:g} N on every touch, a placeholder: taken as no force sensor (localization only)")
        f[touched] = np.nan
    elif why := light_touches(f, touched):
        warnings.warn(f"{where}: {why}", stacklevel=3)
    return f


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
    """``(ids, layout, names)`` for raw ``labels``: each row's location id (-1: no touch), one marker per label, ``{id: label}``."""
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


def _read_labels(path: Path, log=print) -> list[dict]:
    """The label CSV's rows, each checked (a misspelled optional column is refused, not ignored)."""
    if not path.is_file():
        raise ImportDataError(f"{path}: {'is a folder, not' if path.is_dir() else 'no such file; give'} the label CSV of touch intervals")
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
    forces = touch_forces([d["force_n"] for d in out], [not _is_no_touch(d["label"]) for d in out], where=str(path), log=log)
    for d, f in zip(out, forces):
        d["subject"], d["force_n"] = int(d["subject"]), float(f)
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
