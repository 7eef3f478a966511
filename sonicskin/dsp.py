"""Signal chain: chirp (Eq. 1), chirp-synchronous framing, batched spectra and features (no Python loop per chirp)."""

from __future__ import annotations

import functools

import numpy as np
import scipy.fft
import scipy.signal

from . import threads
from .rig import Rig

__all__ = [
    "chirp", "chirp_spectrum", "find_chirp_offset", "frame_stream", "frame_faults", "check_frames",
    "log_magnitude_db", "FrameError",
]

_EPS = 1e-12


class FrameError(ValueError):
    """Audio that cannot be turned into features (wrong length, NaN, silence, clipping)."""


def chirp(*, sr: float, f_lo_hz: float, f_hi_hz: float, n_samples: int, amplitude: float = 1.0,
          phase_rad: float = 0.0) -> np.ndarray:
    """Linear chirp of Eq. 1, ``s(t) = sin(a t^2 + Omega_1 t + phi)``, ``a = (Omega_2 - Omega_1) / (2 T)``, float64."""
    t = np.arange(int(n_samples)) / sr
    duration_s = n_samples / sr
    # scipy's chirp is a cosine; sin(x + phi) = cos(x + phi - pi/2).
    return amplitude * scipy.signal.chirp(t, f0=f_lo_hz, t1=duration_s, f1=f_hi_hz, method="linear", phi=np.degrees(phase_rad) - 90.0)


@functools.lru_cache(maxsize=8)
def rig_chirp(rig: Rig) -> np.ndarray:
    """The sweep a rig transmits, shape (rig.n_chirp,): Eq. 1's chirp or the rig's stored sweep (once per rig, read-only)."""
    stored = rig.sweep()
    if stored is not None:
        x = stored.astype(np.float64)
    else:
        x = chirp(sr=rig.fs_hz, f_lo_hz=rig.f_lo_hz, f_hi_hz=rig.f_hi_hz, n_samples=rig.n_chirp, amplitude=rig.amplitude)
    x.setflags(write=False)
    return x


@functools.lru_cache(maxsize=8)
def chirp_spectrum(rig: Rig) -> np.ndarray:
    """rfft of the transmitted chirp, S(f), shape (rig.n_chirp // 2 + 1,), complex128, read-only."""
    S = scipy.fft.rfft(rig_chirp(rig))
    S.setflags(write=False)
    return S


def find_chirp_offset(stream: np.ndarray, reference: np.ndarray, *, max_periods: int = 8) -> int:
    """Where the first whole chirp of ``stream`` starts, in ``[0, L)``: the matched-filter peak over ``max_periods`` periods."""
    L = reference.shape[-1]
    x = np.asarray(stream, dtype=np.float64)
    if x.ndim != 1:
        raise FrameError(f"stream must be one-dimensional audio, got shape {x.shape}")
    n_per = min(max_periods, x.size // L)
    if n_per < 1:
        raise FrameError(f"stream has {x.size} samples, fewer than one chirp period ({L}); record longer")
    blocks = x[: n_per * L].reshape(n_per, L)
    X = scipy.fft.fft(blocks, axis=-1)
    S = scipy.fft.fft(reference)
    # Analytic matched filter: keep positive frequencies so |output| is the pulse envelope.
    H = np.zeros(L)
    H[1 : (L + 1) // 2] = 2.0
    H[0] = 1.0
    if L % 2 == 0:
        H[L // 2] = 1.0
    env = np.abs(scipy.fft.ifft(X * np.conj(S) * H, axis=-1)).mean(axis=0)
    return int(np.argmax(env))


def frame_stream(stream: np.ndarray, reference: np.ndarray, *, offset: int | None = None) -> tuple[np.ndarray, int]:
    """Cut a chirp train into chirp-aligned frames: ``(frames (n_frames, L) float32, offset)``."""
    L = reference.shape[-1]
    if offset is None:
        offset = find_chirp_offset(stream, reference)
    n = (len(stream) - offset) // L
    if n < 1:
        raise FrameError(f"stream of {len(stream)} samples holds no whole chirp after offset {offset}")
    frames = np.asarray(stream[offset : offset + n * L], dtype=np.float32).reshape(n, L)
    return frames, int(offset)


def frame_faults(frames: np.ndarray, *, clip_level: float = 0.999, min_rms: float = 1e-7) -> np.ndarray:
    """Per-frame fault code: 0 ok, 1 non-finite, 2 silent, 3 clipped (more than 0.1 % of samples at ``clip_level``)."""
    x = np.asarray(frames)
    faults = np.zeros(x.shape[0], dtype=np.int8)
    finite = np.isfinite(x).all(axis=-1)
    faults[~finite] = 1
    xf = np.where(np.isfinite(x), x, 0.0)
    rms = np.sqrt(np.mean(np.square(xf, dtype=np.float64), axis=-1))
    faults[finite & (rms < min_rms)] = 2
    clipped = np.mean(np.abs(xf) >= clip_level, axis=-1) > 1e-3
    faults[finite & (rms >= min_rms) & clipped] = 3
    return faults


_FAULT_TEXT = {
    1: "contains NaN or inf samples (a broken driver or a bad file); drop those chirps",
    2: "is silent (all zeros): is the transmitter playing and the receiver connected?",
    3: "is clipped at full scale: lower the transmit amplitude or the input gain",
}


def check_frames(frames: np.ndarray, rig: Rig) -> np.ndarray:
    """Validate a batch of frames for ``rig`` and return it as float32 (n, n_chirp); else a :class:`FrameError`."""
    x = np.asarray(frames)
    if x.ndim == 1:
        x = x[None, :]
    if x.ndim != 2:
        raise FrameError(f"frames must be (n_chirps, {rig.n_chirp}), got shape {x.shape}")
    if x.shape[1] != rig.n_chirp:
        raise FrameError(
            f"frame length {x.shape[1]} does not match the rig's chirp of {rig.n_chirp} samples "
            f"({rig.period_s * 1e3:.1f} ms at {rig.fs_hz:g} Hz); frame the stream with frame_stream() "
            f"or load the rig the audio was recorded with"
        )
    if not np.issubdtype(x.dtype, np.floating):
        raise FrameError(f"frames must be floating point in [-1, 1], got dtype {x.dtype}")
    if _plainly_ok(x):
        return x.astype(np.float32, copy=False)
    faults = frame_faults(x)
    bad = np.flatnonzero(faults)
    if bad.size:
        k = int(bad[0])
        raise FrameError(f"{bad.size} of {len(x)} frames are unusable; frame {k} {_FAULT_TEXT[int(faults[k])]}")
    return x.astype(np.float32, copy=False)


def _plainly_ok(x: np.ndarray, *, clip_level: float = 0.999, min_rms: float = 1e-7) -> bool:
    """True when no frame can have a fault of :func:`frame_faults` (three passes, no temporaries); else it decides."""
    if x.size == 0:
        return False
    energy = np.einsum("ij,ij->i", x, x)
    if not (np.all(np.isfinite(energy)) and energy.min() >= 2 * x.shape[1] * min_rms ** 2):
        return False
    return bool(x.max() < clip_level and x.min() > -clip_level)


@functools.lru_cache(maxsize=8)
def _inv_power_s(rig: Rig) -> np.ndarray:
    """``1 / |S(f)|^2`` on the band bins (float32): divides the received power by the chirp's."""
    out = (1.0 / np.abs(chirp_spectrum(rig)[rig.band_bins]) ** 2).astype(np.float32)
    out.setflags(write=False)
    return out


def log_magnitude_db(frames: np.ndarray, rig: Rig, *, check: bool = True) -> np.ndarray:
    """Features of chirp-aligned frames: ``20 log10 |H(f)|`` on the band bins, (n, rig.n_band) float32."""
    if check:
        frames = check_frames(frames, rig)
    x = np.asarray(frames, dtype=np.float32)
    if x.ndim == 1:
        x = x[None, :]
    # |H| in dB without the complex division: 10 log10 (|R|^2 / |S|^2 + eps^2), all in float32 on the
    # band bins only (the same numbers as 20 log10 (|R / S| + eps) to float32 rounding).
    lo, hi = rig.band_bins[0], rig.band_bins[-1] + 1
    out = np.empty((x.shape[0], rig.n_band), dtype=np.float32)
    chunk = 64  # a chunk's spectra stay in cache
    for i in range(0, x.shape[0], chunk):
        band_db(scipy.fft.rfft(x[i : i + chunk], axis=-1, workers=threads.fft_workers())[:, lo:hi], rig, out=out[i : i + chunk])
    return out


def band_db(R: np.ndarray, rig: Rig, *, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`log_magnitude_db` of spectra ``R`` (n, n_band) already on the band bins: the same float32 numbers."""
    R = np.asarray(R)
    p = np.empty(R.shape, np.float32) if out is None else out
    np.multiply(R.real, R.real, out=p)
    p += np.square(R.imag)
    p *= _inv_power_s(rig)
    p += np.float32(_EPS ** 2)
    np.log10(p, out=p)
    p *= np.float32(10.0)
    return p


