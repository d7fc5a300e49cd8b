"""The gymnasium environment HexapodTestbed-v0: registration, gymnasium's checker, vector envs,
determinism, what the agent observes, and what its actions do."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import testbed
from testbed.gym_env import HexapodTestbedEnv, Transition
from testbed.model.kinematics import foot_positions

ENV_ID = "HexapodTestbed-v0"
SENSOR_KEYS = {"imu_accel", "imu_gyro", "joint_positions", "foot_forces", "foot_contact"}
TRUTH_KEYS = {"body_position", "body_linear_velocity", "body_angular_velocity", "body_attitude"}


@pytest.mark.parametrize("imports", ["import testbed, gymnasium", "import gymnasium, testbed"])
def test_registered_whichever_is_imported_first(imports):
    code = f"{imports}; print(gymnasium.spec('{ENV_ID}').entry_point)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "testbed.gym_env:HexapodTestbedEnv"


@pytest.mark.parametrize("action", ["joints", "feet", "posture"])
def test_passes_gymnasiums_env_checker(action):
    env = gymnasium.make(ENV_ID, action=action)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)    # the advice on unbounded and unnormalised boxes
        check_env(env.unwrapped)
    env.close()


def test_steps_in_an_async_vector_env():
    envs = gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(ENV_ID, max_episode_steps=50)] * 2)
    try:
        observations, _ = envs.reset(seed=[0, 1])
        assert observations["joint_positions"].shape == (2, 18)
        envs.action_space.seed(0)
        for _ in range(3):
            observations, rewards, terminated, truncated, _ = envs.step(envs.action_space.sample())
        assert rewards.shape == (2,) and np.all(np.isfinite(rewards))
        assert np.all(observations["imu_accel"][:, 2] != 0.0)
    finally:
        envs.close()


def rollout(env: gymnasium.Env, seed: int, steps: int) -> list[dict]:
    observations = [env.reset(seed=seed)[0]]
    env.action_space.seed(seed)
    for _ in range(steps):
        observations.append(env.step(env.action_space.sample())[0])
    return observations


def test_reset_with_a_seed_is_deterministic():
    env = gymnasium.make(ENV_ID, action="feet")
    first, second = rollout(env, 7, 20), rollout(env, 7, 20)
    other = rollout(gymnasium.make(ENV_ID, action="feet"), 7, 20)
    for a, b, c in zip(first, second, other):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
            np.testing.assert_array_equal(a[key], c[key])
    assert not np.array_equal(first[5]["imu_gyro"], rollout(env, 8, 5)[5]["imu_gyro"])   # another seed, other noise


def test_observes_no_ground_truth_unless_privileged():
    plain = gymnasium.make(ENV_ID)
    observation, _ = plain.reset(seed=0)
    assert set(observation) == SENSOR_KEYS | {"estimate", "estimate_valid"}
    assert set(gymnasium.make(ENV_ID, estimator=None).reset(seed=0)[0]) == SENSOR_KEYS
    privileged = gymnasium.make(ENV_ID, privileged=True)
    observation, _ = privileged.reset(seed=0)
    assert set(observation) == SENSOR_KEYS | {"estimate", "estimate_valid"} | TRUTH_KEYS
    assert observation["body_position"][2] == pytest.approx(0.10, abs=0.01)


def test_standing_joint_targets_keep_the_robot_standing():
    env = HexapodTestbedEnv(estimator="ekf", privileged=True)
    observation, _ = env.reset(seed=0)
    standing = env.sim.standing_targets.astype(np.float32)
    total = 0.0
    for _ in range(50):
        observation, reward, terminated, truncated, info = env.step(standing)
        total += reward
        assert not (terminated or truncated)
    np.testing.assert_allclose(observation["joint_positions"], standing, atol=0.02)
    assert observation["estimate_valid"].tolist() == [1, 1, 1, 1]
    assert abs(observation["estimate"][0]) < 0.02 and abs(observation["estimate"][1]) < 0.02
    assert info["t"] == pytest.approx(0.5)
    assert abs(total) < 1.0        # no progress, little tilt or height error


def test_foot_targets_go_through_the_inverse_kinematics():
    env = HexapodTestbedEnv(action="feet", estimator=None)
    env.reset(seed=0)
    feet = foot_positions(env.geometry, env.sim.standing_targets)
    feet[0, 2] += 0.03      # lift the front left foot by 3 cm
    for _ in range(30):
        observation, *_ = env.step(feet.astype(np.float32))
    reached = foot_positions(env.geometry, observation["joint_positions"].astype(float))
    np.testing.assert_allclose(reached, feet, atol=0.005)
    assert observation["foot_contact"][0] == 0


def test_posture_correction_turns_the_body():
    env = HexapodTestbedEnv(action="posture", estimator=None, privileged=True)
    env.reset(seed=0)
    for _ in range(20):     # within the start-up's still time: the gait stands
        observation, *_ = env.step(np.array([0.1, 0.0, 0.0], dtype=np.float32))
    roll, pitch, _ = observation["body_attitude"]
    assert roll == pytest.approx(0.1, abs=0.02) and abs(pitch) < 0.02


def test_reward_and_termination_are_configurable():
    calls = []

    def reward(transition: Transition) -> float:
        calls.append(transition)
        return -transition.tilt

    env = HexapodTestbedEnv(reward=reward, termination=lambda transition: transition.truth.t >= 0.05)
    env.reset(seed=0)
    for step in range(5):
        _, value, terminated, _, _ = env.step(env.sim.standing_targets)
        assert value == -calls[-1].tilt and calls[-1].duration == pytest.approx(0.01)
        assert terminated == (step == 4)
    with pytest.raises(ValueError, match="unknown reward weights"):
        HexapodTestbedEnv(reward_weights={"speed": 1.0})


def test_episode_truncates_at_max_episode_steps_and_terminates_on_a_fall():
    env = HexapodTestbedEnv(max_episode_steps=3, estimator=None)
    env.reset(seed=0)
    results = [env.step(env.sim.standing_targets)[2:4] for _ in range(3)]
    assert results == [(False, False), (False, False), (False, True)]
    env = HexapodTestbedEnv(estimator=None, max_episode_steps=None)
    env.reset(seed=0)
    limp = env.action_space.high.copy()          # every joint to its upper limit: the body drops
    for _ in range(300):
        _, reward, terminated, truncated, info = env.step(limp)
        if terminated:
            break
    assert terminated and info["fell"] and reward < -5.0


def test_control_period_must_be_a_multiple_of_the_physics_step():
    assert HexapodTestbedEnv(control_period=0.02, estimator=None).physics_steps == 20
    with pytest.raises(testbed.model.errors.ConfigError):
        HexapodTestbedEnv(control_period=0.0125)


def test_gymnasium_make_limits_episodes_to_1000_steps_or_as_asked():
    assert gymnasium.make(ENV_ID).spec.max_episode_steps == 1000
    env = gymnasium.make(ENV_ID, max_episode_steps=2, estimator=None)
    env.reset(seed=0)
    standing = env.unwrapped.sim.standing_targets.astype(np.float32)
    assert [env.step(standing)[3] for _ in range(2)] == [False, True]
