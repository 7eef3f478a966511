"""Scenario configs: what happens on the simulated rig, chirp by chirp.

A scenario (``configs/scenarios/<name>.yaml``) sets the link, the touch layout, who touches, how hard, whether the
robot moves and the temperature; :func:`build_timeline` turns it into a per-chirp table of ground truth.  A session
is ``calibration_s`` of no-touch, ``moving_s`` of no-touch while the robot moves, then one press at each location
(``repeats`` times, in random order).  A scenario *family* (:class:`RandomFamily`) draws a whole scenario from a seed."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path
from typing import Any

import numpy as np

from ..dataset import TEMPERATURE_C, check_name
from ..errors import brief, check_memory, is_number
from ..rig import MAX_LOCATIONS, Layout, Rig, check_keys, load_yaml, resolve_config
from .channel import MATERIALS, ChannelModel
from .finger import make_subjects, press_profile
from .noise import NoiseConfig
from .thermal import HotMeltBond

__all__ = ["Scenario", "Timeline", "build_timeline", "SEGMENTS", "RandomFamily", "family_seeds", "is_family"]

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
    loss_factor: float | None = None  # the wall's eta; None: the material's (sonicskin.sim.channel.MATERIALS)

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
    def load(cls, name_or_path: str | Path, *, seed: int | None = None) -> Scenario:
        """A scenario YAML, ``seed`` replaced when given; a *family* (``family:``) draws a whole rig from ``seed``."""
        d = load_yaml(resolve_config(name_or_path, "scenarios"))
        if "family" in d:
            fam = RandomFamily.from_dict(d)
            return fam.draw(fam.design_seeds[0] if seed is None else int(seed))
        sc = cls.from_dict(d)
        return sc if seed is None else sc.replace(seed=int(seed))

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
            raise ValueError(f"order must be 'random' or 'sequential', got {brief(self.order)}")
        check_keys(HotMeltBond, self.bond, "bond")
        check_keys(NoiseConfig, self.noise, "noise")  # here, before a value of an unknown key is kept (and copied)
        if self.touch_s <= 0 or self.calibration_s <= 0:
            raise ValueError("touch_s and calibration_s must be positive")
        if min(self.gap_s, self.moving_s, self.session_interval_s, self.start_s) < 0 or self.part_s <= 0:
            raise ValueError("gap_s, moving_s, session_interval_s and start_s must be >= 0 and part_s > 0")
        _check_parts(self)
        layout_count(self)
        level = self.motion.get("level", 1.0)
        if not (is_number(level) and 0 <= level <= 1):
            raise ValueError(f"motion.level is the robot's motion level in [0, 1], got {brief(level)}")
        if self.loss_factor is not None and not 0 < self.loss_factor < 1:
            raise ValueError(f"loss_factor is the wall's eta, 0 < eta < 1, got {self.loss_factor}")

    def make_layout(self) -> Layout:
        """The markers (:func:`validate` checks that they lie on the wall)."""
        lay = dict(self.layout)
        kind = lay.pop("kind", "rings")
        circ = self.circumference_cm
        if (n := layout_count(self)) > MAX_MARKERS:
            raise ValueError(f"scenario {brief(self.name)}: layout has {n} markers, more than {MAX_MARKERS}; one link's skin "
                             f"holds tens of markers")
        if kind == "rings":
            layout = Layout.rings(tuple(lay.get("counts", (16, 15))), lay.get("spacing_cm", 1.2),
                                  circumference_cm=circ, x0_cm=lay.get("x0_cm", 0.0), y0_cm=lay.get("y0_cm", 0.0))
        elif kind == "grid":
            layout = Layout.grid(lay["nx"], lay["ny"], lay["spacing_cm"], lay.get("x0_cm", 0.0), lay.get("y0_cm", 0.0),
                                 circumference_cm=circ)
        else:
            raise ValueError(f"layout kind must be 'rings' or 'grid', got {brief(kind)}")
        return layout

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


#: markers one simulated link may hold (a layout of 10^6 built for minutes before anything was checked)
MAX_MARKERS = 1000


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
    t_free = -np.inf  # when the previous session's last chirp ended
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
        # Sessions start every session_interval_s, or when the one before ends if it ran longer: one link, one clock,
        # so a recording replayed from power-on as one stream is in time order.
        n_session = sum(seg[1] for seg in segs)
        t0 = max(sc.start_s + s * sc.session_interval_s, t_free)
        t_free = t0 + n_session / cps
        k = 0
        si = 0
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


def _float_text(v) -> bool:
    try:
        return isinstance(v, str) and bool(np.isfinite(float(v)))
    except ValueError:
        return False


def _check_types(cls, d: dict) -> None:
    """Numbers where the scenario has numbers (finite), whole numbers where it has counts: one line each."""
    for f in dataclasses.fields(cls):
        if f.name not in d:
            continue
        v, default = d[f.name], f.default
        if isinstance(default, bool):
            continue
        if f.name in ("sessions", "repeats", "seed", "link_seed") or (f.name == "train_repeats" and v is not None):
            if not is_number(v, integer=True) or (f.name.endswith("seed") and v < 0):
                raise ValueError(f"scenario {f.name} must be a whole number{' >= 0' * f.name.endswith('seed')}, got {brief(v)}")
        elif isinstance(default, float):
            if not is_number(v):
                hint = " (YAML reads a number without a dot, 1e-9, as text: write 1.0e-9)" if _float_text(v) else ""
                raise ValueError(f"scenario {f.name} must be a finite number, got {brief(v)}{hint}")
        elif f.name in ("tx_cm", "rx_cm", "peak_force_n"):
            if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(is_number(x) for x in v)):
                raise ValueError(f"scenario {f.name} must be a list of two finite numbers, got {brief(v)}")
        elif f.name == "subjects":
            if not (isinstance(v, (list, tuple)) and v and all(is_number(x, integer=True) for x in v)):
                raise ValueError(f"scenario subjects must be a non-empty list of whole numbers, got {brief(v)}")
        elif isinstance(f.default, str) or f.name == "name":
            if not isinstance(v, str):
                raise ValueError(f"scenario {f.name} must be a string, got {brief(v)}")
        elif f.default is dataclasses.MISSING and not isinstance(v, dict):
            raise ValueError(f"scenario {f.name} must be a mapping {{key: value}}, got {brief(v)}")


#: The keys of a scenario's mappings: name -> (required, optional).  Anything else is a typo that would
#: silently fall back to a default (``lenght_cm``, ``spacing``, ``ambient``).
_GEOMETRY_KEYS = {"tube": (("radius_cm", "length_cm"), ()), "plate": (("width_cm", "length_cm"), ())}
_LAYOUT_KEYS = {"rings": ((), ("counts", "spacing_cm", "x0_cm", "y0_cm")), "grid": (("nx", "ny", "spacing_cm"), ("x0_cm", "y0_cm"))}
_MOTION_KEYS = ("enabled", "level", "perturbation")
_TEMPERATURE_KEYS = ("ambient_c", "warmup_c", "warmup_tau_s", "swing_c", "swing_period_s", "gradient", "lag")
MIN_TX_RX_CM = 1.0  # the discs (5 mm bonded radius) cannot overlap
MAX_DISC_RADIUS_M = 0.05  # a piezo disc of 10 cm diameter is already large for a robot link


def _keys(what: str, d: dict, required, optional, kind: bool = False) -> None:
    valid = {*required, *optional} | ({"kind"} if kind else set())
    unknown = sorted(set(d) - valid, key=str)
    if unknown:
        raise ValueError(f"unknown {what} keys {unknown}; valid keys: {sorted(valid)}")
    missing = [k for k in required if k not in d]
    if missing:
        raise ValueError(f"{what} {brief(d)} lacks {missing}")


def _field_values(what: str, d: dict, cls, *, positive, nonneg) -> None:
    """Values overriding dataclass ``cls``: whole numbers >= 0 for int fields, finite numbers (> 0, >= 0 where asked) else."""
    kinds = {f.name: type(f.default) for f in dataclasses.fields(cls)}
    for k, v in d.items():
        if kinds.get(k) is int:
            if not (is_number(v, integer=True) and v >= 0):
                raise ValueError(f"{what}.{k} must be a whole number >= 0, got {brief(v)}")
        elif k in kinds:
            if not is_number(v):
                raise ValueError(f"{what}.{k} must be a finite number, got {brief(v)}")
            if (k in positive and not v > 0) or (nonneg(k) and v < 0):
                raise ValueError(f"{what}.{k} must be {'> 0' if k in positive else '>= 0'}, got {brief(v)}")


def _check_parts(sc: Scenario) -> None:
    """The scenario's mappings: known keys, numbers where numbers go, sizes > 0, transducers apart, markers on the link."""
    check_name(sc.name, "scenario name")  # `simulate` writes to data/<name> by default: a name stays a name
    g = sc.geometry
    kind = g.get("kind", "tube")
    if not isinstance(kind, str) or kind not in _GEOMETRY_KEYS:
        raise ValueError(f"geometry kind must be 'tube' or 'plate', got {brief(kind)}")
    _keys(f"geometry ({kind})", g, *_GEOMETRY_KEYS[kind], kind=True)
    for k in _GEOMETRY_KEYS[kind][0]:
        if not (is_number(g[k]) and g[k] > 0):
            raise ValueError(f"geometry {k} must be a positive number of cm, got {brief(g[k])}")
    lay = sc.layout
    lkind = lay.get("kind", "rings")
    if not isinstance(lkind, str) or lkind not in _LAYOUT_KEYS:
        raise ValueError(f"layout kind must be 'rings' or 'grid', got {brief(lkind)}")
    _keys(f"layout ({lkind})", lay, *_LAYOUT_KEYS[lkind], kind=True)
    if lkind == "grid":
        counts = [lay["nx"], lay["ny"]]
    else:
        rings = lay.get("counts", [16, 15])
        counts = list(rings) if isinstance(rings, (list, tuple)) and rings else [None]
    if not all(is_number(c, integer=True) and c >= 1 for c in counts):
        raise ValueError(f"layout {brief(lay)}: marker counts (counts, nx, ny) are whole numbers >= 1")
    for k in ("spacing_cm", "x0_cm", "y0_cm"):
        if k in lay and not is_number(lay[k]):
            raise ValueError(f"layout {k} must be a number of cm, got {brief(lay[k])}")
    if "spacing_cm" in lay and not lay["spacing_cm"] > 0:
        raise ValueError(f"layout spacing_cm must be > 0 (markers apart), got {brief(lay['spacing_cm'])}")
    _keys("motion", sc.motion, (), _MOTION_KEYS)
    if not isinstance(sc.motion.get("enabled", False), bool):
        raise ValueError(f"motion.enabled must be true or false, got {brief(sc.motion['enabled'])}")
    if "perturbation" in sc.motion and not (is_number(sc.motion["perturbation"]) and sc.motion["perturbation"] >= 0):
        raise ValueError(f"motion.perturbation must be a number >= 0, got {brief(sc.motion['perturbation'])}")
    _keys("temperature", sc.temperature, (), _TEMPERATURE_KEYS)
    for k, v in sc.temperature.items():
        if not is_number(v):
            raise ValueError(f"temperature.{k} must be a finite number, got {brief(v)}")
    for k in ("warmup_tau_s", "swing_period_s"):
        if k in sc.temperature and not sc.temperature[k] > 0:
            raise ValueError(f"temperature.{k} must be > 0 s, got {brief(sc.temperature[k])}")

    T = sc.temperature
    lo = T.get("ambient_c", 23.0) + min(0.0, T.get("warmup_c", 0.0)) - abs(T.get("swing_c", 0.0))
    hi = T.get("ambient_c", 23.0) + max(0.0, T.get("warmup_c", 0.0)) + abs(T.get("swing_c", 0.0))
    if lo < TEMPERATURE_C[0] or hi > TEMPERATURE_C[1]:
        raise ValueError(f"temperature: ambient_c, warmup_c and swing_c reach {lo:g}..{hi:g} C, outside the "
                         f"{TEMPERATURE_C[0]:g}..{TEMPERATURE_C[1]:g} C a link can be at; give degrees Celsius")
    allowed = [n for n, prm in inspect.signature(ChannelModel).parameters.items() if prm.kind is prm.KEYWORD_ONLY
               and n not in ("tx_m", "rx_m", "seed")]
    _keys("channel", sc.channel, (), allowed)
    for k, v in sc.channel.items():
        if not (is_number(v) and v >= 0):
            raise ValueError(f"channel.{k} must be a number >= 0, got {brief(v)}")
    _field_values("noise", sc.noise, NoiseConfig, positive=(), nonneg=lambda k: k.endswith(("_rms", "_hz", "_per_chirp")))
    _field_values("bond", sc.bond, HotMeltBond, positive=("fr_hz", "tan_delta"), nonneg=lambda k: False)
    r = sc.channel.get("transducer_radius_m", 5e-3)
    if not 0 < r <= MAX_DISC_RADIUS_M:
        raise ValueError(f"channel.transducer_radius_m is the piezo discs' bonded radius in metres, 0 < r <= {MAX_DISC_RADIUS_M:g}, "
                         f"got {brief(r)}")
    if len(set(sc.subjects)) != len(sc.subjects):
        raise ValueError(f"subjects {list(sc.subjects)} name a person twice; list each simulated person once")
    apart = max(MIN_TX_RX_CM, 2 * r * 100)
    if float(np.hypot(*(np.subtract(sc.tx_cm, sc.rx_cm)))) < apart:
        raise ValueError(f"tx_cm {list(sc.tx_cm)} and rx_cm {list(sc.rx_cm)} are less than {apart:g} cm apart; the two "
                         f"discs cannot overlap: place the receiver elsewhere")
    if layout_count(sc) <= 10_000:  # building a huge layout here would cost what check_size guards against
        xy = sc.make_layout().xy_cm
        length = g["length_cm"]
        width = sc.circumference_cm if kind == "tube" else g["width_cm"]  # round a tube, x past it lands on other markers
        out = (xy[:, 1] < 0) | (xy[:, 1] > length) | (xy[:, 0] < 0) | (xy[:, 0] > width + 1e-9)
        if np.any(out):
            k = int(np.flatnonzero(out)[0])
            raise ValueError(f"layout marker {k} at ({xy[k, 0]:g}, {xy[k, 1]:g}) cm lies outside the {kind} "
                             f"(x 0..{width:.4g}{' round it' if kind == 'tube' else ''}, y 0..{length:g} cm); "
                             f"move the layout (x0_cm, y0_cm, spacing_cm) or use fewer markers")


def layout_count(sc: Scenario) -> int:
    """Markers of the scenario's layout, counted from its settings (before building it)."""
    lay = sc.layout
    kind = lay.get("kind", "rings")
    try:
        n = sum(int(c) for c in lay.get("counts", (16, 15))) if kind == "rings" else int(lay["nx"]) * int(lay["ny"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"layout {brief(lay)}: rings need counts [n, ...], a grid nx and ny (whole numbers)") from None
    if not 1 <= n <= MAX_LOCATIONS:
        raise ValueError(f"the layout has {n} markers; a scenario has 1..{MAX_LOCATIONS}")
    return n


def session_chirps(sc: Scenario, rig: Rig) -> tuple[int, int]:
    """Chirps of the first session and of each other one, from the settings alone (what :func:`build_timeline` will make)."""
    n_loc = layout_count(sc)
    per = rig.seconds_to_chirps(sc.touch_s) + (rig.seconds_to_chirps(sc.gap_s) if sc.gap_s > 0 else 0)
    head = rig.seconds_to_chirps(sc.calibration_s) + (
        rig.seconds_to_chirps(sc.moving_s) if sc.motion.get("enabled", False) and sc.moving_s > 0 else 0)
    subj = 1 if sc.subject_per_session else len(sc.subjects)
    first = sc.repeats if sc.train_repeats is None else sc.train_repeats
    return head + n_loc * subj * first * per, head + n_loc * subj * sc.repeats * per


def check_size(sc: Scenario, rig: Rig) -> int:
    """Refuse a scenario that would not fit in memory, before allocating anything; returns the total number of chirps."""
    first, other = session_chirps(sc, rig)
    total = first + (sc.sessions - 1) * other
    fix = "shorten the scenario (sessions, repeats, touch_s, gap_s, moving_s, calibration_s, part_s)"
    check_memory(256.0 * total + 64.0 * rig.seconds_to_chirps(max(sc.touch_s, sc.moving_s)),
                 f"the ground truth of scenario {brief(sc.name)} ({total:.3g} chirps in {sc.sessions} sessions)", fix)
    per_part = rig.seconds_to_chirps(sc.part_s)
    block = min(max(first, other), per_part * max(1, 1024 // per_part))
    check_memory(64.0 * rig.n_chirp * block, f"rendering scenario {brief(sc.name)} in blocks of {block} chirps", fix)
    return int(total)
def is_family(name_or_path: str | Path) -> bool:
    """Whether ``name_or_path`` is a scenario family (a YAML with ``family:``) rather than one scenario."""
    return "family" in load_yaml(resolve_config(name_or_path, "scenarios"))


def family_seeds(name_or_path: str | Path = "random") -> dict[str, tuple[int, ...]]:
    """The family's ``design`` seeds, ``heldout`` seeds (never tuned on) and ``previous`` (an earlier held-out set)."""
    fam = RandomFamily.from_dict(load_yaml(resolve_config(name_or_path, "scenarios")))
    return {"design": fam.design_seeds, "heldout": fam.heldout_seeds, "previous": fam.previous_seeds}


def _pair(v, what: str) -> tuple[float, float]:
    lo, hi = (float(x) for x in v)
    if not lo <= hi:
        raise ValueError(f"random family: {what} must be [low, high] with low <= high, got {list(v)}")
    return lo, hi


@dataclasses.dataclass(frozen=True)
class RandomFamily:
    """Rigs we did not design on: every seed draws another link, people, motion and warm-up as an ordinary
    :class:`Scenario`.  s000 trains, s001 validates, the rest test; ``design_seeds`` may be developed on,
    ``heldout_seeds`` are only ever evaluated (``benchmarks/bench_random_rigs.py``)."""

    family: str = "random"
    sessions: int = 4
    design_seeds: tuple[int, ...] = tuple(range(10))
    heldout_seeds: tuple[int, ...] = ()
    previous_seeds: tuple[int, ...] = ()
    materials: tuple[str, ...] = ("cfrp", "aluminium", "abs", "glass", "wood")
    kinds: tuple[str, ...] = ("tube", "plate")
    tube_radius_cm: tuple[float, float] = (3.0, 5.0)
    plate_width_cm: tuple[float, float] = (15.0, 30.0)
    length_cm: tuple[float, float] = (18.0, 35.0)
    loss_factor_scale: tuple[float, float] = (0.5, 2.0)
    irregularity: tuple[float, float] = (1e-3, 1e-2)
    grid_n: tuple[int, int] = (2, 4)
    spacing_cm: tuple[float, float] = (1.2, 3.0)
    people: tuple[int, int] = (1, 3)
    motion_probability: float = 0.5
    motion_level: tuple[float, float] = (0.3, 1.0)
    moving_s: float = 5.0
    ambient_c: tuple[float, float] = (15.0, 30.0)
    warmup_c: tuple[float, float] = (0.0, 8.0)
    warmup_tau_s: tuple[float, float] = (1800.0, 10800.0)
    start_s: tuple[float, float] = (0.0, 7200.0)
    session_interval_s: tuple[float, float] = (300.0, 1800.0)
    touch_s: tuple[float, float] = (1.5, 3.0)
    gap_s: float = 0.5
    calibration_s: float = 3.0
    peak_force_n: tuple[float, float] = (1.0, 10.0)
    description: str = ""

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RandomFamily:
        d = dict(d)
        seeds = d.pop("seeds", {}) or {}
        if set(seeds) - {"design", "heldout", "previous"}:
            raise ValueError(f"random family: seeds has keys design, heldout and previous, got {sorted(seeds)}")
        check_keys(cls, d, "random family")
        kw: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name not in d:
                continue
            v = d[f.name]
            if isinstance(f.default, tuple) and len(f.default) == 2 and not isinstance(f.default[0], str):
                v = _pair(v, f.name)
            elif isinstance(f.default, tuple):
                v = tuple(v)
            kw[f.name] = v
        for k in ("design", "heldout", "previous"):
            if k in seeds:
                kw[f"{k}_seeds"] = tuple(int(s) for s in seeds[k])
        fam = cls(**kw)
        fam.validate()
        return fam

    def validate(self) -> None:
        if self.family != "random":
            raise ValueError(f"unknown scenario family {brief(self.family)}; the simulator knows 'random'")
        bad = [m for m in self.materials if m not in MATERIALS]
        if bad:
            raise ValueError(f"random family: unknown materials {bad}; choose from {sorted(MATERIALS)}")
        if set(self.kinds) - {"tube", "plate"} or not self.kinds:
            raise ValueError(f"random family: kinds are 'tube' and/or 'plate', got {list(self.kinds)}")
        for (a, na), (b, nb) in (((self.design_seeds, "design"), (self.heldout_seeds, "held-out")),
                                 ((self.design_seeds, "design"), (self.previous_seeds, "previous")),
                                 ((self.heldout_seeds, "held-out"), (self.previous_seeds, "previous"))):
            both = sorted(set(a) & set(b))
            if both:
                raise ValueError(f"random family: seeds {both} are both {na} and {nb} seeds; the lists must be disjoint")
        if self.sessions < 2:
            raise ValueError("random family: sessions must be >= 2 (one to train, one to test)")
        if not 1 <= self.people[0] <= self.people[1] <= 12 or not 2 <= self.grid_n[0] <= self.grid_n[1]:
            raise ValueError("random family: people within 1..12 and grid_n >= 2")

    def draw(self, seed: int) -> Scenario:
        """The rig and protocol of ``seed`` (deterministic)."""
        rng = np.random.default_rng([int(seed), 2026, 15])

        def uni(r):
            return float(rng.uniform(*r))

        def log_uni(r):
            return float(np.exp(rng.uniform(np.log(r[0]), np.log(r[1]))))

        material = str(rng.choice(self.materials))
        kind = str(rng.choice(self.kinds))
        L = uni(self.length_cm)
        if kind == "tube":
            radius = uni(self.tube_radius_cm)
            W = 2 * np.pi * radius
            geometry = {"kind": "tube", "radius_cm": round(radius, 3), "length_cm": round(L, 3)}
            x_lo, x_hi = 0.0, W
        else:
            W = uni(self.plate_width_cm)
            geometry = {"kind": "plate", "width_cm": round(W, 3), "length_cm": round(L, 3)}
            x_lo, x_hi = 2.0, W - 2.0
        # TX in the first fifth of the link, RX in the last fifth (the paper's arrangement), anywhere around.
        tx = (uni((x_lo, x_hi)), uni((1.5, 0.2 * L)))
        rx = (uni((x_lo, x_hi)), uni((0.8 * L, L - 1.5)))
        # Markers: an nx x ny grid between the transducers (>= 2.5 cm from either along the link).
        nx, ny = (int(rng.integers(self.grid_n[0], self.grid_n[1] + 1)) for _ in range(2))
        y_lo, y_hi = tx[1] + 2.5, rx[1] - 2.5
        x_room = (W / nx) if kind == "tube" else (x_hi - x_lo) / (nx - 1)
        s = min(uni(self.spacing_cm), (y_hi - y_lo) / (ny - 1), x_room)
        x0 = uni((x_lo, x_hi - s * (nx - 1)))
        y0 = uni((y_lo, y_hi - s * (ny - 1)))
        layout = {"kind": "grid", "nx": nx, "ny": ny, "spacing_cm": round(s, 4), "x0_cm": round(x0, 3), "y0_cm": round(y0, 3)}
        eta = MATERIALS[material].eta * log_uni(self.loss_factor_scale)
        k = int(rng.integers(self.people[0], self.people[1] + 1))
        subjects = tuple(int(v) for v in rng.choice(12, size=k, replace=False))
        moving = bool(rng.uniform() < self.motion_probability)
        motion = {"enabled": True, "level": round(uni(self.motion_level), 3)} if moving else {"enabled": False}
        temperature = {"ambient_c": round(uni(self.ambient_c), 2), "warmup_c": round(uni(self.warmup_c), 2),
                       "warmup_tau_s": round(uni(self.warmup_tau_s)), "swing_c": 0.0, "swing_period_s": 86400.0,
                       "gradient": 0.5, "lag": 0.6}
        sc = Scenario(
            name=f"random-{int(seed)}", material=material, geometry=geometry,
            tx_cm=(round(tx[0] % W if kind == "tube" else tx[0], 3), round(tx[1], 3)),
            rx_cm=(round(rx[0] % W if kind == "tube" else rx[0], 3), round(rx[1], 3)),
            layout=layout, sessions=self.sessions, repeats=1, train_repeats=None,
            touch_s=round(uni(self.touch_s), 2), gap_s=self.gap_s, calibration_s=self.calibration_s,
            moving_s=self.moving_s if moving else 0.0, session_interval_s=round(uni(self.session_interval_s)),
            start_s=round(uni(self.start_s)), subjects=subjects, subject_per_session=True, order="random",
            peak_force_n=self.peak_force_n, motion=motion, temperature=temperature,
            channel={"irregularity": round(log_uni(self.irregularity), 5)},
            seed=int(seed), link_seed=int(rng.integers(0, 2 ** 31 - 1)), loss_factor=round(eta, 5),
        )
        sc.validate()
        return sc
