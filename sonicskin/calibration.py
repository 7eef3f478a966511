"""Online feature updating (paper Alg. 2) and touch detection by threshold.  :class:`OnlineReference` is Alg. 2 as
the live loop, the offline replays and the training features all run it."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from .errors import SonicskinError, brief

__all__ = ["OnlineReference", "TouchDetector", "MAX_T_S"]

#: The largest stream time :class:`OnlineReference` takes: 10**12 s (31,700 years); more is a corrupt clock.
MAX_T_S = 1e12
#: A re-boot window's chirps at rest lie within this many first-boot spreads of its chirp closest to the old reference
#: (the simulated stationary link after a 25-min pause: rest chirps within 0.4 of them, chirps of a firm press 8 or more).
REST_SPREADS = 4.0


class OnlineReference:
    """Alg. 2 on a stream: the running no-touch reference, fed one chirp at a time (docs/models.md).

    - **Boot**: the first ``beta`` chirp periods are hands-off; their mean is the first reference.  Faulty chirps leave
      the mean of its clean chirps (at least ``beta // 4``, else the window starts again) and mark
      :attr:`boot_disturbed`: the next ``beta`` no-touch chirps then replace it at once.
    - **Refresh**: ``alpha`` chirps after a reference took effect, the next ``beta`` consecutive no-touch chirps.
    - **Re-boot**: a gap longer than ``alpha`` or a clock going back by more than a chirp starts a new boot, whatever
      the detector says (:attr:`reboots`); a hand in its window is left out (:meth:`_at_rest`, :attr:`boot_touched`).

    With ``score_fn`` the reference also holds the mean model *scores* (:attr:`scores`, the SVM's ``S_c``).
    ``labelled``: the ``touch`` flags are labels.  A ``t_s`` outside ``0 .. MAX_T_S``, or features holding NaN or
    infinite values, is a :class:`~sonicskin.errors.SonicskinError`, the reference unchanged."""

    def __init__(self, beta_chirps: int = 28, alpha_chirps: int | None = 11_250, chirps_per_s: float = 9.375, *,
                 relative: bool = True, score_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                 labelled: bool = False):
        if int(beta_chirps) < 1:
            raise ValueError(f"beta_chirps must be >= 1, got {beta_chirps}")
        if alpha_chirps is not None and int(alpha_chirps) < 1:
            raise ValueError(f"alpha_chirps must be >= 1 or None, got {alpha_chirps}")
        self.beta = int(beta_chirps)
        self.alpha = None if alpha_chirps is None else int(alpha_chirps)
        self.cps = float(chirps_per_s)
        self.relative, self.score_fn = relative, score_fn
        self.labelled = bool(labelled)            # touch flags are labels: a re-boot waits for beta known no-touch chirps
        self.features: np.ndarray | None = None   # mean features of the reference chirps
        self.scores: np.ndarray | None = None     # mean scores of the same chirps (score_fn)
        self.t_set_s: float | None = None         # stream time of the reference's last chirp
        self.refreshes = 0                        # references taken, the boot's included
        self.boot_disturbed = False               # the boot window lost chirps to faults (see class doc)
        self.boot_chirps = 0                      # chirps in the boot reference
        self.reboots = 0                          # boots after a stream gap longer than alpha (see class doc)
        self.last_gap_s: float | None = None      # the gap that caused the last re-boot (< 0: the clock went back)
        self.boot_touched = 0                     # chirps of this boot's window(s) left out as touched (see class doc)
        self._spread: float | None = None         # the first boot's spread (see _at_rest)
        self._rebooting = False
        self._last_t: float | None = None
        self._boot_t0: float | None = None
        self._early = False                       # a disturbed boot: re-take the reference from the next rest
        self._run: list[np.ndarray] = []

    @classmethod
    def from_seconds(cls, *, beta_s: float, alpha_s: float | None, chirps_per_s: float, **kw) -> OnlineReference:
        return cls(max(1, round(beta_s * chirps_per_s)),
                   None if alpha_s is None else max(1, round(alpha_s * chirps_per_s)), chirps_per_s, **kw)

    @property
    def ready(self) -> bool:
        """A reference exists (the boot calibration is complete)."""
        return self.features is not None

    @property
    def calibrating(self) -> bool:
        """In a boot calibration: the first, or a re-boot after a pause longer than ``alpha``."""
        return self.features is None or self._rebooting

    @property
    def boot_cause(self) -> str:
        """Why the last boot was taken, for a status line: ``"power-on"``, ``"a 25 min pause"``, ``"the clock went back 3600 s"``."""
        gap = self.last_gap_s
        why = "power-on" if gap is None else f"a {gap / 60:.0f} min pause" if gap > 0 else f"the clock went back {-gap:.0f} s"
        return why + (f", {self.boot_touched} touched chirps left out" if self.boot_touched else "")

    def _paused(self, dt_s):
        """A step of ``dt_s`` (scalar or array) is a pause longer than ``alpha`` or the clock going back: a re-boot follows."""
        if self.alpha is None:
            return np.zeros(np.shape(dt_s), bool)
        chirps = np.asarray(dt_s) * self.cps
        return (chirps > self.alpha) | (chirps < -1)

    def _gap(self, t_s: float) -> bool:
        """The stream paused longer than ``alpha`` before ``t_s`` (or its clock went back)."""
        return self._last_t is not None and bool(self._paused(t_s - self._last_t))

    @staticmethod
    def _time(t_s) -> float:
        """``t_s`` as seconds, checked before it touches any state (a NaN in the boot window stopped every later chirp)."""
        if isinstance(t_s, (bool, np.bool_)) or not isinstance(t_s, (int, float, np.integer, np.floating)) or not 0 <= t_s <= MAX_T_S:
            raise SonicskinError(f"stream time t_s must be a number of seconds in 0..{MAX_T_S:g}, got {brief(t_s)}: pass "
                                 "the chirp's time on the stream's clock, or skip a chirp whose time is unknown")
        return float(t_s)

    def booting_at(self, t_s: float) -> bool:
        """The chirp at stream time ``t_s`` belongs to a boot calibration (hands off by protocol; no prediction)."""
        t_s = self._time(t_s)
        return self.calibrating or self._gap(t_s)

    def inputs(self, x: np.ndarray) -> np.ndarray:
        """Model inputs of features ``x`` (..., d): minus the reference in relative mode."""
        if self.features is None:
            raise RuntimeError("no reference yet: feed the boot calibration's chirps first")
        x = np.asarray(x, np.float32)
        return x - self.features if self.relative else x

    def _set(self, block: np.ndarray, t_s: float) -> None:
        self.features = block.mean(axis=0).astype(np.float32)
        if self.score_fn is not None:
            self.scores = np.asarray(self.score_fn(self.inputs(block)), np.float64).mean(axis=0)
        self.t_set_s = float(t_s)
        self.refreshes += 1
        self._run = []
        self._rebooting = False

    def _reboot(self) -> None:
        """Start a new boot window from the next chirp (the last boot's state, a disturbed window, is over)."""
        self._rebooting, self._boot_t0, self._run, self.boot_touched = True, None, [], 0
        self.boot_disturbed = self._early = False

    def step(self, x: np.ndarray, t_s: float, touch: bool | None = None) -> bool:
        """Feed one chirp's features at ``t_s`` with its touch detection (``None`` in a boot); True when a new reference completed."""
        t_s = self._time(t_s)
        x = np.asarray(x, np.float32)
        if not np.isfinite(x).all():  # it would become the reference (a NaN in the boot window: every later input NaN)
            raise SonicskinError("the chirp's features hold NaN or infinite values (a NaN, silent or clipped frame); skip "
                                 "that chirp, as the live loop does")
        if self._gap(t_s) and self.features is not None:
            self._reboot()
            self.reboots += 1
            self.last_gap_s = t_s - self._last_t
        self._last_t = t_s
        if self._rebooting:
            if not (self.labelled and touch is not None):  # labels say which chirps are hands-off: wait for them below
                return self._boot_step(x, t_s)
        elif self.features is not None:
            if not self._early and (self.alpha is None or round((t_s - self.t_set_s) * self.cps) < self.alpha):
                return False
        elif touch is None:  # the boot, hands off by protocol: a window of stream time
            return self._boot_step(x, t_s)
        if touch:
            self._run = []
            return False
        self._run.append(np.asarray(x, np.float32))
        if len(self._run) < self.beta:
            return False
        self._early = False
        self._set(np.stack(self._run), t_s)
        return True

    def _boot_step(self, x: np.ndarray, t_s: float) -> bool:
        if self._boot_t0 is None:
            self._boot_t0 = t_s
        # Chirp k of the window starts at t0 + k / cps: the window holds k = 0 .. beta - 1.
        lost = round((t_s - self._boot_t0) * self.cps) >= self.beta  # the window passed with chirps lost to faults
        if not lost:
            self._run.append(np.asarray(x, np.float32))
            if len(self._run) < self.beta:
                return False
        block = np.stack(self._run) if self._run else np.zeros((0, np.size(x)), np.float32)
        rest = self._at_rest(block)
        again = self.boot_touched > 0  # an earlier window of this boot was refused: take this one's rest, however few
        self.boot_touched += int(np.sum(~rest))
        if lost or not rest.all():
            self.boot_disturbed = True
        if rest.sum() >= max(1, self.beta // 4) or (again and rest.any()):  # its clean chirps at rest, never later ones
            self._early = self.boot_disturbed
            if self.features is None:  # the first boot: how far from their mean its chirps lie (what _at_rest allows)
                self._spread = float(np.median(np.abs(block - block.mean(axis=0)), axis=1).max())
            self.boot_chirps = int(rest.sum())
            self._set(block[rest], t_s)
            return True
        # too few: a new window, from this chirp on (after lost chirps) or from the next
        self._boot_t0, self._run = (t_s, [np.asarray(x, np.float32)]) if lost else (None, [])
        return False

    def _at_rest(self, block: np.ndarray) -> np.ndarray:
        """The chirps of a re-boot window at rest: within ``REST_SPREADS`` first-boot spreads of the closest one's distance."""
        if self.features is None or self._spread is None or not len(block):
            return np.ones(len(block), bool)
        e = np.median(np.abs(block - self.features), axis=1)
        return e <= e.min() + REST_SPREADS * self._spread

    def replay(self, X: np.ndarray, time_s: np.ndarray, predict: Callable[[np.ndarray], object], *,
               boot_touch: np.ndarray | None = None) -> Iterator[tuple[int, int, object]]:
        """Vectorised replay: the decisions of :meth:`step`, the model run on whole blocks of chirps sharing one reference.
        Yields ``(lo, hi, out)`` (``out`` ``None`` for a boot's chirps); ``boot_touch``: known flags for the first boot."""
        X = np.asarray(X, np.float32)
        time_s = np.asarray(time_s, float)
        n = len(X)
        chunk = n if self.alpha is None else self.alpha + 8 * self.beta
        # A pause longer than alpha before chirp k: a re-boot starts there (never with alpha None).
        gaps = np.r_[False, self._paused(np.diff(time_s))]
        i = 0
        while i < n:
            lo = i
            while i < n and self.booting_at(time_s[i]):
                self.step(X[i], time_s[i], None if boot_touch is None else bool(boot_touch[i]))
                i += 1
            if i > lo:
                yield lo, i, None
                continue
            hi = min(n, i + chunk)
            nxt = np.flatnonzero(gaps[i + 1:hi])
            hi = i + 1 + int(nxt[0]) if nxt.size else hi
            out = predict(self.inputs(X[i:hi]))
            ref_touch = getattr(out, "reference_touch", None)  # what the reference must skip, where it is not out.touch
            touch = np.asarray(out.touch if ref_touch is None else ref_touch, bool)
            j = i
            while j < hi:
                done = self.step(X[j], time_s[j], bool(touch[j - i]))
                j += 1
                if done:
                    break
            yield i, j, out
            i = j


class TouchDetector:
    """Touch / no-touch by thresholding the largest calibrated score (paper Sec. III-C); ``fit`` by Youden's J."""

    def __init__(self, threshold: float | None = None):
        self.threshold = threshold

    def fit(self, scores_touch: np.ndarray, scores_quiet: np.ndarray) -> TouchDetector:
        st = np.max(np.atleast_2d(scores_touch), axis=1)
        sq = np.max(np.atleast_2d(scores_quiet), axis=1)
        if st.size == 0 or sq.size == 0:
            raise ValueError("need both touch and no-touch chirps to choose a detection threshold")
        if self.threshold is not None:
            thr = float(self.threshold)
        else:
            from sklearn.metrics import roc_curve

            y = np.r_[np.ones(st.size), np.zeros(sq.size)]
            fpr, tpr, thr_c = roc_curve(y, np.r_[st, sq])
            k = int(np.argmax(tpr - fpr))
            thr = float(thr_c[k]) if np.isfinite(thr_c[k]) else float(np.max(sq))
        self.threshold_ = thr
        self.false_touch_rate_ = float(np.mean(sq >= thr))
        self.missed_touch_rate_ = float(np.mean(st < thr))
        return self

    def predict(self, scores: np.ndarray) -> np.ndarray:
        return np.max(np.atleast_2d(scores), axis=1) >= self.threshold_
