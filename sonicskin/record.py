"""``sonicskin record``: the guided one-shot training session on a robot (paper Sec. III-A).

The recorder prompts the user through: hands off (Alg. 2's calibration), hands off while the
robot moves (OSPA's moving variance), then each location in turn ("touch location 7 with
varying force for 3 s"), and writes the received stream and per-chirp labels in the dataset
format as it goes: one part per prompt, each written atomically, so Ctrl-C loses at most the
prompt in progress.  ``--resume`` starts a new session that records only the locations the
dataset does not have yet.

Force ground truth comes from a :class:`ForceSource`: a CSV log (``t_s,force_n`` since the start
of the recording), a serial sensor (one number per line, e.g. a SingleTact via an Arduino), the
simulated sensor of the simulated device, or none (forces are then NaN and only location is
trained).
"""

from __future__ import annotations

import csv
import sys
import time
from pathlib import Path

import numpy as np

from .dataset import COLUMNS, Dataset, DatasetWriter
from .dsp import rig_chirp
from .live import Framer
from .rig import Layout, Rig

__all__ = ["ForceSource", "CsvForce", "SerialForce", "TimelineForce", "NoForce", "Recorder", "make_schedule"]


class ForceSource:
    """Force in N at stream time ``t_s`` (seconds since the recording started)."""

    def force(self, t_s: float) -> float:  # pragma: no cover - interface
        raise NotImplementedError


class NoForce(ForceSource):
    def force(self, t_s: float) -> float:
        return float("nan")


class CsvForce(ForceSource):
    """A force log with columns ``t_s,force_n``, interpolated at each chirp."""

    def __init__(self, path: str | Path):
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        try:
            t = np.array([float(r["t_s"]) for r in rows])
            f = np.array([float(r["force_n"]) for r in rows])
        except (KeyError, ValueError) as e:
            raise ValueError(f"{path}: a force log needs numeric columns t_s,force_n ({e})") from None
        if t.size < 2 or np.any(np.diff(t) <= 0):
            raise ValueError(f"{path}: t_s must increase and have at least two rows")
        self.t, self.f = t, f

    def force(self, t_s: float) -> float:
        return float(np.interp(t_s, self.t, self.f, left=np.nan, right=np.nan))


class SerialForce(ForceSource):
    """A serial force sensor printing one value in newtons per line (read in a thread)."""

    def __init__(self, port: str, baud: int = 115200):
        import threading

        try:
            import serial  # pyserial
        except ImportError:
            raise ValueError("a serial force sensor needs pyserial: pip install pyserial") from None
        self.ser = serial.Serial(port, baud, timeout=0.5)
        self.latest = float("nan")
        self.t0 = time.perf_counter()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        while True:
            line = self.ser.readline().decode(errors="ignore").strip()
            try:
                self.latest = float(line)
            except ValueError:
                continue

    def force(self, t_s: float) -> float:
        return self.latest


class TimelineForce(ForceSource):
    """The simulated force sensor: the scripted force plus 0.02 N of sensor noise."""

    def __init__(self, timeline, chirp0_sample: int, fs_hz: float, n_chirp: int, seed: int = 0):
        self.tl, self.c0, self.fs, self.L = timeline, chirp0_sample, fs_hz, n_chirp
        self.rng = np.random.default_rng(seed)

    def force(self, t_s: float) -> float:
        k = int(round((t_s * self.fs - self.c0) / self.L))
        if not 0 <= k < len(self.tl):
            return 0.0
        f = float(self.tl.force_n[k])
        return max(0.0, f + self.rng.normal(0, 0.02)) if f > 0 else 0.0


def make_schedule(layout: Layout, locations: list[int], rig: Rig, *, calibration_s: float = 3.0, moving_s: float = 10.0,
                  touch_s: float = 3.0, gap_s: float = 1.0) -> list[tuple[str, int, int, str]]:
    """Prompts as ``(segment, location, n_chirps, text)``, in recording order."""
    out = [("calibration", -1, rig.seconds_to_chirps(calibration_s), f"hands off the robot for {calibration_s:g} s")]
    if moving_s > 0:
        out.append(("moving", -1, rig.seconds_to_chirps(moving_s),
                    f"start the robot moving; hands off for {moving_s:g} s"))
    for loc in locations:
        out.append(("touch", loc, rig.seconds_to_chirps(touch_s),
                    f"touch location {loc} with varying force for {touch_s:g} s"))
        out.append(("gap", -1, rig.seconds_to_chirps(gap_s), "release"))
    return out


class Recorder:
    """Record a schedule from a source into a dataset session.

    Parameters
    ----------
    writer : the dataset writer.  session : session folder name.
    source : an audio source (``start``/``read``/``stop``).
    force : a :class:`ForceSource`.  moving : motion level to label the ``moving`` prompt with.
    prompt : called with each prompt's text (default: stderr).
    """

    def __init__(self, writer: DatasetWriter, session: str, source, schedule, force: ForceSource, *,
                 moving_level: float = 1.0, prompt=None, settle_s: float = 0.3):
        self.w, self.session, self.source, self.schedule, self.forcesrc = writer, session, source, schedule, force
        self.rig = writer.rig
        self.moving_level = moving_level
        self.prompt = prompt or (lambda text: print(f"[record] {text}", file=sys.stderr, flush=True))
        self.settle = self.rig.seconds_to_chirps(settle_s)  # reaction time at the start of a touch prompt

    def run(self) -> dict:
        rig, L = self.rig, self.rig.n_chirp
        framer = Framer(rig_chirp(rig))
        stream: list[np.ndarray] = []       # samples not yet written
        stream_start = 0                    # stream index of stream[0][0]
        part = 0
        seg_i, in_seg = 0, 0
        rows: list[dict] = []
        n_written = 0
        t_wall = time.perf_counter()
        self.prompt(self.schedule[0][3])
        while seg_i < len(self.schedule):
            block = self.source.read(timeout=2.0)
            if block is None:
                if getattr(self.source, "finished", None) is not None and self.source.finished.is_set():
                    break
                continue
            if block.discontinuity and rows:
                raise RuntimeError("audio was lost during the recording (overflow); the parts written so far are "
                                   "kept: record again with --resume")
            stream.append(block.samples)
            for start, _frame in framer.push(block.samples, block.start, block.discontinuity):
                seg, loc, n, _ = self.schedule[seg_i]
                t_s = start / rig.fs_hz
                touching = seg == "touch" and in_seg >= self.settle
                rows.append({"chirp": len(rows) + n_written, "t_s": t_s, "time_s": t_s, "segment": seg,
                             "location": loc if touching else -1, "x_cm": np.nan, "y_cm": np.nan,
                             "force_n": self.forcesrc.force(t_s) if seg == "touch" else 0.0,
                             "moving": self.moving_level if seg == "moving" else 0.0,
                             "temperature_c": np.nan, "subject": 0})
                if touching:
                    rows[-1]["x_cm"], rows[-1]["y_cm"] = self.w.layout.coords(np.array([loc]))[0]
                in_seg += 1
                if in_seg >= n:  # prompt done: write its audio and labels as one part
                    end = start + L
                    audio = np.concatenate(stream)
                    cut = end - stream_start
                    labels = {c: np.array([r[c] for r in rows]) for c in COLUMNS}
                    self.w.write_part(self.session, part, audio[:cut], labels)
                    n_written += len(rows)
                    rows, part = [], part + 1
                    stream, stream_start = [audio[cut:]], end
                    seg_i, in_seg = seg_i + 1, 0
                    if seg_i < len(self.schedule):
                        self.prompt(self.schedule[seg_i][3])
                    else:
                        break
        complete = seg_i >= len(self.schedule)
        if complete:
            self.w.finish_session(self.session, {"n_chirps": n_written, "prompts": len(self.schedule)})
        return {"chirps": n_written, "parts": part, "complete": complete, "wall_s": time.perf_counter() - t_wall}


def next_session(root: Path) -> str:
    existing = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.startswith("s")) if root.exists() else []
    nums = [int(n[1:]) for n in existing if n[1:].isdigit()]
    return f"s{(max(nums) + 1 if nums else 0):03d}"


def recorded_locations(root: Path) -> set[int]:
    """Locations with touch chirps in the finished parts of a dataset."""
    ds = Dataset(root)
    out: set[int] = set()
    for s in ds.sessions:
        for p in ds.parts(s):
            lab = ds._read_labels(ds.root / s / f"part-{p:05d}.csv")
            out |= set(int(v) for v in lab["location"][lab["location"] >= 0])
    return out
