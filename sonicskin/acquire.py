"""Audio acquisition: the only module that touches audio hardware (through sounddevice).

A *source* (:class:`AudioSource`) delivers the receiver's audio as blocks while the transmitter plays the chirp back
to back: a sound card, the simulated device or a recorded session; every consumer reads one through :func:`blocks`.
Overflows and dropped blocks flag the next block as a discontinuity, never fatal: the live loop re-locks on them."""

from __future__ import annotations

import atexit
import collections
import contextlib
import dataclasses
import itertools
import os
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from .dsp import rig_chirp
from .errors import SonicskinError, is_number
from .rig import Rig

__all__ = ["Block", "AudioError", "DeviceLost", "MAX_BLOCKSIZE", "check_blocksize", "Link", "realtime_thread", "import_sounddevice",
           "list_devices", "find_device", "resolve_device", "check_device_rate", "AudioSource", "blocks",
           "SoundDeviceSource", "SimulatedSource", "RecordingSource"]


class AudioError(SonicskinError, RuntimeError):
    """No usable audio device, rate or library, or a device that stopped (a :class:`SonicskinError` that is a ``RuntimeError``)."""


class DeviceLost(AudioError):
    """No audio arrived for the watchdog's time: the audio server or the interface stopped (:func:`blocks`)."""


MAX_BLOCKSIZE = 2**20  # frames per audio block (5.5 s at 192 kHz): more holds the whole run in one block


def check_blocksize(value, name: str = "blocksize") -> int:
    """``value`` as frames per audio block, 1 to :data:`MAX_BLOCKSIZE`, for ``blocksize=`` and ``--blocksize`` alike."""
    if not is_number(value, integer=True) or not 1 <= value <= MAX_BLOCKSIZE:
        raise SonicskinError(f"{name} must be an integer from 1 to {MAX_BLOCKSIZE} (audio frames per block), got {value!r}")
    return value


@dataclasses.dataclass
class Block:
    samples: np.ndarray     # (n,) float32, the receiver channel
    index: int              # sequence number of the block (gaps mean lost blocks)
    start: int              # sample index of the first sample in the stream
    discontinuity: bool     # samples before this block were lost (overflow, dropped block)
    t: float = 0.0          # time.perf_counter() when the source delivered it (its chirps' latency starts here)


@dataclasses.dataclass(frozen=True)
class Link:
    """One transmitter/receiver pair (0-based channels); several on one interface share the chirp by time or frequency."""

    tx: int = 0
    rx: int = 0
    slot: int = 0
    n_slots: int = 1
    name: str = "link0"
    rig: Rig | None = None  # frequency duplexing: this link's own chirp band
    # A link of an arm file (sonicskin.links): its frame on the robot, the simulated link, its trained artifact.
    frame: str | None = None
    surface: Any = dataclasses.field(default=None, compare=False, repr=False)   # sonicskin.surface.LinkSurface
    scenario: Any = dataclasses.field(default=None, compare=False, repr=False)  # sonicskin.sim.Scenario
    artifact: Path | None = None

    def tx_period(self, rig: Rig) -> np.ndarray:
        """What this link transmits over one duplex period (``n_slots`` chirps), float32."""
        own = self.rig or rig
        L = own.n_chirp
        out = np.zeros(L * self.n_slots, np.float32)
        out[self.slot * L:(self.slot + 1) * L] = rig_chirp(own)
        return out


def import_sounddevice():
    """Import sounddevice lazily, with an actionable error when PortAudio is missing."""
    try:
        import sounddevice as sd
    except OSError as e:  # sounddevice raises OSError when libportaudio cannot be loaded
        raise AudioError(f"the PortAudio library is not installed ({e}); on Debian/Ubuntu: "
                         f"sudo apt-get install libportaudio2") from None
    return sd


_EXIT = {"code": 2, "armed": False}


def exit_unhung(code: int | None = None) -> None:
    """A process that opened an audio interface exits even when its audio server died during the run: PortAudio's exit
    handler (Pa_Terminate) hangs then, so at exit it runs in a daemon thread and after 5 s the process ends without it,
    outputs flushed, with the verb's exit code (``code``, once known; 2 until then).  The device arms it (no ``code``)."""
    if code is not None:
        _EXIT["code"] = code
    elif not _EXIT["armed"]:
        _EXIT["armed"] = True
        atexit.register(_exit_without_portaudio)  # after sounddevice's own handler: runs before it


def _exit_without_portaudio() -> None:
    sd = sys.modules.get("sounddevice")
    if sd is None:
        return

    def terminate() -> None:
        with contextlib.suppress(Exception):  # a PortAudioError of a dead server: nothing left to close
            sd._exit_handler()

    t = threading.Thread(target=terminate, daemon=True)
    t.start()
    t.join(timeout=5.0)
    if not t.is_alive():
        atexit.unregister(sd._exit_handler)  # done: not again
        return
    for f in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            f.flush()
    os._exit(_EXIT["code"])


def list_devices() -> list[dict]:
    """Audio devices PortAudio sees: index, name, host API, channel counts, default rate."""
    sd = import_sounddevice()
    apis = sd.query_hostapis()
    return [{"index": i, "name": d["name"], "hostapi": apis[d["hostapi"]]["name"],
             "inputs": d["max_input_channels"], "outputs": d["max_output_channels"],
             "default_rate_hz": d["default_samplerate"]} for i, d in enumerate(sd.query_devices())]


def find_device(spec: str | int | None, rig: Rig, n_in: int, n_out: int) -> int:
    """Resolve a device name (substring) or index and check it runs the rig's rate and channels."""
    idx = resolve_device(spec)
    check_device_rate(idx, rig, n_in, n_out)
    return idx


def resolve_device(spec: str | int | None) -> int:
    """The index of a device name (substring) or index (``None``: the default input device)."""
    sd = import_sounddevice()
    devs = list_devices()
    if not devs:
        raise AudioError("no audio device found; connect the audio interface (or start JACK), "
                         "or run with the simulated device: --device sim")
    if spec is None:
        idx = sd.default.device[0] if sd.default.device[0] is not None and sd.default.device[0] >= 0 else devs[0]["index"]
    elif isinstance(spec, int) or str(spec).isdigit():
        idx = int(spec)
        if idx >= len(devs):
            raise AudioError(f"no audio device with index {idx}; `sonicskin devices` lists {len(devs)}")
    else:
        hits = [d for d in devs if str(spec).lower() in d["name"].lower()]
        if not hits:
            raise AudioError(f"no audio device matches {spec!r}; `sonicskin devices` lists: " + ", ".join(d["name"] for d in devs))
        idx = hits[0]["index"]
    return idx


def check_device_rate(idx: int, rig: Rig, n_in: int, n_out: int) -> None:
    """Raise :class:`AudioError` unless device ``idx`` has the channels and runs the rig's rate."""
    sd = import_sounddevice()
    d = list_devices()[idx]
    if d["inputs"] < n_in or d["outputs"] < n_out:
        raise AudioError(f"device {d['name']!r} has {d['inputs']} inputs / {d['outputs']} outputs; "
                         f"the links need {n_in} / {n_out}")
    try:
        sd.check_input_settings(device=idx, channels=n_in, samplerate=rig.fs_hz, dtype="float32")
        sd.check_output_settings(device=idx, channels=n_out, samplerate=rig.fs_hz, dtype="float32")
    except Exception as e:  # sounddevice.PortAudioError and ValueError
        raise AudioError(f"device {d['name']!r} cannot run at {rig.fs_hz:g} Hz ({e}); set the interface to "
                         f"{rig.fs_hz:g} Hz or use a rig config with its rate") from None


def thread_cpu_s(thread: threading.Thread | None) -> float | None:
    """CPU seconds a running thread has used (Linux ``/proc``), ``None`` where that cannot be read."""
    tid = getattr(thread, "native_id", None)
    if tid is None or not thread.is_alive():
        return None
    try:
        with open(f"/proc/self/task/{tid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime, in clock ticks
    except (OSError, ValueError, IndexError):
        return None


#: SCHED_FIFO priorities of ``--realtime``: the audio thread above the processing thread (both below the kernel's own)
AUDIO_PRIORITY, LOOP_PRIORITY = 70, 60


def realtime_thread(priority: int) -> tuple[str, Callable[[], None]]:
    """Real-time scheduling of the calling thread (Linux): SCHED_FIFO, else the lowest nice value; (what was granted, undo)."""
    tid = threading.get_native_id()
    try:
        old = os.sched_getscheduler(tid), os.sched_getparam(tid), os.getpriority(os.PRIO_PROCESS, tid)
    except (AttributeError, OSError):
        return "not available on this system", lambda: None

    def undo() -> None:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(tid, *old[:2])
            os.setpriority(os.PRIO_PROCESS, tid, old[2])

    if old[0] == os.SCHED_FIFO:  # already (a JACK client's thread)
        return f"SCHED_FIFO {old[1].sched_priority} (the audio server's)", lambda: None
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        return f"SCHED_FIFO {priority}", undo
    except OSError as e:
        denied = f"SCHED_FIFO not permitted ({e.strerror})"
    for nice in (-10, -5, -1):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, tid, nice)
            return f"{denied}, nice {nice} instead", undo
    return f"{denied}, nor a negative nice: normal priority (root or an rtprio limit grants it)", undo


class AudioSource(Protocol):
    """The contract of a source: blocks from :meth:`read`, ``(n,)`` for one link, ``(n, links)`` for several."""

    rig: Rig
    #: blocks come at the sample rate (a device, the real-time simulation); ``False``: as fast as they are read
    realtime: bool
    #: set once a finite source (a simulated session, a recording) has delivered its last block; ``None``: never ends
    finished: threading.Event | None
    #: what ended the source's producer thread early, raised in the consumer's thread by :func:`blocks`
    error: BaseException | None
    #: what the watchdog says when nothing arrives (``{s}``: its seconds)
    stall_text: str
    #: ask real-time scheduling for the thread that delivers the blocks (``--realtime``); what it got, once started
    rt_sched: bool
    rt_granted: str | None

    def read(self, timeout: float = 1.0) -> Block | None: ...
    def counters(self) -> dict: ...
    def producer_cpu_s(self) -> float | None: ...
    def start(self) -> None: ...
    def stop(self) -> None: ...
    def __enter__(self) -> AudioSource: ...
    def __exit__(self, *exc) -> None: ...


def blocks(source: AudioSource, *, watchdog_s: float | None = 3.0, poll_s: float = 0.1) -> Iterator[Block | None]:
    """Every block of a started source as it arrives, ``None`` after each ``poll_s`` without one; ends with a finite
    source.  Raises the producer's exception, and :class:`DeviceLost` when nothing arrives for ``watchdog_s`` while
    the producer does not compute either (a slow render is not a stall)."""
    t_alive, cpu_seen = time.perf_counter(), None
    if watchdog_s is not None:  # one block is blocksize / fs of stream: never call a device dead before two could come
        watchdog_s = max(watchdog_s, 2.0 * getattr(source, "blocksize", 0) / source.rig.fs_hz)
    while True:
        block = source.read(timeout=poll_s)
        if block is None and source.finished is not None and source.finished.is_set():
            block = source.read(timeout=0)  # what it delivered before it ended is in the queue by now
            if block is None:
                return
        if block is not None:
            t_alive = time.perf_counter()
            yield block
            continue
        if source.error is not None:  # the producer thread died of it
            raise source.error
        if watchdog_s is not None:  # a device can die silently; a simulated source's producer can stall
            now = time.perf_counter()
            cpu = source.producer_cpu_s()
            if cpu is not None and cpu != cpu_seen:  # still computing (a slow render on a loaded machine)
                cpu_seen, t_alive = cpu, now
            if now - t_alive > watchdog_s:
                raise DeviceLost(source.stall_text.format(s=watchdog_s))
        yield None


class _QueueSource:
    """The consumer side every source shares: a bounded queue of blocks, counters, and a clean shutdown."""

    stall_text = ("no audio from the device for {s:g} s (the audio server or the interface stopped, or the cable is out); "
                  "check it with `sonicskin devices` and start again")
    realtime = True
    finished: threading.Event | None = None
    error: BaseException | None = None
    rt_sched, rt_granted = False, None

    def __init__(self, rig: Rig, blocksize: int, max_queued_s: float | None = None):
        self.rig, self.blocksize = rig, int(blocksize)
        # A stall of the loop up to max(2 s, 16 chirp periods) loses no audio (jaco: 1.7 s of chirps -> 2 s; a 0.5 s
        # chirp: 8 s); longer, blocks drop and lost_spans says which stream time is missing.
        self.queued_s = max(2.0, 16 * rig.period_s) if max_queued_s is None else max_queued_s
        self.queue: queue.Queue = queue.Queue(maxsize=max(4, int(self.queued_s * rig.fs_hz / blocksize)))
        self.overflows = 0       # driver-reported input overflows
        self.underflows = 0      # driver-reported output underflows
        self.dropped_blocks = 0  # blocks the consumer was too slow to take
        self.lost_spans: collections.deque = collections.deque(maxlen=100)  # [first, end) samples of stream lost
        self._index = 0
        self._pos = 0
        self._lost = False
        self._stop = threading.Event()

    def _deliver(self, samples: np.ndarray, lost_before: bool = False, *, wait: bool = False) -> None:
        """Queue the producer's next block; a full queue drops it (flagging the next) unless ``wait``."""
        # t: the arrival, for a source at the sample rate (one paced by its reader has none: latency is processing)
        block = Block(samples, self._index, self._pos, lost_before or self._lost, 0.0 if wait else time.perf_counter())
        self._index += 1
        self._pos += len(samples)
        while True:
            try:
                self.queue.put(block, timeout=0.1) if wait else self.queue.put_nowait(block)
                self._lost = False
                return
            except queue.Full:
                if not wait:
                    self.dropped_blocks += 1
                    self._lose(block.start, self._pos)
                    return
                if self._stop.is_set():
                    return

    def _lose(self, a: int, b: int) -> None:
        """Samples ``a`` to ``b`` of the stream never reach the loop: kept in :attr:`lost_spans`, the next block flagged."""
        self._lost = True
        if self.lost_spans and self.lost_spans[-1][1] == a:
            self.lost_spans[-1][1] = b
        else:
            self.lost_spans.append([a, b])

    def _rt_start(self) -> None:
        """In the thread that delivers the blocks, once: its real-time scheduling (``rt_sched``)."""
        if self.rt_sched and self.rt_granted is None:
            self.rt_granted = realtime_thread(AUDIO_PRIORITY)[0]

    def read(self, timeout: float = 1.0) -> Block | None:
        try:
            return self.queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def counters(self) -> dict:
        spans = [[round(a / self.rig.fs_hz, 4), round(b / self.rig.fs_hz, 4)] for a, b in list(self.lost_spans)]
        return {"overflows": self.overflows, "underflows": self.underflows, "dropped_blocks": self.dropped_blocks,
                "lost_s": round(sum(b - a for a, b in spans), 4), "lost_spans_s": spans[-10:]}

    def producer_cpu_s(self) -> float | None:
        """CPU seconds of the producer thread (``None`` for a device): a producer that still computes is alive."""
        return thread_cpu_s(getattr(self, "_thread", None))

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()


class SoundDeviceSource(_QueueSource):
    """Duplex stream: the chirp train out on ``link.tx``, the receiver in on ``link.rx`` (``links``: blocks (n, links))."""

    def __init__(self, rig: Rig, device: str | int | None = None, *, link: Link = Link(), links: list[Link] | None = None,
                 blocksize: int = 1024, playback: np.ndarray | None = None, rx_channels: list[int] | None = None):
        super().__init__(rig, blocksize)
        self.sd = import_sounddevice()
        self.links = list(links) if links else [link]
        n_in = max([lk.rx for lk in self.links] + list(rx_channels or [])) + 1
        n_out = max(lk.tx for lk in self.links) + 1
        self.device = find_device(device, rig, n_in, n_out)
        # One period of every output channel, precomputed: the callback only indexes into it.
        signals = [lk.tx_period(rig) if playback is None else np.asarray(playback, np.float32) for lk in self.links]
        period = max(len(sig) for sig in signals)
        tx = np.zeros((period, n_out), np.float32)
        for lk, sig in zip(self.links, signals):
            tx[:, lk.tx] += np.resize(sig, period)  # a shorter period repeats
        self._tx = tx[np.arange(period + self.blocksize) % period]  # a block past the period: one slice per callback
        self._period = period
        self._rx = list(rx_channels) if rx_channels else [lk.rx for lk in self.links]
        self._tx_pos = 0
        self.link = self.links[0]
        self.stream = self.sd.Stream(samplerate=rig.fs_hz, blocksize=self.blocksize, device=self.device,
                                     channels=(n_in, n_out), dtype="float32", callback=self._callback)
        exit_unhung()

    def _callback(self, indata, outdata, frames, time_info, status) -> None:
        # Audio thread: copy only (the output a slice of the precomputed period, the input the one copy queued).
        self._rt_start()
        n = self._period
        if frames <= self.blocksize:
            outdata[:] = self._tx[self._tx_pos:self._tx_pos + frames]
        else:  # a host that calls with more frames than asked
            outdata[:] = self._tx[(self._tx_pos + np.arange(frames)) % n]
        self._tx_pos = (self._tx_pos + frames) % n
        if status.input_overflow:
            self.overflows += 1
        if status.output_underflow:
            self.underflows += 1
        rx = indata[:, self._rx[0]].copy() if len(self._rx) == 1 else indata[:, self._rx].copy()
        self._deliver(rx, lost_before=bool(status.input_overflow))

    def start(self) -> None:
        self.stream.start()

    def stop(self) -> None:
        # A stream whose audio server died can block in stop(): close it from a helper thread and
        # give up after 10 s (the process exits anyway; the device is gone).
        def close():
            try:
                self.stream.stop()
                self.stream.close()
            except Exception:  # sounddevice.PortAudioError from a dead server: nothing left to close
                pass

        t = threading.Thread(target=close, name="sonicskin-audio-close", daemon=True)
        t.start()
        t.join(timeout=10.0)


class _ProducerSource(_QueueSource):
    """A source whose audio a thread of its own produces (:meth:`_chunks`), paced at the sample rate or as fast as read."""

    what = "source"  # for the watchdog's message

    def __init__(self, rig: Rig, blocksize: int, *, realtime: bool, drop_every: int | None = None):
        super().__init__(rig, blocksize)
        self.realtime, self.drop_every = realtime, drop_every
        self.finished = threading.Event()
        self._thread = threading.Thread(target=self._run_producer, name=f"sonicskin-{type(self).__name__}", daemon=True)

    @property
    def stall_text(self) -> str:
        return (f"no audio from the {self.what} for {{s:g}} s: its producer thread stopped delivering without ending the "
                f"stream (and is not computing); start again")

    def _chunks(self) -> Iterator[np.ndarray]:  # pragma: no cover - interface
        raise NotImplementedError

    def _run_producer(self) -> None:
        """The producer thread: an exception that ends it is kept for the consumer (:attr:`error`), which raises it."""
        try:
            self._rt_start()
            # The clock starts at the first block: the work before it (a simulated arm renders its first chunk, seconds
            # on a slow PC) is the device booting, not stream time to catch up by flooding the queue.
            chunks, pending, t_next = self._chunks(), None, None
            for n_block in itertools.count(1):
                while (pending is None or len(pending) < self.blocksize) and not self._stop.is_set():
                    chunk = next(chunks, None)
                    if chunk is None:
                        break
                    pending = chunk if pending is None else np.concatenate([pending, chunk])
                if self._stop.is_set() or pending is None or not len(pending):
                    break
                block, pending = pending[:self.blocksize], pending[self.blocksize:]
                if self.drop_every and n_block % self.drop_every == 0:  # what a driver reports when input is lost
                    self.overflows += 1
                    self._index, self._pos = self._index + 1, self._pos + len(block)
                    self._lose(self._pos - len(block), self._pos)
                else:
                    self._deliver(block, wait=not self.realtime)
                if self.realtime:
                    t_next = (time.perf_counter() if t_next is None else t_next) + len(block) / self.rig.fs_hz
                    time.sleep(max(0.0, t_next - time.perf_counter()))
            self.finished.set()
        except BaseException as e:  # handed to the consumer's thread
            self.error = e

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


class SimulatedSource(_ProducerSource):
    """The simulated device: scripted touches rendered ahead in a producer thread, delivered in real time or as fast as
    read; a list of simulators is a whole arm (one input channel per link); ``drop_every``: fault injection."""

    what = "simulated device"

    def __init__(self, simulator, timeline, *, blocksize: int = 1024, realtime: bool = True,
                 drop_every: int | None = None, offset: int = 4321, chunk_chirps: int = 64):
        sims, tls = (list(simulator), list(timeline)) if isinstance(simulator, (list, tuple)) else ([simulator], [timeline])
        if len(sims) != len(tls) or not sims:
            raise ValueError(f"a simulated arm needs one timeline per link: {len(sims)} simulators, {len(tls)} timelines")
        if any(s.rig.mismatch(sims[0].rig) for s in sims):
            raise ValueError("the simulated links of one interface must run one rig (one sample rate and chirp)")
        super().__init__(sims[0].rig, blocksize, realtime=realtime, drop_every=drop_every)
        n = min(len(t) for t in tls)
        self.sims, self.timelines = sims, [t if len(t) == n else t.select(np.arange(n)) for t in tls]
        self.sim, self.timeline = sims[0], self.timelines[0]
        # In real time a chunk is at most about a second of audio: the render holds the blocks back, and the producer
        # then catches up faster than real time, so a long chunk (64 jaco chirps, 6.8 s) overfills the loop's queue.
        self.offset = int(offset) % self.rig.n_chirp
        self.chunk = max(1, min(int(chunk_chirps), round(1.0 / self.rig.period_s))) if realtime else int(chunk_chirps)

    @property
    def length_s(self) -> float:
        """Seconds of stream the session holds (its chirps from ``offset`` on, and half a chirp)."""
        return (len(self.timeline) * self.rig.n_chirp - self.offset + self.rig.n_chirp // 2) / self.rig.fs_hz

    def _chunks(self) -> Iterator[np.ndarray]:
        L, last = self.rig.n_chirp, None
        for a in range(0, len(self.timeline), self.chunk):
            if self._stop.is_set():
                return
            idx = np.arange(a, min(a + self.chunk, len(self.timeline)))
            chans = [sim.render(tl.select(idx)).ravel() for sim, tl in zip(self.sims, self.timelines)]
            audio = np.stack(chans, axis=1) if len(chans) > 1 else chans[0]
            last = audio[-L:]
            yield audio[self.offset:] if a == 0 else audio
        if last is not None:  # the stream goes on a little into the next chirp, as a recording would
            yield last[: L // 2]


class RecordingSource(_ProducerSource):
    """A recorded ``session`` of a dataset played as an audio source, so it runs through the live loop as it was received."""

    what = "recording"

    def __init__(self, dataset, session: str, *, blocksize: int = 1024, realtime: bool = False):
        super().__init__(dataset.rig, blocksize, realtime=realtime)
        self.dataset, self.session = dataset, session

    def audio(self) -> np.ndarray:
        """The session's received stream: its parts concatenated."""
        import soundfile as sf

        parts = [sf.read(self.dataset.root / self.session / f"part-{p:05d}.flac", dtype="float32", always_2d=True)[0][:, 0]
                 for p in self.dataset.parts(self.session)]
        return np.concatenate(parts)

    def _chunks(self) -> Iterator[np.ndarray]:
        yield self.audio()
