"""Drift tracking: estimate the channel's frequency stretch from hands-off chirps and undo it.

A warming wall stretches the untouched channel along frequency, ``H_T(f) = H_0(f / (1 + s))`` (docs/models.md#drift-tracking).
:func:`estimate_stretch` finds ``s`` by correlating *mode patterns* (dB minus a Savitzky-Golay trend, so smooth changes
cannot pose as a stretch); :func:`warp_band` maps features back.  A warp reads each bin from its own segment of the
band (allowed runs and PWM bands between them) only, so no value crosses a PWM band edge or the band's ends."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.ndimage
import scipy.optimize
import scipy.signal

from .errors import SonicskinError, is_number
from .sim.channel import MATERIALS

__all__ = ["DriftError", "DriftEstimate", "DriftTracker", "estimate_stretch", "warp_band", "warp_index",
           "band_segments", "stretch_to_kelvin", "material_kappa", "DEFAULT_MAX_SEARCH", "DEFAULT_SMOOTH_HZ",
           "DEFAULT_MIN_CORRELATION", "DEFAULT_GRID_STEP"]

#: Largest |stretch| searched: 4e-3 is 11 K on the CFRP wall, 0.9 K on ABS (320 Hz at 80 kHz).
DEFAULT_MAX_SEARCH = 4e-3
#: Width of the trend removed before correlating the mode patterns (smooth changes are not a stretch).
DEFAULT_SMOOTH_HZ = 2000.0
#: Below this peak correlation the hands-off spectrum is not the training channel stretched: not used (the
#: simulated CFRP link at rest scores 0.92-0.999 from -5 to +10 K; rest while the robot moves 0.71-0.85).
DEFAULT_MIN_CORRELATION = 0.9
#: Gaussian smoothing (bins) of both mode patterns before they are compared (see :meth:`_Pattern.detrend`).
PATTERN_SIGMA_BINS = 2.0
#: A pattern with less RMS than this (dB) once its trend is removed is flat: no modes to compare.
FLAT_RMS_DB = 1e-6
#: Grid step of the coarse search before the bounded refinement (the correlation peak is ~1e-4 wide).
DEFAULT_GRID_STEP = 2.5e-5


class DriftError(SonicskinError):
    """Drift tracking given inputs it cannot use; the message names the problem and the fix."""


def material_kappa(material: str) -> float:
    """Relative modal frequency shift per kelvin of a simulated wall material (``MATERIALS[name].kappa_per_k``)."""
    if not isinstance(material, str) or material not in MATERIALS:
        raise DriftError(f"unknown material {material!r} for the stretch's temperature equivalent; "
                         f"known: {', '.join(sorted(MATERIALS))} (or pass kappa_per_k)")
    return float(MATERIALS[material].kappa_per_k)


def stretch_to_kelvin(stretch: float, kappa_per_k: float) -> float:
    """Temperature change (K) of a wall with ``kappa_per_k`` whose channel is stretched by ``stretch`` (``1 + s = 1 + kappa dT``)."""
    if not (isinstance(kappa_per_k, (int, float)) and math.isfinite(kappa_per_k) and kappa_per_k != 0):
        raise DriftError(f"kappa_per_k must be a finite non-zero number (relative frequency shift per K), got {kappa_per_k!r}")
    return float(stretch) / float(kappa_per_k)


def band_segments(allowed: np.ndarray) -> np.ndarray:
    """Runs of equal ``allowed`` values over the band, (k, 2) int ``[start, stop)``, in order."""
    a = np.asarray(allowed, bool)
    if a.ndim != 1 or a.size == 0:
        raise DriftError(f"allowed must be a non-empty mask over the band bins, got shape {a.shape}")
    cut = np.flatnonzero(np.diff(a.astype(np.int8))) + 1
    starts = np.r_[0, cut]
    return np.column_stack([starts, np.r_[cut, a.size]])


def _check_freqs(freqs_hz) -> tuple[float, float, int]:
    f = np.asarray(freqs_hz, float)
    if f.ndim != 1 or f.size < 16 or not np.isfinite(f).all() or f[0] <= 0:
        raise DriftError(f"freqs_hz must be the band's bin frequencies (at least 16 positive, finite values; "
                         f"rig.freqs_hz[rig.band_bins]), got shape {f.shape}")
    df = float(f[1] - f[0])
    if df <= 0 or np.max(np.abs(np.diff(f) - df)) > 1e-6 * df:
        raise DriftError("freqs_hz must be evenly spaced and increasing (the rig's contiguous band bins, "
                         "rig.freqs_hz[rig.band_bins])")
    return float(f[0]), df, int(f.size)


def warp_index(freqs_hz, stretch: float, allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gather indices ``i0`` and weights ``w`` of ``X_back(f) = X(f (1 + s))``, each bin within its segment of ``allowed``."""
    f0, df, n = _check_freqs(freqs_hz)
    s = float(stretch)
    if not math.isfinite(s) or abs(s) >= 0.5:
        raise DriftError(f"stretch must be a finite relative frequency change (|s| < 0.5), got {stretch!r}")
    segs = band_segments(np.ones(n, bool) if allowed is None else allowed)
    if segs[-1, 1] != n:
        raise DriftError(f"allowed has {segs[-1, 1]} bins but freqs_hz has {n}; both are over the rig's band bins")
    j = np.arange(n)
    pos = j * (1.0 + s) + (f0 / df) * s  # (f_j (1 + s) - f0) / df; exactly j when s = 0
    lo = np.repeat(segs[:, 0], segs[:, 1] - segs[:, 0])
    hi = np.repeat(segs[:, 1], segs[:, 1] - segs[:, 0]) - 1
    pos = np.clip(pos, lo, hi)
    i0 = np.clip(np.floor(pos).astype(np.int64), 0, max(n - 2, 0))
    w = (pos - i0).astype(np.float32)  # 0 or 1 at a segment's edge: no neighbour from another segment
    return i0, w


def _band_features(X_band, n: int) -> np.ndarray:
    X = np.asarray(X_band, np.float32)
    if X.ndim not in (1, 2) or X.shape[-1] != n:
        raise DriftError(f"expected band features (n, {n}) or ({n},), got shape {X.shape}")
    return X


def warp_band(X_band, stretch: float, freqs_hz, allowed: np.ndarray | None = None) -> np.ndarray:
    """Band features (n, n_band) or (n_band,) in dB, mapped back onto the training axis by ``stretch`` (:func:`warp_index`)."""
    X = _band_features(X_band, np.asarray(freqs_hz).size)
    i0, w = warp_index(freqs_hz, stretch, allowed)
    return X[..., i0] * (1 - w) + X[..., i0 + 1] * w


@dataclasses.dataclass(frozen=True)
class DriftEstimate:
    """One estimate of the channel's drift: the stretch, the peak correlation, the gain and tilt left, whether reliable."""

    stretch: float
    correlation: float
    gain_db: float
    tilt_db_per_khz: float
    n_bins: int
    at_limit: bool
    reliable: bool

    def to_dict(self) -> dict:
        return {k: (bool(v) if isinstance(v, (bool, np.bool_)) else float(v) if isinstance(v, float) else v)
                for k, v in dataclasses.asdict(self).items()}


def _mean_spectrum(spectrum_db, n: int, what: str) -> np.ndarray:
    x = np.asarray(spectrum_db, np.float64)
    if x.ndim == 2 and x.shape[1] == n and x.shape[0] >= 1:
        x = x.mean(axis=0)
    if x.shape != (n,):
        raise DriftError(f"{what} must be band spectra in dB, ({n},) or (m, {n}) (one value per band bin), got shape "
                         f"{np.shape(spectrum_db)}")
    if not np.isfinite(x).all():
        raise DriftError(f"{what} holds NaN or infinite values in {int((~np.isfinite(x)).sum())} bins; "
                         f"drop the faulty chirps before averaging")
    return x


class _Pattern:
    """The mode pattern of spectra on one band: dB minus its smooth trend, masked bins bridged."""

    def __init__(self, freqs_hz, allowed, smooth_hz: float, max_search: float):
        self.f0, self.df, self.n = _check_freqs(freqs_hz)
        self.f = self.f0 + self.df * np.arange(self.n)
        self.allowed = np.ones(self.n, bool) if allowed is None else np.asarray(allowed, bool)
        if self.allowed.shape != (self.n,):
            raise DriftError(f"allowed must be a mask over the {self.n} band bins, got shape {self.allowed.shape}")
        if not (isinstance(smooth_hz, (int, float)) and math.isfinite(smooth_hz) and smooth_hz > 0):
            raise DriftError(f"smooth_hz must be a positive width in Hz, got {smooth_hz!r}")
        if not (isinstance(max_search, (int, float)) and math.isfinite(max_search) and 0 < max_search < 0.1):
            raise DriftError(f"max_search must be a relative stretch in (0, 0.1), got {max_search!r}")
        win = int(round(smooth_hz / self.df)) | 1
        self.window = int(max(5, min(win, (self.n - 1) | 1 if self.n % 2 == 0 else self.n)))
        if self.window > self.n:
            self.window = self.n if self.n % 2 else self.n - 1
        # Usable for the estimate: allowed bins at least the largest searched shift (+1 bin) from any segment edge.
        margin = int(math.ceil(max_search * (self.f[-1]) / self.df)) + 1
        use = np.zeros(self.n, bool)
        for a, b in band_segments(self.allowed):
            if self.allowed[a] and b - a > 2 * margin:
                use[a + margin:b - margin] = True
        self.use = use
        self.margin = margin
        if int(use.sum()) < 64:
            raise DriftError(f"only {int(use.sum())} allowed bins lie {margin} bins inside their band segments; "
                             f"the band is too narrow to estimate a stretch of up to {max_search:g} (lower max_search)")

    def detrend(self, x: np.ndarray) -> np.ndarray:
        y = x.copy()
        if not self.allowed.all():  # bridge masked bins linearly (a PWM line is neither mode nor trend)
            k = np.arange(self.n)
            y[~self.allowed] = np.interp(k[~self.allowed], k[self.allowed], x[self.allowed])
        y -= scipy.signal.savgol_filter(y, self.window, 2, mode="interp")
        # Both patterns lightly smoothed: the search reads the reference between bins, and linear interpolation
        # averages neighbours (less noise at half-bin shifts), which would pull the peak off whole-bin stretches.
        return scipy.ndimage.gaussian_filter1d(y, PATTERN_SIGMA_BINS, mode="nearest")

    def shifted(self, p: np.ndarray, s: float) -> np.ndarray:
        """``p`` (a reference pattern) evaluated at ``f / (1 + s)`` on the usable bins."""
        return np.interp(self.f[self.use] / (1.0 + s), self.f, p)


def _corr(a: np.ndarray, b_std: np.ndarray) -> float:
    a = a - a.mean()
    na = np.sqrt(a @ a)
    return float(a @ b_std / na) if na > 0 else 0.0


def _estimate(pat: _Pattern, cur: np.ndarray, ref: np.ndarray, ref_pattern: np.ndarray, *, max_search: float,
              min_correlation: float, grid_step: float) -> DriftEstimate:
    if not (isinstance(grid_step, (int, float)) and math.isfinite(grid_step) and 0 < grid_step <= max_search):
        raise DriftError(f"grid_step must be in (0, max_search] = (0, {max_search:g}], got {grid_step!r}")
    if not (isinstance(min_correlation, (int, float)) and -1 <= min_correlation <= 1):
        raise DriftError(f"min_correlation must be a correlation in [-1, 1], got {min_correlation!r}")
    c = pat.detrend(cur)[pat.use]
    c = c - c.mean()
    nc = np.sqrt(c @ c)
    if not nc > FLAT_RMS_DB * np.sqrt(c.size):
        raise DriftError("spectrum_db has no mode pattern (flat once its trend is removed); pass hands-off spectra "
                         "of the rig in dB (log_magnitude_db)")
    c /= nc
    k = max(1, int(round(max_search / grid_step)))
    grid = np.arange(-k, k + 1) * (max_search / k)
    cc = np.array([_corr(pat.shifted(ref_pattern, g), c) for g in grid])
    b = int(np.argmax(cc))
    lo, hi = grid[max(b - 1, 0)], grid[min(b + 1, grid.size - 1)]
    opt = scipy.optimize.minimize_scalar(lambda g: -_corr(pat.shifted(ref_pattern, g), c), bounds=(lo, hi),
                                         method="bounded", options={"xatol": 1e-8})
    s, rho = (float(opt.x), float(-opt.fun)) if -opt.fun >= cc[b] else (float(grid[b]), float(cc[b]))
    at_limit = b in (0, grid.size - 1)
    # Gain and tilt after undoing the stretch: least squares of the level difference on the usable bins.
    fu = pat.f[pat.use]
    d = cur[pat.use] - np.interp(fu / (1.0 + s), pat.f, ref)
    A = np.column_stack([np.ones(d.size), (fu - 0.5 * (pat.f[0] + pat.f[-1])) / 1e3])
    gain, tilt = np.linalg.lstsq(A, d, rcond=None)[0]
    return DriftEstimate(stretch=s, correlation=rho, gain_db=float(gain), tilt_db_per_khz=float(tilt),
                         n_bins=int(pat.use.sum()), at_limit=bool(at_limit),
                         reliable=bool(rho >= min_correlation and not at_limit))


def estimate_stretch(spectrum_db, reference_db, freqs_hz, *, allowed: np.ndarray | None = None,
                     max_search: float = DEFAULT_MAX_SEARCH, smooth_hz: float = DEFAULT_SMOOTH_HZ,
                     min_correlation: float = DEFAULT_MIN_CORRELATION,
                     grid_step: float = DEFAULT_GRID_STEP) -> DriftEstimate:
    """Stretch (and gain, tilt) of hands-off band spectra against ``reference_db``: searched on a grid, then refined."""
    pat = _Pattern(freqs_hz, allowed, smooth_hz, max_search)
    cur = _mean_spectrum(spectrum_db, pat.n, "spectrum_db")
    ref = _mean_spectrum(reference_db, pat.n, "reference_db")
    return _estimate(pat, cur, ref, pat.detrend(ref), max_search=max_search, min_correlation=min_correlation, grid_step=grid_step)


class DriftTracker:
    """The training reference of one artifact, the current stretch and its limits (``trained_stretch``: beyond it
    :attr:`warning` says "record a new session").  :meth:`update` on each reference refresh, then :meth:`warp` or
    :meth:`warp_bins` on every chirp; an estimate that is not ``reliable`` leaves the stretch and sets :attr:`warning`."""

    def __init__(self, reference_db, freqs_hz, *, allowed: np.ndarray | None = None, trained_stretch: float,
                 kappa_per_k: float | None = None, material: str | None = None,
                 max_search: float = DEFAULT_MAX_SEARCH, smooth_hz: float = DEFAULT_SMOOTH_HZ,
                 min_correlation: float = DEFAULT_MIN_CORRELATION, grid_step: float = DEFAULT_GRID_STEP):
        self._pat = _Pattern(freqs_hz, allowed, smooth_hz, max_search)
        self.reference_db = _mean_spectrum(reference_db, self._pat.n, "reference_db")
        self._ref_pattern = self._pat.detrend(self.reference_db)
        if not np.std(self._ref_pattern[self._pat.use]) > FLAT_RMS_DB:
            raise DriftError("reference_db has no mode pattern (flat once its trend is removed); pass the training "
                             "session's hands-off spectra in dB (log_magnitude_db)")
        if not (is_number(trained_stretch) and 0 <= trained_stretch <= max_search):
            raise DriftError(f"trained_stretch must be the largest |stretch| the artifact was trained for, in "
                             f"[0, max_search = {max_search:g}], got {trained_stretch!r}")
        if material is not None and kappa_per_k is not None:
            raise DriftError("give kappa_per_k or material, not both")
        self.material = material
        self.kappa_per_k = material_kappa(material) if material is not None else kappa_per_k
        if self.kappa_per_k is not None:
            stretch_to_kelvin(0.0, self.kappa_per_k)  # validates it
        self.trained_stretch = float(trained_stretch)
        self.max_search, self.smooth_hz = float(max_search), float(smooth_hz)
        self.min_correlation, self.grid_step = float(min_correlation), float(grid_step)
        self.freqs_hz = self._pat.f
        self.allowed = self._pat.allowed
        self.stretch = 0.0
        self.estimate: DriftEstimate | None = None
        self.updates = 0
        self._idx = warp_index(self.freqs_hz, 0.0, self.allowed)
        self._bins_cache: dict = {}
        # Check the settings once (a wrong grid_step or min_correlation fails here, not at the first refresh).
        _estimate(self._pat, self.reference_db, self.reference_db, self._ref_pattern, max_search=self.max_search,
                  min_correlation=self.min_correlation, grid_step=self.grid_step)

    @classmethod
    def from_rig(cls, rig, reference_db, **kw) -> DriftTracker:
        """A tracker on ``rig``'s band (its bin frequencies and PWM mask)."""
        return cls(reference_db, rig.freqs_hz[rig.band_bins], allowed=rig.allowed_mask, **kw)

    # -- estimate -----------------------------------------------------------------------
    def measure(self, spectrum_db) -> DriftEstimate:
        """The drift of hands-off spectra (n_band,) or (m, n_band) against the reference, without adopting it."""
        cur = _mean_spectrum(spectrum_db, self._pat.n, "spectrum_db")
        return _estimate(self._pat, cur, self.reference_db, self._ref_pattern, max_search=self.max_search,
                         min_correlation=self.min_correlation, grid_step=self.grid_step)

    def update(self, spectrum_db) -> DriftEstimate:
        """Estimate from a refresh's hands-off spectra and, when reliable, warp by it from now on."""
        est = self.measure(spectrum_db)
        self.estimate = est
        self.updates += 1
        if est.reliable:
            self.set_stretch(est.stretch)
        return est

    def set_stretch(self, stretch: float) -> None:
        """Warp by ``stretch`` from now on (e.g. restored from a saved state)."""
        self._idx = warp_index(self.freqs_hz, stretch, self.allowed)
        self.stretch = float(stretch)
        self._bins_cache = {}

    # -- warp ---------------------------------------------------------------------------
    def warp(self, X_band) -> np.ndarray:
        """Band features (n, n_band) or (n_band,) mapped back onto the training axis by the current stretch."""
        X = _band_features(X_band, self._pat.n)
        i0, w = self._idx
        return X[..., i0] * (1 - w) + X[..., i0 + 1] * w

    def warp_bins(self, X_band, bins) -> np.ndarray:
        """Only the columns ``bins`` (indices into the band) of :meth:`warp`: a model's inputs, per chirp."""
        b = np.asarray(bins)
        key = (b.dtype.str, b.shape, b.tobytes())
        hit = self._bins_cache.get(key)
        if hit is None:
            if b.ndim != 1 or not (b.size == 0 or np.issubdtype(b.dtype, np.integer)):
                raise DriftError(f"bins must be a 1-D array of band-bin indices, got {b.dtype} of shape {b.shape}")
            b = b.astype(np.int64)
            if b.size and (b.min() < 0 or b.max() >= self._pat.n):
                raise DriftError(f"bins must index the {self._pat.n} band bins, got values {int(b.min())}..{int(b.max())}")
            i0, w = self._idx
            hit = self._bins_cache[key] = (i0[b], i0[b] + 1, w[b], (1 - w[b]))
        X = _band_features(X_band, self._pat.n)
        a, b1, w, w0 = hit
        return X[..., a] * w0 + X[..., b1] * w

    # -- limits and reports ------------------------------------------------------------
    def kelvin(self, stretch: float | None = None) -> float | None:
        """Temperature change equivalent to ``stretch`` (default: the current one); ``None`` without kappa."""
        if self.kappa_per_k is None:
            return None
        return stretch_to_kelvin(self.stretch if stretch is None else stretch, self.kappa_per_k)

    def _describe(self, s: float) -> str:
        k = self.kelvin(s)
        where = f" on {self.material}" if self.material else ""
        return f"{s:+.2e}" + ("" if k is None else f" (about {k:+.1f} K{where})")

    @property
    def warning(self) -> str | None:
        """What the user must do, after the last :meth:`update`; ``None`` when all is well."""
        est = self.estimate
        if est is None:
            return None
        if est.correlation < self.min_correlation:
            return (f"the hands-off spectrum does not match the training reference well enough (mode-pattern "
                    f"correlation {est.correlation:.2f} < {self.min_correlation:.2f}: the robot moving while the reference "
                    f"was taken, or another rig): drift tracking kept stretch {self.stretch:+.2e}; if this persists "
                    f"at rest, check the rig (sonicskin check) or record a new session")
        if est.at_limit:
            return (f"the channel's frequency stretch is beyond the {self.max_search:.1e} searched "
                    f"(the best match at {self._describe(est.stretch)}): record a new session and train again")
        if abs(est.stretch) > self.trained_stretch:
            return (f"the channel's frequency axis is stretched by {self._describe(est.stretch)}, beyond the "
                    f"{self.trained_stretch:.1e} this artifact was trained for: record a new session and train again")
        return None

    def status(self) -> str:
        """One short field for a status line: ``drift -1.21e-03 (+3.5 K)``."""
        k = self.kelvin()
        return f"drift {self.stretch:+.2e}" + ("" if k is None else f" ({k:+.1f} K)") + (" !" if self.warning else "")

    def report(self) -> dict:
        """The tracker's state for a report (JSON-able)."""
        return {"stretch": self.stretch, "kelvin": self.kelvin(), "updates": self.updates,
                "estimate": None if self.estimate is None else self.estimate.to_dict(), "warning": self.warning}

    # -- artifact -----------------------------------------------------------------------
    REFERENCE_DECIMALS = 3  # dB: the reference is stored to 1 mdB (noise of 3 s of rest is ~10 mdB)

    def to_dict(self) -> dict:
        """JSON-able settings and training reference (no state): :meth:`from_dict` rebuilds the tracker."""
        return {"format": 1, "f0_hz": float(self.freqs_hz[0]), "df_hz": float(self._pat.df), "n_band": int(self._pat.n),
                "masked_segments": [[int(a), int(b)] for a, b in band_segments(self.allowed) if not self.allowed[a]],
                "reference_db": [round(float(v), self.REFERENCE_DECIMALS) for v in self.reference_db],
                "trained_stretch": self.trained_stretch, "kappa_per_k": self.kappa_per_k, "material": self.material,
                "max_search": self.max_search, "smooth_hz": self.smooth_hz, "min_correlation": self.min_correlation,
                "grid_step": self.grid_step}

    @classmethod
    def from_dict(cls, d: dict, rig=None) -> DriftTracker:
        """The tracker of :meth:`to_dict`; with ``rig``, its band must be the one stored."""
        if not isinstance(d, dict):
            raise DriftError(f"a drift tracker is a mapping (DriftTracker.to_dict()), got {type(d).__name__}")
        need = ("format", "f0_hz", "df_hz", "n_band", "masked_segments", "reference_db", "trained_stretch")
        missing = [k for k in need if k not in d]
        if missing:
            raise DriftError(f"the drift tracker lacks {', '.join(missing)}; export the artifact again")
        if d["format"] != 1:
            raise DriftError(f"drift tracker format {d['format']!r} is not supported (1); update sonicskin or export again")
        try:
            n = int(d["n_band"])
            f = float(d["f0_hz"]) + float(d["df_hz"]) * np.arange(n)
            allowed = np.ones(n, bool)
            for a, b in d["masked_segments"]:
                if not 0 <= int(a) < int(b) <= n:
                    raise ValueError
                allowed[int(a):int(b)] = False
            ref = np.asarray(d["reference_db"], float)
        except (TypeError, ValueError):
            raise DriftError("the drift tracker's band (f0_hz, df_hz, n_band, masked_segments) or reference_db is "
                             "malformed; export the artifact again") from None
        if rig is not None:
            fr = rig.freqs_hz[rig.band_bins]
            if fr.size != n or not np.allclose(fr, f, rtol=0, atol=1e-6 * float(d["df_hz"])) \
                    or not np.array_equal(rig.allowed_mask, allowed):
                raise DriftError(f"the drift tracker was made for another band ({n} bins from {f[0]:.1f} Hz) than "
                                 f"the rig's ({fr.size} bins from {fr[0]:.1f} Hz); use the artifact's own rig")
        kw = {k: d[k] for k in ("kappa_per_k", "material", "max_search", "smooth_hz", "min_correlation", "grid_step")
              if d.get(k) is not None}
        if "material" in kw:
            kw.pop("kappa_per_k", None)
        return cls(ref, f, allowed=allowed, trained_stretch=d["trained_stretch"], **kw)
