"""tether.foxglove_convert and tether export foxglove: every converter's output decodes with
the schema Foxglove publishes for it (the SDK's protobuf FileDescriptorSet), values intact."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

foxglove = pytest.importorskip("foxglove")
pytest.importorskip("google.protobuf")

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402

from msgs.geometry import Odometry2D, Path2D, Pose2D, Pose3D, PoseWithCovariance, Transform  # noqa: E402
from msgs.nav import CostGrid, FeatureGrid, FlowPoints  # noqa: E402
from msgs.sensor import CameraInfo, DepthImage, Grid, Image, PointCloud, RgbdFrame  # noqa: E402
from msgs.slam import RobotTrajectory  # noqa: E402
from msgs.sonar import FanImage, IcpResult, SonarPing  # noqa: E402
from msgs.std import Float64, NodeStats  # noqa: E402
from msgs.swarm import SwarmState  # noqa: E402
from msgs.vision import StereoPair  # noqa: E402
from msgs.control import VehicleState  # noqa: E402
from tether.foxglove_convert import CONVERTERS, JSON_ARRAY_MAX, convert, json_schema  # noqa: E402
from tether.message import message_type  # noqa: E402

RNG = np.random.default_rng(17)
STAMP = 1_700_000_000_123_456_789
INFO = CameraInfo(width_px=6, height_px=4, fx_px=50.0, fy_px=51.0, cx_px=3.0, cy_px=2.0)


def decoder(schema: "foxglove.Schema"):
    """The protobuf class of a Foxglove schema, built from the schema's own FileDescriptorSet."""
    assert schema.encoding == "protobuf"
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def decoded(out):
    """Encode a Foxglove message with the SDK, decode it with its published schema."""
    return decoder(type(out).get_schema()).FromString(out.encode())


SAMPLES = {
    "sonar.FanImage": FanImage(image=RNG.integers(0, 255, (5, 7), dtype=np.uint8), stamp_ns=STAMP, frame_id="fls"),
    "sonar.SonarPing": SonarPing(intensities=RNG.integers(0, 65535, (8, 3), dtype=np.uint16), stamp_ns=STAMP),
    "sonar.IcpResult": IcpResult(correction=Pose3D(x_m=1.0, qw=0.0, qz=1.0), stamp_ns=STAMP),
    "sensor.Image": Image(data=RNG.integers(0, 255, (4, 6, 3), dtype=np.uint8), encoding="bgr8", stamp_ns=STAMP),
    "sensor.DepthImage": DepthImage(depth_m=RNG.random((4, 6)).astype(np.float32), info=INFO, stamp_ns=STAMP),
    "sensor.RgbdFrame": RgbdFrame(rgb=RNG.integers(0, 255, (4, 6, 3), dtype=np.uint8),
                                  depth_m=RNG.random((4, 6)).astype(np.float32), info=INFO, stamp_ns=STAMP),
    "sensor.CameraInfo": INFO,
    "sensor.PointCloud": PointCloud(points_m=RNG.normal(size=(9, 3)).astype(np.float32),
                                    intensity=RNG.random(9).astype(np.float32), stamp_ns=STAMP),
    "sensor.Grid": Grid(data=RNG.random((3, 5)).astype(np.float32), resolution_m=0.5, origin_x_m=2.0,
                        origin_y_m=-1.0, origin_yaw_rad=math.pi / 2),
    "vision.StereoPair": StereoPair(left=np.zeros((2, 3, 3), np.uint8), right=np.ones((2, 3, 3), np.uint8)),
    "nav.FlowPoints": FlowPoints(points_m=RNG.normal(size=(4, 3)).astype(np.float32),
                                 velocity_mps=RNG.normal(size=(4, 3)).astype(np.float32)),
    "nav.CostGrid": CostGrid(cost=np.array([[1.0, np.inf], [2.0, 3.0]], np.float32), resolution_m=0.25),
    "nav.FeatureGrid": FeatureGrid(features=RNG.integers(0, 2, (2, 3, 12), dtype=np.uint8),
                                   names=[f"feat{k}" for k in range(12)]),
    "geometry.Pose2D": Pose2D(x_m=1.0, y_m=2.0, yaw_rad=-3.0, frame_id="map", stamp_ns=STAMP),
    "geometry.Pose3D": Pose3D(x_m=1.0, y_m=2.0, z_m=3.0, qw=2.0, stamp_ns=STAMP),
    "geometry.PoseWithCovariance": PoseWithCovariance(pose=Pose3D(z_m=4.0), frame_id="odom"),
    "geometry.Odometry2D": Odometry2D(pose=Pose2D(x_m=5.0, yaw_rad=1.0)),
    "geometry.Path2D": Path2D(poses=np.array([[0.0, 0.0, 0.0], [1.0, 1.0, np.pi], [np.nan, 0.0, 0.0]])),
    "geometry.Transform": Transform(child_frame_id="sonar", frame_id="base",
                                    matrix=np.array([[0.0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]])),
    "control.VehicleState": VehicleState(x_m=1.0, y_m=-1.0, theta_rad=0.5, v_front_mps=float("nan")),
    "slam.RobotTrajectory": RobotTrajectory(poses=np.array([[0.0, 1.0, 0.5], [2.0, 3.0, -0.5]]),
                                            ids=np.array([0, 1])),
}


def test_the_table_names_real_message_types_and_every_one_is_sampled():
    for tag in CONVERTERS:
        assert message_type(tag).type_name() == tag
    assert set(SAMPLES) == set(CONVERTERS)


@pytest.mark.parametrize("tag", sorted(CONVERTERS))
def test_every_converter_output_decodes_with_its_foxglove_schema(tag: str):
    outputs = convert(tag, SAMPLES[tag])
    assert outputs and len({suffix for suffix, _ in outputs}) == len(outputs)
    for suffix, out in outputs:
        if isinstance(out, dict):
            json.dumps(out, allow_nan=False)                     # strict JSON: no NaN
            continue
        assert type(out).get_schema().name == f"foxglove.{type(out).__name__}"
        msg = decoded(out)
        if hasattr(msg, "timestamp") and SAMPLES[tag].stamp_ns:
            assert msg.timestamp.seconds * 10**9 + msg.timestamp.nanos == STAMP


def _pixels(img) -> np.ndarray:
    dtype = {"mono8": "u1", "rgb8": "u1", "bgr8": "u1", "mono16": "<u2", "32FC1": "<f4"}[img.encoding]
    arr = np.frombuffer(img.data, dtype=dtype)
    assert img.step * img.height == len(img.data)
    return arr.reshape(img.height, img.width, -1).squeeze(-1) if arr.size == img.height * img.width else \
        arr.reshape(img.height, img.width, -1)


def test_images_keep_pixels_and_encodings():
    fan = decoded(convert("sonar.FanImage", SAMPLES["sonar.FanImage"])[0][1])
    assert fan.encoding == "mono8" and fan.frame_id == "fls"
    np.testing.assert_array_equal(_pixels(fan), SAMPLES["sonar.FanImage"].image)
    ping = decoded(convert("sonar.SonarPing", SAMPLES["sonar.SonarPing"])[0][1])
    assert ping.encoding == "mono16" and ping.step == 3 * 2
    np.testing.assert_array_equal(_pixels(ping), SAMPLES["sonar.SonarPing"].intensities[::-1])   # far at the top
    bgr = decoded(convert("sensor.Image", SAMPLES["sensor.Image"])[0][1])
    assert bgr.encoding == "bgr8"
    np.testing.assert_array_equal(_pixels(bgr), SAMPLES["sensor.Image"].data)
    parts = {s: decoded(o) for s, o in convert("sensor.RgbdFrame", SAMPLES["sensor.RgbdFrame"])}
    assert set(parts) == {"/rgb", "/depth", "/calibration"}
    np.testing.assert_array_equal(_pixels(parts["/depth"]), SAMPLES["sensor.RgbdFrame"].depth_m)
    assert list(parts["/calibration"].K) == [50.0, 0, 3.0, 0, 51.0, 2.0, 0, 0, 1]


def test_a_float64_image_becomes_32fc1_and_a_two_channel_one_is_refused():
    img = decoded(convert("sensor.Image", Image(data=np.eye(3), encoding="64FC1"))[0][1])
    assert img.encoding == "32FC1"
    np.testing.assert_array_equal(_pixels(img), np.eye(3, dtype=np.float32))
    with pytest.raises(ValueError, match="H x W x 3/4"):
        convert("sensor.Image", Image(data=np.zeros((2, 2, 2), np.uint8)))


def test_point_cloud_fields_and_values():
    src = SAMPLES["sensor.PointCloud"]
    cloud = decoded(convert("sensor.PointCloud", src)[0][1])
    assert [(f.name, f.offset) for f in cloud.fields] == [("x", 0), ("y", 4), ("z", 8), ("intensity", 12)]
    data = np.frombuffer(cloud.data, "<f4").reshape(-1, cloud.point_stride // 4)
    np.testing.assert_array_equal(data[:, :3], src.points_m)
    np.testing.assert_array_equal(data[:, 3], src.intensity)
    bad = PointCloud(points_m=np.array([[0, 0, 0], [np.nan, 1, 1], [1, 2, 3]], np.float32))
    kept = decoded(convert("sensor.PointCloud", bad)[0][1])
    assert len(kept.data) == 2 * kept.point_stride                 # the NaN point is left out
    sonar = PointCloud(points_m=np.array([[0, 0, 0], [np.nan, 1, 1], [1, 2, 3]], np.float32),
                       intensity=np.array([3, 4, 5], np.float32), sigma_m=np.array([0.1, 0.2, 0.3], np.float32))
    both = decoded(convert("sensor.PointCloud", sonar)[0][1])
    assert [f.name for f in both.fields] == ["x", "y", "z", "intensity", "sigma_m"]
    np.testing.assert_allclose(np.frombuffer(both.data, "<f4").reshape(2, 5)[:, 4], [0.1, 0.3])   # colour by sigma


def test_grid_corner_cells_and_forbidden_cells():
    g = decoded(convert("sensor.Grid", SAMPLES["sensor.Grid"])[0][1])
    # cell (0, 0) centred at (2, -1), grid turned 90 degrees: the corner is half a cell back on both axes
    assert (g.pose.position.x, g.pose.position.y) == pytest.approx((2.25, -1.25))
    assert (g.column_count, g.row_stride, g.cell_stride, g.cell_size.x) == (5, 20, 4, 0.5)
    np.testing.assert_array_equal(np.frombuffer(g.data, "<f4").reshape(3, 5), SAMPLES["sensor.Grid"].data)
    cost = decoded(convert("nav.CostGrid", SAMPLES["nav.CostGrid"])[0][1])
    cells = np.frombuffer(cost.data, "<f4")
    assert cost.fields[0].name == "cost" and np.isnan(cells[1]) and cells[3] == 3.0
    feats = decoded(convert("nav.FeatureGrid", SAMPLES["nav.FeatureGrid"])[0][1])
    assert [f.name for f in feats.fields][:2] == ["feat0", "feat1"] and feats.cell_stride == 12
    np.testing.assert_array_equal(np.frombuffer(feats.data, np.uint8).reshape(2, 3, 12),
                                  SAMPLES["nav.FeatureGrid"].features)


def test_poses_paths_and_transforms():
    pose = decoded(convert("geometry.Pose2D", SAMPLES["geometry.Pose2D"])[0][1])
    assert pose.frame_id == "map" and 2 * math.atan2(pose.pose.orientation.z, pose.pose.orientation.w) == \
        pytest.approx(-3.0)
    q = decoded(convert("geometry.Pose3D", SAMPLES["geometry.Pose3D"])[0][1]).pose.orientation
    assert (q.w, q.x) == (1.0, 0.0) and q.w == 1.0                 # normalised (qw was 2)
    path = decoded(convert("geometry.Path2D", SAMPLES["geometry.Path2D"])[0][1])
    assert len(path.poses) == 2 and path.poses[1].position.x == 1.0 and path.frame_id == "world"
    tf = decoded(convert("geometry.Transform", SAMPLES["geometry.Transform"])[0][1])
    assert (tf.parent_frame_id, tf.child_frame_id) == ("base", "sonar")
    assert (tf.translation.x, tf.translation.y, tf.translation.z) == (1, 2, 3)
    assert (tf.rotation.z, tf.rotation.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    with pytest.raises(ValueError, match="4 x 4"):
        convert("geometry.Transform", Transform(matrix=np.full((4, 4), np.nan)))


def test_everything_else_is_plottable_json_that_fits_its_schema():
    doc = convert("control.VehicleState", SAMPLES["control.VehicleState"])[0][1]
    assert doc["v_front_mps"] is None and doc["theta_rad"] == 0.5         # NaN -> null
    schema = json.loads(json_schema(VehicleState))
    assert schema["type"] == "object" and set(doc) <= set(schema["properties"])
    assert {k for k, v in schema["properties"].items() if v.get("type") == "number"} >= {"x_m", "theta_rad"}
    stats = convert("std.NodeStats", NodeStats(node_id="a", published={"x": 3}))[0][1]
    assert stats["published"] == {"x": 3}
    nested = json.loads(json_schema(NodeStats))
    assert "$ref" not in json.dumps(nested)                               # references inlined
    small = convert("swarm.SwarmState", SwarmState(heading_rad=np.arange(3, dtype=np.float32)))[0][1]
    assert small["heading_rad"] == [0.0, 1.0, 2.0]
    big = convert("unknown.Type", {"a": {"dtype": "<f4", "shape": [JSON_ARRAY_MAX + 1],
                                         "data": bytes(4 * (JSON_ARRAY_MAX + 1))}, "b": b"\x01"})[0][1]
    assert big["a"]["shape"] == [JSON_ARRAY_MAX + 1] and big["b"] == "AQ=="
    plain = convert("unknown.Type", {"v": {"dtype": "<f8", "shape": [2], "data": np.array([1.5, np.nan]).tobytes()}})
    assert plain[0][1] == {"v": [1.5, None]}


def test_export_writes_foxglove_schemas_and_counts_bad_records(tmp_path: Path, caplog):
    from mcap.reader import make_reader

    from tether.export import export_foxglove
    from tether.log import LogWriter

    log, out = tmp_path / "run.mcap", tmp_path / "fox.mcap"
    with LogWriter(log) as w:
        for k in range(3):
            w.write("cam/image", SAMPLES["sensor.Image"], log_time_ns=STAMP + k)
            w.write("cloud/points", SAMPLES["sensor.PointCloud"], log_time_ns=STAMP + k)
            w.write("x/value", Float64(data=float(k)), log_time_ns=STAMP + k)
        w.write("cam/image", Image(data=np.zeros((2, 2, 2), np.uint8)), log_time_ns=STAMP + 9)   # no schema holds it
        w.write_encoded("odd/thing", "nosuch.Type", b"\x81\xa1a\x01", log_time_ns=STAMP + 10)     # type unknown here
    counters = export_foxglove(log, out)
    assert (counters.converted, counters.errors) == (10, 1)
    seen: dict[str, list] = {}
    with open(out, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            seen.setdefault(channel.topic, []).append((schema.name, channel.message_encoding, message))
    assert {t: v[0][:2] for t, v in seen.items()} == {
        "cam/image": ("foxglove.RawImage", "protobuf"), "cloud/points": ("foxglove.PointCloud", "protobuf"),
        "x/value": ("std.Float64", "json"), "odd/thing": ("nosuch.Type", "json")}
    img = decoder(foxglove.messages.RawImage.get_schema()).FromString(seen["cam/image"][1][2].data)
    np.testing.assert_array_equal(_pixels(img), SAMPLES["sensor.Image"].data)
    assert [m.log_time for _, _, m in seen["x/value"]] == [STAMP, STAMP + 1, STAMP + 2]
    assert json.loads(seen["x/value"][2][2].data)["data"] == 2.0
    assert json.loads(seen["odd/thing"][0][2].data) == {"a": 1}
    assert "dropped a message on cam/image" in caplog.text


def test_real_oculus_pings_export_as_the_images_they_are(tmp_path: Path, runtime_env: dict, shared_data: Path):
    """Three real Oculus M1200d pings (../shared/data), imported, exported: each a mono8 image of the
    ping's ranges x beams, far ranges on top."""
    from mcap.reader import make_reader

    from conftest import tether
    from tether.export import export_foxglove
    from tether.log import LogReader

    log, out = tmp_path / "pings.mcap", tmp_path / "fox.mcap"
    res = tether("import", "oculus", str(shared_data / "sonar" / "oculus-m1200d" / "three_pings_8bit.raw"),
                 "-o", str(log), env=runtime_env)
    assert res.returncode == 0, res.stderr
    pings = [LogReader(log).decode(r) for r in LogReader(log).messages()]
    assert export_foxglove(log, out).converted == 3
    with open(out, "rb") as fh:
        images = [decoder(foxglove.messages.RawImage.get_schema()).FromString(m.data)
                  for _, _, m in make_reader(fh).iter_messages()]
    assert len(images) == 3
    for ping, img in zip(pings, images):
        assert (img.height, img.width, img.encoding) == (*ping.intensities.shape, "mono8")
        np.testing.assert_array_equal(_pixels(img), ping.intensities[::-1])
        assert img.timestamp.seconds * 10**9 + img.timestamp.nanos == ping.stamp_ns
