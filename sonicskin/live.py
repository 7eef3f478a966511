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
- **Faults**: frames with NaN/inf, silence, clipping or a dropout (a run of exact zeros, which no
  live ADC produces) are skipped and counted and never reach the model; overflows and underflows
  are counted.  A boot calibration that loses chirps to such faults is detected
  (:class:`~sonicskin.calibration.OnlineReference`) and re-taken from later rest, with one warning.
- **Watchdog and clock**: ``duration_s`` is honoured by the wall clock (and by stream time, when a
  fast simulated source runs ahead of it); when no audio arrives for ``watchdog_s`` (the audio
  server or the interface died), the run stops with :class:`DeviceLost`.
- **Output**: :class:`~sonicskin.events.TouchEvent` per touched chirp (and one ``release``), as
  JSON lines (the contract of :mod:`sonicskin.events`) and optionally as UDP datagrams.
"""

from __future__ import annotations

import socket
import sys
import time
from collections.abc import Callable

import numpy as np

from .acquire import AudioError
from .dsp import find_chirp_offset, frame_faults, log_magnitude_db, rig_chirp
from .errors import SonicskinError
from .events import TouchEvent
from .runtime import Predictions, SkinRuntime

__all__ = ["TouchEvent", "Framer", "LiveLoop", "UdpSink", "run_loops", "DeviceLost", "InputUnusable", "dropout_frames"]


class DeviceLost(AudioError):
    """No audio arrived for the watchdog's time: the audio server or the interface stopped."""


# Chirp-to-chirp spread (std, dB) of the band features over the boot window, median over the usable bins: a repeating
# chirp gives ~0.1 dB on every shipped rig and scenario (moving robot, aluminium plate, several people), noise without a
# chirp (the transmitter off) the Rayleigh figure, 5.6 dB.
NO_CHIRP_SPREAD_DB = 4.0


class InputUnusable(DeviceLost):
    """Audio arrives but for the watchdog's time not one chirp of it could be used (all NaN, silent,
    clipped or cut by lost blocks): the model would be blind while the loop looked healthy."""


def dropout_frames(frames: np.ndarray, *, min_run: int = 64) -> np.ndarray:
    """(n,) bool: frames holding a run of at least ``min_run`` exact zeros (a dropout; a live 24-bit
    ADC with its noise floor never gives 64 zeros in a row, a driver filling a gap does)."""
    z = np.asarray(frames) == 0
    out = np.zeros(z.shape[0], bool)
    for i in np.flatnonzero(z.sum(axis=-1) >= min_run):
        edges = np.flatnonzero(np.diff(np.r_[0, z[i].view(np.int8), 0]))
        out[i] = bool(np.any(edges[1::2] - edges[::2] >= min_run))
    return out


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
            off = find_chirp_offset(np.nan_to_num(self.buf[: self.L], nan=0.0, posinf=0.0, neginf=0.0), self.ref, max_periods=1)
            self.next_start = self.buf_start + off
        while self.next_start + self.L <= self.buf_start + self.buf.size:
            a = self.next_start - self.buf_start
            frame = self.buf[a:a + self.L]
            self.n_frames += 1
            if self.n_frames % self.check_every == 0:
                drift = find_chirp_offset(np.nan_to_num(frame, nan=0.0, posinf=0.0, neginf=0.0), self.ref, max_periods=1)
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
    """Send event JSON as UDP datagrams; localhost unless told otherwise.

    The host is resolved once, here: an unknown name is one :class:`SonicskinError` before the
    run starts.  A datagram that cannot be sent later (network down) is counted in :attr:`errors`
    and reported once on stderr; the loop goes on.
    """

    def __init__(self, target: str):
        host, _, port = target.rpartition(":")
        host = host or "127.0.0.1"
        try:
            port_n = int(port)
            if not 1 <= port_n <= 65535:
                raise ValueError
        except ValueError:
            raise SonicskinError(f"--udp {target}: expected [HOST:]PORT with a port 1-65535") from None
        try:
            info = socket.getaddrinfo(host, port_n, socket.AF_UNSPEC, socket.SOCK_DGRAM)
        except (socket.gaierror, UnicodeError) as e:
            msg = e.strerror if isinstance(e, socket.gaierror) else str(e)
            raise SonicskinError(f"--udp {host}:{port_n}: cannot resolve host {host!r} ({msg}); "
                                 f"pass an IP address or a name this machine resolves") from None
        family, _, _, _, self.addr = info[0]
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.errors = 0

    def __call__(self, line: str) -> None:
        try:
            self.sock.sendto(line.encode(), self.addr)
        except OSError as e:
            self.errors += 1
            if self.errors == 1:
                print(f"sonicskin: warning: UDP to {self.addr[0]}:{self.addr[1]} failed ({e.strerror or e}); "
                      f"events still go to stdout", file=sys.stderr)


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
                 on_chirp: Callable[[float, Predictions | None], None] | None = None,
                 on_event: Callable[[TouchEvent], None] | None = None, warn: Callable[[str], None] | None = None):
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
        self.on_event = on_event
        self.warn = warn or (lambda msg: print(f"sonicskin: warning: {msg}", file=sys.stderr, flush=True))
        self.boot_faults = 0  # chirps skipped before the boot reference was taken
        self.touching = False
        self.events: list[TouchEvent] = []
        self.latencies_ms: list[float] = []
        self.skipped = {"nan": 0, "silent": 0, "clipped": 0, "dropout": 0}
        self.n_chirps = 0
        # Since the last usable chirp: seconds of audio fed to this loop and what became of their frames.
        self.blind_s = 0.0
        self.blind_skipped = dict(self.skipped)
        self.blind_relocks = 0
        self._boot_sum: np.ndarray | None = None  # sums of the boot chirps' band features and their squares
        self._boot_sq: np.ndarray | None = None
        self._boot_n = 0
        self.boot_spread_db: float | None = None

    @property
    def refreshes(self) -> int:
        return self.stream.reference.refreshes

    # -- per chirp ---------------------------------------------------------------------

    def process_frame(self, start: int, frame: np.ndarray, t_ready: float) -> TouchEvent | None:
        fault = int(frame_faults(frame[None])[0])
        if not fault and dropout_frames(frame[None])[0]:
            fault = 4
        if fault:  # never reaches the features or the model
            kind = {1: "nan", 2: "silent", 3: "clipped", 4: "dropout"}[fault]
            self.skipped[kind] += 1
            self.blind_skipped[kind] += 1
            self.boot_faults += self.stream.calibrating
            return None
        self.n_chirps += 1
        self.blind_s, self.blind_skipped, self.blind_relocks = 0.0, dict.fromkeys(self.skipped, 0), self.framer.relocks
        t_s = start / self.rig.fs_hz
        was_calibrating = self.stream.calibrating
        if was_calibrating and self.boot_spread_db is None:
            self._boot_add(frame)
        p = self.stream.frame(frame, t_s)  # features, Alg. 2 reference, model, detection, force
        ref = self.stream.reference
        if was_calibrating and not self.stream.calibrating and self.boot_spread_db is None:
            self._boot_check()
        if was_calibrating and not self.stream.calibrating and ref.boot_disturbed:
            self.warn(f"boot calibration disturbed: {self.boot_faults} faulty chirp(s) (NaN, dropout, silence or clipping) "
                      f"in the first {ref.beta / ref.cps:.1f} s; reference from the {ref.boot_chirps} clean chirps of "
                      f"that window, re-taken from the next {ref.beta / ref.cps:.1f} s of rest")
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
        self.blind_s += len(samples) / self.source.rig.fs_hz  # reset by the next usable chirp
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
                if self.on_event is not None:
                    self.on_event(ev)

    def run(self, *, duration_s: float | None = None, max_chirps: int | None = None, idle_timeout_s: float = 2.0,
            watchdog_s: float | None = 3.0, stop=None) -> dict:
        """Run until ``duration_s`` (wall clock, or stream time if that runs ahead), ``max_chirps``,
        Ctrl-C, ``stop`` (a :class:`threading.Event`) is set, or the source ends; see :func:`run_loops`."""
        return run_loops([self], self.source, duration_s=duration_s, max_chirps=max_chirps,
                         idle_timeout_s=idle_timeout_s, watchdog_s=watchdog_s, stop=stop)[0]

    def _boot_add(self, frame: np.ndarray) -> None:
        x = log_magnitude_db(frame[None], self.rig, check=False)[0][self.rig.allowed_mask].astype(np.float64)
        if self._boot_sum is None:
            self._boot_sum, self._boot_sq = np.zeros_like(x), np.zeros_like(x)
        self._boot_sum += x
        self._boot_sq += x * x
        self._boot_n += 1

    def _boot_check(self) -> None:
        """The hands-off boot window must hold a repeating chirp: noise alone (the transmitter off or not reaching the
        receiver) would be taken as the reference and give touch events at random."""
        if self._boot_n < 4:
            self.boot_spread_db = float("nan")
            return
        mean = self._boot_sum / self._boot_n
        var = np.maximum(self._boot_sq / self._boot_n - mean * mean, 0.0)
        self.boot_spread_db = float(np.median(np.sqrt(var)))
        if self.boot_spread_db > NO_CHIRP_SPREAD_DB:
            raise InputUnusable(f"no chirp in the input: over the {self._boot_n} hands-off chirps of the boot calibration the "
                                f"received spectrum varies by {self.boot_spread_db:.1f} dB from chirp to chirp (a chirp "
                                f"repeats within ~0.1 dB, noise alone varies by 5.6 dB); is the transmitter playing on "
                                f"output --tx and reaching the receiver? check it with `sonicskin check`")

    def unusable_input(self) -> str:
        """Why the audio since the last usable chirp gave none, with the fix (for :class:`InputUnusable`)."""
        sk = {k: v for k, v in self.blind_skipped.items() if v}
        relocks = self.framer.relocks - self.blind_relocks
        c = self.source.counters()
        lost = c.get("overflows", 0) + c.get("dropped_blocks", 0)
        where = (", ".join(f"{v} {k}" for k, v in sk.items()) + " frame(s)" if sk else "no whole chirp framed") + \
            (f", {relocks} re-locks after lost audio" if relocks else "")
        worst = max(sk, key=sk.get) if sk else None
        fix = {"nan": "the driver delivers NaN/inf samples: restart the audio interface or its driver",
               "silent": f"the input is silent: is the transmitter playing and the receiver on input channel {self.channel} "
                         f"(--rx)? check the cable and the levels with `sonicskin check`",
               "dropout": "the input drops out (runs of exact zeros from the driver): check the cable and the interface "
                          "with `sonicskin check`",
               "clipped": "the input is clipped at full scale: lower the transmit amplitude or the input gain "
                          "(`sonicskin check` measures the level)",
               None: f"audio blocks are lost ({lost} overflows or dropped blocks): close other programs or raise --blocksize"}
        return (f"the device delivers audio but none of the last {self.blind_s:.1f} s gave a usable chirp ({where}); "
                f"{fix[worst]}")

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
                "reference_refreshes": self.refreshes, "boot_disturbed": self.stream.reference.boot_disturbed,
                "skipped": dict(self.skipped), **self.source.counters()}


def run_loops(loops: list[LiveLoop], source, *, duration_s: float | None = None, max_chirps: int | None = None,
              idle_timeout_s: float = 2.0, watchdog_s: float | None = 3.0, stop=None) -> list[dict]:
    """Feed every block of one source to several loops (one per link of a multi-link rig).

    Ends at ``duration_s`` seconds of wall clock since the call or of stream time, whichever comes
    first (a source with ``realtime = False``, the ``--fast`` simulation, by stream time only),
    after ``max_chirps``, on Ctrl-C, when ``stop`` is set, or when a finite source ends.  When no
    block arrives for ``watchdog_s`` seconds from an audio device (a source without a ``finished``
    event), raises :class:`DeviceLost` (``None``: wait for ever); when audio arrives but ``watchdog_s`` seconds of it
    give a loop no usable chirp (all NaN, silent, clipped, or cut by lost blocks), raises :class:`InputUnusable`,
    whatever the source: the model would be blind while the loop looked healthy.  ``idle_timeout_s``
    is kept for callers that set it, the wait for a block is never longer than 0.1 s.
    """
    t_last_status = time.perf_counter()
    started = time.perf_counter()
    t_last_block = started
    cpu0 = time.process_time()
    stream_s = 0.0
    status = any(lp.status for lp in loops)
    finished = getattr(source, "finished", None)
    poll = min(0.1, idle_timeout_s)
    # A faster-than-real-time simulated source (--fast) runs on its own stream clock; everything that
    # claims to be real time (devices, real-time simulation) is also bounded by the wall clock.
    wall_bound = getattr(source, "realtime", True)
    try:
        while True:
            now = time.perf_counter()
            if duration_s is not None and wall_bound and now - started >= duration_s:
                break
            if stop is not None and stop.is_set():
                break
            block = source.read(timeout=poll)
            if block is None:
                if finished is not None and finished.is_set():
                    if source.queue.empty():
                        break
                    continue
                # A finite source (simulated, recording) ends by itself; a device can die silently.
                if watchdog_s is not None and finished is None and time.perf_counter() - t_last_block > watchdog_s:
                    if status:
                        print(file=sys.stderr)
                    raise DeviceLost(f"no audio from the device for {watchdog_s:g} s (the audio server or the interface "
                                     f"stopped, or the cable is out); check it with `sonicskin devices` and start again")
                continue
            t_last_block = time.perf_counter()
            for lp in loops:
                lp.feed(block)
                if watchdog_s is not None and lp.blind_s > max(watchdog_s, 2 * lp.framer.L / source.rig.fs_hz):
                    if status:
                        print(file=sys.stderr)
                    raise InputUnusable(lp.unusable_input())
            stream_s = (block.start + len(block.samples)) / source.rig.fs_hz
            if status and time.perf_counter() - t_last_status > 1.0:
                t_last_status = time.perf_counter()
                print("\r" + " | ".join(lp.status_line() for lp in loops), end="", file=sys.stderr, flush=True)
            if (duration_s is not None and stream_s >= duration_s) or (max_chirps and min(lp.n_chirps for lp in loops) >= max_chirps):
                break
    except KeyboardInterrupt:
        pass
    for lp in loops:  # a finite source that ended before the watchdog's time, without one usable chirp in it
        if lp.n_chirps == 0 and lp.blind_s > 2 * lp.framer.L / source.rig.fs_hz:
            lp.warn(lp.unusable_input())
    if status:
        print("\r" + " | ".join(lp.status_line() for lp in loops), file=sys.stderr, flush=True)
    wall = time.perf_counter() - started
    return [lp.summary(wall, time.process_time() - cpu0, stream_s) for lp in loops]
