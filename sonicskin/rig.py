"""Rig description: sample rate, chirp (Eq. 1), the bands OSPA step 1 drops, and the touch-location layout.  Stored
in every dataset and artifact, so a model never runs on a rig it was not trained for."""

from __future__ import annotations

import dataclasses
import functools
import importlib.resources
from pathlib import Path
from typing import Any

import numpy as np

from .errors import SonicskinError, brief

__all__ = ["Rig", "Layout", "ConfigError", "MAX_N_CHIRP", "MAX_FS_HZ", "MAX_LOCATIONS",
           "load_yaml", "config_dir", "config_names", "resolve_config", "CONFIG_KINDS"]

class ConfigError(SonicskinError):
    """A rig, scenario or training config that cannot be used as it is; the message names the file or key."""


#: Bounds of a rig: a chirp of 4 Mi samples (21.8 s at 192 kHz) and a 10 MHz sample rate are far
#: beyond any audio interface; larger values are corrupt files or typos that would ask for terabytes.
MAX_N_CHIRP = 1 << 22
MAX_FS_HZ = 10e6
#: Markers of one layout (a scenario's, a dataset's, an import's): more is a corrupt file or a column that is no location.
MAX_LOCATIONS = 100_000

#: The config folders (``configs/<kind>/<name>.yaml``) a bare name can refer to.
CONFIG_KINDS = ("rigs", "scenarios", "links", "arms", "train")


def config_dir() -> Path:
    """The folder bare config names resolve in: the wheel's ``sonicskin/configs``, else the checkout's ``configs/``."""
    shipped = importlib.resources.files(__package__) / "configs"
    if shipped.is_dir():
        return Path(str(shipped))  # pip installs wheels unpacked, so this is a real folder
    return Path(__file__).resolve().parent.parent / "configs"


def config_names(kind: str) -> list[str]:
    """The bare names of the ``kind`` configs (``rigs``, ``scenarios``, ``links``, ``train``, ``arms``), sorted."""
    if kind not in CONFIG_KINDS:
        raise ValueError(f"unknown config kind {brief(kind)}; valid kinds: {', '.join(CONFIG_KINDS)}")
    return sorted(p.stem for p in (config_dir() / kind).glob("*.yaml"))


def resolve_config(name_or_path: str | Path, kind: str) -> Path:
    """The YAML file a config argument refers to (a bare name is a shipped config); else :class:`FileNotFoundError`."""
    text = str(name_or_path)
    p = Path(name_or_path)
    if isinstance(name_or_path, Path) or p.suffix in (".yaml", ".yml") or "/" in text or "\\" in text or p.is_file():
        if not p.is_file():
            raise FileNotFoundError(f"{kind} config file {text} does not exist (a bare name like "
                                    f"{brief((config_names(kind) or ['NAME'])[0])} picks a shipped config)")
        return p
    candidate = config_dir() / kind / f"{text}.yaml"
    if not candidate.is_file():
        known = config_names(kind)
        listed = ", ".join(known) if known else f"none (no {config_dir() / kind}: the package was installed without its configs)"
        raise FileNotFoundError(f"no {kind} config named {brief(text)}; known: {listed}; or give a path to a YAML file")
    return candidate


MAX_YAML_BYTES = 4 * 2**20  # a config is a page of settings; more is not a config


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping of plain values; else one :class:`ConfigError` line naming the file."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file {path} does not exist")
    if path.stat().st_size > MAX_YAML_BYTES:
        raise ConfigError(f"{path}: {path.stat().st_size / 2**20:.0f} MB is too large for a config file "
                          f"(at most {MAX_YAML_BYTES // 2**20} MB)")

    class _Loader(yaml.SafeLoader):
        pass

    def mapping(loader, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = loader.construct_object(key_node, deep=True)
            try:
                if key in seen:
                    raise yaml.constructor.ConstructorError(None, None, f"the key {brief(key)} appears twice", key_node.start_mark)
                seen.add(key)
            except TypeError:  # an unhashable key: SafeLoader reports it below
                pass
        return loader.construct_mapping(node, deep=deep)

    _Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    try:
        text = path.read_bytes().decode("utf-8")
        loader = _Loader(text)  # a SafeLoader that also refuses duplicated keys
        try:
            data = loader.get_single_data()
        finally:
            loader.dispose()
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start}); save the config as UTF-8") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = " ".join(str(getattr(e, "problem", None) or e).split())
        if "could not determine a constructor" in problem or "tag" in problem and "python" in problem:
            problem = f"{problem.split(' for the tag ')[-1]} is a tag that builds an object; configs hold plain values only"
        raise ConfigError(f"{path}: not a valid YAML config ({where}{problem[:160]}); fix the file") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply to be a config file") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a YAML mapping at the top level, got {type(data).__name__}")
    return data


def check_keys(cls, d: dict[str, Any], what: str, required: tuple[str, ...] = ()) -> None:
    """Reject config keys a dataclass does not have, naming the valid ones, and a missing ``required`` key."""
    if not isinstance(d, dict):
        raise ConfigError(f"a {what} must be a mapping of keys to values, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise ConfigError(f"unknown {what} keys {sorted(unknown, key=str)}; valid keys: {sorted(names)}")
    missing = [k for k in required if k not in d]
    if missing:
        raise ConfigError(f"the {what} lacks {', '.join(missing)}: a {what} names {', '.join(required)} (no default "
                          f"fits every hardware); add {missing[0]}")


#: What a rig file must say: the sample rate and the chirp (a default 192 kHz on a 48 kHz interface is silently wrong).
RIG_REQUIRED = ("fs_hz", "f_lo_hz", "f_hi_hz", "n_chirp")


@dataclasses.dataclass(frozen=True)
class Rig:
    """Acquisition parameters of one transmitter/receiver pair (the paper's are the defaults).  ``n_chirp``: samples per
    chirp, one FFT frame; ``pwm_hz``: centres of the motor-PWM bands the matched filter drops, ``pwm_halfwidth_hz``
    each side; ``sweep_b64``: a transmitted sweep other than Eq. 1's chirp, one period of float32 in base64."""

    fs_hz: float = 192_000.0
    f_lo_hz: float = 20_000.0
    f_hi_hz: float = 80_000.0
    n_chirp: int = 20_480
    pwm_hz: tuple[float, ...] = (30_000.0, 60_000.0, 90_000.0)
    pwm_halfwidth_hz: float = 3_250.0
    amplitude: float = 0.5
    name: str = "jaco-link"
    sweep_b64: str | None = None

    def __post_init__(self) -> None:
        for k in ("fs_hz", "f_lo_hz", "f_hi_hz", "pwm_halfwidth_hz", "amplitude"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
                raise ConfigError(f"rig {k} must be a finite number, got {brief(v)}")
        if isinstance(self.n_chirp, bool) or not isinstance(self.n_chirp, (int, float, np.integer, np.floating)) \
                or not np.isfinite(self.n_chirp):
            raise ConfigError(f"rig n_chirp must be a whole number of samples, got {brief(self.n_chirp)}")
        if not isinstance(self.pwm_hz, (list, tuple)) or len(self.pwm_hz) > 64:
            raise ConfigError(f"rig pwm_hz must be a list of at most 64 frequencies in Hz, got {brief(self.pwm_hz)}")
        try:
            object.__setattr__(self, "pwm_hz", tuple(float(f) for f in self.pwm_hz))
        except (TypeError, ValueError):
            raise ConfigError(f"rig pwm_hz must be a list of frequencies in Hz, got {brief(self.pwm_hz)}") from None
        if not all(np.isfinite(self.pwm_hz)):
            raise ConfigError(f"rig pwm_hz must be finite, got {list(self.pwm_hz)}")
        if not isinstance(self.name, str):
            raise ConfigError(f"rig name must be a string, got {brief(self.name)}")
        if self.sweep_b64 is not None and not isinstance(self.sweep_b64, str):
            raise ConfigError("rig sweep_b64 must be a base64 text")
        nyq = self.fs_hz / 2
        if not 0 < self.fs_hz <= MAX_FS_HZ:
            raise ValueError(f"fs_hz must be in (0, {MAX_FS_HZ:g}] Hz, got {self.fs_hz:g}")
        if not 64 <= self.n_chirp <= MAX_N_CHIRP:
            raise ValueError(f"n_chirp must be 64..{MAX_N_CHIRP} samples (a frame of {MAX_N_CHIRP} samples is "
                             f"{MAX_N_CHIRP / self.fs_hz:.3g} s here), got {self.n_chirp:g}")
        if not 0 < self.f_lo_hz < self.f_hi_hz <= nyq:
            raise ValueError(
                f"need 0 < f_lo_hz < f_hi_hz <= fs_hz/2 = {nyq:g}, got f_lo_hz={self.f_lo_hz:g}, "
                f"f_hi_hz={self.f_hi_hz:g}"
            )
        if int(self.n_chirp) != self.n_chirp or self.n_chirp < 64:
            raise ValueError(f"n_chirp must be an integer >= 64 samples, got {self.n_chirp}")
        if self.pwm_halfwidth_hz < 0:
            raise ValueError(f"pwm_halfwidth_hz must be >= 0, got {self.pwm_halfwidth_hz}")
        # A line above the sample rate is a typo (500000 for 50000); lines between fs/2 and fs (the paper's motor
        # harmonics on a slower interface) notch nothing but stay readable.
        off = [f for f in self.pwm_hz if not 0 < f <= self.fs_hz]
        if off:
            raise ValueError(f"pwm_hz {off[0]:g} Hz is outside 0..{self.fs_hz:g} Hz (the sample rate); the PWM lines to "
                             f"notch are frequencies of the motors' drive: check the value")
        if not 0 < self.amplitude <= 1:
            raise ValueError(f"amplitude must be in (0, 1] of full scale, got {self.amplitude}")
        if self.sweep_b64 is not None and self.sweep().size != self.n_chirp:
            raise ValueError(f"the stored sweep has {self.sweep().size} samples but n_chirp is {self.n_chirp}")
        if self.allowed_mask.sum() == 0:
            raise ValueError("the PWM bands remove every bin of the chirp band; narrow pwm_halfwidth_hz")

    # -- construction -----------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Rig:
        check_keys(cls, d, "rig", required=RIG_REQUIRED)
        return cls(**d)

    @classmethod
    def load(cls, name_or_path: str | Path = "jaco") -> Rig:
        """Load a shipped rig by name (``configs/rigs/<name>.yaml``) or a YAML file path (:func:`resolve_config`)."""
        path = resolve_config(name_or_path, "rigs")
        d = load_yaml(path)
        try:
            return cls.from_dict(d)
        except ValueError as e:
            raise ConfigError(f"{path}: {e}") from None

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["pwm_hz"] = list(self.pwm_hz)
        if d["sweep_b64"] is None:
            del d["sweep_b64"]
        return d

    def sweep(self) -> np.ndarray | None:
        """The stored transmitted sweep (float32), or ``None`` for Eq. 1's chirp."""
        if self.sweep_b64 is None:
            return None
        import base64

        return np.frombuffer(base64.b64decode(self.sweep_b64), dtype="<f4").copy()

    @staticmethod
    def encode_sweep(x: np.ndarray) -> str:
        import base64

        return base64.b64encode(np.asarray(x, dtype="<f4").tobytes()).decode()

    # -- derived quantities -----------------------------------------------------------
    @property
    def period_s(self) -> float:
        """Chirp period T in seconds (20480 / 192 kHz = 106.7 ms)."""
        return self.n_chirp / self.fs_hz

    @property
    def chirps_per_s(self) -> float:
        return self.fs_hz / self.n_chirp

    def seconds_to_chirps(self, seconds: float) -> int:
        """Whole chirps in ``seconds`` (at least one)."""
        return max(1, int(round(seconds * self.chirps_per_s)))

    @functools.cached_property
    def freqs_hz(self) -> np.ndarray:
        """Frequencies of the rfft bins of one chirp frame, shape (n_chirp // 2 + 1,)."""
        return np.fft.rfftfreq(self.n_chirp, d=1.0 / self.fs_hz)

    @functools.cached_property
    def band_bins(self) -> np.ndarray:
        """rfft bin indices inside [f_lo_hz, f_hi_hz]: the feature space, shape (n_band,)."""
        f = self.freqs_hz
        return np.flatnonzero((f >= self.f_lo_hz) & (f <= self.f_hi_hz))

    @property
    def n_band(self) -> int:
        return int(self.band_bins.size)

    @functools.cached_property
    def allowed_mask(self) -> np.ndarray:
        """Matched filter of OSPA step 1 over the band bins: False inside a PWM band."""
        f = self.freqs_hz[self.band_bins]
        keep = np.ones(f.shape, dtype=bool)
        for fc in self.pwm_hz:
            keep &= np.abs(f - fc) > self.pwm_halfwidth_hz
        return keep

    def mismatch(self, other: Rig) -> list[str]:
        """Fields that differ in a way that invalidates a model (everything but name/amplitude)."""
        diffs = []
        for f in ("fs_hz", "f_lo_hz", "f_hi_hz", "n_chirp", "pwm_hz", "pwm_halfwidth_hz", "sweep_b64"):
            a, b = getattr(self, f), getattr(other, f)
            if a != b:
                diffs.append(f"{f}: {a} vs {b}" if f != "sweep_b64" else "the transmitted sweep differs")
        return diffs


@dataclasses.dataclass(frozen=True)
class Layout:
    """Touch locations: ids and coordinates in cm on the unrolled surface (with ``circumference_cm`` distances wrap)."""

    ids: tuple[int, ...]
    xy_cm: np.ndarray  # (n, 2)
    circumference_cm: float | None = None

    def __post_init__(self) -> None:
        xy = np.asarray(self.xy_cm, dtype=float)
        object.__setattr__(self, "xy_cm", xy)
        object.__setattr__(self, "ids", tuple(int(i) for i in self.ids))
        if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] != len(self.ids):
            raise ValueError(f"xy_cm must have shape ({len(self.ids)}, 2), got {xy.shape}")
        if len(set(self.ids)) != len(self.ids):
            raise ValueError("location ids must be unique")

    def __len__(self) -> int:
        return len(self.ids)

    def __hash__(self) -> int:
        return hash((self.ids, self.xy_cm.tobytes(), self.circumference_cm))

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Layout) and self.ids == other.ids
                and np.allclose(self.xy_cm, other.xy_cm) and self.circumference_cm == other.circumference_cm)

    @functools.cached_property
    def _lut(self) -> dict[int, int]:  # built once: a lookup per call made coords() of K markers quadratic in K
        return {i: k for k, i in enumerate(self.ids)}

    def index_of(self, ids: np.ndarray) -> np.ndarray:
        """Row index in ``xy_cm`` of each location id (raises on an unknown id)."""
        lut = self._lut
        ids = np.asarray(ids)
        try:
            return np.array([lut[int(i)] for i in ids.ravel()], dtype=int).reshape(ids.shape)
        except KeyError as e:
            raise ValueError(f"location id {e.args[0]} is not in the layout (ids {self.ids[0]}..{self.ids[-1]})") from None

    def coords(self, ids: np.ndarray) -> np.ndarray:
        return self.xy_cm[self.index_of(ids)]

    def distance_cm(self, a_xy: np.ndarray, b_xy: np.ndarray) -> np.ndarray:
        """Surface distance between points (..., 2), wrapping around the circumference."""
        d = np.abs(np.asarray(a_xy, float) - np.asarray(b_xy, float))
        if self.circumference_cm:
            d[..., 0] = np.minimum(d[..., 0], self.circumference_cm - d[..., 0])
        return np.hypot(d[..., 0], d[..., 1])

    @classmethod
    def rings(cls, counts: tuple[int, ...] = (16, 15), spacing_cm: float = 1.2,
              circumference_cm: float | None = None, x0_cm: float = 0.0, y0_cm: float = 0.0) -> Layout:
        """Rows of markers ``spacing_cm`` apart, every other shifted by half; the default 16 + 15 is the paper's (Fig. 10)."""
        xy = []
        for row, n in enumerate(counts):
            shift = 0.5 * spacing_cm * (row % 2)
            for k in range(n):
                xy.append((x0_cm + shift + k * spacing_cm, y0_cm + row * spacing_cm))
        return cls(ids=tuple(range(len(xy))), xy_cm=np.array(xy), circumference_cm=circumference_cm)

    @classmethod
    def grid(cls, nx: int, ny: int, spacing_cm: float, x0_cm: float = 0.0, y0_cm: float = 0.0,
             circumference_cm: float | None = None) -> Layout:
        xs, ys = np.meshgrid(x0_cm + spacing_cm * np.arange(nx), y0_cm + spacing_cm * np.arange(ny))
        xy = np.column_stack([xs.ravel(), ys.ravel()])
        return cls(ids=tuple(range(len(xy))), xy_cm=xy, circumference_cm=circumference_cm)

    def to_dict(self) -> dict[str, Any]:
        return {"ids": list(self.ids), "xy_cm": self.xy_cm.round(6).tolist(), "circumference_cm": self.circumference_cm}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Layout:
        return cls(ids=tuple(d["ids"]), xy_cm=np.asarray(d["xy_cm"], float), circumference_cm=d.get("circumference_cm"))
