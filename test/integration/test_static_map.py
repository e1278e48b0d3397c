"""/mos/static_map: the node's cleaned local map holds static points only, in the odometry frame."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from ros_harness import BASE_STAMP, TYPES, cloud, running_harness  # noqa: E402
from scenes import street_sequence  # noqa: E402

from ros2_mos.apps.mapping import VoxelMap, VoxelMapConfig  # noqa: E402
from ros2_mos.core.config import MosConfig  # noqa: E402
from ros2_mos.core.pipeline import MosPipeline  # noqa: E402
from ros2_mos.io.pointcloud2 import decode_xyz_intensity  # noqa: E402
from ros2_mos.ros import messages as m  # noqa: E402

DOMAIN = 20 + os.getpid() % 150


def test_static_map_is_published_without_the_moving_car(tiny_model_path):
    overrides = {"model": str(tiny_model_path), "static_map.enabled": True, "static_map.insert_every": 1,
                 "static_map.publish_period": 0.2, "static_map.voxel_size": 0.1}
    with running_harness(DOMAIN, overrides) as h:
        maps: list = []
        got = threading.Event()

        def on_map(msg) -> None:
            maps.append(msg)
            got.set()

        h.peer.create_subscription(TYPES.point_cloud2, "/mos/static_map", on_map,
                                   QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))

        seq = street_sequence(6)
        for i, (pts, rem, _, _) in enumerate(seq):
            assert h.feed(cloud(BASE_STAMP + i * 100_000_000, pts, rem)) is not None
        got.clear()
        assert got.wait(5.0), "no /mos/static_map published"
        msg = maps[-1]
        assert msg.header.frame_id == "odom"
        assert m.stamp_ns(msg.header.stamp) == BASE_STAMP + 5 * 100_000_000
        xyz = decode_xyz_intensity(msg)[0]
        # The same map built offline from the pipeline's static points, and one from all points.
        offline = MosPipeline(MosConfig(model=str(tiny_model_path)))
        static_map, full_map = (VoxelMap(VoxelMapConfig(0.1, 60.0, 300000)) for _ in range(2))
        moving_total = 0
        for i, (pts, rem, _, _) in enumerate(seq):
            res = offline.process(pts, rem, (BASE_STAMP + i * 100_000_000) * 1e-9)
            static_map.insert_scan(pts[res.valid & (res.labels == 0)], res.pose)
            full_map.insert_scan(pts[res.valid], res.pose)
            moving_total += int(res.labels.sum())
        assert moving_total > 100
        np.testing.assert_allclose(np.sort(xyz, axis=0), np.sort(static_map.points, axis=0), atol=1e-4)
        assert len(full_map) > len(static_map)  # the moving points were kept out
