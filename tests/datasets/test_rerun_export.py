"""The Rerun recording of a run, read back with rerun's own reader: entities, sample counts, the
simulation-time timeline, a blueprint; `rerun rrd verify` passes."""

from __future__ import annotations

from collections import Counter

import pytest
from rerun.chunk import RrdReader

from datasets.reader import read_recording
from datasets.rerun_export import TIMELINE, export_rrd
from tests.datasets.conftest import run_rerun


@pytest.fixture(scope="module")
def exported(ekf_run, tmp_path_factory):
    config, ticks, path = ekf_run
    rrd = tmp_path_factory.mktemp("rrd") / "run.rrd"
    export_rrd(read_recording(path), rrd)
    return ticks, rrd


def timed_rows(rrd) -> Counter:
    """Rows on the simulation timeline per entity path."""
    rows = Counter()
    for chunk in RrdReader(rrd).stream().to_chunks():
        if not chunk.is_static:
            assert chunk.timeline_names == [TIMELINE], chunk.entity_path
            rows[chunk.entity_path] += chunk.num_rows
    return rows


def static_entities(rrd) -> set[str]:
    return {chunk.entity_path for chunk in RrdReader(rrd).stream().to_chunks() if chunk.is_static}


def test_time_series_have_one_row_per_sample(exported):
    ticks, rrd = exported
    rows = timed_rows(rrd)
    estimates = sum(len(tick.estimates) for tick in ticks)
    imu = sum(type(s).__name__ == "ImuSample" for tick in ticks for s in tick.samples)
    truth_rows = len(ticks[::5])
    for axis in ("roll", "pitch"):
        assert rows[f"/plots/attitude/{axis}/truth"] == len(ticks)
        assert rows[f"/plots/attitude/{axis}/estimate"] == estimates
        assert rows[f"/plots/attitude/{axis}/band_3sigma"] == estimates
    assert rows["/plots/imu/accel"] == rows["/plots/imu/gyro"] == imu
    for leg in range(1, 7):
        assert rows[f"/plots/joints/leg{leg}"] == truth_rows
    assert rows["/plots/stability_margin"] == truth_rows


def test_the_3d_scene_has_terrain_robot_contacts_support_and_trajectory(exported):
    ticks, rrd = exported
    rows = timed_rows(rrd)
    truth_rows = len(ticks[::5])
    for entity in ("/world/contact_forces", "/world/support_polygon", "/world/com_projection", "/transforms/body"):
        assert rows[entity] == truth_rows, entity
    for leg in range(1, 7):
        for joint in range(1, 4):
            assert rows[f"/transforms/leg{leg}_joint{joint}"] == truth_rows
    static = static_entities(rrd)
    assert {"/world/terrain", "/world/trajectory", "/run", "/world/hexapod"} <= static
    assert any(path.startswith("/world/hexapod/visual_geometries/leg6_tibia") for path in static)


def test_the_file_carries_a_blueprint_and_verifies(exported):
    _, rrd = exported
    assert RrdReader(rrd).blueprints()
    result = run_rerun("rrd", "verify", str(rrd))
    assert result.returncode == 0, result.stdout + result.stderr
