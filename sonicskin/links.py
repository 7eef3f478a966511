"""Links and arm files: several robot links, each with its own TX/RX pair, on one audio interface.

A *links file* (``configs/links``) lists the TX/RX pairs and how they share the chirp (``duplex``: ``time``,
``frequency`` or ``none``).  An *arm file* (``configs/arms``) also places each link on the robot and, simulated, says
what it is made of.  The keys: docs/arm.md."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Any

import yaml

from .acquire import Link
from .dataset import check_name
from .errors import ConfigNotFoundError, brief, is_number
from .rig import ConfigError, Rig, load_yaml, resolve_config
from .sim import Scenario
from .sim.channel import MATERIALS
from .surface import LinkSurface

__all__ = ["load_links", "load_arm", "arm_urdf", "missing_datasets", "write_arm", "link_scenario", "ARM_FILE"]

#: The arm file :func:`write_arm` writes next to the trained links' artifacts.
ARM_FILE = "arm.yaml"

_TOP_KEYS = {"name", "rig", "urdf", "duplex", "links"}
_LINK_KEYS = {"name", "tx", "rx", "frame", "surface", "scenario", "artifact"}


def _text(v, what: str, where) -> str | None:
    """``v`` when it is ``None`` or a string, else one line naming it (never ``str()`` of a nested value)."""
    if v is None or isinstance(v, str):
        return v
    raise ConfigError(f"{where}: {what} must be a string, got {brief(v)}")


def _resolve(name_or_path) -> Path:
    """A links file by name (configs/links, then configs/arms) or path."""
    try:
        return resolve_config(name_or_path, "links")
    except FileNotFoundError:
        return resolve_config(name_or_path, "arms")


def file_rig(name_or_path) -> Rig | None:
    """The rig an arm file names (``rig:``), else ``None``."""
    where = _resolve(name_or_path)
    cfg = load_yaml(where)
    r = cfg.get("rig")
    if isinstance(r, dict):
        return Rig.from_dict(r)
    if _text(r, "rig (a rig name, a path or a mapping)", where) is None:
        return None
    p = where.parent / r
    return Rig.load(p if p.is_file() else r)


def load_arm(spec, rig=None) -> tuple[Rig, list[Link]]:
    """The rig and the links of a links or arm file; every ``--links`` verb reads an arm through here."""
    the_rig = (Rig.load(rig) if isinstance(rig, (str, Path)) else rig) or file_rig(spec) or Rig.load("jaco")
    return the_rig, load_links(spec, the_rig)


def arm_urdf(spec) -> Path | None:
    """The URDF an arm file names (``urdf:``, relative to the file), else ``None``."""
    where = _resolve(spec)
    return where.parent / u if isinstance(u := load_yaml(where).get("urdf"), str) else None


def missing_datasets(links: list[Link], data: Path) -> list[str]:
    """The links with no dataset under ``data/<link>`` (what ``simulate --links`` and ``record --links`` write)."""
    return [lk.name for lk in links if not (Path(data) / lk.name / "dataset.json").is_file()]


def link_scenario(spec, *, name: str, surface=None, where: str = "link"):
    """The simulated link of a link: a scenario name or ``{base: NAME, key: value}``; without ``geometry``, the surface's."""
    if isinstance(spec, str):
        sc = Scenario.load(spec)
        return sc.replace(name=name) if sc.name != name else sc
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: scenario must be a scenario name or a mapping {{base: NAME, key: value}}, got {brief(spec)}")
    spec = dict(spec)
    base = _text(spec.pop("base", "stationary"), "scenario: base", where)
    d = {**Scenario.load(base).to_dict(), "name": name, **spec}
    if "geometry" not in spec and surface is not None:
        d["geometry"] = scenario_geometry(surface)

    if not isinstance(d.get("material"), str) or d["material"] not in MATERIALS:  # here, not at the first render
        raise ConfigError(f"{where}: scenario: unknown material {brief(d.get('material'))}; choose one of {sorted(MATERIALS)}")
    try:
        return Scenario.from_dict(d)
    except (ValueError, TypeError) as e:
        raise ConfigError(f"{where}: scenario: {e}") from None


def scenario_geometry(surface) -> dict:
    """The simulator's geometry (cm) of a surface: a URDF cylinder is the simulated tube, a box the plate."""
    if surface.kind == "tube":
        return {"kind": "tube", "radius_cm": round(100 * surface.dims_m[0], 6), "length_cm": round(100 * surface.dims_m[1], 6)}
    return {"kind": "plate", "width_cm": round(100 * surface.dims_m[0], 6), "length_cm": round(100 * surface.dims_m[1], 6)}


def scenario_surface(scenario, frame: str):
    """The surface of a simulated link placed by nothing else: its scenario's shape, centred in a frame of its own."""
    g = scenario.geometry
    if g.get("kind", "tube") == "tube":
        return LinkSurface(frame, "tube", (g["radius_cm"] / 100, g["length_cm"] / 100))
    return LinkSurface(frame, "plate", (g["width_cm"] / 100, g["length_cm"] / 100, 0.0))


def load_links(name_or_path, rig: Rig) -> list[Link]:
    """The links of a links or arm file (module docstring), checked: one-line errors naming the file and link."""
    where = _resolve(name_or_path)
    cfg = load_yaml(where)
    bad = set(cfg) - _TOP_KEYS
    if bad:
        raise ConfigError(f"{where}: unknown keys {sorted(map(str, bad))}; a links file has {', '.join(sorted(_TOP_KEYS))}")
    items = cfg.get("links") or []
    duplex = cfg.get("duplex", "time")
    if duplex not in ("time", "frequency", "none"):
        raise ConfigError(f"{where}: duplex must be 'time', 'frequency' or 'none', got {brief(duplex)}")
    if not items or not isinstance(items, list):
        raise ConfigError(f"{where}: a links config needs a non-empty 'links' list of {{name, tx, rx}}")
    urdf = None
    if _text(cfg.get("urdf"), "urdf", where) is not None:
        urdf = where.parent / cfg["urdf"]
        if urdf.is_dir():
            raise ConfigError(f"{where}: urdf {brief(cfg['urdf'])} is a folder ({urdf}); give the URDF file's path, "
                              f"relative to the arm file")
        if not urdf.is_file():
            raise ConfigNotFoundError(f"{where}: urdf {brief(cfg['urdf'])} does not exist next to it ({urdf}); give its path "
                                    f"relative to the arm file")
    arm_name = _text(cfg.get("name", where.stem), "name", where)
    n = len(items)
    out = []
    for i, d in enumerate(items):  # each link a mapping with 0-based integer channels (0.7 was channel 0, silently)
        if not isinstance(d, dict):
            raise ConfigError(f"{where}: link {i}: expected a mapping {{name, tx, rx}}, got {brief(d)}")
        bad = set(d) - _LINK_KEYS
        if bad:
            raise ConfigError(f"{where}: link {i}: unknown keys {sorted(map(str, bad))}; a link has "
                             f"{', '.join(sorted(_LINK_KEYS))}")
        for k in ("tx", "rx"):
            v = d.get(k)
            if not is_number(v, integer=True) or v < 0:
                raise ConfigError(f"{where}: link {i}: {k} must be a 0-based channel number (an integer >= 0), got "
                                 f"{'nothing' if k not in d else brief(v)}")
        name = d.get("name", f"link{i}")
        if not isinstance(name, str):
            raise ConfigError(f"{where}: link {i}: name must be a string, got {brief(name)}")
        check_name(name, "name", where=f"{where}: link {i}")  # it names the link's folder (data/<name>, out/<name>)
        extra = _placement(d, where=f"{where}: link {brief(name)}", urdf=urdf, arm_name=arm_name, base=where.parent)
        if duplex == "time":
            out.append(Link(int(d["tx"]), int(d["rx"]), i, n, name, **extra))
        elif duplex == "none":
            out.append(Link(int(d["tx"]), int(d["rx"]), 0, 1, name, **extra))
        else:
            step = (rig.f_hi_hz - rig.f_lo_hz) / n
            sub = dataclasses.replace(rig, f_lo_hz=rig.f_lo_hz + i * step, f_hi_hz=rig.f_lo_hz + (i + 1) * step, name=f"{rig.name}/{name}")
            out.append(Link(int(d["tx"]), int(d["rx"]), 0, 1, name, sub, **extra))
    rx = [lk.rx for lk in out]
    if len(set(rx)) != len(rx):
        raise ConfigError(f"links share receiver channels {rx}; each link needs its own RX channel")
    tx = [lk.tx for lk in out]
    if duplex == "none" and len(set(tx)) != len(tx):
        raise ConfigError(f"{where}: duplex none: links share transmitter channels {tx}; each link needs its own TX "
                         f"channel (or share the chirp with duplex: time or frequency)")
    if all(lk.scenario is not None for lk in out):  # the simulated arm: link k is the simulator on channel pair k
        off = next((lk for k, lk in enumerate(out) if (lk.tx, lk.rx) != (k, k)), None)
        if off is not None:
            k = out.index(off)
            raise ConfigError(f"{where}: link {off.name!r}: tx {off.tx}, rx {off.rx}, but the simulated arm plays link k "
                              f"(in file order) on its own TX/RX pair k: give tx: {k}, rx: {k}")
    names = [lk.name for lk in out]
    if len(set(names)) != len(names):
        raise ConfigError(f"{where}: link names {names} repeat; every link needs its own name (events carry it)")
    return out


def _placement(d: dict, *, where: str, urdf: Path | None, arm_name: str, base: Path) -> dict[str, Any]:
    """A link's frame, surface, simulated scenario and artifact (all optional)."""
    frame = d.get("frame")
    if frame is not None and not isinstance(frame, str):
        raise ConfigError(f"{where}: frame must be the name of the link's frame (a URDF link), got {brief(frame)}")
    surface = None
    if d.get("surface") is not None or (urdf is not None and frame is not None):
        over = d.get("surface") or {}
        if not isinstance(over, dict):
            raise ConfigError(f"{where}: surface must be a mapping (sonicskin.surface.LinkSurface), got {brief(over)}")
        if urdf is not None and frame is not None:
            surface = LinkSurface.from_urdf(urdf, frame, **over)
        else:
            surface = LinkSurface.from_dict({**({"frame": frame} if frame and "frame" not in over else {}), **over},
                                            where=f"{where}: surface")
        frame = surface.frame_id
    scenario = None
    if d.get("scenario") is not None:
        scenario = link_scenario(d["scenario"], name=f"{arm_name}-{d.get('name', 'link')}", surface=surface, where=where)
        if surface is None:  # a simulated link without a frame: its own shape, in a frame named after it
            surface = scenario_surface(scenario, frame or f"{d.get('name', 'link')}_link")
            frame = surface.frame_id
    if surface is not None and scenario is not None:
        try:
            surface.check_layout(scenario.make_layout())
        except ValueError as e:
            raise ConfigError(f"{where}: {e}") from None
    artifact = None
    if _text(d.get("artifact"), "artifact", where) is not None:
        artifact = base / d["artifact"]
    return {"frame": frame, "surface": surface, "scenario": scenario, "artifact": artifact}


def write_arm(source, out: Path, artifacts: dict[str, Path], rig: Rig) -> Path:
    """``out/arm.yaml``: the links of ``source`` with each link's artifact, its rig and the URDF beside it."""
    where = _resolve(source)
    cfg = load_yaml(where)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    new = {k: v for k, v in cfg.items() if k != "links"}
    new["rig"] = rig.to_dict()
    if cfg.get("urdf") is not None:
        src = where.parent / str(cfg["urdf"])
        shutil.copyfile(src, out / src.name)
        new["urdf"] = src.name
    links = []
    for d in cfg["links"]:
        d = dict(d)
        name = d.get("name")
        if name in artifacts:
            p = Path(artifacts[name]).resolve()
            try:
                d["artifact"] = str(p.relative_to(out.resolve()))
            except ValueError:
                d["artifact"] = str(p)
        links.append(d)
    new["links"] = links
    path = out / ARM_FILE
    tmp = path.with_suffix(".yaml.tmp")
    tmp.write_text(f"# written by sonicskin from {where.name}: the trained arm (`sonicskin live --links {path}`)\n"
                   + yaml.safe_dump(new, sort_keys=False))
    tmp.replace(path)
    return path
