"""Scenario configs: what happens on the simulated rig, chirp by chirp.

A scenario (``configs/scenarios/<name>.yaml``) sets the link (material, geometry, transducer
positions), the touch layout, who touches, how hard, whether the robot moves, and how the
temperature evolves.  :func:`build_timeline` turns it into a per-chirp table of ground truth;
:class:`sonicskin.sim.simulator.Simulator` renders that table into received audio.

Each *session* is one continuous recording: ``calibration_s`` of no-touch (Alg. 2's beta),
``moving_s`` of no-touch while the robot moves (OSPA's moving variance; only when motion is
on), then one press-hold-release at each location (``repeats`` times, in random order) with
``gap_s`` of no-touch between presses.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ..rig import Layout, Rig, _resolve_config, check_keys, load_yaml
from .finger import make_subjects, press_profile

__all__ = ["Scenario", "Timeline", "build_timeline", "SEGMENTS"]

SEGMENTS = ("calibration", "moving", "touch", "gap")


@dataclasses.dataclass(frozen=True)
class Scenario:
    name: str = "stationary"
    material: str = "cfrp"
    geometry: dict = dataclasses.field(default_factory=lambda: {"kind": "tube", "radius_cm": 3.75, "length_cm": 25.0})
    tx_cm: tuple = (0.0, 2.5)
    rx_cm: tuple = (5.9, 22.5)
    layout: dict = dataclasses.field(default_factory=lambda: {
        "kind": "rings", "counts": [16, 15], "spacing_cm": 1.2, "x0_cm": 2.4, "y0_cm": 11.9})
    sessions: int = 3
    repeats: int = 1
    train_repeats: int | None = None  # presses per location in the first (one-shot training) session; None: repeats
    touch_s: float = 3.0
    gap_s: float = 0.5
    calibration_s: float = 3.0
    moving_s: float = 10.0
    session_interval_s: float = 600.0
    start_s: float = 3600.0
    subjects: tuple = (0,)
    subject_per_session: bool = False
    order: str = "random"  # "random" or "sequential" (the guided recording prompts in order)
    peak_force_n: tuple = (1.0, 10.0)
    motion: dict = dataclasses.field(default_factory=lambda: {"enabled": False})
    temperature: dict = dataclasses.field(default_factory=lambda: {
        "ambient_c": 23.0, "warmup_c": 5.6, "warmup_tau_s": 5400.0, "swing_c": 0.0, "swing_period_s": 86400.0,
        "gradient": 0.5, "lag": 0.6})
    noise: dict = dataclasses.field(default_factory=dict)
    bond: dict = dataclasses.field(default_factory=dict)  # HotMeltBond overrides (sonicskin.sim.thermal)
    channel: dict = dataclasses.field(default_factory=dict)
    part_s: float = 20.0
    seed: int = 0
    link_seed: int = 7

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scenario:
        check_keys(cls, d, "scenario")
        d = dict(d)
        _check_types(cls, d)
        for k in ("tx_cm", "rx_cm", "subjects", "peak_force_n"):
            if k in d:
                d[k] = tuple(d[k])
        sc = cls(**d)
        sc.validate()
        return sc

    @classmethod
    def load(cls, name_or_path: str | Path) -> Scenario:
        return cls.from_dict(load_yaml(_resolve_config(name_or_path, "scenarios")))

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for k in ("tx_cm", "rx_cm", "subjects", "peak_force_n"):
            d[k] = list(d[k])
        return d

    def replace(self, **kw) -> Scenario:
        return dataclasses.replace(self, **kw)

    def validate(self) -> None:
        if self.sessions < 1 or self.repeats < 1 or (self.train_repeats is not None and self.train_repeats < 1):
            raise ValueError("sessions, repeats and train_repeats must be >= 1")
        if not 0 < self.peak_force_n[0] <= self.peak_force_n[1]:
            raise ValueError(f"peak_force_n must be (low, high) with 0 < low <= high, got {self.peak_force_n}")
        if any(not 0 <= s < 12 for s in self.subjects):
            raise ValueError(f"subjects are indices 0..11 of the 12 simulated people, got {list(self.subjects)}")
        if self.order not in ("random", "sequential"):
            raise ValueError(f"order must be 'random' or 'sequential', got {self.order!r}")
        from .thermal import HotMeltBond

        check_keys(HotMeltBond, self.bond, "bond")
        if self.touch_s <= 0 or self.calibration_s <= 0:
            raise ValueError("touch_s and calibration_s must be positive")
        if min(self.gap_s, self.moving_s, self.session_interval_s, self.start_s) < 0 or self.part_s <= 0:
            raise ValueError("gap_s, moving_s, session_interval_s and start_s must be >= 0 and part_s > 0")
        layout_count(self)
        level = self.motion.get("level", 1.0)
        if isinstance(level, bool) or not isinstance(level, (int, float)) or not 0 <= level <= 1:
            raise ValueError(f"motion.level is the robot's motion level in [0, 1], got {level!r}")

    def make_layout(self) -> Layout:
        lay = dict(self.layout)
        kind = lay.pop("kind", "rings")
        circ = self.circumference_cm
        if kind == "rings":
            return Layout.rings(tuple(lay.get("counts", (16, 15))), lay.get("spacing_cm", 1.2),
                                circumference_cm=circ, x0_cm=lay.get("x0_cm", 0.0), y0_cm=lay.get("y0_cm", 0.0))
        if kind == "grid":
            return Layout.grid(lay["nx"], lay["ny"], lay["spacing_cm"], lay.get("x0_cm", 0.0), lay.get("y0_cm", 0.0),
                               circumference_cm=circ)
        raise ValueError(f"layout kind must be 'rings' or 'grid', got {kind!r}")

    @property
    def circumference_cm(self) -> float | None:
        g = self.geometry
        return 2 * np.pi * g["radius_cm"] if g.get("kind", "tube") == "tube" else None

    def temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        """Link temperature at time ``t_s`` since power-on: warm-up plus a slow ambient swing."""
        T = self.temperature
        t = np.asarray(t_s, float)
        return (T.get("ambient_c", 23.0) + T.get("warmup_c", 0.0) * (1 - np.exp(-t / T.get("warmup_tau_s", 5400.0)))
                + T.get("swing_c", 0.0) * np.sin(2 * np.pi * t / T.get("swing_period_s", 86400.0)))


@dataclasses.dataclass
class Timeline:
    """Per-chirp ground truth (all arrays of length n_chirps)."""

    session: np.ndarray
    chirp: np.ndarray          # index within the session
    time_s: np.ndarray         # since power-on
    segment: np.ndarray        # index into SEGMENTS
    event: np.ndarray          # press id, -1 for no touch
    location: np.ndarray       # location id, -1 for no touch
    x_cm: np.ndarray
    y_cm: np.ndarray
    force_n: np.ndarray
    moving: np.ndarray         # motion level 0..1
    temperature_c: np.ndarray
    subject: np.ndarray

    def __len__(self) -> int:
        return self.session.size

    def select(self, mask: np.ndarray) -> Timeline:
        return Timeline(**{f.name: getattr(self, f.name)[mask] for f in dataclasses.fields(self)})


def _motion_level(rng: np.random.Generator, n: int, cps: float) -> np.ndarray:
    """Smooth random joint speed in [0.25, 1]: the robot reaching random end-effector poses."""
    a = np.exp(-1.0 / (1.5 * cps))  # ~1.5 s correlation
    e = rng.standard_normal(n) * np.sqrt(1 - a * a)
    x = np.empty(n)
    acc = rng.standard_normal()
    for i in range(n):  # AR(1); n is the session length, cheap
        acc = a * acc + e[i]
        x[i] = acc
    return 0.25 + 0.75 / (1 + np.exp(-1.5 * x))


def build_timeline(sc: Scenario, rig: Rig) -> Timeline:
    """Ground truth for every chirp of every session of ``sc`` (deterministic in ``sc.seed``)."""
    check_size(sc, rig)
    rng = np.random.default_rng([sc.seed, 101])
    layout = sc.make_layout()
    subjects = make_subjects()
    cps = rig.chirps_per_s
    moving_on = bool(sc.motion.get("enabled", False))
    cols: dict[str, list] = {f.name: [] for f in dataclasses.fields(Timeline)}
    event = 0
    for s in range(sc.sessions):
        if sc.subject_per_session:
            subj_ids = [sc.subjects[s % len(sc.subjects)]]
        else:
            subj_ids = list(sc.subjects)
        segs: list[tuple[str, int, int, float, float, np.ndarray]] = []  # (segment, n, loc, x, y, force)
        segs.append(("calibration", rig.seconds_to_chirps(sc.calibration_s), -1, np.nan, np.nan, None))
        if moving_on and sc.moving_s > 0:
            segs.append(("moving", rig.seconds_to_chirps(sc.moving_s), -1, np.nan, np.nan, None))
        n_touch = rig.seconds_to_chirps(sc.touch_s)
        reps = sc.repeats if (s > 0 or sc.train_repeats is None) else sc.train_repeats
        order = [(loc, subj) for loc in range(len(layout)) for subj in subj_ids for _ in range(reps)]
        if sc.order == "random":
            rng.shuffle(order)
        subj_of_seg = []
        for loc_idx, subj in order:
            who = subjects[subj]
            peak = rng.uniform(*sc.peak_force_n) * who.max_force_n / 6.0
            F = press_profile(n_touch, peak_n=peak, rng=rng)
            aim = np.array(who.aim_bias_m) + rng.normal(0, who.aim_jitter_m, 2)
            x, y = layout.xy_cm[loc_idx] + aim * 100
            segs.append(("touch", n_touch, layout.ids[loc_idx], x, y, F))
            subj_of_seg.append(subj)
            if sc.gap_s > 0:
                segs.append(("gap", rig.seconds_to_chirps(sc.gap_s), -1, np.nan, np.nan, None))
        t0 = sc.start_s + s * sc.session_interval_s
        k = 0
        si = 0
        n_session = sum(seg[1] for seg in segs)
        level = _motion_level(rng, n_session, cps) * float(sc.motion.get("level", 1.0)) if moving_on else np.zeros(n_session)
        for seg, n, loc, x, y, F in segs:
            idx = np.arange(k, k + n)
            cols["session"].append(np.full(n, s))
            cols["chirp"].append(idx)
            cols["time_s"].append(t0 + idx / cps)
            cols["segment"].append(np.full(n, SEGMENTS.index(seg)))
            touching = seg == "touch"
            cols["event"].append(np.full(n, event if touching else -1))
            cols["location"].append(np.full(n, loc))
            cols["x_cm"].append(np.full(n, x))
            cols["y_cm"].append(np.full(n, y))
            cols["force_n"].append(F if touching else np.zeros(n))
            lv = level[idx]
            if seg == "calibration":
                lv = np.zeros(n)  # Alg. 2's calibration chirps are taken with the robot at rest
            cols["moving"].append(lv)
            subj = subj_of_seg[si] if touching else (subj_ids[0])
            cols["subject"].append(np.full(n, subj))
            if touching:
                event += 1
                si += 1
            k += n
    arrays = {name: np.concatenate(v) for name, v in cols.items() if name != "temperature_c"}
    arrays["temperature_c"] = sc.temperature_c(arrays["time_s"])
    return Timeline(**arrays)


def _check_types(cls, d: dict) -> None:
    """Numbers where the scenario has numbers (finite), whole numbers where it has counts: one line each."""
    import math

    for f in dataclasses.fields(cls):
        if f.name not in d:
            continue
        v, default = d[f.name], f.default
        if isinstance(default, bool):
            continue
        if f.name in ("sessions", "repeats", "seed", "link_seed") or (f.name == "train_repeats" and v is not None):
            if isinstance(v, bool) or not isinstance(v, int):
                raise ValueError(f"scenario {f.name} must be a whole number, got {v!r}")
        elif isinstance(default, float):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"scenario {f.name} must be a finite number, got {v!r}")
        elif f.name in ("tx_cm", "rx_cm", "peak_force_n"):
            if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
                raise ValueError(f"scenario {f.name} must be a list of two finite numbers, got {v!r}")
        elif f.name == "subjects":
            if not (isinstance(v, (list, tuple)) and v and all(isinstance(x, int) and not isinstance(x, bool) for x in v)):
                raise ValueError(f"scenario subjects must be a non-empty list of whole numbers, got {v!r}")
        elif isinstance(f.default, str) or f.name == "name":
            if not isinstance(v, str):
                raise ValueError(f"scenario {f.name} must be a text, got {v!r}")
        elif f.default is dataclasses.MISSING and not isinstance(v, dict):
            raise ValueError(f"scenario {f.name} must be a mapping {{key: value}}, got {v!r}")


MAX_LOCATIONS = 100_000


def layout_count(sc: Scenario) -> int:
    """Markers of the scenario's layout, counted from its settings (before building it)."""
    lay = sc.layout
    kind = lay.get("kind", "rings")
    try:
        n = sum(int(c) for c in lay.get("counts", (16, 15))) if kind == "rings" else int(lay["nx"]) * int(lay["ny"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"layout {lay!r}: rings need counts [n, ...], a grid nx and ny (whole numbers)") from None
    if not 1 <= n <= MAX_LOCATIONS:
        raise ValueError(f"the layout has {n} markers; a scenario has 1..{MAX_LOCATIONS}")
    return n


def session_chirps(sc: Scenario, rig: Rig) -> tuple[int, int]:
    """Chirps of the first session and of each other one, from the settings alone (what
    :func:`build_timeline` will make)."""
    n_loc = layout_count(sc)
    per = rig.seconds_to_chirps(sc.touch_s) + (rig.seconds_to_chirps(sc.gap_s) if sc.gap_s > 0 else 0)
    head = rig.seconds_to_chirps(sc.calibration_s) + (
        rig.seconds_to_chirps(sc.moving_s) if sc.motion.get("enabled", False) and sc.moving_s > 0 else 0)
    subj = 1 if sc.subject_per_session else len(sc.subjects)
    first = sc.repeats if sc.train_repeats is None else sc.train_repeats
    return head + n_loc * subj * first * per, head + n_loc * subj * sc.repeats * per


def check_size(sc: Scenario, rig: Rig) -> int:
    """Refuse a scenario whose timeline or rendering would not fit in memory, before allocating anything.

    Returns the total number of chirps.  The estimate: ~256 bytes per chirp of ground truth (plus one
    press profile), and one rendering block (about 1024 chirps, or one part) of spectra and frames.
    """
    from ..limits import check_memory

    first, other = session_chirps(sc, rig)
    total = first + (sc.sessions - 1) * other
    fix = "shorten the scenario (sessions, repeats, touch_s, gap_s, moving_s, calibration_s, part_s)"
    check_memory(256.0 * total + 64.0 * rig.seconds_to_chirps(max(sc.touch_s, sc.moving_s)),
                 f"the ground truth of scenario {sc.name!r} ({total:.3g} chirps in {sc.sessions} sessions)", fix)
    per_part = rig.seconds_to_chirps(sc.part_s)
    block = min(max(first, other), per_part * max(1, 1024 // per_part))
    check_memory(64.0 * rig.n_chirp * block, f"rendering scenario {sc.name!r} in blocks of {block} chirps", fix)
    return int(total)
