"""Fingers and the people they belong to: contact patch, tissue impedance, press profiles."""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Subject", "make_subjects", "press_profile"]


@dataclasses.dataclass(frozen=True)
class Subject:
    """One simulated person's finger.

    radius_1n_m : contact radius at 1 N; the radius grows as ``(F / 1 N) ** radius_exp``
        (sub-linear, Hertz-like: 0.15-0.33).
    damping_1n : tissue damping at 1 N in N s / m (scales with contact area).
    mass_1n_kg : tissue mass moving with the wall at 1 N (scales with contact area).
    stiffness_1n : contact stiffness at 1 N in N / m (scales with radius).
    aim_bias_m : where this person habitually presses relative to a marker (x, y).
    aim_jitter_m : spread of single presses around that point.
    max_force_n : typical peak force of this person's presses.
    """

    name: str
    radius_1n_m: float
    radius_exp: float
    damping_1n: float
    mass_1n_kg: float
    stiffness_1n: float
    aim_bias_m: tuple[float, float]
    aim_jitter_m: float
    max_force_n: float

    def radius_m(self, force_n: np.ndarray) -> np.ndarray:
        return self.radius_1n_m * np.power(np.maximum(force_n, 1e-3), self.radius_exp)

    def dynamic_stiffness(self, force_n: np.ndarray, f_hz: np.ndarray) -> np.ndarray:
        """``K(w) = k_c + i w c - w^2 m`` per chirp and frequency, shape (n, n_f); zero where F = 0."""
        F = np.atleast_1d(np.asarray(force_n, float))
        area = (self.radius_m(F) / self.radius_1n_m) ** 2  # relative contact area
        w = 2 * np.pi * np.asarray(f_hz, float)
        K = (self.stiffness_1n * np.sqrt(area))[:, None] + 1j * w * (self.damping_1n * area)[:, None] \
            - w ** 2 * (self.mass_1n_kg * area)[:, None]
        return np.where((F > 0)[:, None], K, 0).astype(np.complex64)


def make_subjects(n: int = 12, seed: int = 1234) -> list[Subject]:
    """``n`` distinct people; subject 0 is the median finger that presses where it aims."""
    rng = np.random.default_rng(seed)
    out = [Subject("s00", 5.5e-3, 0.25, 40.0, 0.10e-3, 3e3, (0.0, 0.0), 0.8e-3, 6.0)]
    for i in range(1, n):
        out.append(Subject(
            name=f"s{i:02d}",
            radius_1n_m=float(rng.uniform(4.5e-3, 6.5e-3)),
            radius_exp=float(rng.uniform(0.15, 0.33)),
            damping_1n=float(rng.uniform(25.0, 60.0)),
            mass_1n_kg=float(rng.uniform(0.05e-3, 0.15e-3)),
            stiffness_1n=float(rng.uniform(1.5e3, 5e3)),
            aim_bias_m=(float(rng.normal(0, 1.2e-3)), float(rng.normal(0, 1.2e-3))),
            aim_jitter_m=float(rng.uniform(0.5e-3, 1.5e-3)),
            max_force_n=float(rng.uniform(3.0, 9.0)),
        ))
    return out


def press_profile(n_chirps: int, *, peak_n: float, rng: np.random.Generator, ramp_frac: float = 0.2,
                  wobble: float = 0.35) -> np.ndarray:
    """Press-hold-release force trace in N over ``n_chirps`` chirps: a smooth ramp up, a hold
    that wanders ("touch with varying force"), a ramp down to zero."""
    t = np.linspace(0, 1, n_chirps)
    r = max(ramp_frac, 1.0 / n_chirps)
    env = np.clip(np.minimum(t / r, (1 - t) / r), 0, 1)
    env = 0.5 - 0.5 * np.cos(np.pi * env)  # raised-cosine ramps
    phase = rng.uniform(0, 2 * np.pi, 2)
    hold = 1 + wobble * (0.6 * np.sin(2 * np.pi * 1.3 * t + phase[0]) + 0.4 * np.sin(2 * np.pi * 2.9 * t + phase[1]))
    return np.clip(peak_n * env * hold, 0, None)
