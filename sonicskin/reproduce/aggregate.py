"""Numbers over several simulator seeds: a mean that remembers its spread."""

from __future__ import annotations

import numpy as np

__all__ = ["Spread", "aggregate", "pool"]


class Spread(float):
    """A mean over simulator seeds that remembers its spread: ``f"{x:.1%}"`` gives ``"95.1% +- 1.2%"``."""

    def __new__(cls, values):
        v = np.asarray(values, float)
        obj = super().__new__(cls, float(np.mean(v)))
        obj.std = float(np.std(v))
        obj.values = [float(x) for x in v]
        return obj

    def __format__(self, spec: str) -> str:
        if len(self.values) < 2 or self.std <= 1e-9 * max(1.0, abs(float(self))):
            return format(float(self), spec)
        return f"{format(float(self), spec)} +- {format(self.std, spec)}"


def aggregate(runs: list):
    """Combine several seeds' results: numbers become :class:`Spread`, confusion matrices summed, error lists pooled."""
    first = runs[0]
    if isinstance(first, dict):
        return {k: aggregate([r[k] for r in runs]) for k in first if all(isinstance(r, dict) and k in r for r in runs)}
    if isinstance(first, (bool, np.bool_)):
        return first
    if isinstance(first, (int, float, np.integer, np.floating)):
        return Spread([float(r) for r in runs])
    if isinstance(first, np.ndarray) and first.ndim == 2 and all(np.shape(r) == first.shape for r in runs):
        return np.sum(runs, axis=0)  # confusion matrices
    if isinstance(first, np.ndarray) and first.ndim == 1:
        return np.concatenate(runs)  # per-press errors: pooled
    if isinstance(first, list) and first and all(isinstance(x, (int, float, np.floating)) for x in first) \
            and all(isinstance(r, list) and len(r) == len(first) for r in runs):
        return [Spread([r[i] for r in runs]) for i in range(len(first))]
    return first


def pool(v) -> list[float]:
    """All per-seed values behind a list of Spreads (or plain numbers)."""
    return [x for s in v for x in (s.values if isinstance(s, Spread) else [float(s)])]
