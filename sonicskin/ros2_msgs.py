"""The ROS 2 message definitions :mod:`sonicskin.rosbag` writes, in the concatenated form MCAP's ``ros2msg``
schema encoding takes (the type's own ``.msg`` text, then each type it uses after a line of 80 ``=`` and
``MSG: pkg/Type``), so no ROS installation is needed.

The field lists are those of ROS 2 Humble and later (``ros2/common_interfaces``, ``ros2/rcl_interfaces``); the
CDR bytes follow the fields, so ``ros2 bag play`` decodes them with the installed types.  Comments and constants
other than the Marker's are left out (they do not change the encoding).
"""

from __future__ import annotations

__all__ = ["DEFINITIONS", "definition"]

_SEP = "=" * 80

_MSGS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PointStamped": "std_msgs/Header header\nPoint point\n",
    "geometry_msgs/Wrench": "Vector3 force\nVector3 torque\n",
    "geometry_msgs/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "visualization_msgs/UVCoordinate": "float32 u\nfloat32 v\n",
    "visualization_msgs/MeshFile": "string filename\nuint8[] data\n",
    "visualization_msgs/Marker": (
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\nint32 LINE_LIST=5\n"
        "int32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\nint32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\n"
        "int32 TRIANGLE_LIST=11\nint32 ARROW_STRIP=12\n"
        "int32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n"
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\n"
        "geometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\nbool frame_locked\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n"
        "sensor_msgs/CompressedImage texture\nUVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\n"
        "MeshFile mesh_file\nbool mesh_use_embedded_materials\n"),
    "visualization_msgs/MarkerArray": "Marker[] markers\n",
}

# The types each message uses, directly or not, in the order they are appended.
_DEPS = {
    "geometry_msgs/PointStamped": ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Point"],
    "geometry_msgs/WrenchStamped": ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Wrench", "geometry_msgs/Vector3"],
    "visualization_msgs/MarkerArray": [
        "visualization_msgs/Marker", "std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Pose", "geometry_msgs/Point",
        "geometry_msgs/Quaternion", "geometry_msgs/Vector3", "std_msgs/ColorRGBA", "builtin_interfaces/Duration",
        "sensor_msgs/CompressedImage", "visualization_msgs/UVCoordinate", "visualization_msgs/MeshFile"],
}


def definition(name: str) -> str:
    """The concatenated definition of ``name`` (``"geometry_msgs/msg/PointStamped"`` or ``"geometry_msgs/PointStamped"``)."""
    key = name.replace("/msg/", "/")
    parts = [_MSGS[key]] + [f"{_SEP}\nMSG: {dep}\n{_MSGS[dep]}" for dep in _DEPS[key]]
    return "".join(parts)


#: the schemas written, by their ROS 2 type name
DEFINITIONS = {t: definition(t) for t in ("geometry_msgs/msg/PointStamped", "geometry_msgs/msg/WrenchStamped",
                                           "visualization_msgs/msg/MarkerArray")}
