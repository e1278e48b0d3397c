"""The benchmark runs on a tiny input and reports every stage (no timing assertions)."""

import numpy as np
from scenes import street_sequence

from ros2_mos.io.bags import write_scans_bag
from ros2_mos.tools.bench import STAGES, bench_pipeline, format_table


def test_bench_pipeline_reports_every_stage(tmp_path, tiny_model_path):
    scans = street_sequence(5)
    bag = tmp_path / "bag"
    write_scans_bag(bag, ((i * 100_000_000 + 1, p, r) for i, (p, r, _, _) in enumerate(scans)))
    result = bench_pipeline(bag, tiny_model_path, scans=3, warmup=2)
    assert result.scans == 3
    assert set(STAGES) <= set(result.stage_ms)
    assert all(med > 0 and p95 >= med for med, p95 in result.stage_ms.values() if med > 0)
    assert result.total_ms[0] >= result.stage_ms["inference"][0]
    assert result.peak_rss_mb > 10
    table = format_table([result])
    assert "| decode |" in table and "end to end" in table and "residual-threshold" in table


def test_reference_pipeline_labels_every_point():
    from conftest import TEST_SENSOR

    from ros2_mos.training.reference import ReferencePipeline

    pipe = ReferencePipeline(TEST_SENSOR, n_past=2, threads=1)
    for points, rem, _, pose in street_sequence(3):
        labels, timings = pipe.process(points, rem, pose)
        assert labels.shape == (len(points),)
        assert set(np.unique(labels.numpy() if hasattr(labels, "numpy") else labels)) <= {1, 2}
        assert {"residuals", "projection", "inference", "postprocess", "total"} <= set(timings)


def test_untrained_network_is_exported_for_timing_with_its_setup(tmp_path):
    import pytest
    import typer

    from ros2_mos.cli.bench_command import _export_untrained
    from ros2_mos.core.inference import read_metadata

    path = _export_untrained("fastmos:2", tmp_path)
    meta = read_metadata(path)
    assert (meta.network, meta.input.kind, meta.input.n_past) == ("fastmos", "residual", 2)
    assert (meta.sensor.height, meta.sensor.width) == (64, 2048)
    assert "untrained" in meta.trained_on
    for bad in ("nonet:8", "salsanext", "salsanext:x"):
        with pytest.raises(typer.BadParameter):
            _export_untrained(bad, tmp_path)
