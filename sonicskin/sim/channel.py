"""Acoustic channel of a thin-walled robot link: modal synthesis of bending (A0 Lamb) waves.

A thin plate (a tube unrolled with periodic edges, or a flat plate) with Mindlin dispersion; the transfer function is
the modal sum ``G(r, s, w) = sum_n phi_n(r) phi_n(s) / (w_n^2 (1 + i eta) - w^2)``.  A finger is a contact patch
coupled through the wall by a Woodbury update, ``H_touched = G_rs - g_r^T (I + K G_pp)^{-1} K g_s``, computed at a
few contact radii per press and interpolated.  The physics and its sources: docs/simulator.md."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.special import j1

from ..rig import Rig

__all__ = ["Material", "MATERIALS", "Geometry", "ChannelModel", "mindlin_omega", "disc_average"]


@dataclasses.dataclass(frozen=True)
class Material:
    """Wall material and thickness; ``kappa_per_k``: relative shift of every modal frequency per kelvin (negative: lower)."""

    name: str
    youngs_pa: float
    density: float
    poisson: float
    thickness_m: float
    eta: float
    kappa_per_k: float
    deta_per_k: float

    @property
    def bending_stiffness(self) -> float:
        return self.youngs_pa * self.thickness_m ** 3 / (12 * (1 - self.poisson ** 2))

    @property
    def mass_per_area(self) -> float:
        return self.density * self.thickness_m

    def wavenumber(self, f_hz: np.ndarray) -> np.ndarray:
        """Mindlin flexural wavenumber at ``f_hz`` (inverse of :func:`mindlin_omega`)."""
        w = 2 * np.pi * np.asarray(f_hz, float)
        D, rh, rho, h = self.bending_stiffness, self.mass_per_area, self.density, self.thickness_m
        Gk = (np.pi ** 2 / 12) * self.youngs_pa / (2 * (1 + self.poisson))
        # (-k^2 + A w^2)(-D k^2 + B w^2) - rho h w^2 = 0, quadratic in k^2; the real root is flexural.
        A, B = rho / Gk, rho * h ** 3 / 12
        a, b, c = D, -(D * A * w ** 2 + B * w ** 2), A * B * w ** 4 - rh * w ** 2
        k2 = (-b + np.sqrt(b ** 2 - 4 * a * c)) / (2 * a)
        return np.sqrt(k2)


MATERIALS: dict[str, Material] = {
    # Quasi-isotropic carbon-fibre wall of a Jaco-like link (estimates, see DESIGN.md).
    "cfrp": Material("cfrp", 45e9, 1550.0, 0.30, 2.0e-3, 0.010, -3.5e-4, 0.02),
    "aluminium": Material("aluminium", 70e9, 2700.0, 0.33, 2.0e-3, 0.003, -2.5e-4, 0.01),
    "abs": Material("abs", 2.2e9, 1050.0, 0.35, 3.0e-3, 0.020, -4.5e-3, 0.03),
    "glass": Material("glass", 70e9, 2500.0, 0.22, 3.0e-3, 0.002, -1.0e-4, 0.01),
    "wood": Material("wood", 10e9, 600.0, 0.30, 5.0e-3, 0.015, -6.0e-4, 0.02),
}


def mindlin_omega(k: np.ndarray, mat: Material) -> np.ndarray:
    """Angular frequency (rad/s) of the flexural Mindlin branch at wavenumber ``k``: the lower root in ``w^2`` of
    ``(-k^2 + rho w^2 / (kappa^2 G)) (-D k^2 + rho h^3 w^2 / 12) - rho h w^2 = 0``, ``kappa^2 = pi^2 / 12``."""
    k = np.asarray(k, float)
    D, rh, rho, h = mat.bending_stiffness, mat.mass_per_area, mat.density, mat.thickness_m
    Gk = (np.pi ** 2 / 12) * mat.youngs_pa / (2 * (1 + mat.poisson))
    A, B = rho / Gk, rho * h ** 3 / 12
    a = A * B
    b = -(k ** 2 * B + A * D * k ** 2 + rh)
    c = D * k ** 4
    disc = np.sqrt(b ** 2 - 4 * a * c)
    w2 = (-b - disc) / (2 * a)
    # Numerically stable form of the lower root.
    w2 = np.where(np.abs(b) > 0, (2 * c) / (-b + disc), w2)
    return np.sqrt(w2)


def disc_average(k: np.ndarray, radius_m: float | np.ndarray) -> np.ndarray:
    """Average of a plane wave of wavenumber ``k`` over a disc: ``2 J1(k a) / (k a)``."""
    x = np.multiply.outer(np.atleast_1d(radius_m), np.asarray(k, float)) if np.ndim(radius_m) else np.asarray(k) * radius_m
    x = np.asarray(x, float)
    out = np.ones_like(x)
    nz = x > 1e-9
    out[nz] = 2 * j1(x[nz]) / x[nz]
    return out


@dataclasses.dataclass(frozen=True)
class Geometry:
    """The wall's surface: ``kind="tube"`` (periodic around ``width_m`` = circumference) or ``"plate"``."""

    kind: str = "tube"
    width_m: float = 2 * np.pi * 0.0375
    length_m: float = 0.25

    def __post_init__(self):
        if self.kind not in ("tube", "plate"):
            raise ValueError(f"geometry kind must be 'tube' or 'plate', got {self.kind!r}")
        if self.width_m <= 0 or self.length_m <= 0:
            raise ValueError("geometry width_m and length_m must be positive")


class ChannelModel:
    """Green's functions of one link between transducers and contact points, on the rig's frequency grid (plus
    ``margin_hz`` for the temperature stretch).  Positions in m on the unrolled surface; ``irregularity``: relative
    spread of the modal frequencies; ``seed`` fixes it: one seed is one physical link."""

    def __init__(self, rig: Rig, material: Material, geometry: Geometry, *, tx_m=(0.0, 0.025),
                 rx_m=(0.059, 0.225), transducer_radius_m: float = 5e-3, transducer_fr_hz: float = 28e3,
                 transducer_q: float = 1.5, irregularity: float = 3e-3, margin_hz: float = 4e3,
                 mode_fmax_factor: float = 1.3, seed: int = 0):
        self.rig, self.material, self.geometry = rig, material, geometry
        self.tx_m, self.rx_m = np.asarray(tx_m, float), np.asarray(rx_m, float)
        for name, p in (("tx_m", self.tx_m), ("rx_m", self.rx_m)):
            if not (0 <= p[1] <= geometry.length_m and (geometry.kind == "tube" or 0 <= p[0] <= geometry.width_m)):
                key = {"tx_m": "tx_cm", "rx_m": "rx_cm"}[name]
                raise ValueError(f"the {'transmitter' if name == 'tx_m' else 'receiver'} disc at ({100 * p[0]:.4g}, "
                                 f"{100 * p[1]:.4g}) cm lies off the {geometry.kind} (y 0..{100 * geometry.length_m:.4g} cm"
                                 + ("" if geometry.kind == "tube" else f", x 0..{100 * geometry.width_m:.4g} cm")
                                 + f"); set the scenario's {key} on the wall, or give the wall its real size")
        f = rig.freqs_hz
        sel = (f >= rig.f_lo_hz - margin_hz) & (f <= min(rig.f_hi_hz + margin_hz, rig.fs_hz / 2))
        self.bins = np.flatnonzero(sel)
        self.f_hz = f[self.bins]
        self.df_hz = rig.fs_hz / rig.n_chirp
        rng = np.random.default_rng(seed)
        self._modes(mode_fmax_factor * self.f_hz[-1], irregularity, rng)
        w = 2 * np.pi * self.f_hz
        self.phi_tx = self.mode_shapes(self.tx_m[None, :])[0] * disc_average(self.k, transducer_radius_m)
        self.phi_rx = self.mode_shapes(self.rx_m[None, :])[0] * disc_average(self.k, transducer_radius_m)
        wrs = self.phi_tx * self.phi_rx
        # The modal matrix M = 1 / (w_n^2 (1 + i eta) - w^2), complex128 a block of bins at a time
        # (no full-size temporaries); kept as complex64, read as interleaved float32 by _project (one
        # real GEMM); _Mr / _Mi are views of it.  dM: d/d(eta) of M, for the damping rise with
        # temperature (first order in d eta).
        self._M = np.empty((self.n_modes, w.size), np.complex64)
        self.G_rs = np.empty(w.size, np.complex64)
        self.dG_rs_deta = np.empty(w.size, np.complex64)
        for a in range(0, w.size, 512):
            c = slice(a, a + 512)
            M = 1.0 / (self.wn2[:, None] * (1 + 1j * material.eta) - w[None, c] ** 2)
            self._M[:, c] = M
            self.G_rs[c] = wrs @ M
            M *= M
            M *= -1j * self.wn2[:, None]
            self.dG_rs_deta[c] = wrs @ M
        self._Mr, self._Mi = self._M.real, self._M.imag
        s = 1j * self.f_hz / transducer_fr_hz
        self.transducer = (1.0 / (1 + s / transducer_q + s ** 2)).astype(np.complex64)  # TX and RX alike

    # -- modes ------------------------------------------------------------------------
    def _modes(self, fmax: float, irregularity: float, rng: np.random.Generator) -> None:
        g, mat = self.geometry, self.material
        kmax = float(mat.wavenumber(fmax))
        W, L = g.width_m, g.length_m
        ny = np.arange(1, int(kmax * L / np.pi) + 2)
        if g.kind == "tube":
            mx = np.arange(0, int(kmax * W / (2 * np.pi)) + 2)
            MX, NY = np.meshgrid(mx, ny, indexing="ij")
            kx, ky = 2 * np.pi * MX.ravel() / W, np.pi * NY.ravel() / L
            m = MX.ravel()
            # cos and sin variants around the circumference (m = 0: cos only).
            kx = np.r_[kx, kx[m > 0]]
            ky = np.r_[ky, ky[m > 0]]
            variant = np.r_[np.zeros(m.size, int), np.ones(int((m > 0).sum()), int)]
            norm = np.where((kx == 0), np.sqrt(2 / (mat.mass_per_area * W * L)), np.sqrt(4 / (mat.mass_per_area * W * L)))
        else:
            mx = np.arange(1, int(kmax * W / np.pi) + 2)
            MX, NY = np.meshgrid(mx, ny, indexing="ij")
            kx, ky = np.pi * MX.ravel() / W, np.pi * NY.ravel() / L
            variant = np.full(kx.size, 2, int)
            norm = np.full(kx.size, 2 / np.sqrt(mat.mass_per_area * W * L))
        k = np.hypot(kx, ky)
        wn = mindlin_omega(k, mat) * (1 + irregularity * rng.standard_normal(k.size))
        keep = wn < 2 * np.pi * fmax
        self.kx, self.ky, self.k, self.variant, self.norm = kx[keep], ky[keep], k[keep], variant[keep], norm[keep]
        self.wn2 = wn[keep] ** 2
        self.n_modes = int(keep.sum())

    def mode_shapes(self, pts_m: np.ndarray) -> np.ndarray:
        """Mass-normalised mode shapes at points (P, 2) in metres, shape (P, n_modes)."""
        x, y = np.asarray(pts_m, float)[:, :1], np.asarray(pts_m, float)[:, 1:2]
        along = np.sin(self.ky * y)
        around = np.where(self.variant == 0, np.cos(self.kx * x), np.where(self.variant == 1, np.sin(self.kx * x), np.sin(self.kx * x)))
        return self.norm * around * along

    def modal_density_per_hz(self) -> float:
        """Modes per Hz in the chirp band (compare: Kirchhoff's ``A / 2 sqrt(rho h / D)`` / 2 pi)."""
        fn = np.sqrt(self.wn2) / (2 * np.pi)
        band = (fn >= self.rig.f_lo_hz) & (fn <= self.rig.f_hi_hz)
        return band.sum() / (self.rig.f_hi_hz - self.rig.f_lo_hz)

    # -- Green's functions ------------------------------------------------------------
    def _project(self, weights: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(R, n_modes) real weights -> (R, n_f) complex modal sums, one real GEMM (``out``: (R, 2 n_f) float32)."""
        w = np.asarray(weights, dtype=np.float32)
        # Real weights times the interleaved (re, im) modal matrix: row r of the product is the
        # complex64 row sum_n w_rn M_n(f), read in place.
        M = self._M.view(np.float32)
        return np.matmul(w, M, out=out).view(np.complex64)

    def contact_greens(self, pts_m: np.ndarray, radii_m: np.ndarray) -> np.ndarray:
        """Green's functions (P, R, 3, n_f) complex64 ``[G_rc, G_cs, G_cc]`` of disc contacts at ``pts_m`` per radius."""
        phi_c = self.mode_shapes(pts_m)  # (P, n)
        A = disc_average(self.k, np.asarray(radii_m, float))  # (R, n)
        pa = phi_c[:, None, :] * A[None, :, :]  # (P, R, n)
        W = np.stack([pa * self.phi_rx, pa * self.phi_tx, pa * pa], axis=2)  # (P, R, 3, n)
        P, R = W.shape[:2]
        return self._project(W.reshape(-1, self.n_modes)).reshape(P, R, 3, -1).astype(np.complex64)

    def patch_weights(self, pts_m: np.ndarray, sub_radius_m: float) -> np.ndarray:
        """Modal weights of a P-point patch, (2P + P(P+1)/2, n_modes): rows g_r, g_s, upper G_pp."""
        phi = self.mode_shapes(pts_m) * disc_average(self.k, sub_radius_m)  # (P, n)
        iu, ju = np.triu_indices(phi.shape[0])
        return np.concatenate([phi * self.phi_rx, phi * self.phi_tx, phi[iu] * phi[ju]])

    def gradient_greens(self, order: int = 1, *, n_y: int = 400) -> np.ndarray:
        """First-order change of ``G_rs`` (n_f,) per unit of a stiffness profile along the link.

        A relative stiffness change ``psi(y) = P_order(1 - 2 y / L)`` (order 1: +1 at the motor end, -1 at the far
        end; 2: ends vs middle) perturbs the stiffness operator by ``dK_nm = w_n w_m rho h integral(psi phi_n phi_m)
        dA`` and the Green's function by the Born term ``dG = -sum_nm phi_n(r) dK_nm phi_m(s) / (D_n D_m)``, ``D_n =
        w_n^2 (1 + i eta) - w^2``: modes of the same circumferential order couple, so mode shapes change.  The odd
        term cancels at first order when TX and RX sit at mirror positions along the link (the default link).
        """
        L = self.geometry.length_m
        y = (np.arange(n_y) + 0.5) / n_y * L
        psi = np.polynomial.legendre.Legendre.basis(order)(1 - 2 * y / L)
        wn = np.sqrt(self.wn2)
        out = np.zeros(self.f_hz.size, np.complex64)
        # Modes of one circumferential order and variant share kx: dK is block-diagonal over those groups.
        key = np.round(self.kx * 1e3).astype(np.int64) * 4 + self.variant
        for k in np.unique(key):
            idx = np.flatnonzero(key == k)
            if idx.size < 2 and order % 2:
                continue
            S = np.sin(np.outer(self.ky[idx], y))  # (g, n_y)
            Iy = (S * psi) @ S.T * (L / n_y)  # integral of psi sin sin over y
            Ix = self.geometry.width_m * (1.0 if (self.kx[idx[0]] == 0 and self.geometry.kind == "tube") else 0.5)
            dK = self.material.mass_per_area * np.outer(self.norm[idx], self.norm[idx]) * Ix * Iy
            dK *= np.outer(wn[idx], wn[idx])
            M = self._M[idx]  # (g, n_f) complex64
            a = self.phi_rx[idx, None].astype(np.float32) * M
            b = self.phi_tx[idx, None].astype(np.float32) * M
            out -= np.sum(a * (dK.astype(np.float32) @ b), axis=0)
        return out

    def transfer_between(self, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
        """G(a, b) between two points, (n_f,), point-sized; reciprocity: equal to G(b, a)."""
        return self._project(self.mode_shapes(np.atleast_2d(a_m)) * self.mode_shapes(np.atleast_2d(b_m)))[0]
