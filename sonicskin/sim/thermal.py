"""What moves with temperature on a warming robot link: the piezo's hot-melt bond and the wall.

The disc sits on the bond layer: a mounted resonance ``f_r = sqrt(k / m) / 2 pi`` whose transmissibility shapes both
the drive and the pick-up; the EVA adhesive softens near its glass transition, so ``f_r`` moves by
``0.5 d ln E' / dT``.  The link warms from its motor end (:func:`warmup_field`, read qualitatively off the paper's
Fig. 7).  The coefficients and their sources: docs/simulator.md."""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["HotMeltBond", "warmup_field", "project_field"]


@dataclasses.dataclass(frozen=True)
class HotMeltBond:
    """A piezo disc on a hot-melt (EVA) bond: a mounted resonance ``fr_hz`` with loss tangent ``tan_delta`` at
    ``t_ref_c`` (0.67: Q = 1.5, paper Sec. III-B), moving with ``log10_modulus_per_k`` and ``ln_tan_delta_per_k``."""

    fr_hz: float = 28e3
    tan_delta: float = 0.67
    t_ref_c: float = 23.0
    log10_modulus_per_k: float = -0.02
    ln_tan_delta_per_k: float = 0.02

    def modulus_ratio(self, temp_c: np.ndarray) -> np.ndarray:
        """``E'(T) / E'(T_ref)``."""
        return np.power(10.0, self.log10_modulus_per_k * (np.asarray(temp_c, float) - self.t_ref_c))

    def resonance_hz(self, temp_c: np.ndarray) -> np.ndarray:
        return self.fr_hz * np.sqrt(self.modulus_ratio(temp_c))

    def loss_tangent(self, temp_c: np.ndarray) -> np.ndarray:
        return self.tan_delta * np.exp(self.ln_tan_delta_per_k * (np.asarray(temp_c, float) - self.t_ref_c))

    def response(self, f_hz: np.ndarray, temp_c: np.ndarray) -> np.ndarray:
        """Transmissibility of the mounted disc, (n_temps, n_f) complex64."""
        T = np.atleast_1d(np.asarray(temp_c, float))
        r2 = (np.asarray(f_hz, float)[None, :] / self.resonance_hz(T)[:, None]) ** 2
        eta = self.loss_tangent(T)[:, None]
        return ((1 + 1j * eta) / (1 + 1j * eta - r2)).astype(np.complex64)


def warmup_field(t_s: np.ndarray, y_frac: np.ndarray, *, warmup_c: float, tau_s: float, gradient: float = 0.0,
                 lag: float = 0.0) -> np.ndarray:
    """Warm-up temperature rise (K), (n, m), at times ``t_s`` and positions ``y_frac`` from the motor end (0): a final
    rise ``warmup_c (1 + gradient (0.5 - y))`` with time constant ``tau_s (1 + lag (y - 0.5))``."""
    t = np.asarray(t_s, float)[:, None]
    y = np.asarray(y_frac, float)[None, :]
    amp = warmup_c * (1 + gradient * (0.5 - y))
    tau = tau_s * np.maximum(1 + lag * (y - 0.5), 0.05)
    return amp * (1 - np.exp(-np.maximum(t, 0) / tau))


def project_field(field: np.ndarray, y_frac: np.ndarray, order: int = 2) -> np.ndarray:
    """Legendre coefficients (n, order + 1) of a field (n, m) on ``y_frac``: mean, linear part, ends vs middle."""
    x = 1 - 2 * np.asarray(y_frac, float)
    V = np.polynomial.legendre.legvander(x, order)  # (m, order + 1)
    coef, *_ = np.linalg.lstsq(V, np.asarray(field, float).T, rcond=None)
    return coef.T
