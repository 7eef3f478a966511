"""A link's skin placed on its real surface: layout coordinates (cm, unrolled) -> point and normal in the link's frame.

A :class:`LinkSurface` names the robot frame and the shape the skin covers (a tube or a plate) with its pose in that
frame; the conventions are the contract between a layout and the robot (docs/robot-frame.md).  Bad input raises
:class:`SurfaceError`, one line."""

from __future__ import annotations

import dataclasses
import functools
import math
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from .errors import SonicskinError, brief, is_number

__all__ = ["LinkSurface", "SurfaceError", "pose_matrix"]


class SurfaceError(SonicskinError):
    """A link surface description (YAML or URDF) that cannot place a layout; the message names the problem and the fix."""


_COMMON = {"frame", "kind", "xyz", "rpy"}
_KEYS = {"tube": _COMMON | {"radius_m", "length_m", "theta0_deg", "axis_from"},
         "plate": _COMMON | {"width_m", "length_m", "thickness_m", "face"}}
_OVERRIDES = {"tube": {"theta0_deg", "axis_from"}, "plate": {"face"}}
_TOL_CM = 0.05  # a layout may reach this far past the surface's edge (rounding of hand-written coordinates)


def pose_matrix(xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The 4x4 transform of URDF's ``<origin xyz rpy>``: ``R = Rz(yaw) Ry(pitch) Rx(roll)``, then the translation."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    T = np.eye(4)
    T[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                 [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                 [-sp, cp * sr, cp * cr]]
    T[:3, 3] = [float(a) for a in xyz]
    return T


@dataclasses.dataclass(frozen=True, eq=False)
class LinkSurface:
    """The surface a link's skin covers, in the link's frame: ``dims_m`` ``(radius, length)`` for a tube,
    ``(width, length, thickness)`` for a plate; ``pose`` the shape's 4x4 transform; ``theta0_deg``/``axis_from`` (tube)
    or ``face`` (plate)."""

    frame_id: str
    kind: str  # "tube" | "plate"
    dims_m: tuple[float, ...]
    pose: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(4))
    theta0_deg: float = 0.0
    axis_from: str = "-z"  # the shape's end that holds the transmitter (layout y = 0)
    face: str = "+z"  # the plate's touched face

    def __post_init__(self) -> None:
        if not isinstance(self.frame_id, str) or not self.frame_id.strip():
            raise SurfaceError(f"frame must be the link's frame name (a non-empty string), got {brief(self.frame_id)}")
        if not isinstance(self.kind, str) or self.kind not in _KEYS:
            raise SurfaceError(f"kind must be 'tube' or 'plate', got {brief(self.kind)}")
        n = 2 if self.kind == "tube" else 3
        dims = tuple(float(d) for d in self.dims_m)
        names = ("radius_m", "length_m") if self.kind == "tube" else ("width_m", "length_m", "thickness_m")
        if len(dims) != n:
            raise SurfaceError(f"a {self.kind} has {n} dimensions {names}, got {len(dims)}")
        for k, d in zip(names, dims):
            if not (math.isfinite(d) and (d > 0 or (k == "thickness_m" and d == 0))):
                raise SurfaceError(f"{self.kind} {k} must be a positive number of metres, got {brief(d)}")
        pose = np.array(self.pose, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)) or not np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-6):
            raise SurfaceError("pose must be a finite 4x4 rigid transform (a rotation and a translation)")
        pose.setflags(write=False)
        if self.axis_from not in ("-z", "+z"):
            raise SurfaceError(f"axis_from must be '-z' or '+z' (the tube's end that holds the transmitter), got {brief(self.axis_from)}")
        if self.face not in ("+z", "-z"):
            raise SurfaceError(f"face must be '+z' or '-z' (the plate's touched face), got {brief(self.face)}")
        t0 = self.theta0_deg
        if not is_number(t0):
            raise SurfaceError(f"theta0_deg must be a finite angle in degrees, got {brief(self.theta0_deg)}")
        object.__setattr__(self, "dims_m", dims)
        object.__setattr__(self, "pose", pose)
        object.__setattr__(self, "theta0_deg", float(self.theta0_deg))

    # -- geometry ---------------------------------------------------------------------------------------------------
    @property
    def radius_m(self) -> float:
        return self.dims_m[0] if self.kind == "tube" else math.nan

    @property
    def length_m(self) -> float:
        return self.dims_m[1]

    @property
    def width_cm(self) -> float:
        """The unrolled surface's extent along layout x: the circumference (tube) or the width (plate), in cm."""
        return 100 * (2 * math.pi * self.dims_m[0] if self.kind == "tube" else self.dims_m[0])

    def point_normal(self, xy_cm) -> tuple[np.ndarray, np.ndarray]:
        """Layout coordinates ``(n, 2)`` cm -> contact points ``(n, 3)`` m and unit outward normals, in the link frame."""
        xy = np.asarray(xy_cm, dtype=float)
        if xy.ndim == 1:
            xy = xy[None]
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise SurfaceError(f"xy_cm must have shape (n, 2), got {np.shape(xy_cm)}")
        x, y = xy[:, 0] / 100, xy[:, 1] / 100
        if self.kind == "tube":
            r, L = self.dims_m
            z = y - L / 2 if self.axis_from == "-z" else L / 2 - y
            th = math.radians(self.theta0_deg) + x / r
            c, s = np.cos(th), np.sin(th)
            p = np.stack([r * c, r * s, z], axis=1)
            nrm = np.stack([c, s, np.zeros_like(c)], axis=1)
        else:
            W, L, h = self.dims_m
            sign = 1.0 if self.face == "+z" else -1.0
            p = np.stack([x - W / 2, y - L / 2, np.full_like(x, sign * h / 2)], axis=1)
            nrm = np.zeros_like(p)
            nrm[:, 2] = sign
        R, t = self.pose[:3, :3], self.pose[:3, 3]
        return p @ R.T + t, nrm @ R.T

    def point_normal_one(self, x_cm: float, y_cm: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """:meth:`point_normal` of one contact in plain floats, for every live event (a tenth of the batched call's cost)."""
        x, y = x_cm / 100, y_cm / 100
        if self.kind == "tube":
            r, L = self.dims_m
            th = math.radians(self.theta0_deg) + x / r
            c, s = math.cos(th), math.sin(th)
            p, n = (r * c, r * s, y - L / 2 if self.axis_from == "-z" else L / 2 - y), (c, s, 0.0)
        else:
            W, L, h = self.dims_m
            sign = 1.0 if self.face == "+z" else -1.0
            p, n = (x - W / 2, y - L / 2, sign * h / 2), (0.0, 0.0, sign)
        R, t = self._rows
        return (tuple(a * p[0] + b * p[1] + c * p[2] + o for (a, b, c), o in zip(R, t)),
                tuple(a * n[0] + b * n[1] + c * n[2] for (a, b, c) in R))

    @functools.cached_property
    def _rows(self) -> tuple[tuple[tuple[float, ...], ...], tuple[float, ...]]:
        return tuple(tuple(float(v) for v in row) for row in self.pose[:3, :3]), tuple(float(v) for v in self.pose[:3, 3])

    def check_layout(self, layout) -> None:
        """Raise :class:`SurfaceError` when ``layout`` does not fit (another circumference, a marker off the surface)."""
        xy = np.asarray(layout.xy_cm, dtype=float)
        wid, length = self.width_cm, 100 * self.length_m
        what = f"the {self.kind} of {self.frame_id}"
        if self.kind == "tube":
            circ = getattr(layout, "circumference_cm", None)
            if circ is not None and abs(circ - wid) > max(_TOL_CM, 0.01 * wid):
                raise SurfaceError(f"the layout's circumference {circ:g} cm is not that of {what} ({wid:.2f} cm = 2 pi x "
                                   f"{100 * self.radius_m:g} cm): use the link's radius in the scenario's geometry or fix radius_m")
        if len(xy) == 0:
            return
        x0, x1, y0, y1 = xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()
        if x0 < -_TOL_CM or x1 > wid + _TOL_CM:
            across = "circumference" if self.kind == "tube" else "width"
            raise SurfaceError(f"the layout spans x {x0:g}..{x1:g} cm, wider than the {across} of {what} ({wid:.2f} cm): "
                               "the layout is for another link, or its size in the URDF/YAML is wrong")
        if y0 < -_TOL_CM or y1 > length + _TOL_CM:
            raise SurfaceError(f"the layout spans y {y0:g}..{y1:g} cm, longer than {what} ({length:.2f} cm): "
                               "the layout is for another link, or its length in the URDF/YAML is wrong")

    def to_dict(self) -> dict[str, Any]:
        """The YAML mapping :meth:`from_dict` reads back (pose as xyz + rpy)."""
        R, t = self.pose[:3, :3], self.pose[:3, 3]
        pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
        if abs(math.cos(pitch)) > 1e-9:
            roll, yaw = math.atan2(R[2, 1], R[2, 2]), math.atan2(R[1, 0], R[0, 0])
        else:  # gimbal lock: put the whole rotation about z into yaw
            roll, yaw = 0.0, math.atan2(-R[0, 1], R[1, 1])
        d: dict[str, Any] = {"frame": self.frame_id, "kind": self.kind}
        if self.kind == "tube":
            d |= {"radius_m": self.dims_m[0], "length_m": self.dims_m[1], "theta0_deg": self.theta0_deg, "axis_from": self.axis_from}
        else:
            d |= {"width_m": self.dims_m[0], "length_m": self.dims_m[1], "thickness_m": self.dims_m[2], "face": self.face}
        return d | {"xyz": [float(v) for v in t], "rpy": [roll, pitch, yaw]}

    # -- constructors -----------------------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: Any, where: str = "surface", base_dir: str | Path | None = None) -> LinkSurface:
        """A surface from a short YAML mapping (docs/robot-frame.md), checked strictly; a URDF path relative to ``base_dir``."""
        if not isinstance(d, dict):
            raise SurfaceError(f"{where}: a surface is a mapping like {{frame: forearm_link, kind: tube, radius_m: 0.0375, "
                               f"length_m: 0.25}}, got {type(d).__name__}")
        if "urdf" in d:
            if "frame" not in d:
                raise SurfaceError(f"{where}: a URDF surface needs frame: the link's name in the URDF")
            path = Path(str(d["urdf"]))
            if base_dir is not None and not path.is_absolute():
                path = Path(base_dir) / path
            over = {k: v for k, v in d.items() if k not in ("urdf", "frame")}
            try:
                return cls.from_urdf(path, str(d["frame"]), **over)
            except SurfaceError as e:
                raise SurfaceError(f"{where}: {e}") from None
        kind = d.get("kind")
        if not isinstance(kind, str) or kind not in _KEYS:
            raise SurfaceError(f"{where}: kind must be 'tube' or 'plate' (or give urdf: PATH), got {brief(kind)}")
        unknown = sorted(set(d) - _KEYS[kind])
        if unknown:
            raise SurfaceError(f"{where}: unknown key(s) {unknown} for a {kind}; the keys are {sorted(_KEYS[kind])}")
        need = ["frame", "radius_m", "length_m"] if kind == "tube" else ["frame", "width_m", "length_m"]
        missing = [k for k in need if k not in d]
        if missing:
            raise SurfaceError(f"{where}: a {kind} needs {missing}")

        def num(k, default=None):
            v = d.get(k, default)
            if not is_number(v):
                raise SurfaceError(f"{where}: {k} must be a finite number, got {brief(v)}")
            return float(v)

        def vec3(k):
            v = d.get(k, [0.0, 0.0, 0.0])
            if not isinstance(v, (list, tuple)) or len(v) != 3 or not all(is_number(a) for a in v):
                raise SurfaceError(f"{where}: {k} must be 3 finite numbers ({'m' if k == 'xyz' else 'rad'}), got {brief(v)}")
            return [float(a) for a in v]

        dims = (num("radius_m"), num("length_m")) if kind == "tube" else (num("width_m"), num("length_m"), num("thickness_m", 0.0))
        pose, theta0 = pose_matrix(vec3("xyz"), vec3("rpy")), num("theta0_deg", 0.0)
        try:
            return cls(d["frame"], kind, dims, pose, theta0_deg=theta0, axis_from=d.get("axis_from", "-z"), face=d.get("face", "+z"))
        except SurfaceError as e:
            raise SurfaceError(f"{where}: {e}") from None

    @classmethod
    def from_urdf(cls, path: str | Path, link_name: str, **overrides) -> LinkSurface:
        """The surface of URDF link ``link_name`` (its collision, else visual, cylinder or box); ``overrides`` what a URDF lacks."""
        path = Path(path)
        if not path.is_file():
            raise SurfaceError(f"{path}: no such URDF file")
        try:  # well-formed XML with a <robot> root, checked before yourdfpy (which logs and "recovers" from broken XML)
            root = ET.parse(path).getroot()
        except ET.ParseError as e:
            raise SurfaceError(f"{path}: not a URDF file (XML error: {e})") from None
        if root.tag != "robot":
            raise SurfaceError(f"{path}: not a URDF file (the root element is <{root.tag}>, not <robot>)")
        twice = [n for n, k in Counter(el.get("name") for el in root.findall("link")).items() if k > 1]
        if twice:  # yourdfpy would keep the last one silently
            raise SurfaceError(f"{path}: two <link> elements are named {brief(twice[0])}; a URDF names each link once: "
                               "rename or remove one")
        for el in root.iter("origin"):  # poses reach /tf_static and every touch point: finite numbers only
            for att in ("xyz", "rpy"):
                v = el.get(att)
                try:
                    ok = v is None or (len(nums := [float(t) for t in v.split()]) == 3 and all(map(math.isfinite, nums)))
                except ValueError:
                    ok = False
                if not ok:
                    raise SurfaceError(f"{path}: an <origin {att}={brief(v)}> is not three finite numbers; fix the URDF")
        for j in root.findall("joint"):
            parent, child = (j.find(k).get("link") if j.find(k) is not None else None for k in ("parent", "child"))
            if parent is not None and parent == child:
                raise SurfaceError(f"{path}: joint {brief(j.get('name'))} has link {brief(parent)} as both its parent and "
                                   "its child; a joint connects two links")
        try:
            import yourdfpy
        except ImportError:  # the optional extra (pyproject: urdf)
            raise SurfaceError("reading a URDF needs yourdfpy: pip install 'sonicskin[urdf]' (or give the link's surface "
                               "in the arm file's YAML: docs/robot-frame.md)") from None
        try:
            urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
        except Exception as e:  # yourdfpy raises its own URDFError types and ValueError on a bad document
            raise SurfaceError(f"{path}: not a usable URDF ({type(e).__name__}: {e})") from None
        links = urdf.link_map
        if link_name not in links:
            raise SurfaceError(f"{path}: no link named {brief(link_name)}; its links are {sorted(links)}")
        link = links[link_name]
        shapes = [(s, "collision") for s in link.collisions] or [(s, "visual") for s in link.visuals]
        if not shapes:
            raise SurfaceError(f"{path}: link {brief(link_name)} has no collision or visual geometry: give it a <cylinder> or <box>")
        geo, which = shapes[0][0].geometry, shapes[0][1]
        origin = shapes[0][0].origin
        pose = np.eye(4) if origin is None else np.asarray(origin, dtype=float)
        if geo is None or (geo.cylinder is None and geo.box is None):
            got = "nothing" if geo is None else next((k for k in ("mesh", "sphere") if getattr(geo, k) is not None), "nothing")
            raise SurfaceError(f"{path}: link {brief(link_name)} {which} geometry is a {got}, not a <cylinder> or <box>: a skin "
                               "needs a tube or a plate (add a cylinder/box collision element for the skinned part)")
        kind = "tube" if geo.cylinder is not None else "plate"
        bad = sorted(set(overrides) - _OVERRIDES[kind])
        if bad:
            raise SurfaceError(f"{path}: link {brief(link_name)} is a {kind}: unknown option(s) {bad}; a {kind} takes "
                               f"{sorted(_OVERRIDES[kind])}")
        dims = (geo.cylinder.radius, geo.cylinder.length) if kind == "tube" else tuple(np.asarray(geo.box.size, dtype=float))
        try:
            return cls(link_name, kind, dims, pose, **overrides)
        except SurfaceError as e:
            raise SurfaceError(f"{path}: link {brief(link_name)}: {e}") from None
