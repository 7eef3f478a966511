"""Render a scenario's timeline into received audio, chirp by chirp, in batches: the untouched channel at the
link's temperature, the finger's update when touched, the robot's motion, both transducers, the chirp spectrum, the
noise, then one inverse FFT (a periodic chirp train through a linear channel) and 24-bit quantisation."""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.fft
import scipy.signal

from .. import threads
from ..dsp import chirp_spectrum
from ..rig import Layout, Rig
from .channel import MATERIALS, ChannelModel, Geometry
from .finger import make_subjects
from .noise import NoiseConfig, NoiseDraws
from .scenario import Scenario, Timeline
from .thermal import HotMeltBond, project_field, warmup_field

__all__ = ["Simulator"]

_BORN_CACHE: dict = {}  # the warm-up's Born terms of the last link (reproduce simulates several datasets per link)


class Simulator:
    """The simulated rig of one scenario: untouched signal at ``target_rms`` of full scale, quantised to ``quantize_bits``."""

    def __init__(self, scenario: Scenario, rig: Rig, *, target_rms: float = 0.05, quantize_bits: int | None = 24):
        if scenario.material not in MATERIALS:
            raise ValueError(f"unknown material {scenario.material!r}; choose one of {sorted(MATERIALS)}")
        self.scenario, self.rig = scenario, rig
        self.material = MATERIALS[scenario.material]
        if scenario.loss_factor is not None:  # a drawn rig's own loss factor (sonicskin.sim.scenario.RandomFamily)
            self.material = dataclasses.replace(self.material, eta=float(scenario.loss_factor))
        g = scenario.geometry
        kind = g.get("kind", "tube")
        width_m = 2 * np.pi * g["radius_cm"] / 100 if kind == "tube" else g["width_cm"] / 100
        self.geometry = Geometry(kind=kind, width_m=width_m, length_m=g["length_cm"] / 100)
        self.channel = ChannelModel(rig, self.material, self.geometry, tx_m=np.array(scenario.tx_cm) / 100,
                                    rx_m=np.array(scenario.rx_cm) / 100, seed=scenario.link_seed, **scenario.channel)
        self.layout: Layout = scenario.make_layout()
        self.subjects = make_subjects()
        self.noise = NoiseConfig.from_dict(scenario.noise)
        self.quantize_bits = quantize_bits
        S_full = chirp_spectrum(rig)
        self._S = S_full[self.channel.bins].astype(np.complex64)
        self.bond = HotMeltBond(**scenario.bond)
        self._ambient_c = float(scenario.temperature.get("ambient_c", 23.0))
        T0 = self.bond.response(self.channel.f_hz, self._ambient_c)[0]
        self._T2 = T0 ** 2
        self._B = None  # Born term of the warm-up gradient, computed on first use
        y0 = self.channel.G_rs * self._T2 * self._S
        rms0 = np.sqrt(2 * np.sum(np.abs(y0) ** 2)) / rig.n_chirp
        self.gain = np.float32(target_rms / rms0)
        f = self.channel.f_hz
        self._f0, self._df = f[0], self.channel.df_hz
        m = scenario.motion
        self._perturb = float(m.get("perturbation", 0.03)) if m.get("enabled", False) else 0.0
        self._nb = rig.n_chirp // 2 + 1
        bins = self.channel.bins
        assert np.array_equal(bins, np.arange(bins[0], bins[-1] + 1))  # one contiguous run of rfft bins
        self._band = (int(bins[0]), int(bins[-1]) + 1)
        self._buffers = None  # the noise's Gaussian draws, reused batch after batch
        self._H = None  # and the channel of a batch
        self._G = None  # and the contact Green's functions of its presses
        self._Ybuf = None  # and the spectra of one chunk of frames
        self._work: dict = {}  # and the noise's scratch arrays

    # -- helpers ----------------------------------------------------------------------
    def _stretch_index(self, dT: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gather indices/weights for ``G_T(f) = G_0(f / (1 + kappa dT))`` on the channel grid, (n, n_f)."""
        f = self.channel.f_hz
        pos = (f[None, :] / (1 + self.material.kappa_per_k * dT[:, None]) - self._f0) / self._df
        pos = np.clip(pos, 0, f.size - 1.000001)
        i0 = np.floor(pos).astype(np.int64)
        return i0, (pos - i0).astype(np.float32)

    @staticmethod
    def _gather(G: np.ndarray, i0: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Linear interpolation of G (..., n_f) or per-row G (n, n_f) at fractional positions."""
        if G.ndim == 1:
            return G[i0] * (1 - w) + G[i0 + 1] * w
        rows = np.arange(G.shape[0])[:, None]
        return G[rows, i0] * (1 - w) + G[rows, i0 + 1] * w

    def _dT(self, tl: Timeline) -> np.ndarray:
        return tl.temperature_c - self._ambient_c

    _Y_GRID = np.linspace(0.0, 1.0, 41)

    def temperatures(self, tl: Timeline) -> dict[str, np.ndarray]:
        """Per chirp: the wall's mean rise ``dT``, its gradient ``dT_grad`` (K) and the TX and RX bond temperatures (C)."""
        T = self.scenario.temperature
        L = self.geometry.length_m
        ys = np.r_[self._Y_GRID, self.scenario.tx_cm[1] / 100 / L, self.scenario.rx_cm[1] / 100 / L, 0.5]
        field = warmup_field(tl.time_s, ys, warmup_c=float(T.get("warmup_c", 0.0)), tau_s=float(T.get("warmup_tau_s", 5400.0)),
                             gradient=float(T.get("gradient", 0.0)), lag=float(T.get("lag", 0.0)))
        dev = field - field[:, -1:]  # relative to the middle (the label)
        g = self._Y_GRID.size
        c = project_field(dev[:, :g], self._Y_GRID, order=2)
        return {"dT": self._dT(tl) + c[:, 0], "dT_grad": c[:, 1:], "tx_c": tl.temperature_c + dev[:, g],
                "rx_c": tl.temperature_c + dev[:, g + 1]}

    def transducers(self, tx_c: np.ndarray, rx_c: np.ndarray) -> np.ndarray:
        """Product of the TX and RX bond responses per chirp, (n, n_f) complex64."""
        T2, inv = self._bond_rows(tx_c, rx_c)
        return T2[inv]

    _DT_STEP_K = 1e-3  # temperatures closer than this share one stretch (0.003 bin at 80 kHz)

    def untouched(self, dT: np.ndarray, dT_grad: np.ndarray | None = None) -> np.ndarray:
        """Untouched channel H_rs (n, n_f) at mean offsets ``dT`` and Legendre parts ``dT_grad`` (n, 2) along the link."""
        G, inv = self._untouched_rows(dT, dT_grad)
        return G[inv]

    def _untouched_rows(self, dT: np.ndarray, dT_grad: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`untouched` of the distinct temperatures (u, n_f) complex64 and each chirp's row (n,)."""
        dT = np.asarray(dT, float)
        grad = np.zeros((dT.size, 2)) if dT_grad is None else np.asarray(dT_grad, float).reshape(dT.size, -1)
        q, inv = np.unique(np.round(np.column_stack([dT, grad]) / self._DT_STEP_K), axis=0, return_inverse=True)
        q = q * self._DT_STEP_K
        dTu, gu = q[:, 0], q[:, 1:]
        i0, w = self._stretch_index(dTu)
        deta = (self.material.eta * self.material.deta_per_k * dTu).astype(np.float32)[:, None]
        G = self._gather(self.channel.G_rs, i0, w) + deta * self._gather(self.channel.dG_rs_deta, i0, w)
        if np.any(gu != 0):
            if self._B is None:
                key = (repr(self.material), repr(self.geometry), tuple(self.scenario.tx_cm), tuple(self.scenario.rx_cm),
                       self.scenario.link_seed, repr(sorted(self.scenario.channel.items())), repr(self.rig))
                if key not in _BORN_CACHE:
                    _BORN_CACHE.clear()  # one link at a time: a few MB
                    _BORN_CACHE[key] = [self.channel.gradient_greens(order=k + 1) for k in range(gu.shape[1])]
                self._B = _BORN_CACHE[key]
            # Relative stiffness change 2 kappa dT (modal frequencies go as sqrt(E)): first-order Born terms.
            for k, B in enumerate(self._B):
                de = (2 * self.material.kappa_per_k * gu[:, k]).astype(np.float32)[:, None]
                G = G + de * self._gather(B, i0, w)
        return G.astype(np.complex64, copy=False), inv.ravel()

    def channel_response(self, tl: Timeline, temps: dict | None = None, *, out: np.ndarray | None = None) -> np.ndarray:
        """Noise-free channel H(f) for each chirp of ``tl``, (n, n_f) complex64, into ``out`` when given."""
        temps = self.temperatures(tl) if temps is None else temps
        dT = temps["dT"]
        Gu, inv = self._untouched_rows(dT, temps["dT_grad"])
        # mode="clip" (every index is valid): with the default "raise" numpy buffers ``out``, a fresh
        # (n, n_f) temporary per batch.
        H = np.take(Gu, inv, axis=0, out=out, mode="clip")
        # Every press of the batch: contact radii nodes and sub-contact layouts, then ONE projection.
        presses = []
        for ev in np.unique(tl.event[tl.event >= 0]):
            idx = np.flatnonzero((tl.event == ev) & (tl.force_n > 0))
            if idx.size == 0:
                continue
            who = self.subjects[int(tl.subject[idx[0]])]
            centre = np.array([tl.x_cm[idx[0]], tl.y_cm[idx[0]]]) / 100
            a = who.radius_m(tl.force_n[idx])
            radii = np.linspace(a.min(), a.max(), 3) if np.ptp(a) > 1e-6 else np.array([a.min(), a.min() * 1.0001])
            # Real contact grows while the press is held (time since the first touching chirp).
            g = who.occlusion((tl.chirp[idx] - tl.chirp[idx[0]]) / self.rig.chirps_per_s)
            occl = np.array([g.min(), g.max()]) if np.ptp(g) > 1e-6 else np.array([g.min(), g.min() * 1.0001])
            theta0 = float(np.random.default_rng([self.scenario.seed, 13, int(ev)]).uniform(0, 2 * np.pi))
            presses.append((idx, who, a, g, occl, radii, [self._patch_points(centre, r, theta0) for r in radii]))
        if presses:
            W = np.concatenate([self.channel.patch_weights(pts, r / 2) for *_, radii, pl in presses for r, pts in zip(radii, pl)])
            rows = W.shape[0] // sum(len(p[5]) for p in presses)
            nf2 = 2 * self.channel.f_hz.size
            if self._G is None or self._G.size < W.shape[0] * nf2:
                self._G = np.empty(W.shape[0] * nf2, np.float32)
            G_all = self.channel._project(W, out=self._G[:W.shape[0] * nf2].reshape(W.shape[0], nf2))
            k = 0
            for idx, who, a, g, occl, radii, _ in presses:
                # (R, 2, n_f): contact radius x real-contact share, all in one batched Woodbury solve.
                R = len(radii)
                Gp = G_all[k:k + R * rows].reshape(R, rows, -1)
                k += R * rows
                K = np.stack([who.dynamic_stiffness(np.full(2, who.force_at_radius(r)), self.channel.f_hz, occl)
                              for r in radii]) / np.float32(self._N_SUB)  # (R, 2, n_f) per sub-contact
                dH = _woodbury(Gp, K, self._N_SUB).reshape(R * 2, -1)
                # Temperature stretch at the press's temperature (constant over 3 s to 1e-3 K),
                # then bilinear interpolation in contact radius and real-contact share chirp by chirp.
                i0, w = self._stretch_index(np.full(1, dT[idx].mean()))
                dH = (dH[:, i0[0]] * (1 - w[0]) + dH[:, i0[0] + 1] * w[0]).reshape(R, 2, -1)
                r = np.interp(a, radii, np.arange(radii.size))
                r0 = np.minimum(np.floor(r).astype(int), radii.size - 2)
                rw = (r - r0).astype(np.float32)
                ow = ((g - occl[0]) / (occl[1] - occl[0])).astype(np.float32)
                # Bilinear in (rw, ow) on the cell r0: A + ow (B - A) + rw (C - A) + rw ow (D - C - B + A),
                # one small real GEMM per cell: (chirps, 4) coefficients times (4, n_f) complex corners.
                coef = np.column_stack([np.ones_like(rw), ow, rw, rw * ow])
                for j in np.unique(r0):
                    sel = r0 == j
                    A, B, C, D = dH[j, 0], dH[j, 1], dH[j + 1, 0], dH[j + 1, 1]
                    basis = np.stack([A, B - A, C - A, D - C - B + A])
                    rows_j = idx[sel]
                    H[rows_j] += (coef[sel] @ basis.view(np.float32)).view(np.complex64)
        if self._perturb > 0 and np.any(tl.moving > 0):
            self._motion_ripple(tl, H)
        return H

    _RING = 0.6  # sub-contacts: the centre and three on a ring at 0.6 a, each a disc of radius a / 2
    _N_SUB = 4

    def _patch_points(self, centre_m: np.ndarray, radius_m: float, theta0: float) -> np.ndarray:
        ang = theta0 + np.arange(self._N_SUB - 1) * 2 * np.pi / (self._N_SUB - 1)
        return np.vstack([centre_m, centre_m + self._RING * radius_m * np.column_stack([np.cos(ang), np.sin(ang)])])

    def _motion_ripple(self, tl: Timeline, H: np.ndarray) -> None:
        """A small smooth change of H (n, n_f), in place, while the robot moves (joint poses load the link)."""
        rng = np.random.default_rng([self.scenario.seed, 7, int(tl.session[0]), int(tl.chirp[0])])
        n, J = len(tl), 6
        tau = rng.uniform(0.02e-3, 0.4e-3, J)
        a = 0.9  # AR(1) per chirp: the pose changes smoothly
        e = (rng.standard_normal((n, J)) + 1j * rng.standard_normal((n, J))) / np.sqrt(2) * np.sqrt(1 - a * a)
        e[0] /= np.sqrt(1 - a * a)  # start in the stationary distribution
        c = scipy.signal.lfilter([1.0], [1.0, -a], e, axis=0)
        c = (c * ((self._perturb / np.sqrt(J)) * tl.moving)[:, None]).astype(np.complex64)
        basis = np.exp(-2j * np.pi * np.outer(tau, self.channel.f_hz)).astype(np.complex64)  # (J, n_f)
        for s in range(0, n, self._CHUNK):  # 1 + ripple, a few chirps at a time
            r = c[s:s + self._CHUNK] @ basis
            r += 1
            H[s:s + self._CHUNK] *= r

    # -- rendering --------------------------------------------------------------------
    def render(self, tl: Timeline, *, rng: np.random.Generator | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """Received frames (n, n_chirp) for ``tl``; an int32 ``out`` gets them as 24-bit codes (libsndfile's float -> PCM_24)."""
        if rng is None:
            rng = np.random.default_rng([self.scenario.seed, 3, int(tl.session[0]), int(tl.chirp[0])])
        rig = self.rig
        n = len(tl)
        temps = self.temperatures(tl)
        if self._H is None or self._H.size < n * self.channel.f_hz.size:
            self._H = np.empty(n * self.channel.f_hz.size, np.complex64)
        H = self.channel_response(tl, temps, out=self._H[:n * self.channel.f_hz.size].reshape(n, -1))
        # Sensor noise, and the robot's own noise while it moves, in one draw (drawn whole, rendered by rows).
        if self._buffers is None or self._buffers[0].size < n * self._nb:
            self._buffers = (np.empty(n * self._nb, np.float32), np.empty(n * self._nb, np.float32))
        noise = NoiseDraws(rng, tl.moving, self.noise, n_fft=rig.n_chirp, fs_hz=rig.fs_hz,
                           floor_rms=self.noise.sensor_rms, buffers=self._buffers, work=self._work)
        # Transducers x chirp x gain, per distinct pair of bond temperatures.
        T2, inv = self._bond_rows(temps["tx_c"], temps["rx_c"])
        T2 = T2 * (self.gain * self._S)
        out = np.empty((n, rig.n_chirp), np.float32) if out is None else out
        assert out.shape == (n, rig.n_chirp) and out.dtype in (np.float32, np.int32)
        pcm = out.dtype == np.int32
        q = float(2 ** (self.quantize_bits - 1) - 1) if self.quantize_bits else None
        b0, b1 = self._band
        if self._Ybuf is None:
            self._Ybuf = np.empty((self._CHUNK, self._nb), np.complex64)  # one chunk's spectra, reused
        for a in range(0, n, self._CHUNK):
            c = slice(a, min(a + self._CHUNK, n))
            Y = noise.fill(self._Ybuf[:c.stop - a], a)
            Y[:, b0:b1] += H[c] * T2[inv[c]]
            x = scipy.fft.irfft(Y, n=rig.n_chirp, axis=-1, workers=threads.fft_workers())
            o = x if pcm else out[c]  # float frames: quantised straight into the output rows
            if q:
                np.clip(x, -1.0, 1.0, out=o)
                o *= q
                np.round(o, out=o)
                o /= q
            elif not pcm:
                o[...] = x
            if pcm:  # x * 2^23 is exact in float32; rounded and clipped as libsndfile does, then << 8 (exact)
                x *= np.float32(2 ** 23)
                np.clip(x, -2.0 ** 23, 2.0 ** 23 - 1, out=x)
                np.rint(x, out=x)
                np.multiply(x, np.float32(256), out=out[c], casting="unsafe")
        return out

    _CHUNK = 64  # frames per inverse FFT: keeps the spectra in cache

    def _bond_rows(self, tx_c: np.ndarray, rx_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distinct rows of ``T_tx * T_rx`` (u, n_f) complex64 and each chirp's row (n,)."""
        key = np.round(np.column_stack([tx_c, rx_c]) / self._DT_STEP_K)
        u, inv = np.unique(key, axis=0, return_inverse=True)
        f = self.channel.f_hz
        return self.bond.response(f, u[:, 0] * self._DT_STEP_K) * self.bond.response(f, u[:, 1] * self._DT_STEP_K), inv.ravel()


_WB_DTYPE = np.complex64


def _woodbury(Gp: np.ndarray, K: np.ndarray, P: int) -> np.ndarray:
    """Change of H by a contact of ``P`` sub-contacts, ``-g_r^T (I + K G_pp)^{-1} K g_s`` (R, O, n_f), every P x P
    system solved at once by Gaussian elimination over whole arrays (no pivoting, complex128)."""
    R, _, F = Gp.shape
    n_o = K.shape[1]
    iu, ju = np.triu_indices(P)
    g_r, g_s = Gp[:, :P], Gp[:, P:2 * P]  # (R, P, F)
    Kd = K.astype(_WB_DTYPE)[:, None]  # (R, 1, O, F)
    A = np.empty((P, P, R, n_o, F), _WB_DTYPE)
    for t, (i, j) in enumerate(zip(iu, ju)):
        A[i, j] = Kd[:, 0] * Gp[:, 2 * P + t, None, :]
        if i != j:
            A[j, i] = A[i, j]
        else:
            A[i, i] += 1
    b = np.moveaxis(Kd * g_s[:, :, None, :], 1, 0)  # (P, R, O, F)
    for k in range(P):
        piv = 1 / A[k, k]
        A[k, k + 1:] *= piv
        b[k] *= piv
        if k + 1 < P:
            lk = A[k + 1:, k]  # (P-k-1, R, O, F)
            A[k + 1:, k + 1:] -= lk[:, None] * A[k, k + 1:][None]
            b[k + 1:] -= lk * b[k]
    for k in range(P - 2, -1, -1):
        b[k] -= np.sum(A[k, k + 1:] * b[k + 1:], axis=0)
    return (-np.einsum("rpf,prof->rof", g_r, b)).astype(np.complex64)
