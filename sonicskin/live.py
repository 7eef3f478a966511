"""The real-time loop: blocks -> chirp frames -> features -> model -> Alg. 2 -> touch events.

The consumer side of an audio source (:mod:`sonicskin.acquire`).  Per chirp it costs one FFT,
one ONNX call and some numpy, a few percent of the 106.7 ms chirp period.

- **Framing** locks onto the chirp train by cross-correlation over one period, then cuts frames
  every ``n_chirp`` samples; a discontinuity (overflow, dropped block) or a drift of the
  correlation peak makes it discard what it holds and lock again.
- **Per chirp** one call, :meth:`sonicskin.runtime.SkinStream.frame`: features, Alg. 2's online
  reference (the first ``beta`` seconds are taken as no-touch, as the system starts with hands
  off; every ``alpha`` seconds the next ``beta`` seconds in which no touch is detected become the
  new reference), model, detection, force.  Offline evaluation replays recordings through the
  same object (:meth:`sonicskin.runtime.SkinStream.replay`).
- **Faults**: frames with NaN/inf, silence or clipping are skipped and counted; overflows and
  underflows are counted; nothing is fatal.
- **Output**: :class:`TouchEvent` per touched chirp (and one ``release``), as JSON lines and
  optionally as UDP datagrams to localhost.
"""

from __future__ import annotations

import dataclasses
import json
import socket
import sys
import time
from collections.abc import Callable

import numpy as np

from .dsp import find_chirp_offset, frame_faults, rig_chirp
from .runtime import Predictions, SkinRuntime

__all__ = ["TouchEvent", "Framer", "LiveLoop", "UdpSink", "run_loops"]


@dataclasses.dataclass
class TouchEvent:
    t_s: float            # stream time of the chirp's start
    kind: str             # "touch" (every touched chirp) or "release" (first chirp after a touch)
    location: int
    x_cm: float
    y_cm: float
    force_n: float
    confidence: float
    model: str
    latency_ms: float     # frame complete -> event

    def to_json(self) -> str:
        d = dataclasses.asdict(self)
        for k in ("t_s", "x_cm", "y_cm", "force_n", "confidence", "latency_ms"):
            d[k] = round(float(d[k]), 4) if np.isfinite(d[k]) else None  # no force model: null
        return json.dumps(d)


class Framer:
    """Chirp-synchronous framing of a block stream that re-locks after lost audio.

    Parameters
    ----------
    reference : the transmitted chirp (one period).
    check_every : verify the lock every this many frames (an FFT of one period).
    tolerance : samples the correlation peak may wander before re-locking.  A firm touch on a moving
        robot moves the peak of the simulated CFRP link by up to ~80 samples; a small slip is
        harmless anyway (in steady state it is a circular shift, which leaves |H| unchanged).
    """

    def __init__(self, reference: np.ndarray, *, check_every: int = 16, tolerance: int = 256):
        self.ref = np.asarray(reference, np.float64)
        self.L = self.ref.size
        self.check_every, self.tolerance = check_every, tolerance
        self.buf = np.zeros(0, np.float32)
        self.buf_start = 0          # stream sample index of buf[0]
        self.next_start: int | None = None
        self.relocks = 0
        self.n_frames = 0

    def reset(self) -> None:
        self.buf = np.zeros(0, np.float32)
        self.next_start = None

    def push(self, samples: np.ndarray, start: int, discontinuity: bool = False) -> list[tuple[int, np.ndarray]]:
        """Add a block (starting at stream sample ``start``); return the complete ``(start, frame)`` pairs."""
        if discontinuity or (self.buf.size and start != self.buf_start + self.buf.size):
            if self.next_start is not None:
                self.relocks += 1
            self.reset()
        if self.buf.size == 0:
            self.buf_start = start
        self.buf = np.concatenate([self.buf, np.asarray(samples, np.float32)])
        out = []
        if self.next_start is None:
            if self.buf.size < self.L:
                return out
            off = find_chirp_offset(self.buf[: self.L], self.ref, max_periods=1)
            self.next_start = self.buf_start + off
        while self.next_start + self.L <= self.buf_start + self.buf.size:
            a = self.next_start - self.buf_start
            frame = self.buf[a:a + self.L]
            self.n_frames += 1
            if self.n_frames % self.check_every == 0:
                drift = find_chirp_offset(frame, self.ref, max_periods=1)
                drift = min(drift, self.L - drift)
                if drift > self.tolerance:  # lost lock without a reported gap
                    self.relocks += 1
                    keep = self.buf[a:]
                    self.buf_start += a
                    self.buf = keep
                    self.next_start = None
                    return out
            out.append((self.next_start, frame.copy()))
            self.next_start += self.L
        cut = self.next_start - self.buf_start
        if cut > 0:
            self.buf = self.buf[cut:]
            self.buf_start += cut
        return out


class UdpSink:
    """Send event JSON as UDP datagrams; localhost unless told otherwise."""

    def __init__(self, target: str):
        host, _, port = target.rpartition(":")
        self.addr = (host or "127.0.0.1", int(port))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def __call__(self, line: str) -> None:
        self.sock.sendto(line.encode(), self.addr)


class LiveLoop:
    """Consume a source, emit touch events.

    Parameters
    ----------
    runtime : a loaded artifact model (:class:`sonicskin.runtime.SkinRuntime`).
    source : an audio source (:mod:`sonicskin.acquire`).
    emit : called with each event's JSON line (default: print to stdout).
    status : write a status line to stderr about once a second.
    on_chirp : called with ``(t_s, predictions)`` for every processed chirp (``None`` during the
        boot calibration), e.g. to record a replay chirp by chirp.
    """

    startup_dropped: int | None = None  # audio blocks dropped before the first chirp was framed

    def __init__(self, runtime: SkinRuntime, source, *, emit: Callable[[str], None] | None = None,
                 status: bool = False, link=None, channel: int = 0,
                 on_chirp: Callable[[float, Predictions | None], None] | None = None):
        self.rt, self.source = runtime, source
        self.rig = runtime.rig
        link_rig = link.rig if link is not None and link.rig is not None else source.rig
        if link_rig.mismatch(self.rig):
            raise ValueError(f"the audio source runs another rig than the model ({'; '.join(link_rig.mismatch(self.rig))})")
        self.emit = emit or (lambda line: print(line, flush=True))
        self.status = status
        # Time-duplexed links: frame whole duplex periods, keep this link's chirp slot.
        self.channel = channel
        self.slot = (link.slot, link.n_slots) if link is not None else (0, 1)
        self.framer = Framer(link.tx_period(source.rig) if link is not None else rig_chirp(self.rig))
        self.stream = runtime.stream()
        self.on_chirp = on_chirp
        self.touching = False
        self.events: list[TouchEvent] = []
        self.latencies_ms: list[float] = []
        self.skipped = {"nan": 0, "silent": 0, "clipped": 0}
        self.n_chirps = 0

    @property
    def refreshes(self) -> int:
        return self.stream.reference.refreshes

    # -- per chirp ---------------------------------------------------------------------

    def process_frame(self, start: int, frame: np.ndarray, t_ready: float) -> TouchEvent | None:
        fault = int(frame_faults(frame[None])[0])
        if fault:
            self.skipped[{1: "nan", 2: "silent", 3: "clipped"}[fault]] += 1
            return None
        self.n_chirps += 1
        t_s = start / self.rig.fs_hz
        p = self.stream.frame(frame, t_s)  # features, Alg. 2 reference, model, detection, force
        if self.on_chirp is not None:
            self.on_chirp(t_s, p)
        if p is None:  # boot calibration
            return None
        touch = bool(p.touch[0])
        ev = None
        if touch or self.touching:
            ev = TouchEvent(t_s, "touch" if touch else "release", int(p.location[0]), float(p.xy_cm[0, 0]),
                            float(p.xy_cm[0, 1]), float(p.force_n[0]), float(p.confidence[0]), self.rt.kind,
                            (time.perf_counter() - t_ready) * 1e3)
        self.touching = touch
        self.latencies_ms.append((time.perf_counter() - t_ready) * 1e3)
        return ev

    # -- loop --------------------------------------------------------------------------
    def feed(self, block) -> None:
        """Process one block from the source (frames, features, model, events)."""
        samples = block.samples if block.samples.ndim == 1 else block.samples[:, self.channel]
        for start, frame in self.framer.push(samples, block.start, block.discontinuity):
            if self.startup_dropped is None:  # blocks lost before the first chirp was framed (loading, first lock)
                self.startup_dropped = self.source.counters()["dropped_blocks"]
            if self.slot[1] > 1:  # this link's chirp within the duplex period
                L = self.rig.n_chirp
                start, frame = start + self.slot[0] * L, frame[self.slot[0] * L:(self.slot[0] + 1) * L]
            ev = self.process_frame(start, frame, time.perf_counter())
            if ev is not None:
                self.events.append(ev)
                self.emit(ev.to_json())

    def run(self, *, duration_s: float | None = None, max_chirps: int | None = None, idle_timeout_s: float = 2.0) -> dict:
        """Run until ``duration_s`` of stream time, ``max_chirps``, Ctrl-C, or the source ends."""
        return run_loops([self], self.source, duration_s=duration_s, max_chirps=max_chirps,
                         idle_timeout_s=idle_timeout_s)[0]

    def status_line(self) -> str:
        lat = np.asarray(self.latencies_ms[-200:]) if self.latencies_ms else np.zeros(1)
        last = next((e for e in reversed(self.events) if e.kind == "touch"), None)
        c = self.source.counters()
        touch = f"last touch: loc {last.location} ({last.x_cm:.1f}, {last.y_cm:.1f}) cm {last.force_n:.1f} N" if last else "no touch yet"
        state = "calibrating" if self.stream.calibrating else "running"
        return (f"{state}  {self.n_chirps} chirps  latency median {np.median(lat):.2f} ms p99 {np.percentile(lat, 99):.2f} ms  "
                f"{touch}  relocks {self.framer.relocks}  driver overflows {c['overflows']}  dropped blocks {c['dropped_blocks']}"
                f"{self._startup_note(c['dropped_blocks'])}  skipped frames {sum(self.skipped.values())}   ")

    def _startup_note(self, dropped: int) -> str:
        """Why blocks were dropped when it was at start-up: the 2 s queue filled before the loop framed its first chirp
        (a slow first render of the simulated device catching up, or a loaded machine); not a fault of the link."""
        d0 = self.startup_dropped if self.startup_dropped is not None else dropped
        if not d0:
            return ""
        return f" ({d0} at start-up, before the first chirp was framed: the source ran ahead while the loop started)"

    def summary(self, wall_s: float, cpu_s: float, stream_s: float) -> dict:
        lat = np.asarray(self.latencies_ms) if self.latencies_ms else np.full(1, np.nan)
        return {"chirps": self.n_chirps, "stream_s": stream_s, "wall_s": wall_s, "cpu_share": cpu_s / max(wall_s, 1e-9),
                "latency_ms_median": float(np.median(lat)), "latency_ms_p99": float(np.percentile(lat, 99)),
                "touch_events": sum(e.kind == "touch" for e in self.events), "relocks": self.framer.relocks,
                "reference_refreshes": self.refreshes, "skipped": dict(self.skipped), **self.source.counters()}


def run_loops(loops: list[LiveLoop], source, *, duration_s: float | None = None, max_chirps: int | None = None,
              idle_timeout_s: float = 2.0) -> list[dict]:
    """Feed every block of one source to several loops (one per link of a multi-link rig)."""
    t_last_status = time.perf_counter()
    started = time.perf_counter()
    cpu0 = time.process_time()
    stream_s = 0.0
    status = any(lp.status for lp in loops)
    try:
        while True:
            block = source.read(timeout=idle_timeout_s)
            if block is None:
                if getattr(source, "finished", None) is not None and source.finished.is_set():
                    break
                continue
            for lp in loops:
                lp.feed(block)
            stream_s = (block.start + len(block.samples)) / source.rig.fs_hz
            if status and time.perf_counter() - t_last_status > 1.0:
                t_last_status = time.perf_counter()
                print("\r" + " | ".join(lp.status_line() for lp in loops), end="", file=sys.stderr, flush=True)
            if (duration_s is not None and stream_s >= duration_s) or (max_chirps and min(lp.n_chirps for lp in loops) >= max_chirps):
                break
    except KeyboardInterrupt:
        pass
    if status:
        print("\r" + " | ".join(lp.status_line() for lp in loops), file=sys.stderr, flush=True)
    wall = time.perf_counter() - started
    return [lp.summary(wall, time.process_time() - cpu0, stream_s) for lp in loops]
