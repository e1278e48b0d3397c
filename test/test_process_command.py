"""`ros2-mos process`: a bag in, the node's topics out, labels as the pipeline gives them."""

from __future__ import annotations

import numpy as np
from scenes import street_sequence
from typer.testing import CliRunner

from ros2_mos.cli import app
from ros2_mos.config import MosConfig
from ros2_mos.datasets.bags import bag_topics, iter_messages, write_scans_bag
from ros2_mos.pipeline import MosPipeline
from ros2_mos.pointcloud2 import view_cloud

STAMP0, PERIOD = 1_700_000_000_000_000_000, 100_000_000


def test_process_writes_every_output_topic(tmp_path, tiny_model_path):
    seq = street_sequence(4)
    scans = [(STAMP0 + i * PERIOD, p, r) for i, (p, r, _, _) in enumerate(seq)]
    scans.insert(2, (STAMP0 + PERIOD + 1, np.full((10, 3), np.nan, np.float32), np.zeros(10, np.float32)))
    write_scans_bag(tmp_path / "in", iter(scans))
    params = tmp_path / "p.yaml"
    params.write_text("mos_node:\n  ros__parameters:\n    topics:\n      labels: /out/labels\n")
    result = CliRunner().invoke(app, ["process", str(tmp_path / "in"), str(tmp_path / "out"),
                                      "--model", str(tiny_model_path), "--params", str(params)])
    assert result.exit_code == 0, result.output
    assert "4 scans processed, 1 skipped" in result.output
    topics = bag_topics(tmp_path / "out")
    assert topics["/out/labels"] == "sensor_msgs/msg/PointCloud2"
    assert topics["/mos/odometry"] == "nav_msgs/msg/Odometry" and topics["/tf"] == "tf2_msgs/msg/TFMessage"
    assert topics["/points"] == "sensor_msgs/msg/PointCloud2" and topics["/mos/mask"] == "sensor_msgs/msg/Image"
    labels = [msg for _, _, msg in iter_messages(tmp_path / "out", ["/out/labels"])]
    assert len(labels) == 4
    pipe = MosPipeline(MosConfig(model=str(tiny_model_path)))
    for (stamp, pts, rem), msg in zip([s for s in scans if np.isfinite(s[1]).any()], labels):
        res = pipe.process(pts, rem, stamp * 1e-9)
        np.testing.assert_array_equal(view_cloud(msg).records["moving"], res.labels[res.valid])


def test_process_refuses_an_existing_output(tmp_path, tiny_model_path):
    write_scans_bag(tmp_path / "in", iter([(STAMP0, *street_sequence(1)[0][:2])]))
    (tmp_path / "out").mkdir()
    result = CliRunner().invoke(app, ["process", str(tmp_path / "in"), str(tmp_path / "out"),
                                      "--model", str(tiny_model_path)])
    assert result.exit_code != 0
