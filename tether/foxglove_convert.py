"""Tether messages to Foxglove's well-known schemas: one table, type tag -> converter.

A converter takes a typed message and returns ``[(suffix, out), ...]``: ``out`` is a
``foxglove.messages`` object (protobuf on the wire) or a JSON document (a dict), and
``suffix`` is appended to the Tether topic ('' for the topic itself, '/depth' for the
depth half of an RGB-D frame). Types without an entry become plottable JSON: numbers
stay numbers, small arrays nested lists (``/topic.field[3]`` plots), non-finite floats
``null``. The live server (:mod:`tether.foxglove_bridge`) and ``tether export foxglove``
both go through :func:`convert`, so a live view and an exported log render alike.

Converters read fields by name, so this module imports no ``msgs`` module (the runtime
sits below the message library). Frames: a message's ``frame_id``, or ``"world"`` when
it has none (Foxglove's 3-D panel needs a frame to place things in).
"""
from __future__ import annotations

import base64
import math
from typing import Any, Callable

import msgspec
import numpy as np

from tether.errors import TetherError

try:
    import foxglove  # noqa: F401 - the bridge and the export import it from here (one install hint)
    from foxglove import messages as fm
except ImportError:            # an optional extra: say how to get it, in one line
    raise TetherError("the Foxglove live view and export need foxglove-sdk: pip install 'tether[foxglove]'") from None

DEFAULT_FRAME = "world"
#: Arrays up to this many elements become JSON lists (plottable); larger ones stay one base64 blob.
JSON_ARRAY_MAX = 65536

Converted = list[tuple[str, Any]]


# -- building blocks ----------------------------------------------------------------------
def timestamp(stamp_ns: int) -> fm.Timestamp:
    stamp_ns = max(int(stamp_ns), 0)
    return fm.Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def _frame(msg: Any) -> str:
    return msg.frame_id or DEFAULT_FRAME


def _yaw_pose(x: float, y: float, yaw: float, z: float = 0.0) -> fm.Pose:
    return fm.Pose(position=fm.Vector3(x=float(x), y=float(y), z=float(z)),
                   orientation=fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))


def _pose3(p: Any) -> fm.Pose:
    q = np.array([p.qw, p.qx, p.qy, p.qz], dtype=float)
    norm = float(np.linalg.norm(q)) if np.all(np.isfinite(q)) else 0.0
    w, x, y, z = (q / norm) if norm > 0 else (1.0, 0.0, 0.0, 0.0)      # a zero quaternion reads as no rotation
    return fm.Pose(position=fm.Vector3(x=p.x_m, y=p.y_m, z=p.z_m),
                   orientation=fm.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)))


def _quaternion(rotation: np.ndarray) -> fm.Quaternion:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_quat()
    return fm.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w))


_IMAGE_ENCODINGS = {("u1", 1): "mono8", ("u2", 1): "mono16", ("f4", 1): "32FC1",
                    ("u1", 3): "rgb8", ("u1", 4): "rgba8"}
_SAME_LAYOUT = {"bgr8": ("u1", 3), "bgra8": ("u1", 4), "8UC1": ("u1", 1), "16UC1": ("u2", 1),
                "mono8": ("u1", 1), "mono16": ("u2", 1), "rgb8": ("u1", 3), "rgba8": ("u1", 4), "32FC1": ("f4", 1)}


def raw_image(pixels: np.ndarray, stamp_ns: int, frame_id: str, encoding: str = "") -> fm.RawImage:
    """A ``RawImage`` of an H x W or H x W x C array; ``encoding`` is kept when it names the
    array's layout ('bgr8' stays 'bgr8'), else chosen from the dtype. Other dtypes become 32FC1."""
    a = np.asarray(pixels)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)):
        raise ValueError(f"an image is H x W or H x W x 3/4, got shape {a.shape}")
    channels = 1 if a.ndim == 2 else a.shape[2]
    key = (a.dtype.kind + str(a.dtype.itemsize), channels)
    if key not in _IMAGE_ENCODINGS:
        if channels != 1:
            raise ValueError(f"a {channels}-channel image must be uint8, got {a.dtype}")
        a, key = a.astype(np.float32), ("f4", 1)
    a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))     # Foxglove reads little-endian
    chosen = encoding if _SAME_LAYOUT.get(encoding) == key else _IMAGE_ENCODINGS[key]
    h, w = a.shape[:2]
    return fm.RawImage(timestamp=timestamp(stamp_ns), frame_id=frame_id, width=w, height=h, encoding=chosen,
                       step=w * channels * a.dtype.itemsize, data=a.tobytes())


_FIELD_TYPES = {"u1": fm.PackedElementFieldNumericType.Uint8, "f4": fm.PackedElementFieldNumericType.Float32}


def _packed(columns: dict[str, np.ndarray], dtype: str) -> tuple[list[fm.PackedElementField], bytes, int]:
    """Interleave equal-length columns of one dtype: (fields, bytes, stride)."""
    names = list(columns)
    block = np.stack([np.asarray(columns[n], dtype=dtype) for n in names], axis=-1) if names else np.zeros((0, 0))
    size = np.dtype(dtype).itemsize
    fields = [fm.PackedElementField(name=n, offset=i * size, type=_FIELD_TYPES[dtype[1:]]) for i, n in enumerate(names)]
    return fields, np.ascontiguousarray(block, dtype=dtype).tobytes(), size * len(names)


def point_cloud(points: np.ndarray, stamp_ns: int, frame_id: str, **extra: np.ndarray) -> fm.PointCloud:
    """A ``PointCloud`` of N x 3 points (float32 x, y, z) plus per-point columns of length N;
    rows with a non-finite coordinate are left out (a renderer cannot place them)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    keep = np.all(np.isfinite(pts), axis=1)
    columns = {"x": pts[keep, 0], "y": pts[keep, 1], "z": pts[keep, 2]}
    for name, values in extra.items():
        v = np.asarray(values)
        if v.shape[0] == len(pts):
            columns[name] = v[keep]
    fields, data, stride = _packed(columns, "<f4")
    return fm.PointCloud(timestamp=timestamp(stamp_ns), frame_id=frame_id, pose=_yaw_pose(0, 0, 0),
                         point_stride=stride, fields=fields, data=data)


def grid(cells: np.ndarray, stamp_ns: int, frame_id: str, *, resolution_m: float, centre_x_m: float,
         centre_y_m: float, yaw_rad: float = 0.0, names: list[str] | None = None) -> fm.Grid:
    """A ``Grid`` of rows (y) x cols (x) [x K] cells whose cell (0, 0) is centred at (centre_x_m,
    centre_y_m); Foxglove places the grid by its corner, half a cell back along both axes.
    Float cells are float32 ('value' or ``names[0]``); uint8 cells keep one field per layer."""
    c = np.asarray(cells)
    if c.ndim == 2:
        c = c[:, :, None]
    if c.ndim != 3:
        raise ValueError(f"a grid is rows x cols or rows x cols x K, got shape {c.shape}")
    dtype = "<u1" if c.dtype in (np.uint8, np.bool_) else "<f4"
    values = c.astype(dtype)
    if dtype == "<f4":
        values[np.isinf(values)] = np.nan      # inf (forbidden) has no colour in a colour map: drawn as unknown
    labels = list(names or [])[: c.shape[2]]
    labels += [("value" if c.shape[2] == 1 else f"f{k}") for k in range(len(labels), c.shape[2])]
    fields, data, stride = _packed({n: values[:, :, k] for k, n in enumerate(labels)}, dtype)
    half = resolution_m / 2
    cos, sin = math.cos(yaw_rad), math.sin(yaw_rad)
    corner = (centre_x_m - cos * half + sin * half, centre_y_m - sin * half - cos * half)
    return fm.Grid(timestamp=timestamp(stamp_ns), frame_id=frame_id, pose=_yaw_pose(*corner, yaw_rad),
                   column_count=c.shape[1], cell_size=fm.Vector2(x=resolution_m, y=resolution_m),
                   row_stride=stride * c.shape[1], cell_stride=stride, fields=fields, data=data)


def camera_calibration(info: Any, stamp_ns: int, frame_id: str) -> fm.CameraCalibration:
    fx, fy, cx, cy = info.fx_px, info.fy_px, info.cx_px, info.cy_px
    return fm.CameraCalibration(timestamp=timestamp(stamp_ns), frame_id=frame_id, width=info.width_px,
                                height=info.height_px, distortion_model="plumb_bob", D=[0.0] * 5,
                                K=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                                R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                                P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


# -- plottable JSON -------------------------------------------------------------------------
def _array_json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        if value.size <= JSON_ARRAY_MAX:
            return value.tolist()
        a = np.ascontiguousarray(value)
        return {"dtype": a.dtype.str, "shape": list(a.shape), "data": base64.b64encode(a.tobytes()).decode()}
    if isinstance(value, np.generic):
        return value.item()
    raise NotImplementedError(f"cannot convert {type(value).__name__} to JSON")


def finite(value: Any) -> Any:
    """``value`` with NaN and +-inf replaced by None (JSON has no non-finite numbers)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [finite(v) for v in value]
    return value


def as_json(msg: Any) -> dict[str, Any]:
    """A message (typed, or plain msgpack as a dict) as a plottable JSON document."""
    if isinstance(msg, msgspec.Struct):
        msg = msgspec.to_builtins(msg, enc_hook=_array_json)
    elif isinstance(msg, dict):
        msg = _plain_json(msg)
    return finite(msg)


def _plain_json(value: Any) -> Any:
    """A plain-decoded record: bytes as base64, inline array maps as nested lists when small."""
    if isinstance(value, dict):
        if set(value) == {"dtype", "shape", "data"} and isinstance(value["data"], (bytes, bytearray)):
            try:
                arr = np.frombuffer(value["data"], dtype=np.dtype(value["dtype"])).reshape(value["shape"])
                return _array_json(arr)
            except (TypeError, ValueError):
                pass
        return {str(k): _plain_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain_json(v) for v in value]
    if isinstance(value, (bytes, bytearray, memoryview)):
        return base64.b64encode(bytes(value)).decode()
    return value


def json_schema(tp: type | None) -> bytes:
    """The JSON schema of a JSON-converted type: the type's own schema, references inlined
    (Foxglove reads plain nested objects), arrays untyped (lists, or a base64 map when large)."""
    import json

    if tp is None:
        return b""
    from tether.codec import json_schema as tether_schema

    doc = tether_schema(tp)
    defs = doc.get("$defs", {})

    def inline(node: Any, depth: int = 0) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/") and depth < 16:
                target = defs.get(ref.split("/")[-1], {})
                if target.get("title") == "Array":
                    return {"description": "n-d array: nested lists, or {dtype, shape, data (base64)} when over "
                                           f"{JSON_ARRAY_MAX} elements"}
                return inline(target, depth + 1)
            return {k: inline(v, depth) for k, v in node.items() if k != "$defs"}
        if isinstance(node, list):
            return [inline(v, depth) for v in node]
        return node

    root = inline(doc)
    root.setdefault("type", "object")
    return json.dumps(root).encode()


# -- the table --------------------------------------------------------------------------------
def _fan_image(m: Any) -> Converted:
    return [("", raw_image(m.image, m.stamp_ns, m.frame_id or "sonar"))]


def _sonar_ping(m: Any) -> Converted:
    # Polar image, far ranges at the top: row 0 of a ping is nearest the sonar.
    return [("", raw_image(np.asarray(m.intensities)[::-1], m.stamp_ns, m.frame_id or "sonar"))]


def _image(m: Any) -> Converted:
    return [("", raw_image(m.data, m.stamp_ns, _frame(m), m.encoding))]


def _depth(m: Any) -> Converted:
    out: Converted = [("", raw_image(np.asarray(m.depth_m, dtype=np.float32), m.stamp_ns, _frame(m)))]
    if m.info.fx_px > 0:
        out.append(("/calibration", camera_calibration(m.info, m.stamp_ns, _frame(m))))
    return out


def _rgbd(m: Any) -> Converted:
    out: Converted = [("/rgb", raw_image(m.rgb, m.stamp_ns, _frame(m), "rgb8")),
                      ("/depth", raw_image(np.asarray(m.depth_m, dtype=np.float32), m.stamp_ns, _frame(m)))]
    if m.info.fx_px > 0:
        out.append(("/calibration", camera_calibration(m.info, m.stamp_ns, _frame(m))))
    return out


def _stereo(m: Any) -> Converted:
    return [("/left", raw_image(m.left, m.stamp_ns, _frame(m), "bgr8")),
            ("/right", raw_image(m.right, m.stamp_ns, _frame(m), "bgr8"))]


def _cloud(m: Any) -> Converted:
    return [("", point_cloud(m.points_m, m.stamp_ns, _frame(m), intensity=m.intensity, sigma_m=m.sigma_m))]


def _flow(m: Any) -> Converted:
    v = np.asarray(m.velocity_mps, dtype=np.float64).reshape(-1, 3)
    return [("", point_cloud(m.points_m, m.stamp_ns, _frame(m), vx=v[:, 0], vy=v[:, 1], vz=v[:, 2]))]


def _pose_in_frame(pose: fm.Pose, m: Any) -> fm.PoseInFrame:
    return fm.PoseInFrame(timestamp=timestamp(m.stamp_ns), frame_id=_frame(m), pose=pose)


def _pose2d(m: Any) -> Converted:
    return [("", _pose_in_frame(_yaw_pose(m.x_m, m.y_m, m.yaw_rad), m))]


def _pose3d(m: Any) -> Converted:
    return [("", _pose_in_frame(_pose3(m), m))]


def _pose_cov(m: Any) -> Converted:
    return [("", fm.PoseInFrame(timestamp=timestamp(m.stamp_ns), frame_id=m.frame_id or _frame(m.pose),
                                pose=_pose3(m.pose)))]


def _odometry(m: Any) -> Converted:
    p = m.pose
    return [("", as_json(m)), ("/pose", _pose_in_frame(_yaw_pose(p.x_m, p.y_m, p.yaw_rad), m))]


def _vehicle(m: Any) -> Converted:
    return [("", as_json(m)), ("/pose", _pose_in_frame(_yaw_pose(m.x_m, m.y_m, m.theta_rad), m))]


def _icp(m: Any) -> Converted:
    return [("", as_json(m)), ("/pose", _pose_in_frame(_pose3(m.correction), m))]


def _poses(rows: np.ndarray, m: Any) -> fm.PosesInFrame:
    xyt = np.asarray(rows, dtype=float).reshape(-1, 3)
    return fm.PosesInFrame(timestamp=timestamp(m.stamp_ns), frame_id=_frame(m),
                           poses=[_yaw_pose(x, y, t) for x, y, t in xyt if math.isfinite(x + y + t)])


def _path(m: Any) -> Converted:
    return [("", _poses(m.poses, m))]


def _trajectory(m: Any) -> Converted:
    return [("", _poses(m.poses, m))]


def _transform(m: Any) -> Converted:
    t = np.asarray(m.matrix, dtype=float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise ValueError(f"a transform is a finite 4 x 4 matrix, got shape {t.shape}")
    return [("", fm.FrameTransform(timestamp=timestamp(m.stamp_ns), parent_frame_id=_frame(m),
                                   child_frame_id=m.child_frame_id or "child",
                                   translation=fm.Vector3(x=t[0, 3], y=t[1, 3], z=t[2, 3]),
                                   rotation=_quaternion(t[:3, :3])))]


def _camera_info(m: Any) -> Converted:
    return [("", camera_calibration(m, m.stamp_ns, _frame(m)))]


def _sensor_grid(m: Any) -> Converted:
    return [("", grid(m.data, m.stamp_ns, _frame(m), resolution_m=m.resolution_m, centre_x_m=m.origin_x_m,
                      centre_y_m=m.origin_y_m, yaw_rad=m.origin_yaw_rad))]


def _cost_grid(m: Any) -> Converted:
    return [("", grid(m.cost, m.stamp_ns, _frame(m), resolution_m=m.resolution_m, centre_x_m=m.origin_x_m,
                      centre_y_m=m.origin_y_m, names=["cost"]))]


def _feature_grid(m: Any) -> Converted:
    return [("", grid(m.features, m.stamp_ns, _frame(m), resolution_m=m.resolution_m, centre_x_m=m.origin_x_m,
                      centre_y_m=m.origin_y_m, names=list(m.names)))]


#: type tag -> converter; every other type becomes plottable JSON (:func:`as_json`).
CONVERTERS: dict[str, Callable[[Any], Converted]] = {
    "sonar.FanImage": _fan_image,
    "sonar.SonarPing": _sonar_ping,
    "sonar.IcpResult": _icp,
    "sensor.Image": _image,
    "sensor.DepthImage": _depth,
    "sensor.RgbdFrame": _rgbd,
    "sensor.CameraInfo": _camera_info,
    "sensor.PointCloud": _cloud,
    "sensor.Grid": _sensor_grid,
    "vision.StereoPair": _stereo,
    "nav.FlowPoints": _flow,
    "nav.CostGrid": _cost_grid,
    "nav.FeatureGrid": _feature_grid,
    "geometry.Pose2D": _pose2d,
    "geometry.Pose3D": _pose3d,
    "geometry.PoseWithCovariance": _pose_cov,
    "geometry.Odometry2D": _odometry,
    "geometry.Path2D": _path,
    "geometry.Transform": _transform,
    "control.VehicleState": _vehicle,
    "slam.RobotTrajectory": _trajectory,
}


def convert(type_name: str, msg: Any) -> Converted:
    """What Foxglove gets for one message: ``[(topic suffix, foxglove message or JSON dict)]``.

    ``msg`` is the typed message, or a plain dict when the type is unknown here (JSON then).
    Raises ``ValueError``/``TypeError`` on content a schema cannot hold (the caller counts it).
    """
    fn = CONVERTERS.get(type_name)
    if fn is None or not isinstance(msg, msgspec.Struct):
        return [("", as_json(msg))]
    return fn(msg)
