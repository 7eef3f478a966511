"""Additive noise of a moving robot, synthesised directly as rfft spectra of a frame: O(bins) per chirp.  Motor PWM
lines at ``m f_c +- n f_0`` (each the exact DFT of a sinusoid that is not bin-centred); mechanical ``1/f^alpha``,
gear-mesh tones and rare impacts; sensor: white."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ..rig import check_keys

__all__ = ["NoiseConfig", "white_spectrum", "tone_spectrum", "motion_noise_spectrum"]


@dataclasses.dataclass(frozen=True)
class NoiseConfig:
    sensor_rms: float = 3e-5            # white noise at the ADC input, full scale = 1
    pwm_carrier_hz: float = 30_000.0
    pwm_harmonics: int = 3
    pwm_sidebands: int = 4              # n = -4..4 around each harmonic
    pwm_f0_hz: float = 420.0            # motor electrical frequency at full speed
    pwm_rms: float = 0.012              # per carrier line at full motor current
    pwm_sideband_db: float = -7.0       # per sideband order
    pwm_jitter_hz: float = 40.0         # slow wander of the carrier
    mech_rms: float = 0.05              # 1/f noise rms over the whole band at full speed
    mech_alpha: float = 2.0
    mech_knee_hz: float = 300.0
    gear_hz: float = 1_650.0            # gear-mesh frequency at full speed
    gear_harmonics: int = 14
    gear_rms: float = 0.004
    impact_rate_per_chirp: float = 0.01
    impact_rms: float = 0.02

    @classmethod
    def from_dict(cls, d: dict | None) -> NoiseConfig:
        d = dict(d or {})
        check_keys(cls, d, "noise")
        return cls(**d)


def white_spectrum(rng: np.random.Generator, n: int, n_fft: int, rms: float) -> np.ndarray:
    """rfft of ``n`` frames of white noise with per-sample ``rms``: (n, n_fft // 2 + 1) complex64."""
    nb = n_fft // 2 + 1
    s = rms * np.sqrt(n_fft / 2)
    X = (rng.standard_normal((n, nb), dtype=np.float32) + 1j * rng.standard_normal((n, nb), dtype=np.float32)) * s
    X[:, 0] = X[:, 0].real * np.sqrt(2)
    return X.astype(np.complex64)


def tone_spectrum(freq_hz: np.ndarray, amp: np.ndarray, phase: np.ndarray, *, n_fft: int, fs_hz: float,
                  half_width_bins: int = 128) -> np.ndarray:
    """rfft (n, n_fft // 2 + 1) complex64 of tones ``amp cos(2 pi f t + phase)`` (n, T) over one rectangular frame:
    the Dirichlet kernel (near the tone ``1 / (pi d) + i / N``), ``half_width_bins`` either side (> 50 dB down)."""
    freq_hz, amp, phase = (np.atleast_2d(a).astype(np.float64) for a in (freq_hz, amp, phase))
    n, T = freq_hz.shape
    nb = n_fft // 2 + 1
    nu = freq_hz * n_fft / fs_hz
    k0 = np.floor(nu).astype(np.int64)
    frac = nu - k0
    # Kernel 1/(pi d) + i/N tabulated on frac quantised to 1/1024 bin (0.01 Hz at 192 kHz / 20480).
    q = np.minimum(np.round(frac * _NQ).astype(np.int64), _NQ - 1)
    table = _kernel_table(half_width_bins, n_fft)
    fq = q / _NQ
    c = (0.5 * n_fft * amp * np.exp(1j * phase) * (-np.sin(np.pi * fq) * np.exp(1j * np.pi * fq))).astype(np.complex64)
    c = np.where(q == 0, (0.5 * n_fft * amp * np.exp(1j * phase)).astype(np.complex64), c)
    out = np.zeros((n, nb + 2 * half_width_bins), dtype=np.complex64)  # padded: no bounds checks
    rows = np.arange(n)[:, None]
    offs = np.arange(-half_width_bins + 1, half_width_bins + 1)
    for t in range(T):  # one scatter per tone, vectorised over frames
        k = np.clip(k0[:, t:t + 1] + offs + half_width_bins, 0, out.shape[1] - 1)
        out[rows, k] += c[:, t:t + 1] * table[q[:, t]]
    return out[:, half_width_bins:half_width_bins + nb]


_NQ = 1024


@functools.lru_cache(maxsize=4)
def _kernel_table(half_width_bins: int, n_fft: int) -> np.ndarray:
    """(NQ, 2W) kernel values for frac = q / NQ; row 0 is a bin-centred tone (a single 1)."""
    offs = np.arange(-half_width_bins + 1, half_width_bins + 1, dtype=np.float64)
    frac = np.arange(_NQ)[:, None] / _NQ
    d = offs[None, :] - frac
    d[0] = 1.0
    tab = 1.0 / (np.pi * d) + 1j / n_fft
    tab[0] = 0.0
    tab[0, half_width_bins - 1] = 1.0
    return tab.astype(np.complex64)


def motion_noise_spectrum(rng: np.random.Generator, level: np.ndarray, cfg: NoiseConfig, *, n_fft: int,
                          fs_hz: float, floor_rms: float = 0.0) -> np.ndarray:
    """Noise of a moving robot for frames with motion ``level`` in [0, 1], (n, nb), plus white ``floor_rms`` in one draw."""
    level = np.asarray(level, float)
    out = np.empty((level.size, n_fft // 2 + 1), np.complex64)
    draws = NoiseDraws(rng, level, cfg, n_fft=n_fft, fs_hz=fs_hz, floor_rms=floor_rms)
    for a in range(0, level.size, 256):
        draws.fill(out[a:a + 256], a)
    return out


class NoiseDraws:
    """Every random draw of :func:`motion_noise_spectrum` for a batch, made up front, turned into spectra by :meth:`fill`."""

    def __init__(self, rng: np.random.Generator, level: np.ndarray, cfg: NoiseConfig, *, n_fft: int, fs_hz: float,
                 floor_rms: float = 0.0, buffers: tuple[np.ndarray, np.ndarray] | None = None, work: dict | None = None):
        level = np.asarray(level, float)
        self.work = {} if work is None else work  # scratch arrays of :meth:`fill`, reused call after call (and batch after batch)
        n = level.size
        nb = n_fft // 2 + 1
        self.nb, self.n_fft = nb, n_fft
        # The white part: real then imaginary parts, (n, nb) each (white_spectrum's draw).
        if buffers is not None and buffers[0].size >= n * nb:
            re, im = (b.ravel()[:n * nb].reshape(n, nb) for b in buffers)
        else:
            re, im = np.empty((n, nb), np.float32), np.empty((n, nb), np.float32)
        rng.standard_normal(out=re, dtype=np.float32)
        rng.standard_normal(out=im, dtype=np.float32)
        self.re, self.im = re, im
        self.moving = bool((level > 0).any())
        if not self.moving:
            self.scale = np.float32(floor_rms * np.sqrt(n_fft / 2))
            return
        self.scale = np.float32(np.sqrt(n_fft / 2))
        self.level = level
        f = np.fft.rfftfreq(n_fft, 1 / fs_hz)
        # Mechanical 1/f^alpha noise with a knee, normalised to mech_rms over the whole band.
        shape = 1.0 / np.power(1 + f / cfg.mech_knee_hz, cfg.mech_alpha / 2)
        shape *= np.sqrt(nb / np.sum(shape ** 2))
        self.shape = (cfg.mech_rms * shape).astype(np.float32)
        self.floor2 = np.float32(floor_rms ** 2)
        m = n
        lv = level
        # PWM carrier harmonics with sidebands; carrier wanders (random walk), f0 follows speed.
        fc = cfg.pwm_carrier_hz + np.cumsum(rng.normal(0, cfg.pwm_jitter_hz / 4, m)).clip(-cfg.pwm_jitter_hz * 3, cfg.pwm_jitter_hz * 3)
        f0 = cfg.pwm_f0_hz * (0.4 + 0.6 * lv)
        h = np.arange(1, cfg.pwm_harmonics + 1)
        sb = np.arange(-cfg.pwm_sidebands, cfg.pwm_sidebands + 1)
        H, SB = np.meshgrid(h, sb, indexing="ij")
        freqs = H.ravel()[None, :] * fc[:, None] + SB.ravel()[None, :] * f0[:, None]
        amps = (cfg.pwm_rms * np.sqrt(2) * lv[:, None] / H.ravel()[None, :]
                * 10 ** (cfg.pwm_sideband_db * np.abs(SB.ravel()) / 20)[None, :])
        amps = amps * np.exp(0.2 * rng.standard_normal(amps.shape))  # current ripple
        # Gear-mesh tones with speed.
        g = np.arange(1, cfg.gear_harmonics + 1)
        gfreq = (cfg.gear_hz * (0.3 + 0.7 * lv))[:, None] * g[None, :]
        gamp = cfg.gear_rms * np.sqrt(2) * lv[:, None] / g[None, :] ** 0.5 * np.ones((m, g.size))
        allf = np.concatenate([freqs, gfreq], axis=1)
        alla = np.concatenate([amps, gamp], axis=1)
        allp = rng.uniform(0, 2 * np.pi, allf.shape)
        ok = allf < fs_hz / 2
        alla = np.where(ok, alla, 0.0)
        allf = np.where(ok, allf, 1000.0)
        self.tones = _ToneKernel(allf, alla, allp, n_fft=n_fft, fs_hz=fs_hz)
        # Rare broadband impacts (a click: flat spectrum, random delay).
        hit = rng.random(m) < cfg.impact_rate_per_chirp * lv
        self.hit_rows = np.flatnonzero(hit)
        self.impacts = None
        if hit.any():
            self.impacts = white_spectrum(rng, int(hit.sum()), n_fft, cfg.impact_rms) * np.exp(-f / 40e3).astype(np.float32)

    def fill(self, out: np.ndarray, start: int) -> np.ndarray:
        """Write the noise spectra of rows ``start:start + len(out)`` into ``out`` (rows, nb) complex64."""
        n = out.shape[0]
        rows = slice(start, start + n)
        v = out.view(np.float32).reshape(n, self.nb, 2)
        if not self.moving:
            np.multiply(self.re[rows], self.scale, out=v[..., 0])
            np.multiply(self.im[rows], self.scale, out=v[..., 1])
        else:
            # rms per bin: sqrt(sensor^2 + (mech_rms * level * shape)^2), in float32.
            s = _scratch(self.work, "rms", (n, self.nb), np.float32)
            np.multiply.outer(self.level[rows].astype(np.float32), self.shape, out=s)
            np.square(s, out=s)
            s += self.floor2
            np.sqrt(s, out=s)
            s *= self.scale
            np.multiply(self.re[rows], s, out=v[..., 0])
            np.multiply(self.im[rows], s, out=v[..., 1])
        out[:, 0] = out[:, 0].real * np.float32(np.sqrt(2))
        if self.moving:
            self.tones.add_to(out, start, pad=_scratch(self.work, "pad", (n, self.nb + 2 * self.tones.W), np.complex64))
            if self.impacts is not None:
                k = (self.hit_rows >= start) & (self.hit_rows < start + n)
                out[self.hit_rows[k] - start] += self.impacts[k]
        return out


def _scratch(work: dict, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
    """A C-contiguous scratch array of ``shape`` from ``work[name]``, grown when too small (contents undefined)."""
    size = int(np.prod(shape))
    buf = work.get(name)
    if buf is None or buf.size < size or buf.dtype != dtype:
        buf = work[name] = np.empty(size, dtype)
    return buf[:size].reshape(shape)


class _ToneKernel:
    """:func:`tone_spectrum`'s per-tone Dirichlet kernels, added into spectra a few frames at a time."""

    def __init__(self, freq_hz, amp, phase, *, n_fft: int, fs_hz: float, half_width_bins: int = 128):
        freq_hz, amp, phase = (np.atleast_2d(a).astype(np.float64) for a in (freq_hz, amp, phase))
        nu = freq_hz * n_fft / fs_hz
        self.k0 = np.floor(nu).astype(np.int64)
        frac = nu - self.k0
        self.q = np.minimum(np.round(frac * _NQ).astype(np.int64), _NQ - 1)
        self.table = _kernel_table(half_width_bins, n_fft)
        fq = self.q / _NQ
        c = (0.5 * n_fft * amp * np.exp(1j * phase) * (-np.sin(np.pi * fq) * np.exp(1j * np.pi * fq))).astype(np.complex64)
        self.c = np.where(self.q == 0, (0.5 * n_fft * amp * np.exp(1j * phase)).astype(np.complex64), c)
        self.W = half_width_bins
        self.nb = n_fft // 2 + 1

    def add_to(self, out: np.ndarray, start: int, pad: np.ndarray | None = None) -> None:
        """Add the tones of frames ``start:start + len(out)`` to ``out``; ``pad``: optional scratch (n, nb + 2W) complex64."""
        n, W = out.shape[0], self.W
        if pad is None:
            pad = np.zeros((n, self.nb + 2 * W), np.complex64)  # padded: no bounds checks
        else:
            pad[...] = 0
        # windows[r, s] is pad[r, s:s + 2W]: a tone whose kernel starts at bin k0 + 1 - W (padded: k0 + 1)
        # is one contiguous row slice, so a scatter of a tone over frames copies whole rows.
        windows = np.lib.stride_tricks.as_strided(pad, shape=(n, self.nb + 1, 2 * W), strides=(pad.strides[0], pad.itemsize, pad.itemsize))
        rows = slice(start, start + n)
        k0, q, c = self.k0[rows], self.q[rows], self.c[rows]
        ar = np.arange(n)
        for t in range(k0.shape[1]):  # one scatter per tone, vectorised over frames
            windows[ar, np.clip(k0[:, t], -1, self.nb - 1) + 1] += c[:, t:t + 1] * self.table[q[:, t]]
        out += pad[:, W:W + self.nb]
