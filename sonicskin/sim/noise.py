"""Additive noise of a moving robot, in the frequency domain of one chirp frame.

Everything is synthesised directly as rfft spectra of a frame (batch, n_chirp // 2 + 1), so a
chirp of noise costs O(bins), not a time-domain oscillator bank:

- motor PWM: lines at ``m f_c +- n f_0`` (carrier harmonics with sidebands at the motor's
  electrical frequency), the carrier jittering slowly, amplitude following the motor current;
  each line is the exact DFT of a sinusoid that is not bin-centred (a Dirichlet kernel), so it
  leaks into neighbouring bins as a real tone does in a rectangular frame;
- mechanical noise: ``1/f^alpha`` below ~20 kHz with its tail into the band, gear-mesh tones
  scaled with joint speed, and rare broadband impacts;
- sensor noise: white.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

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
        from ..rig import check_keys

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
    """rfft of sinusoids ``amp cos(2 pi f t + phase)`` over one rectangular frame.

    freq_hz, amp, phase : (n, T) tones per frame.  For a tone at fractional bin ``nu`` the exact
    DFT is the Dirichlet kernel ``X[k] = A/2 e^{i phase} sum_t e^{-2 pi i (k - nu) t / N}``
    ``= A/2 e^{i phase} (-sin(pi frac) e^{i pi frac}) e^{i pi d / N} / (N sin(pi d / N))`` with
    ``d = k - nu``; near the tone (``|d| << N``) the last factor is ``1 / (pi d) + i / N`` to
    relative order ``(pi d / N)^2`` (< 2e-3 here).  Only ``half_width_bins`` bins either side
    are evaluated: the kernel has fallen by > 50 dB there.
    Returns (n, n_fft // 2 + 1) complex64.
    """
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
    """Noise of a moving robot for frames with motion ``level`` in [0, 1] (speed/current), (n, nb).

    ``floor_rms`` adds white (sensor) noise of that per-sample rms in the same Gaussian draw as the
    mechanical noise (the sum of independent Gaussians is one Gaussian), saving a second draw.
    """
    level = np.asarray(level, float)
    n = level.size
    nb = n_fft // 2 + 1
    if not (level > 0).any():
        return white_spectrum(rng, n, n_fft, floor_rms)
    out = np.zeros((n, nb), dtype=np.complex64)
    idx = np.arange(n)
    lv = level[idx]
    m = idx.size
    f = np.fft.rfftfreq(n_fft, 1 / fs_hz)
    # Mechanical 1/f^alpha noise with a knee, normalised to mech_rms over the whole band.
    shape = 1.0 / np.power(1 + f / cfg.mech_knee_hz, cfg.mech_alpha / 2)
    shape *= np.sqrt(nb / np.sum(shape ** 2))
    mech = white_spectrum(rng, m, n_fft, 1.0) * np.sqrt(floor_rms ** 2 + (cfg.mech_rms * np.outer(lv, shape)) ** 2).astype(np.float32)
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
    tones = tone_spectrum(allf, alla, allp, n_fft=n_fft, fs_hz=fs_hz)
    # Rare broadband impacts (a click: flat spectrum, random delay).
    hit = rng.random(m) < cfg.impact_rate_per_chirp * lv
    imp = np.zeros((m, nb), dtype=np.complex64)
    if hit.any():
        imp[hit] = white_spectrum(rng, int(hit.sum()), n_fft, cfg.impact_rms) * np.exp(-f / 40e3).astype(np.float32)
    out[idx] = mech + tones + imp
    return out
