"""Augmentation along what varies between presses at one marker, measured from the user's own session.

:class:`Augmenter` draws new touch chirps along the nuisance directions a later press will move along, each measured
from the training session itself or fixed by physics, never from a test session (:data:`AUGMENTATIONS`).  All work
on relative dB over every usable bin; the model's inputs are selected afterwards."""

from __future__ import annotations

import numpy as np

from sonicskin.selection import press_ids

__all__ = ["AUGMENTATIONS", "Augmenter", "make_augmenter", "neighbour_rings"]

#: augmentations and their default size (see the module notes)
AUGMENTATIONS = {"press": 0.5, "strength": 0.25, "aim": 0.15, "stretch": 1e-3, "gain": 0.3, "tilt": 0.3, "motion": 1.0}


def neighbour_rings(positions_cm, K: int, circumference_cm: float | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each marker's nearest ring of neighbours (at most 4, within 1.5 x the nearest distance) and their distances (cm)."""
    P = np.asarray(positions_cm, np.float64)
    if P.shape != (K, 2):
        raise ValueError(f"positions_cm must be ({K}, 2), one (x, y) per marker in label order, got {P.shape}")
    dx, dy = np.abs(P[:, None, 0] - P[None, :, 0]), np.abs(P[:, None, 1] - P[None, :, 1])
    if circumference_cm:
        dx = np.minimum(dx, circumference_cm - dx)
    D = np.hypot(dx, dy)
    rings = []
    for k in range(K):
        others = np.argsort(D[k])[1:]
        near = np.array([j for j in others if D[k, j] <= D[k, others[0]] * 1.5][:4], int)
        rings.append((near, D[k, near]))
    return rings



class Augmenter:
    """Draws one augmented copy of every training touch chirp per call: ``X`` (n, D) relative dB over every usable
    bin, ``y`` marker labels and ``press`` ids per chirp; draws returned over ``cols``.  ``freqs_hz`` (D,) for
    ``stretch`` and ``tilt``; ``X_rest`` (m, D) hands-off chirps for ``motion``; ``positions_cm`` (K, 2) in the order
    of ``np.unique(y)`` (and ``circumference_cm``) for ``aim``; ``sizes``: :data:`AUGMENTATIONS` (zero: off)."""

    def __init__(self, X, y, press, *, cols=None, freqs_hz=None, X_rest=None, positions_cm=None,
                 circumference_cm: float | None = None, sizes: dict | None = None):
        self.X = np.asarray(X, np.float64)
        self.y = np.asarray(y)
        self.press = np.asarray(press)
        n, D = self.X.shape
        if self.y.shape != (n,) or self.press.shape != (n,):
            raise ValueError(f"X has {n} chirps but y {self.y.shape} and press {self.press.shape}; give one label and press id per chirp")
        self.cols = np.arange(D) if cols is None else np.asarray(cols, int)
        self.sizes = dict(AUGMENTATIONS if sizes is None else sizes)
        unknown = set(self.sizes) - set(AUGMENTATIONS)
        if unknown:
            raise ValueError(f"unknown augmentations {sorted(unknown)}; choose from {sorted(AUGMENTATIONS)}")
        self.classes, self.yi = np.unique(self.y, return_inverse=True)
        K = len(self.classes)
        self.means = np.stack([self.X[self.yi == k].mean(axis=0) for k in range(K)])
        # rows of the same press, for the force-ramp draws
        self._same = {p: np.flatnonzero(self.press == p) for p in np.unique(self.press)}
        self.f = None if freqs_hz is None else np.asarray(freqs_hz, np.float64)
        if self.f is not None and self.f.shape != (D,):
            raise ValueError(f"freqs_hz must give the frequency of each of the {D} columns, got shape {self.f.shape}")
        if self.f is not None:
            self._order = np.argsort(self.f, kind="stable")
            self._fs = self.f[self._order]
        for need, what in (("stretch", self.f), ("tilt", self.f)):
            if self.sizes.get(need) and what is None:
                raise ValueError(f"the {need} augmentation needs freqs_hz")
        self.rest = None
        if X_rest is not None and len(X_rest) >= 2:
            R = np.asarray(X_rest, np.float64)
            self.rest = R - R.mean(axis=0)
        self.neigh: list[tuple[np.ndarray, np.ndarray]] = []
        if positions_cm is not None:
            self.neigh = neighbour_rings(positions_cm, K, circumference_cm)

    def draw(self, rng: np.random.Generator, rows: np.ndarray | None = None) -> np.ndarray:
        """Augmented copies of the touch chirps ``rows`` (default: all), over the input columns."""
        rows = np.arange(len(self.X)) if rows is None else np.asarray(rows, int)
        X = self.X[rows].copy()
        s = self.sizes
        n, D = X.shape
        if s.get("press"):
            e = s["press"]
            j = np.array([rng.choice(self._same[p]) for p in self.press[rows]])
            lam = rng.uniform(-e, 1 + e, n)[:, None]
            X = X + lam * (self.X[j] - X)
        if s.get("strength"):
            X *= np.exp(rng.normal(0.0, s["strength"], n))[:, None]
        if s.get("aim") and self.neigh:
            for i, k in enumerate(self.yi[rows]):
                near, dist = self.neigh[k]
                if near.size:
                    m = rng.integers(near.size)
                    a = min(1.0, abs(rng.normal(0.0, s["aim"] / dist[m])))
                    X[i] += a * (self.means[near[m]] - self.means[k])
        if s.get("stretch") and self.f is not None:
            st = rng.uniform(-s["stretch"], s["stretch"], n)
            Xo = X[:, self._order]
            for i in range(n):
                Xo[i] = np.interp(self._fs * (1.0 + st[i]), self._fs, Xo[i])
            X[:, self._order] = Xo
        if self.f is not None and (s.get("gain") or s.get("tilt")):
            u = (self.f - self.f.mean()) / max(np.ptp(self.f), 1e-12)
            g, t = (rng.normal(0.0, s.get(k, 0.0) or 0.0, n)[:, None] for k in ("gain", "tilt"))
            X += g + t * u[None, :]
        elif s.get("gain"):
            X += rng.normal(0.0, s["gain"], n)[:, None]
        if s.get("motion") and self.rest is not None:
            pick = rng.integers(len(self.rest), size=n)
            X += rng.uniform(0.0, s["motion"], n)[:, None] * self.rest[pick]
        return X[:, self.cols]


def make_augmenter(data, rows: np.ndarray, *, n_cols: int | None = None, sizes: dict | None = None):
    """The augmenter of one training session's touch chirps, and each of ``rows``' row in it (-1: not a touch chirp)."""
    t = data.table
    rows = np.asarray(rows, bool)
    n_loc = data.n_locations
    touch = rows & (data.cls < n_loc)
    seg = t["segment"] if "segment" in t.labels else None
    press = press_ids(t["location"], t["session"], seg)
    sessions = np.isin(t["session"], sorted(set(t["session"][rows])))
    hands_off = sessions & (data.cls == n_loc)
    moving = hands_off & (t["moving"] > 0)
    rest = moving if moving.sum() >= 10 else hands_off & data.usable
    cls_touch = data.cls[touch]
    freqs = data.rig.freqs_hz[data.rig.band_bins][list(data.spec.bins)]
    aug = Augmenter(data.X[touch], cls_touch, press[touch], cols=np.arange(n_cols or data.X.shape[1]), freqs_hz=freqs,
                    X_rest=data.X[rest] if rest.sum() >= 2 else None,
                    positions_cm=data.layout.xy_cm[np.unique(cls_touch)], circumference_cm=data.layout.circumference_cm,
                    sizes=sizes)
    pos = np.full(len(rows), -1)
    pos[np.flatnonzero(touch)] = np.arange(int(touch.sum()))
    return aug, pos[np.flatnonzero(rows)]
