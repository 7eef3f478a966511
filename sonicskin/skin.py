"""The paper's complete SonicSkin pipeline on feature arrays: locate, detect, calibrate, weigh.

:class:`SkinSVM` bundles the reference system of the paper:

1. :class:`~sonicskin.baseline.SVMLocalizer` (OSPA bins -> scaler -> RBF SVM) on touch chirps;
2. Alg. 2: scores calibrated by the mean score of no-touch chirps, ``S_final = S - S_c``,
   refreshed online (the location itself is the argmax of the raw scores, see ``predict``);
3. touch detection by a threshold on ``max S_final``, chosen on training chirps;
4. force from ``E^O`` (energy over the OSPA bins, relative to the no-touch reference) with one
   first-order Fourier model per location.

Inputs are dB-magnitude features (:func:`sonicskin.dsp.log_magnitude_db`).
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from .baseline import SVMLocalizer
from .calibration import OnlineReference, TouchDetector
from .force import PerLocationForce, energy_db
from .rig import Layout, Rig

__all__ = ["SkinSVM", "Predictions"]


@dataclasses.dataclass
class Predictions:
    location: np.ndarray      # (n,) predicted location id (argmax of calibrated scores)
    xy_cm: np.ndarray         # (n, 2)
    touch: np.ndarray         # (n,) bool, detection (all True when trained without no-touch chirps)
    force_n: np.ndarray       # (n,) estimated force (0 where no touch is detected; NaN without a force model)
    scores: np.ndarray        # (n, K) calibrated scores
    energy_db: np.ndarray     # (n,) E^O relative to the reference


class SkinSVM:
    """Reference SonicSkin system (paper Sec. III) trained on arrays.

    Parameters
    ----------
    rig, layout : acquisition and touch locations.
    n_bins : OSPA gamma.  C : SVM regularisation.
    force_model : curve model for force (``fourier1`` as in the paper).
    min_force_n : a chirp counts as a touch for training when its force is at least this.
    calibrator : Alg. 2 settings (``beta``/``alpha`` in chirps); every predicted stream gets a fresh copy.
    """

    def __init__(self, rig: Rig, layout: Layout, *, n_bins: int = 300, C: float = 10.0,
                 force_model: str = "fourier1", min_force_n: float = 0.5,
                 calibrator: OnlineReference | None = None):
        self.rig, self.layout = rig, layout
        self.n_bins, self.C, self.force_model, self.min_force_n = n_bins, C, force_model, min_force_n
        self.calibrator = calibrator or OnlineReference.from_seconds(beta_s=3.0, alpha_s=1200.0,
                                                                     chirps_per_s=rig.chirps_per_s)

    def _raw(self, X: np.ndarray) -> np.ndarray:
        """Raw scores S and E^O (absolute), columns [S_1..S_K, E]."""
        S = self.localizer_.decision_function(X)
        E = energy_db(X, self.localizer_.selected_)
        return np.column_stack([S, E])

    def fit(self, X: np.ndarray, location: np.ndarray, force_n: np.ndarray, *, quiet: np.ndarray,
            X_moving: np.ndarray | None = None) -> SkinSVM:
        """Train on one-shot data.

        X : (n, n_band) features of a training session; location (n,) id or -1; force_n (n,).
        quiet : (n,) bool, no-touch chirps at rest (calibration reference and detector negatives).  Without
            any (a table of touches only) ``detector_`` is ``None`` and every chirp counts as a touch.
            ``force_`` is ``None`` without a force sensor (NaN forces) or with a constant force.
        X_moving : no-touch chirps while the robot moves (OSPA's MV); quiet chirps when ``None``.
        """
        X, location, force_n, quiet = (np.asarray(a) for a in (X, location, force_n, quiet))
        n = X.shape[0]
        if not (location.shape == force_n.shape == quiet.shape == (n,)):
            raise ValueError(f"X has {n} rows but location/force/quiet have {location.size}/{force_n.size}/{quiet.size}")
        # A touch is a location with enough force, or any force when there is no force sensor (NaN).
        touch = (location >= 0) & ((force_n >= self.min_force_n) | np.isnan(force_n))
        rest = quiet.sum() >= 2  # a table of touches only has no rest: no detector, no Alg. 2 reference
        self.localizer_ = SVMLocalizer(n_bins=self.n_bins, C=self.C, allowed=self.rig.allowed_mask)
        X_ref = X_moving if X_moving is not None else (X[quiet] if rest else None)
        self.localizer_.fit(X[touch], location[touch], X_moving=X_ref)
        raw = self._raw(X)
        # S_c and E^O of the training session's rest (without rest: none, E^O is absolute).
        self.reference_ = raw[quiet].mean(axis=0) if rest else np.zeros(raw.shape[1])
        cal = raw - self.reference_
        self.detector_ = TouchDetector().fit(cal[touch, :-1], cal[quiet, :-1]) if rest else None
        has_f = touch & np.isfinite(force_n)
        self.force_ = None  # no force sensor, or a constant force (no curve to fit)
        if has_f.sum() >= 8 and np.ptp(force_n[has_f]) > 0:
            self.force_ = PerLocationForce(self.force_model).fit(cal[has_f, -1], force_n[has_f], location[has_f])
        return self

    def predict(self, X: np.ndarray, *, time_s: np.ndarray | None = None, online: bool = True) -> Predictions:
        """Predict one stream of chirps (in time order) as the running system would.

        ``online``: Alg. 2 through :class:`~sonicskin.calibration.OnlineReference`: the first
        ``beta`` chirps are the boot calibration (hands off; predicted no-touch), later references
        are refreshed every ``alpha`` from chirps this model's own detector calls no-touch.  No
        label is used.  ``online=False``: the training session's reference throughout.
        ``time_s``: the stream clock when it has gaps (chirp count otherwise).
        """
        raw = self._raw(X)
        if online and self.detector_ is not None:  # no detector (touches only): nothing to refresh from
            c = self.calibrator
            ref = OnlineReference(c.beta, c.alpha, c.cps, relative=False)
            clock = np.arange(len(raw)) / c.cps if time_s is None else np.asarray(time_s, float)
            cal = np.full_like(raw, np.nan)

            def detect(block):
                d = block - ref.features
                return SimpleNamespace(touch=self.detector_.predict(d[:, :-1]), cal=d)

            for lo, hi, out in ref.replay(raw, clock, detect):
                cal[lo:hi] = out.cal[: hi - lo]
            boot = np.isnan(cal[:, 0])
            cal[boot] = 0.0  # boot calibration: no touch
        else:
            cal = raw - self.reference_
            boot = np.zeros(len(raw), bool)
        S, E = cal[:, :-1], cal[:, -1]
        # Location from the raw one-vs-rest scores: they are votes plus a confidence term, and
        # subtracting the no-touch votes S_c scrambles their argmax (measured on the simulated
        # moving robot: 96 % raw vs 33 % calibrated).  S_c serves detection and force instead.
        loc = self.localizer_.classes_[np.argmax(raw[:, :-1], axis=1)]
        touch = (self.detector_.predict(S) if self.detector_ is not None else np.ones(len(loc), bool)) & ~boot
        F = (np.where(touch, np.clip(self.force_.predict(E, loc), 0, None), 0.0) if self.force_ is not None
             else np.full(len(loc), np.nan))
        return Predictions(loc, self.layout.coords(loc), touch, F, S, E)
