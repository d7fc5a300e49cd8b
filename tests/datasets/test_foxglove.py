"""What Foxglove reads from a native recording: /tf holds every link's frame at the truth rate, and
chained from the world they put each foot where the simulation had it; /robot_description holds
the URDF as a std_msgs/String-like `data` field."""

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

import testbed
from datasets.links import LinkTree
from testbed.model.robot import LEG_NAMES

FOOT_IN_TIBIA = np.array([0.12, 0.0, 0.0])      # m, the tibia's tip: the foot sphere's centre in the URDF


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    path = tmp_path_factory.mktemp("foxglove") / "walk.mcap"
    testbed.run({"run": {"terrain": "rough", "gait": "tripod", "duration": 3.0, "seed": 5}}, out=path)
    return testbed.load(path)


def test_tf_holds_the_body_and_every_joint_s_child_link_at_the_truth_rate(walk):
    frames, stamps = set(), []
    with open(walk.path, "rb") as stream:
        for _, _, message, decoded in make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/tf"]):
            frames |= {(tf.parent_frame_id, tf.child_frame_id) for tf in decoded.transforms}
            assert {tf.timestamp.seconds * 10**9 + tf.timestamp.nanos for tf in decoded.transforms} == {message.log_time}
            stamps.append(message.log_time)
    assert len({child for _, child in frames}) == 19 and ("world", "body") in frames
    assert np.median(np.diff(stamps)) == pytest.approx(1e9 / float(walk.run_info["truth_rate_hz"]))


def test_the_link_frames_chained_from_the_world_put_each_foot_where_the_simulation_had_it(walk):
    tf, feet = walk.table("/tf"), walk.table("/truth/feet").set_index("t")
    rows = tf.iloc[::37]
    assert len(rows) > 10
    for _, row in rows.iterrows():
        nearest = feet.index.get_indexer([row.t], method="nearest")[0]     # /tf's t: its nanosecond stamp
        assert abs(feet.index[nearest] - row.t) < 1e-9
        foot_truth = feet.iloc[nearest]
        for leg, name in enumerate(LEG_NAMES, start=1):
            position, rotation = pose(row, "body")
            for link in ("coxa", "femur", "tibia"):
                translation, turn = pose(row, f"{name}_{link}")
                position, rotation = position + rotation.apply(translation), rotation * turn
            foot = position + rotation.apply(FOOT_IN_TIBIA)
            expected = [foot_truth[f"foot_positions_leg{leg}_{axis}"] for axis in "xyz"]
            np.testing.assert_allclose(foot, expected, rtol=0, atol=1e-12)


def test_robot_description_is_the_recorded_urdf_once_at_t0(walk):
    table = walk.table("/robot_description")
    assert list(table.t) == [0.0]
    urdf = table.data[0]
    assert "<robot" in urdf and len(LinkTree.from_urdf(urdf).joints) == 18


def pose(row, frame: str) -> tuple[np.ndarray, Rotation]:
    return (np.array([row[f"{frame}_translation_{axis}"] for axis in "xyz"]),
            Rotation.from_quat([row[f"{frame}_rotation_{axis}"] for axis in "xyzw"]))
