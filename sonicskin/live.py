"""The real-time loop: blocks -> chirp frames -> features -> model -> Alg. 2 -> touch events.

:class:`Framer` locks onto the chirp train by cross-correlation and cuts a frame every ``n_chirp`` samples; each frame
goes through the same :class:`sonicskin.head.Stream` every offline replay uses.  Faulty frames are counted and never
reach the model.  The run stops with :class:`DeviceLost` when no audio arrives for ``watchdog_s``, and with
:class:`InputUnusable` when audio arrives but holds no usable chirp."""

from __future__ import annotations

import collections
import functools
import math
import socket
import sys
import time
from collections.abc import Callable

import numpy as np
import scipy.fft

from .acquire import AudioSource, DeviceLost, blocks
from .dsp import band_db, find_chirp_offset, frame_faults, rig_chirp
from .errors import SonicskinError
from .events import SCHEMA_VERSION, TouchEvent, attach_surface
from .runtime import Predictions, SkinRuntime

__all__ = ["TouchEvent", "Framer", "LiveLoop", "UdpSink", "LslSink", "run_loops", "DeviceLost", "InputUnusable", "dropout_frames"]


# Chirp-to-chirp spread (std, dB, median over the usable bins) of the hands-off boot window: a repeating chirp gives
# ~0.1 dB on every shipped rig and scenario, noise alone (the transmitter off) 5.6 dB.
NO_CHIRP_SPREAD_DB = 4.0
# After the boot every frame must repeat the one before (chirp_coherence): a chirp train scores 0.92-1.00 per frame on
# the shipped rigs, scenarios and 42 random-family rigs, noise alone 0.03-0.24.
MIN_COHERENCE = 0.5
CHIRP_CHECK_S = 1.0  # a chirp lost mid-run stops the run about half of this later
MIN_AC_RMS = 1e-7  # a frame whose samples vary (std) by less is a constant level: a DC offset with no signal on it


class InputUnusable(DeviceLost):
    """Audio arrives but no chirp of it is usable (or it holds none): the model would be blind while the loop looked healthy."""


def band_spectrum(frame: np.ndarray, rig) -> np.ndarray:
    """The frame's rfft on the rig's usable band bins (PWM notches dropped), complex64."""
    return band_rfft(frame, rig)[rig.allowed_mask]


def band_rfft(frame: np.ndarray, rig) -> np.ndarray:
    """The frame's rfft on the rig's band bins, complex64: one FFT per chirp for the chirp check and the features."""
    lo, hi = rig.band_bins[0], rig.band_bins[-1] + 1
    return scipy.fft.rfft(np.asarray(frame, np.float32), workers=1)[lo:hi]


@functools.lru_cache(maxsize=16)
def _allowed_bins(rig) -> np.ndarray:
    """The rfft bins of :func:`band_spectrum` (the band without the PWM notches), built once per rig."""
    out = np.asarray(rig.band_bins)[rig.allowed_mask]
    out.setflags(write=False)
    return out


def chirp_coherence(X: np.ndarray, X_prev: np.ndarray, rig) -> float:
    """How much one chirp frame repeats an earlier one, 0..1: the largest normalised circular cross-correlation."""
    L = rig.n_chirp
    Y = np.zeros(L, np.complex64)
    Y[_allowed_bins(rig)] = X * np.conj(X_prev)
    c = np.abs(scipy.fft.ifft(Y, workers=1)) * L  # the analytic cross-correlation at every circular lag
    norm = np.sqrt(float(np.vdot(X, X).real) * float(np.vdot(X_prev, X_prev).real))
    return float(c.max() / norm) if norm > 0 else 0.0


def clearly_clean(frame: np.ndarray, *, clip_level: float = 0.999, min_rms: float = 1e-7, min_run: int = 64) -> bool:
    """True when a frame can have none of the live loop's faults (four cheap reductions); ``False`` means "look closer"."""
    e = float(np.dot(frame, frame))  # non-finite samples make it non-finite
    n = frame.size
    if not (math.isfinite(e) and e >= 4 * n * min_rms ** 2):
        return False
    hi, lo = float(frame.max()), float(frame.min())
    if not (hi < clip_level and lo > -clip_level):
        return False
    # n samples spanning hi - lo vary by at least (hi - lo) / sqrt(2 n) (one at each end, the rest at the mean): exact,
    # where e / n - mean^2 in float32 sums is not for a DC offset far above its variation
    if (hi - lo) / math.sqrt(2 * n) < 2 * MIN_AC_RMS:
        return False
    return int(np.count_nonzero(frame == 0)) < min_run  # fewer zeros than one dropout run holds


def dropout_frames(frames: np.ndarray, *, min_run: int = 64) -> np.ndarray:
    """(n,) bool: frames holding a run of at least ``min_run`` exact zeros (a driver filling a gap; no live ADC does)."""
    z = np.asarray(frames) == 0
    out = np.zeros(z.shape[0], bool)
    for i in np.flatnonzero(z.sum(axis=-1) >= min_run):
        edges = np.flatnonzero(np.diff(np.r_[0, z[i].view(np.int8), 0]))
        out[i] = bool(np.any(edges[1::2] - edges[::2] >= min_run))
    return out


class Framer:
    """Chirp-synchronous framing, re-locked after lost audio and when the peak wanders more than ``tolerance`` samples."""

    def __init__(self, reference: np.ndarray, *, check_every: int = 16, tolerance: int = 256):
        self.ref = np.asarray(reference, np.float64)
        self.L = self.ref.size
        self.check_every, self.tolerance = check_every, tolerance
        self._bufs = [np.zeros(2 * self.L, np.float32) for _ in range(2)]  # preallocated: a block is copied, not joined
        self.n = 0                  # samples held, buf = _bufs[0][:n]
        self.buf_start = 0          # stream sample index of buf[0]
        self.next_start: int | None = None
        self.relocks = 0
        self.n_frames = 0

    @property
    def buf(self) -> np.ndarray:
        return self._bufs[0][:self.n]

    def reset(self) -> None:
        self.n, self.next_start = 0, None

    def _drop(self, k: int) -> None:
        """Forget the first ``k`` samples held (copied to the other buffer, never allocated)."""
        if k > 0:
            self._bufs[1][:self.n - k] = self._bufs[0][k:self.n]
            self._bufs.reverse()
            self.n, self.buf_start = self.n - k, self.buf_start + k

    def push(self, samples: np.ndarray, start: int, discontinuity: bool = False) -> list[tuple[int, np.ndarray]]:
        """Add a block (starting at stream sample ``start``); return the complete ``(start, frame)`` pairs."""
        if discontinuity or (self.n and start != self.buf_start + self.n):
            if self.next_start is not None:
                self.relocks += 1
            self.reset()
        if self.n == 0:
            self.buf_start = start
        m = len(samples)
        if self.n + m > self._bufs[0].size:  # a longer block than any before: the buffers grow, once
            self._bufs = [np.concatenate([self.buf, np.zeros(self.L + m, np.float32)]) for _ in range(2)]
        self._bufs[0][self.n:self.n + m] = samples
        self.n += m
        out = []
        if self.next_start is None:
            if self.buf.size < self.L:
                return out
            off = find_chirp_offset(np.nan_to_num(self.buf[: self.L], nan=0.0, posinf=0.0, neginf=0.0), self.ref, max_periods=1)
            self.next_start = self.buf_start + off
        while self.next_start + self.L <= self.buf_start + self.n:
            a = self.next_start - self.buf_start
            frame = self.buf[a:a + self.L]
            self.n_frames += 1
            if self.n_frames % self.check_every == 0:
                drift = find_chirp_offset(np.nan_to_num(frame, nan=0.0, posinf=0.0, neginf=0.0), self.ref, max_periods=1)
                drift = min(drift, self.L - drift)
                if drift > self.tolerance:  # lost lock without a reported gap
                    self.relocks += 1
                    self._drop(a)
                    self.next_start = None
                    return out
            out.append((self.next_start, frame.copy()))
            self.next_start += self.L
        self._drop(self.next_start - self.buf_start)
        return out


class UdpSink:
    """Send event JSON as UDP datagrams; a datagram that cannot be sent is counted in :attr:`errors`, reported once."""

    def __init__(self, target: str):
        host, _, port = target.rpartition(":")
        host = host or "127.0.0.1"
        if host.startswith("[") and host.endswith("]"):  # [::1]:9999, an IPv6 address in URL brackets
            host = host[1:-1]
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
        self._check_destination(target, family)
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.errors = 0

    def _check_destination(self, target: str, family) -> None:
        import errno
        import ipaddress

        ip = ipaddress.ip_address(self.addr[0].split("%")[0])
        why = None
        if ip.is_unspecified:
            why = f"{ip} is the unspecified address, not a destination"
        elif ip == ipaddress.IPv4Address("255.255.255.255"):
            why = f"{ip} is the broadcast address, which a UDP socket may not send to (Permission denied)"
        else:  # a connect() of a datagram socket sends nothing; it asks the kernel for a route
            probe = socket.socket(family, socket.SOCK_DGRAM)
            try:
                probe.connect(self.addr)
            except OSError as e:
                if e.errno in (errno.EACCES, errno.EPERM, errno.ENETUNREACH, errno.EHOSTUNREACH, errno.EADDRNOTAVAIL):
                    why = f"this machine cannot send to {ip} ({e.strerror})"
            finally:
                probe.close()
        if why:
            raise SonicskinError(f"--udp {target}: {why}; give the address of the machine that reads the events "
                                 f"(127.0.0.1 for this one)")

    def __call__(self, line: str) -> None:
        try:
            self.sock.sendto(line.encode(), self.addr)
        except OSError as e:
            self.errors += 1
            if self.errors == 1:
                print(f"sonicskin: warning: UDP to {self.addr[0]}:{self.addr[1]} failed ({e.strerror or e}); "
                      f"events still go to stdout", file=sys.stderr)


class LiveLoop:
    """Consume ``source``, run ``runtime`` on it, emit touch events (``emit``, ``status``, ``on_chirp`` callbacks)."""

    startup_dropped: int | None = None  # audio blocks dropped before the first chirp was framed

    def __init__(self, runtime: SkinRuntime, source: AudioSource, *, emit: Callable[[str], None] | None = None,
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
        self.link_name = link.name if link is not None else None  # each event names its link (live --links)
        self.surface = getattr(link, "surface", None)  # an arm's link: events carry the contact in the link's frame
        self.framer = Framer(link.tx_period(source.rig) if link is not None else rig_chirp(self.rig))
        self.stream = runtime.stream()
        self.on_chirp = on_chirp
        self.on_event = on_event
        self.warn = warn or (lambda msg: print(f"sonicskin: warning: {msg}", file=sys.stderr, flush=True))
        self.boot_faults = 0  # chirps skipped before the boot reference was taken
        self._drift_warned: str | None = None  # the drift tracker's last warning, said once
        self.touching, self._held = False, False  # a press is open; the chirp before was a held first chirp at 0 N
        self._press: dict[int, tuple[int, float, float]] = {}  # the open press: marker -> (chirps, x_cm, y_cm)
        self.place: tuple[int, float, float] = (-1, math.nan, math.nan)  # the last chirp's (marker, x_cm, y_cm)
        self.events: list[TouchEvent] = []
        self.latencies_ms: list[float] = []
        self.skipped = {"nan": 0, "silent": 0, "clipped": 0, "dropout": 0, "constant": 0, "no_chirp": 0}
        self.n_chirps = 0
        # Since the last usable chirp: seconds of audio fed to this loop and what became of their frames.
        self.blind_s = 0.0
        self.blind_skipped = dict(self.skipped)
        self.blind_relocks = 0
        self._boot_sum: np.ndarray | None = None  # sums of the boot chirps' band features and their squares
        self._boot_sq: np.ndarray | None = None
        self._boot_n = 0
        self.boot_spread_db: float | None = None
        # the running check (_no_chirp): the last usable frame's band spectrum, the recent coherences
        self._prev_spectrum: np.ndarray | None = None
        self.coherences: collections.deque = collections.deque(maxlen=max(8, math.ceil(CHIRP_CHECK_S * self.rig.chirps_per_s)))

    @property
    def refreshes(self) -> int:
        return self.stream.reference.refreshes

    # -- per chirp ---------------------------------------------------------------------

    def process_frame(self, start: int, frame: np.ndarray, t_ready: float) -> TouchEvent | None:
        fault = 0 if clearly_clean(frame) else self._fault(frame)
        R = band_rfft(frame, self.rig) if not fault else None  # the one FFT of this chirp: its check and its features
        if not fault and self._no_chirp(R[self.rig.allowed_mask]):  # after the boot: no chirp (noise alone, a knock)
            fault = 6
        if fault:  # never reaches the features or the model
            kind = {1: "nan", 2: "silent", 3: "clipped", 4: "dropout", 5: "constant", 6: "no_chirp"}[fault]
            self.skipped[kind] += 1
            self.blind_skipped[kind] += 1
            self.boot_faults += self.stream.calibrating
            return None
        self.n_chirps += 1
        self.blind_s, self.blind_skipped, self.blind_relocks = 0.0, dict.fromkeys(self.skipped, 0), self.framer.relocks
        t_s = start / self.rig.fs_hz
        was_calibrating = self.stream.calibrating
        x = band_db(R[None], self.rig)[0]  # the band features (log_magnitude_db's numbers), from the same FFT
        if was_calibrating and self.boot_spread_db is None:
            self._boot_add(x)
        refreshes, reboots = self.stream.reference.refreshes, self.stream.reference.reboots
        p = self.stream.chirp(x, t_s)  # Alg. 2 reference (and drift tracking), model, detection, force
        ref = self.stream.reference
        if ref.reboots != reboots:
            gap = ref.last_gap_s or 0.0
            why = (f"the stream clock went back {-gap:.0f} s" if gap < 0 else f"the stream paused for {gap / 60:.0f} min "
                   f"(more than alpha, {ref.alpha / ref.cps / 60:.0f} min)")
            self.warn(f"{why}: boot calibration again from the next {ref.beta / ref.cps:.1f} s (hands off the link, as at "
                      f"power-on)")
        drift = self.stream.drift
        if drift is not None and ref.refreshes != refreshes and drift.warning and drift.warning != self._drift_warned:
            self._drift_warned = drift.warning  # once per new finding, at the reference that found it
            self.warn(f"drift tracking: {drift.warning}")
        if was_calibrating and not self.stream.calibrating and self.boot_spread_db is None:
            self._boot_check()
        if was_calibrating and not self.stream.calibrating and ref.boot_disturbed:
            c = self.source.counters()
            lost = (f"{ref.boot_touched} chirp(s) that read a hand on the link" if ref.boot_touched else
                    f"{self.boot_faults} faulty chirp(s) (NaN, dropout, silence, a constant level or clipping)"
                    if self.boot_faults else  # none faulty: the chirps were cut by lost audio (a slow start, a busy machine)
                    f"chirps cut by lost audio ({c['overflows'] + c['dropped_blocks']} overflows or dropped blocks, "
                    f"{self.framer.relocks} re-locks)")
            self.warn(f"boot calibration disturbed: {lost} in the first {ref.beta / ref.cps:.1f} s; reference from the "
                      f"{ref.boot_chirps} clean chirps of that window, re-taken from the next {ref.beta / ref.cps:.1f} s "
                      f"of rest")
        if p is None:  # boot calibration
            if self.on_chirp is not None:
                self.on_chirp(t_s, p)
            return None
        # A press opens at its first touched chirp with a force, else at its second touched chirp (a first chirp at 0 N
        # is held: alone, it is no press); each touched chirp is a touch event at its marker; the release names the
        # press's marker, the one most of its chirps named (its last chirp may have slid to a neighbour).
        touch, loc, ev = bool(p.touch[0]), int(p.location[0]), None
        x, y = float(p.xy_cm[0, 0]), float(p.xy_cm[0, 1])
        self._held = touch and not self.touching and not self._held and not float(p.force_n[0]) > 0
        if touch and not self._held:
            self._press = {} if not self.touching else self._press
            n, _, _ = self._press.get(loc, (0, 0.0, 0.0))
            self._press[loc] = (n + 1, x, y)
        elif self.touching:
            loc = max(self._press, key=lambda k: self._press[k][0])  # ties: the marker the press named first
            x, y = self._press[loc][1:]
        if (touch and not self._held) or self.touching:
            ev = TouchEvent(t_s, "touch" if touch else "release", loc, x, y, float(p.force_n[0]), float(p.confidence[0]),
                            self.rt.kind, (time.perf_counter() - t_ready) * 1e3, link=self.link_name,
                            force_reliable=self.rt.m.get("force_reliable"))
            if self.surface is not None:
                ev = attach_surface(ev, self.surface)
        self.touching = touch and not self._held
        self.place = loc, x, y  # a release: the press's marker
        if self.on_chirp is not None:  # after the press rule: a held chirp is untouched for them too
            self.on_chirp(t_s, p)
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
            ev = self.process_frame(start, frame, block.t or time.perf_counter())  # latency from the block's arrival
            if ev is not None:
                self.events.append(ev)
                self.emit(ev.to_json())
                if self.on_event is not None:
                    self.on_event(ev)

    def run(self, *, duration_s: float | None = None, max_chirps: int | None = None, idle_timeout_s: float = 2.0,
            watchdog_s: float | None = 3.0, stop=None) -> dict:
        """Run until ``duration_s``, ``max_chirps``, Ctrl-C, ``stop`` is set, or the source ends (:func:`run_loops`)."""
        return run_loops([self], self.source, duration_s=duration_s, max_chirps=max_chirps,
                         idle_timeout_s=idle_timeout_s, watchdog_s=watchdog_s, stop=stop)[0]

    def _boot_add(self, x_band: np.ndarray) -> None:
        x = x_band[self.rig.allowed_mask].astype(np.float64)
        if self._boot_sum is None:
            self._boot_sum, self._boot_sq = np.zeros_like(x), np.zeros_like(x)
        self._boot_sum += x
        self._boot_sq += x * x
        self._boot_n += 1

    def _boot_check(self) -> None:
        """The boot window must hold a repeating chirp: noise alone would be taken as the reference."""
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

    @staticmethod
    def _fault(frame: np.ndarray) -> int:
        """The frame's fault code (0 none; 1-3 :func:`frame_faults`, 4 a dropout, 5 a DC offset alone)."""
        fault = int(frame_faults(frame[None])[0])
        if not fault and dropout_frames(frame[None])[0]:
            fault = 4
        if not fault and float(np.std(frame)) < MIN_AC_RMS:  # a DC offset alone: its band features are all at the floor
            fault = 5
        return fault

    def _no_chirp(self, X: np.ndarray) -> bool:
        """After the boot, skip a frame that does not repeat the last usable one; most of a window so: :class:`InputUnusable`."""
        prev, self._prev_spectrum = self._prev_spectrum, X
        if prev is None:
            return False
        rho = chirp_coherence(X, prev, self.rig)
        self.coherences.append(rho)
        if self.stream.calibrating:
            return False
        low = [c for c in self.coherences if c < MIN_COHERENCE]
        if len(self.coherences) == self.coherences.maxlen and 2 * len(low) > len(self.coherences):
            n = len(self.coherences)
            raise InputUnusable(f"the chirp was lost: {len(low)} of the last {n} chirps ({n / self.rig.chirps_per_s:.1f} s) "
                                f"do not repeat the chirp before them (coherence median {np.median(low):.2f}; a chirp "
                                f"train's is 0.92-1.00, noise's 0.03-0.25); is the transmitter still playing on output "
                                f"--tx and reaching the receiver? check it with `sonicskin check`")
        return rho < MIN_COHERENCE

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
               "no_chirp": "the input holds no chirp (noise alone): is the transmitter still playing on output --tx and "
                           "reaching the receiver? check it with `sonicskin check`",
               "constant": "the input is a constant level with no signal on it (a DC offset): the receiver's preamp or "
                           "the interface's input (--rx) is stuck; check the cable and the levels with `sonicskin check`",
               None: f"audio blocks are lost ({lost} overflows or dropped blocks): close other programs or raise --blocksize"}
        return (f"the device delivers audio but none of the last {self.blind_s:.1f} s gave a usable chirp ({where}); "
                f"{fix[worst]}")

    def status_line(self) -> str:
        lat = np.asarray(self.latencies_ms[-200:]) if self.latencies_ms else np.zeros(1)
        last = next((e for e in reversed(self.events) if e.kind == "touch"), None)
        c = self.source.counters()
        touch = f"last touch: loc {last.location} ({last.x_cm:.1f}, {last.y_cm:.1f}) cm {last.force_n:.1f} N" if last else "no touch yet"
        state = "calibrating" if self.stream.calibrating else "running"
        drift = f"  {self.stream.drift.status()}" if self.stream.drift is not None else ""
        return (f"{state}{drift}  {self.n_chirps} chirps  latency median {np.median(lat):.2f} ms p99 {np.percentile(lat, 99):.2f} ms  "
                f"{touch}  relocks {self.framer.relocks}  driver overflows {c['overflows']}  dropped blocks {c['dropped_blocks']}"
                f"{self._startup_note(c['dropped_blocks'])}{self._lost_note(c)}  skipped frames {sum(self.skipped.values())}   ")

    @staticmethod
    def _lost_note(c: dict) -> str:
        return f"  lost {c['lost_s']:.2f} s of stream (the last {c['lost_spans_s'][-1][0]:.2f}-{c['lost_spans_s'][-1][1]:.2f} s)" \
            if c.get("lost_spans_s") else ""

    def _startup_note(self, dropped: int) -> str:
        """Blocks dropped at start-up (the queue filled before the loop framed its first chirp): not the link's fault."""
        d0 = self.startup_dropped if self.startup_dropped is not None else dropped
        if not d0:
            return ""
        return f" ({d0} at start-up, before the first chirp was framed: the source ran ahead while the loop started)"

    def summary(self, wall_s: float, cpu_s: float, stream_s: float) -> dict:
        lat = np.asarray(self.latencies_ms) if self.latencies_ms else np.full(1, np.nan)
        return {"chirps": self.n_chirps, "stream_s": stream_s, "wall_s": wall_s, "cpu_share": cpu_s / max(wall_s, 1e-9),
                "latency_ms_median": float(np.median(lat)), **{f"latency_ms_p{q}": float(np.percentile(lat, q)) for q in (95, 99)},
                "touch_events": sum(e.kind == "touch" for e in self.events), "relocks": self.framer.relocks,
                "reference_refreshes": self.refreshes, "boot_disturbed": self.stream.reference.boot_disturbed,
                "drift": None if self.stream.drift is None else self.stream.drift.report(),
                "skipped": dict(self.skipped), **self.source.counters()}


def run_loops(loops: list[LiveLoop], source: AudioSource, *, duration_s: float | None = None,
              max_chirps: int | None = None, idle_timeout_s: float = 2.0, watchdog_s: float | None = 3.0,
              stop=None) -> list[dict]:
    """Feed every block of one source to several loops (one per link).  Ends at ``duration_s`` (wall clock or stream
    time), ``max_chirps``, Ctrl-C, ``stop``, or a finite source's end; nothing for ``watchdog_s``: :class:`DeviceLost`;
    audio without a usable chirp for ``watchdog_s``: :class:`InputUnusable`."""
    t_last_status = started = time.perf_counter()
    cpu0, lost_seen = time.process_time(), 0.0
    stream_s = 0.0
    status = any(lp.status for lp in loops)
    # A faster-than-real-time simulated source (--fast) runs on its own stream clock; everything that
    # claims to be real time (devices, real-time simulation) is also bounded by the wall clock.
    wall_bound = source.realtime
    try:
        for block in blocks(source, watchdog_s=watchdog_s, poll_s=min(0.1, idle_timeout_s)):
            if duration_s is not None and wall_bound and time.perf_counter() - started >= duration_s:
                break
            if stop is not None and stop.is_set():
                break
            if block is None:
                continue
            for lp in loops:
                lp.feed(block)  # InputUnusable: no chirp in the input (the boot's check or the running one)
                if watchdog_s is not None and lp.blind_s > max(watchdog_s, 2 * lp.framer.L / source.rig.fs_hz):
                    raise InputUnusable(lp.unusable_input())
            stream_s = (block.start + len(block.samples)) / source.rig.fs_hz
            if time.perf_counter() - t_last_status > 1.0:
                t_last_status, lost_seen = time.perf_counter(), _warn_lost(loops[0], source, lost_seen, status)
                if status:
                    print("\r" + " | ".join(lp.status_line() for lp in loops), end="", file=sys.stderr, flush=True)
            if (duration_s is not None and stream_s >= duration_s) or (max_chirps and min(lp.n_chirps for lp in loops) >= max_chirps):
                break
    except KeyboardInterrupt:
        pass
    except DeviceLost:  # InputUnusable too: the status line ends before the error's line
        if status:
            print(file=sys.stderr)
        raise
    _warn_lost(loops[0], source, lost_seen, status)
    for lp in loops:  # a finite source that ended before the watchdog's time, without one usable chirp in it
        if lp.n_chirps == 0 and lp.blind_s > 2 * lp.framer.L / source.rig.fs_hz:
            lp.warn(lp.unusable_input())
    if status:
        print("\r" + " | ".join(lp.status_line() for lp in loops), file=sys.stderr, flush=True)
    wall = time.perf_counter() - started
    return [lp.summary(wall, time.process_time() - cpu0, stream_s) for lp in loops]


def _warn_lost(loop: LiveLoop, source: AudioSource, seen: float, status: bool) -> float:
    """One warning line (at most one a second) naming the stream time lost since the last one; returns the lost end."""
    spans = [s for s in source.counters().get("lost_spans_s", []) if s[1] > seen]
    if not spans:
        return seen
    c = source.counters()
    print("\n" if status else "", end="", file=sys.stderr)  # the status line ends before the warning's
    loop.warn(f"audio lost: stream time {', '.join(f'{a:.3f}-{b:.3f} s' for a, b in spans[-3:])} is missing "
              f"({c['lost_s']:.3f} s in all: {c['dropped_blocks']} blocks dropped as the loop fell behind the audio, "
              f"{c['overflows']} lost by the driver)" + ("; --realtime, or fewer busy programs" if c["dropped_blocks"] else ""))
    return spans[-1][1]


# -- Lab Streaming Layer (optional: pip install 'sonicskin[lsl]'): one irregular-rate string stream of type
# TouchEvents, each sample one event's JSON, the schema version in desc/schema_version; LSL stamps its own clock.
STREAM_TYPE = "TouchEvents"


def import_pylsl():
    try:
        import pylsl
    except (ImportError, RuntimeError, OSError) as e:  # pylsl raises RuntimeError when liblsl cannot load
        raise SonicskinError(f"--lsl needs pylsl ({str(e).splitlines()[0][:120]}): pip install 'sonicskin[lsl]'") from None
    return pylsl


class LslSink:
    """Publish event JSON lines on an LSL outlet named ``name``."""

    def __init__(self, name: str = "sonicskin", *, source_id: str | None = None):
        pylsl = import_pylsl()
        info = pylsl.StreamInfo(name, STREAM_TYPE, 1, pylsl.IRREGULAR_RATE, pylsl.cf_string, source_id or f"sonicskin-{name}")
        desc = info.desc()
        desc.append_child_value("schema_version", str(SCHEMA_VERSION))
        desc.append_child_value("format", "one JSON touch event per sample (sonicskin.events)")
        self.outlet = pylsl.StreamOutlet(info)

    def __call__(self, line: str) -> None:
        self.outlet.push_sample([line])
