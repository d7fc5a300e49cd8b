"""Metrics in bounded memory: the streaming scorer gives the same numbers whatever the chunks it is
fed, the whole-array `score`'s within rounding, and a live run's metrics equal its replay's."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from datasets.recorder import McapRecorder
from datasets.replay import replay
from estimators.base import Estimate
from estimators.scoring import METRIC_KEYS, StreamingScore, estimate_arrays, score, support_plane_truth
from testbed.runtime import config as config_module
from testbed.runtime.metrics import RunMetrics
from testbed.runtime.runner import run

STEPS = 2 * StreamingScore.BLOCK_STEPS + 1234
FOOT_RADIUS = 0.02


def synthetic_run(seed: int):
    """Truth of a rocking, yawing body on four to six feet, and a noisy estimator with a
    covariance and a support plane at every other step."""
    rng = np.random.default_rng(seed)
    t = np.arange(STEPS) * 1e-3
    roll, pitch, yaw = 0.1 * np.sin(2 * t), -0.05 + 0.03 * np.cos(3 * t), 0.3 * t
    quaternion = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_quat()
    body = np.column_stack([0.1 * t, np.zeros_like(t), np.full_like(t, 0.12)])
    angles = np.arange(6) * np.pi / 3
    feet = body[:, None, :] + np.stack([0.2 * np.cos(angles), 0.2 * np.sin(angles), np.full(6, -0.1)], axis=1)
    feet = feet + rng.normal(0.0, 0.002, feet.shape)
    contact = rng.random((STEPS, 6)) < 0.8
    estimates = []
    for k in range(0, STEPS, 2):
        covariance = np.diag(rng.uniform(1e-5, 4e-5, 3))
        plane = {} if k % 4 else {"terrain_roll": rng.normal(0, 0.01), "terrain_pitch": rng.normal(0, 0.01),
                                  "body_height": 0.1 + rng.normal(0, 0.002)}
        estimates.append(Estimate(t[k] + 2e-4, quaternion[k], roll[k] + rng.normal(0, 0.005),
                                  pitch[k] + rng.normal(0, 0.005), yaw[k], attitude_cov=covariance, **plane,
                                  position=body[k] - body[0] + rng.normal(0, 0.003, 3),
                                  velocity=np.array([0.1, 0.0, 0.0]) + rng.normal(0, 0.002, 3),
                                  position_cov=np.diag(rng.uniform(1e-6, 1e-5, 3)),
                                  velocity_cov=np.diag(rng.uniform(1e-6, 1e-5, 3))))
    return (t, quaternion, body, feet, contact), estimates


def scored_in_chunks(truth, estimates, chunk_sizes) -> dict:
    stream = StreamingScore(FOOT_RADIUS)
    start = 0
    times = np.array([e.t for e in estimates])
    for size in chunk_sizes:
        stop = min(start + size, STEPS)
        end_time = truth[0][stop - 1]
        stream.add_estimates([e for e, te in zip(estimates, times) if truth[0][start] - 1e-3 < te <= end_time]
                             if start else [e for e, te in zip(estimates, times) if te <= end_time])
        stream.add_truth(*(column[start:stop] for column in truth))
        start = stop
        if start >= STEPS:
            break
    stream.add_estimates([e for e, te in zip(estimates, times) if te > truth[0][-1]])
    return stream.metrics()


@pytest.mark.parametrize("seed", [1, 7])
def test_the_streaming_score_does_not_depend_on_the_chunks(seed):
    truth, estimates = synthetic_run(seed)
    whole = StreamingScore(FOOT_RADIUS)
    whole.add_estimates(estimates)
    whole.add_truth(*truth)
    expected = whole.metrics()
    assert all(expected[key] is not None for key in METRIC_KEYS)
    rng = np.random.default_rng(seed)
    for chunk_sizes in ([1] * STEPS, rng.integers(1, 3000, 100).tolist(), [StreamingScore.BLOCK_STEPS] * 3):
        assert scored_in_chunks(truth, estimates, chunk_sizes) == expected


@pytest.mark.parametrize("seed", [2, 11])
def test_the_streaming_score_equals_the_whole_array_score(seed):
    (t, quaternion, body, feet, contact), estimates = synthetic_run(seed)
    stream = StreamingScore(FOOT_RADIUS)
    stream.add_estimates(estimates)
    stream.add_truth(t, quaternion, body, feet, contact)
    rotation = Rotation.from_quat(quaternion).as_matrix()
    whole = score(estimate_arrays(estimates), t, rotation,
                  support_plane_truth(t, feet, contact, body, rotation, FOOT_RADIUS), truth_position=body)
    streamed = stream.metrics()
    for key in METRIC_KEYS:
        assert streamed[key] == pytest.approx(whole[key], rel=1e-12, abs=1e-12), key


def test_nothing_to_score_gives_none():
    truth, estimates = synthetic_run(3)
    one_step = StreamingScore(FOOT_RADIUS)
    one_step.add_estimates(estimates[:5])
    one_step.add_truth(*(column[:1] for column in truth))
    assert set(one_step.metrics().values()) == {None}
    early = StreamingScore(FOOT_RADIUS)
    early.add_estimates([e for e in estimates if e.t < 0.9])
    early.add_truth(*truth)
    assert set(early.metrics().values()) == {None}


def test_truth_times_that_do_not_increase_are_refused():
    (t, *rest), estimates = synthetic_run(4)
    stream = StreamingScore(FOOT_RADIUS)
    stream.add_estimates(estimates)
    with pytest.raises(ValueError, match="increase"):
        stream.add_truth(t[::-1].copy(), *rest)
        stream.metrics()


def test_run_metrics_keep_at_most_one_block_of_steps():
    config = config_module.load(None, {"run": {"duration": 6.0, "gait": "tripod", "terrain": "flat", "estimator": "ekf"}})
    kept = []

    original = RunMetrics.add

    def add(self, tick):
        original(self, tick)
        kept.append(len(self._rows))

    RunMetrics.add = add
    try:
        outcome = run(config)
    finally:
        RunMetrics.add = original
    assert len(kept) > StreamingScore.BLOCK_STEPS and max(kept) < StreamingScore.BLOCK_STEPS
    assert outcome.metrics["tilt_rms_deg"] is not None and outcome.metrics["roll_rmse_deg"] is not None


@pytest.mark.parametrize("estimator,seed", [("ekf", 5)])
def test_a_live_run_and_its_replay_have_the_same_metrics(tmp_path, estimator, seed):
    config = config_module.load(None, {"run": {"duration": 5.0, "gait": "tripod", "terrain": "rough",
                                               "estimator": estimator, "seed": seed}})
    path = tmp_path / "run.mcap"
    outcome = run(config, McapRecorder(path))
    assert outcome.error is None
    replayed = replay(path, estimator).metrics
    assert outcome.metrics["roll_rmse_deg"] is not None and outcome.metrics["slope_error_deg"] is not None
    for key in METRIC_KEYS:
        assert replayed[key] == outcome.metrics[key], key
    assert not math.isnan(replayed["anees_tilt"])


def test_the_height_metric_is_the_vertical_height_above_the_feet_s_ground_plane():
    from testbed.runtime.metrics import carried_forward, support_plane_heights
    rng = np.random.default_rng(4)
    radius, slope_x, slope_y = 0.0125, math.tan(math.radians(17.0)), math.tan(math.radians(-6.0))
    normal = np.array([-slope_x, -slope_y, 1.0]) / math.sqrt(1.0 + slope_x ** 2 + slope_y ** 2)
    angles = np.radians([60, 120, 180, 240, 300, 360])
    ground_xy = 0.2 * np.column_stack([np.cos(angles), np.sin(angles)]) + rng.uniform(-0.03, 0.03, (50, 6, 2))
    ground = np.concatenate([ground_xy, (ground_xy @ [slope_x, slope_y])[..., None] + 0.3], axis=2)
    feet = ground + radius * normal                     # sphere centres touching the plane
    body_xy = rng.uniform(-0.05, 0.05, (50, 2))
    height = rng.uniform(0.05, 0.15, 50)
    body = np.column_stack([body_xy, body_xy @ [slope_x, slope_y] + 0.3 + height])
    contact = rng.random((50, 6)) < 0.7
    contact[:10] = [True, False, True, False, True, False]
    contact[10] = [True, True, False, False, False, False]             # two feet: no plane
    measured = support_plane_heights(body, feet, contact, radius)
    three = contact.sum(axis=1) >= 3
    np.testing.assert_allclose(measured[three], height[three], rtol=1e-9, atol=1e-12)
    assert np.isnan(measured[~three]).all()
    filled = carried_forward(measured, 0.5)
    previous = np.flatnonzero(three)
    for step in np.flatnonzero(~three):
        before = previous[previous < step]
        assert filled[step] == (measured[before[-1]] if len(before) else 0.5)


def test_crossing_tilts_count_the_posture_benchmark_s_window_whatever_the_blocks():
    """A step edge at x = 1 and a rough patch [2, 3]: feet 0.3 m apart walk at 0.1 m/s; the tilt
    peaks inside each crossing window (edge: 0.5 s before the front foot passes to 1 s after the
    rear one has) and beyond them. Fed as one block, in blocks of 700 ticks or of 97 (shorter than
    the lead), the maxima are those of the windows alone."""
    from testbed.runtime.metrics import CrossingTilts
    from testbed.world.terrain.base import EDGE, ROUGH_PATCH, TerrainFeature
    features = [TerrainFeature(EDGE, 1.0, 1.0), TerrainFeature(ROUGH_PATCH, 2.0, 3.0)]
    t = np.arange(0.0, 40.0, 0.001)
    body = 0.1 * t
    feet_x = body[:, None] + np.linspace(-0.15, 0.15, 6)
    tilt = np.full_like(t, 0.2)
    # the front foot passes 1.0 at 8.5 s, the rear one at 11.5 s; the rough patch 18.5 ... 31.5 s
    for when, value in ((8.05, 1.5), (12.45, 1.7), (12.6, 9.0), (25.0, 2.5), (32.6, 9.0), (7.9, 9.0)):
        tilt[np.argmin(np.abs(t - when))] = value
    for block in (len(t), 700, 97):
        crossings = CrossingTilts(features)
        for start in range(0, len(t), block):
            rows = slice(start, start + block)
            crossings.add(t[rows], tilt[rows], feet_x[rows])
        assert crossings.metrics() == {"edge_tilt_max_deg": 1.7, "rough_tilt_max_deg": 2.5}
    assert CrossingTilts([]).metrics() == {"edge_tilt_max_deg": None, "rough_tilt_max_deg": None}


def test_the_height_metric_stands_the_body_on_the_feet_resting_on_the_ground_whatever_the_contact_model():
    """Feet on both levels of a 5 cm step: those whose sphere rests within GROUND_TOLERANCE of the
    ground carry the plane, whatever a contact model's flags say (DART's chatter on loaded feet);
    a foot lifted 3 mm does not. Fed in blocks, the height error RMS is the plane's."""
    from testbed.runtime.metrics import PostureSums, carried_forward, support_plane_heights
    from testbed.world.stability import GROUND_TOLERANCE, feet_on_ground
    from testbed.world.terrain import make_terrain
    config = config_module.load(None, {"run": {"terrain": "step"},
                                       "terrain": {"step_height": 0.05, "step_edge_x": 0.0}})
    terrain = make_terrain("step", config, np.random.default_rng(0))
    radius = config.robot.foot_radius
    rng = np.random.default_rng(8)
    steps = 3000
    t = config.startup_time + 1.0 + np.arange(steps) * 1e-3
    xy = np.array([[0.15, 0.12], [0.16, 0.0], [0.15, -0.12], [-0.15, 0.12], [-0.14, 0.0], [-0.15, -0.12]])
    ground = np.where(xy[:, 0] > 0.0, 0.05, 0.0) + terrain.height(np.array([[-1.0, 0.0]]))[0]
    gap = rng.uniform(0.0, 0.9 * GROUND_TOLERANCE, (steps, 6))
    lifted = rng.integers(0, 6, steps)
    gap[np.arange(steps) % 3 == 0, lifted[np.arange(steps) % 3 == 0]] = 0.003
    feet = np.empty((steps, 6, 3))
    feet[:, :, :2] = xy
    feet[:, :, 2] = ground + radius + gap
    body = np.column_stack([rng.uniform(-0.01, 0.01, (steps, 2)), 0.15 + rng.uniform(-0.004, 0.004, steps)])
    on_ground = gap <= GROUND_TOLERANCE
    np.testing.assert_array_equal(feet_on_ground(terrain, feet, radius), on_ground)
    assert on_ground.sum(axis=1).min() == 5
    sums = PostureSums(config, terrain)
    quaternions = np.tile([0.0, 0.0, 0.0, 1.0], (steps, 1))
    for start in range(0, steps, 700):
        rows = slice(start, start + 700)
        sums.add(t[rows], quaternions[rows], body[rows], feet[rows])
    expected = carried_forward(support_plane_heights(body, feet, on_ground, radius), math.nan) - config.robot.stance_height
    assert sums.metrics()["height_error_rms_m"] == pytest.approx(math.sqrt(np.mean(expected ** 2)), rel=1e-9)
    # the plane through the resting feet lies between the levels, under the body's centre
    plane_height = support_plane_heights(body, feet, on_ground, radius)
    assert np.all((plane_height > body[:, 2] - ground.max() - 0.002) & (plane_height < body[:, 2] - ground.min() + 0.002))
