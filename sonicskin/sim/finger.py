"""Fingers and the people they belong to: contact patch, tissue impedance, press profiles.

What a fingertip presents to the wall at 20-80 kHz, and how it changes with force and time.  The ranges and their
sources (Serina et al., Dzidek et al., Pawluk & Howe): docs/simulator.md."""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Subject", "make_subjects", "press_profile"]


@dataclasses.dataclass(frozen=True)
class Subject:
    """One simulated person's finger: its contact and tissue at 1 N and how they grow with force, its aim and peak force."""

    name: str
    radius_1n_m: float
    radius_exp: float
    damping_1n: float
    mass_1n_kg: float
    stiffness_1n: float
    aim_bias_m: tuple[float, float]
    aim_jitter_m: float
    max_force_n: float
    damping_exp: float = 0.8
    occlusion_tau_s: float = 5.0
    occlusion_r0: float = 0.55

    def radius_m(self, force_n: np.ndarray) -> np.ndarray:
        return self.radius_1n_m * np.power(np.maximum(force_n, 1e-3), self.radius_exp)

    def force_at_radius(self, radius_m: np.ndarray) -> np.ndarray:
        return np.power(np.asarray(radius_m, float) / self.radius_1n_m, 1 / self.radius_exp)

    def occlusion(self, held_s: np.ndarray) -> np.ndarray:
        """Share of the saturated real contact after ``held_s`` seconds of contact, ``g(t)``."""
        t = np.maximum(np.asarray(held_s, float), 0)
        return 1 - (1 - self.occlusion_r0) * np.exp(-t / self.occlusion_tau_s)

    def dynamic_stiffness(self, force_n: np.ndarray, f_hz: np.ndarray, occlusion: np.ndarray | float = 1.0) -> np.ndarray:
        """``K(w) = k(F) + i w c(F, t) - w^2 m(F)`` (n, n_f), zero where F = 0; ``occlusion``: the press's ``g(t)``."""
        F = np.atleast_1d(np.asarray(force_n, float))
        Fp = np.maximum(F, 1e-3)
        area = (self.radius_m(F) / self.radius_1n_m) ** 2  # relative gross contact area
        w = 2 * np.pi * np.asarray(f_hz, float)
        k = self.stiffness_1n * (0.2 + 0.8 * Fp)
        c = self.damping_1n * np.power(Fp, self.damping_exp) * np.broadcast_to(np.asarray(occlusion, float), F.shape)
        K = k[:, None] + 1j * w * c[:, None] - w ** 2 * (self.mass_1n_kg * area)[:, None]
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
    # Drawn from their own stream, so the people above stay who they were.
    rng2 = np.random.default_rng([seed, 2])
    for i in range(1, n):
        out[i] = dataclasses.replace(out[i], damping_exp=float(rng2.uniform(0.6, 1.0)),
                                     occlusion_tau_s=float(rng2.uniform(3.0, 8.0)), occlusion_r0=float(rng2.uniform(0.4, 0.7)))
    return out


def press_profile(n_chirps: int, *, peak_n: float, rng: np.random.Generator, ramp_frac: float = 0.2,
                  wobble: float = 0.35) -> np.ndarray:
    """Press-hold-release force trace in N over ``n_chirps`` chirps: ramp up, a wandering hold, ramp down to zero."""
    t = np.linspace(0, 1, n_chirps)
    r = max(ramp_frac, 1.0 / n_chirps)
    env = np.clip(np.minimum(t / r, (1 - t) / r), 0, 1)
    env = 0.5 - 0.5 * np.cos(np.pi * env)  # raised-cosine ramps
    phase = rng.uniform(0, 2 * np.pi, 2)
    hold = 1 + wobble * (0.6 * np.sin(2 * np.pi * 1.3 * t + phase[0]) + 0.4 * np.sin(2 * np.pi * 2.9 * t + phase[1]))
    return np.clip(peak_n * env * hold, 0, None)
