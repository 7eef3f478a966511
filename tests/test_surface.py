"""A link's layout placed on its real surface (sonicskin.surface): known answers, the pose, the shipped URDF, bad input."""

import math
from pathlib import Path

import numpy as np
import pytest

from sonicskin.rig import Layout
from sonicskin.surface import LinkSurface, SurfaceError, pose_matrix

REPO = Path(__file__).resolve().parents[1]
ARM = REPO / "configs" / "arms" / "arm6.urdf"
# The shipped arm: link -> (kind, dims in m, geometry origin z in the link frame)
ARM_LINKS = {"base_link": ("tube", (0.06, 0.15), 0.075), "shoulder_link": ("tube", (0.05, 0.20), 0.10),
             "upper_arm_link": ("tube", (0.045, 0.40), 0.20), "forearm_link": ("tube", (0.0375, 0.25), 0.125),
             "wrist_link": ("tube", (0.03, 0.15), 0.075), "hand_plate": ("plate", (0.20, 0.25, 0.01), 0.125)}


def tube(**kw):
    return LinkSurface.from_dict({"frame": "forearm_link", "kind": "tube", "radius_m": 0.0375, "length_m": 0.25, **kw})


def test_tube_known_answers():
    s = tube()
    circ_cm = 2 * math.pi * 3.75
    p, n = s.point_normal([[0, 0], [circ_cm / 4, 0], [circ_cm / 2, 25.0], [0, 12.5]])
    np.testing.assert_allclose(p, [[0.0375, 0, -0.125], [0, 0.0375, -0.125], [-0.0375, 0, 0.125], [0.0375, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(n, [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [1, 0, 0]], atol=1e-12)
    # theta0 moves x = 0; the transmitter at the +z end flips the axis
    p, _ = tube(theta0_deg=90, axis_from="+z").point_normal([[0, 0], [0, 25]])
    np.testing.assert_allclose(p, [[0, 0.0375, 0.125], [0, 0.0375, -0.125]], atol=1e-12)


def test_tube_normals_are_unit_outward_radial():
    s = tube(xyz=[0.01, -0.02, 0.1], rpy=[0.3, -0.7, 1.1])
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(0, 2 * math.pi * 3.75, 200), rng.uniform(0, 25, 200)])
    p, n = s.point_normal(xy)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-12)
    # back in the tube's own frame: the normal is the radial direction of the point, and the point is on the cylinder
    R, t = s.pose[:3, :3], s.pose[:3, 3]
    pl, nl = (p - t) @ R, n @ R
    np.testing.assert_allclose(np.hypot(pl[:, 0], pl[:, 1]), 0.0375, atol=1e-12)
    np.testing.assert_allclose(nl[:, :2], pl[:, :2] / 0.0375, atol=1e-12)
    np.testing.assert_allclose(nl[:, 2], 0, atol=1e-12)


def test_plate_corners_and_faces():
    d = {"frame": "hand_plate", "kind": "plate", "width_m": 0.2, "length_m": 0.25, "thickness_m": 0.01}
    p, n = LinkSurface.from_dict(d).point_normal([[0, 0], [20, 0], [0, 25], [20, 25]])
    np.testing.assert_allclose(p, [[-0.1, -0.125, 0.005], [0.1, -0.125, 0.005], [-0.1, 0.125, 0.005], [0.1, 0.125, 0.005]])
    np.testing.assert_allclose(n, [[0, 0, 1]] * 4)
    p, n = LinkSurface.from_dict({**d, "face": "-z"}).point_normal([[10, 12.5]])
    np.testing.assert_allclose(p, [[0, 0, -0.005]], atol=1e-12)
    np.testing.assert_allclose(n, [[0, 0, -1]])


def test_the_pose_is_applied():
    # yaw 90 deg: the shape's x is the link's y; then the translation
    s = tube(xyz=[0.1, 0.2, 0.3], rpy=[0, 0, math.pi / 2])
    p, n = s.point_normal([[0, 12.5]])
    np.testing.assert_allclose(p, [[0.1, 0.2375, 0.3]], atol=1e-12)
    np.testing.assert_allclose(n, [[0, 1, 0]], atol=1e-12)
    # roll 90 deg: the plate's +z face looks along the link's -y, its length runs along the link's z (URDF's rpy)
    plate = LinkSurface.from_dict({"frame": "hand_plate", "kind": "plate", "width_m": 0.2, "length_m": 0.25,
                                   "thickness_m": 0.01, "rpy": [math.pi / 2, 0, 0]})
    p, n = plate.point_normal([[10, 25]])
    np.testing.assert_allclose(p, [[0, -0.005, 0.125]], atol=1e-12)
    np.testing.assert_allclose(n, [[0, -1, 0]], atol=1e-12)
    np.testing.assert_allclose(pose_matrix(rpy=[0, math.pi / 2, 0])[:3, :3] @ [1, 0, 0], [0, 0, -1], atol=1e-12)


def test_yaml_round_trip():
    s = tube(xyz=[0.01, 0.02, 0.1], rpy=[0.2, -0.4, 2.5], theta0_deg=30, axis_from="+z")
    back = LinkSurface.from_dict(s.to_dict())
    np.testing.assert_allclose(back.pose, s.pose, atol=1e-12)
    assert (back.frame_id, back.kind, back.dims_m, back.theta0_deg, back.axis_from) == ("forearm_link", "tube", (0.0375, 0.25),
                                                                                         30.0, "+z")


def test_every_link_of_the_shipped_urdf():
    for name, (kind, dims, z) in ARM_LINKS.items():
        s = LinkSurface.from_urdf(ARM, name)
        assert (s.frame_id, s.kind) == (name, kind)
        np.testing.assert_allclose(s.dims_m, dims)
        np.testing.assert_allclose(s.pose[:3, 3], [0, 0, z])
    # the hand plate's box is rolled 90 deg: its touched face looks along the link's -y, its length along the link's z
    p, n = LinkSurface.from_urdf(ARM, "hand_plate").point_normal([[10, 0], [10, 25]])
    np.testing.assert_allclose(p, [[0, -0.005, 0], [0, -0.005, 0.25]], atol=1e-9)
    np.testing.assert_allclose(n, [[0, -1, 0]] * 2, atol=1e-9)
    # a tube's layout starts at the link's own origin (the joint) when the transmitter sits at the -z end
    p, _ = LinkSurface.from_urdf(ARM, "forearm_link", theta0_deg=90).point_normal([[0, 0]])
    np.testing.assert_allclose(p, [[0, 0.0375, 0]], atol=1e-12)
    # the YAML form pointing into the URDF, as an arm file would (path relative to the file's folder)
    s = LinkSurface.from_dict({"urdf": "arm6.urdf", "frame": "wrist_link", "axis_from": "+z"}, base_dir=ARM.parent)
    assert s.dims_m == (0.03, 0.15) and s.axis_from == "+z"


def test_the_paper_layout_fits_the_forearm_and_not_the_wrist():
    from sonicskin.sim import Scenario

    layout = Scenario.load("stationary").make_layout()
    LinkSurface.from_urdf(ARM, "forearm_link").check_layout(layout)  # r 3.75 cm, 25 cm: the paper's tube
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_urdf(ARM, "wrist_link").check_layout(layout)
    assert str(e.value) == ("the layout's circumference 23.5619 cm is not that of the tube of wrist_link (18.85 cm = 2 pi x 3 cm): "
                            "use the link's radius in the scenario's geometry or fix radius_m")


@pytest.mark.parametrize("layout, msg", [
    (Layout((0, 1), [[1, 2], [3, 30]], None),
     "the layout spans y 2..30 cm, longer than the tube of forearm_link (25.00 cm): the layout is for another link, "
     "or its length in the URDF/YAML is wrong"),
    (Layout((0, 1), [[1, 2], [25, 3]], None),
     "the layout spans x 1..25 cm, wider than the circumference of the tube of forearm_link (23.56 cm): the layout is for "
     "another link, or its size in the URDF/YAML is wrong"),
])
def test_a_layout_that_does_not_fit_is_one_line(layout, msg):
    with pytest.raises(SurfaceError) as e:
        tube().check_layout(layout)
    assert str(e.value) == msg


def _urdf(tmp_path, geometry):
    p = tmp_path / "r.urdf"
    p.write_text(f'<robot name="r"><link name="a"><collision><geometry>{geometry}</geometry></collision></link></robot>')
    return p


@pytest.mark.parametrize("d, msg", [
    ({"frame": "f", "kind": "tube", "radius_m": 0.03, "length_m": 0.2, "radius_cm": 3},
     "links[0].surface: unknown key(s) ['radius_cm'] for a tube; the keys are ['axis_from', 'frame', 'kind', 'length_m', "
     "'radius_m', 'rpy', 'theta0_deg', 'xyz']"),
    ({"frame": "f", "kind": "cone"}, "links[0].surface: kind must be 'tube' or 'plate' (or give urdf: PATH), got 'cone'"),
    ({"frame": "f", "kind": "plate", "width_m": 0.2}, "links[0].surface: a plate needs ['length_m']"),
    ({"frame": "f", "kind": "tube", "radius_m": -0.03, "length_m": 0.2},
     "links[0].surface: tube radius_m must be a positive number of metres, got -0.03"),
    ({"frame": "f", "kind": "tube", "radius_m": 0.03, "length_m": 0.2, "xyz": [0, 0]},
     "links[0].surface: xyz must be 3 finite numbers (m), got [0, 0]"),
    ({"frame": "f", "kind": "tube", "radius_m": 0.03, "length_m": 0.2, "axis_from": "z"},
     "links[0].surface: axis_from must be '-z' or '+z' (the tube's end that holds the transmitter), got 'z'"),
    ({"frame": "f", "kind": "plate", "width_m": 0.2, "length_m": 0.2, "theta0_deg": 5},
     "links[0].surface: unknown key(s) ['theta0_deg'] for a plate; the keys are ['face', 'frame', 'kind', 'length_m', "
     "'rpy', 'thickness_m', 'width_m', 'xyz']"),
    ("tube", "links[0].surface: a surface is a mapping like {frame: forearm_link, kind: tube, radius_m: 0.0375, "
             "length_m: 0.25}, got str"),
])
def test_bad_yaml_is_one_line(d, msg):
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_dict(d, where="links[0].surface")
    assert str(e.value) == msg and "\n" not in msg


def test_bad_urdf_is_one_line(tmp_path):
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_urdf(ARM, "elbow_link")
    assert str(e.value) == (f"{ARM}: no link named 'elbow_link'; its links are ['base_link', 'forearm_link', 'hand_plate', "
                            "'shoulder_link', 'upper_arm_link', 'wrist_link']")
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_urdf(_urdf(tmp_path, '<mesh filename="a.stl"/>'), "a")
    assert str(e.value) == (f"{tmp_path / 'r.urdf'}: link 'a' collision geometry is a mesh, not a <cylinder> or <box>: a skin "
                            "needs a tube or a plate (add a cylinder/box collision element for the skinned part)")
    with pytest.raises(SurfaceError, match=r"link 'a' collision geometry is a sphere, not a <cylinder> or <box>"):
        LinkSurface.from_urdf(_urdf(tmp_path, '<sphere radius="0.1"/>'), "a")
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_urdf(ARM, "hand_plate", theta0_deg=10)
    assert str(e.value) == f"{ARM}: link 'hand_plate' is a plate: unknown option(s) ['theta0_deg']; a plate takes ['face']"
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_dict({"urdf": "no-such.urdf", "frame": "a"}, where="arm6.yaml: links[1]", base_dir=tmp_path)
    assert str(e.value) == f"arm6.yaml: links[1]: {tmp_path / 'no-such.urdf'}: no such URDF file"
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link name='a'>")
    with pytest.raises(SurfaceError, match=r"bad.urdf: not a URDF file \(XML error: "):
        LinkSurface.from_urdf(bad, "a")
    bad.write_text("<sdf/>")
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_urdf(bad, "a")
    assert str(e.value) == f"{bad}: not a URDF file (the root element is <sdf>, not <robot>)"


def test_one_contact_is_the_batched_mapping():
    """point_normal_one (each event of the live loop) gives point_normal's numbers, under a general pose, tube and plate."""
    rng = np.random.default_rng(5)
    for kind, dims in (("tube", (0.05, 0.3)), ("plate", (0.2, 0.25, 0.01))):
        for axis_face in (("-z", "+z"), ("+z", "-z")):
            s = LinkSurface("l", kind, dims, pose=pose_matrix(rng.normal(size=3), rng.normal(size=3)), theta0_deg=23.0,
                            axis_from=axis_face[0], face=axis_face[1])
            xy = rng.uniform(0, 20, size=(20, 2))
            P, N = s.point_normal(xy)
            for (x, y), p, n in zip(xy, P, N):
                p1, n1 = s.point_normal_one(x, y)
                assert np.allclose(p1, p, atol=1e-12) and np.allclose(n1, n, atol=1e-12)


def test_a_urdf_naming_a_link_twice_is_refused(tmp_path):
    """Two <link name="a">: yourdfpy kept the later one silently; which shape the skin sits on is then a guess."""
    p = tmp_path / "twice.urdf"
    p.write_text('<robot name="r"><link name="a"><collision><geometry><cylinder radius="0.03" length="0.2"/></geometry>'
                 '</collision></link><link name="a"><collision><geometry><box size="0.1 0.2 0.01"/></geometry></collision>'
                 '</link></robot>')
    with pytest.raises(SurfaceError) as e:
        LinkSurface.from_urdf(p, "a")
    assert str(e.value) == f"{p}: two <link> elements are named 'a'; a URDF names each link once: rename or remove one"
