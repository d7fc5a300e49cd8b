"""The Rerun recording of a run, read back with rerun's own reader: entities, sample counts, the
simulation-time timeline, a blueprint; `rerun rrd verify` passes."""

from __future__ import annotations

from collections import Counter

import numpy as np
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
    for axis in ("roll", "pitch", "yaw"):
        assert rows[f"/plots/attitude/{axis}/truth"] == len(ticks)
        assert rows[f"/plots/attitude/{axis}/estimate"] == estimates
        assert rows[f"/plots/attitude/{axis}/band_3sigma"] == estimates
    for entity in ("/plots/height", "/plots/terrain/roll", "/plots/terrain/pitch", "/plots/gyro_bias/x",
                   "/plots/gyro_bias/z"):     # the EKF estimates them, with covariances
        assert rows[f"{entity}/estimate"] == rows[f"{entity}/band_3sigma"] == estimates, entity
    assert rows["/plots/imu/accel"] == rows["/plots/imu/gyro"] == imu
    for leg in range(1, 7):
        assert rows[f"/plots/joints/leg{leg}"] == truth_rows
    assert rows["/plots/stability_margin"] == truth_rows


def test_the_3d_scene_has_terrain_robot_contacts_support_and_trajectory(exported):
    ticks, rrd = exported
    rows = timed_rows(rrd)
    truth_rows = len(ticks[::5])
    for entity in ("/world/contact_forces", "/world/support_polygon", "/world/com_projection", "/transforms/body",
                   "/transforms/estimate/body"):
        assert rows[entity] == truth_rows, entity
    assert rows["/transforms/joints"] == rows["/transforms/estimate/joints"] == 18 * truth_rows
    static = static_entities(rrd)
    assert {"/world/terrain", "/world/trajectory", "/run", "/world/hexapod", "/world/hexapod_estimate"} <= static
    assert any(path.startswith("/world/hexapod/visual_geometries/leg6_tibia") for path in static)
    assert any(path.startswith("/world/hexapod_estimate/visual_geometries/body") for path in static)


def test_the_ghost_carries_the_estimated_attitude_at_the_true_position(exported, ekf_run):
    _, _, path = ekf_run
    recording = read_recording(path)
    t, positions, _ = recording.poses()
    estimates = {round(e.t, 9): e.quaternion for e in recording.estimates()}
    _, rrd = exported
    checked = 0
    for chunk in RrdReader(rrd).stream().to_chunks():
        if chunk.entity_path != "/transforms/estimate/body" or chunk.is_static:
            continue
        table = chunk.to_record_batch().to_pydict()
        times = table[TIMELINE]
        columns = {name.rsplit(":", 1)[-1]: values for name, values in table.items()}
        for time, translation, quaternion, child in list(zip(times, columns["translation"], columns["quaternion"],
                                                              columns["child_frame"]))[::50]:
            seconds = time.total_seconds() if hasattr(time, "total_seconds") else time / 1e9
            k = int(np.argmin(abs(t - seconds)))
            np.testing.assert_allclose(np.ravel(translation), positions[k], atol=1e-6)
            np.testing.assert_allclose(np.ravel(quaternion), estimates[round(seconds, 9)], atol=1e-6)
            assert np.ravel(child)[0] == "estimate/body"
            checked += 1
    assert checked > 5


def test_the_file_carries_a_blueprint_and_verifies(exported):
    _, rrd = exported
    assert RrdReader(rrd).blueprints()
    result = run_rerun("rrd", "verify", str(rrd))
    assert result.returncode == 0, result.stdout + result.stderr
