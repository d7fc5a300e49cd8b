"""`HexapodTestbed-v0`: the testbed as a gymnasium environment (docs/extending.md, "Gymnasium
environment"). `import testbed` registers it; `gymnasium.make("HexapodTestbed-v0", **options)`.

Each episode is a fresh run: the world, sensors and estimator of `testbed.runtime.runner.build_parts`,
stepped as `testbed run` steps them (a physics step, then the sensors on the new truth, the
estimator on their samples, the controller), with the agent in the controller's place. An action
holds for `control_period` seconds. The agent observes what the robot's own computer has: the
latest sensor samples and the estimator's latest estimate; ground truth only with `privileged=True`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium
import numpy as np
from gymnasium import spaces

from estimators.base import Estimate
from estimators.registry import NONE as NO_ESTIMATOR
from estimators.registry import check_estimator_spec
from estimators.scoring import roll_pitch_yaw
from sensors.samples import EncoderSample, FootSample, ImuSample, Sample
from testbed.control.controller import CONTROLLERS, Controller
from testbed.control.posture import tilted_targets
from testbed.model.errors import ConfigError, SimulationDiverged
from testbed.model.kinematics import LegGeometry, joint_targets_or_last
from testbed.model.truth import NUM_JOINTS, NUM_LEGS, Truth
from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.runtime.runner import Onboard, build_parts
from testbed.world.simulation import FALL_TILT

ENV_ID = "HexapodTestbed-v0"
ACTIONS = ("joints", "feet", "posture")
# The env's config starts from the testbed's defaults with a walking gait (what action="posture" corrects).
ENV_DEFAULTS: dict[str, Any] = {"run": {"gait": "tripod"}}
POSTURE_ACTION_LIMITS = (math.radians(15.0), math.radians(15.0), 0.03)   # roll, pitch (rad), height (m)
DEFAULT_REWARD_WEIGHTS = {"forward": 1.0, "tilt": 0.5, "height": 5.0, "fall": 10.0}
TERRAIN_MARGIN = 0.3        # m: an episode is truncated when the body centre comes this close to the terrain's edge
TIME_STEP_TOLERANCE = 1e-9  # relative: how close control_period must be to a multiple of the physics step


class Transition(NamedTuple):
    """One env step as the reward and termination functions see it (ground truth: the env's
    judgement, never the agent's observation)."""
    previous: Truth             # at the start of the step
    truth: Truth                # at its end
    duration: float             # s of simulated time the step took
    tilt: float                 # rad, body z axis from the vertical, at the end
    height_error: float         # m, body origin above the terrain under it minus robot.stance_height
    fell: bool                  # the body touched the ground or tilted past 45 degrees
    config: Config


def default_reward(transition: Transition, weights: dict[str, float]) -> float:
    """Forward speed along +x (m/s) minus the tilt (rad) and the height error (m), weighted, and a
    penalty on a fall."""
    forward = (transition.truth.body_position[0] - transition.previous.body_position[0]) / transition.duration
    return (weights["forward"] * forward - weights["tilt"] * transition.tilt
            - weights["height"] * abs(transition.height_error) - weights["fall"] * transition.fell)


def fell(transition: Transition) -> bool:
    """The default termination: a fall."""
    return transition.fell


class AgentController(Controller):
    """The agent's place on the robot's computer: keeps the latest samples and estimate (the
    observation) and answers the joint targets of the agent's last action."""

    def __init__(self) -> None:
        self.imu: ImuSample | None = None
        self.encoders: EncoderSample | None = None
        self.feet: FootSample | None = None
        self.estimate: Estimate | None = None
        self.targets = np.zeros(NUM_JOINTS)

    def start(self, joint_positions: np.ndarray) -> None:
        self.targets = np.array(joint_positions, dtype=float)

    def observe(self, samples: list[Sample], estimate: Estimate | None) -> None:
        for sample in samples:
            if isinstance(sample, ImuSample):
                self.imu = sample
            elif isinstance(sample, EncoderSample):
                self.encoders = sample
            elif isinstance(sample, FootSample):
                self.feet = sample
        self.estimate = estimate

    def tick(self, t: float, samples: list[Sample], estimate: Estimate | None) -> np.ndarray:
        self.observe(samples, estimate)
        return self.targets


class CorrectedPilot(AgentController):
    """The built-in pilot (gait, terrain adaptation, posture loops, inverse kinematics) with the
    agent's body correction on top: the pilot's body-frame foot targets (its `command_details`)
    turned by the correction's roll and pitch and raised by its height, as the posture loops turn
    and raise them (`testbed.control.posture.tilted_targets`), then the inverse kinematics, a leg
    out of reach keeping its last joints. It uses nothing of the pilot but the Controller interface."""

    def __init__(self, pilot: Controller, geometry: LegGeometry):
        super().__init__()
        self.pilot = pilot
        self.geometry = geometry
        self.correction = (0.0, 0.0, 0.0)       # roll rad, pitch rad, height m
        self.command = None

    def start(self, joint_positions: np.ndarray) -> None:
        super().start(joint_positions)
        self.pilot.start(joint_positions)

    def tick(self, t: float, samples: list[Sample], estimate: Estimate | None) -> np.ndarray:
        self.observe(samples, estimate)
        targets = self.pilot.tick(t, samples, estimate)
        command = self.pilot.command_details()
        if self.correction == (0.0, 0.0, 0.0) or command is None:
            self.command = command
            self.targets = np.asarray(targets, dtype=float) if targets is not None else self.targets
            return self.targets
        feet = tilted_targets(command.foot_targets, *self.correction)
        self.targets, _ = joint_targets_or_last(self.geometry, feet, self.targets)
        self.command = command._replace(foot_targets=feet, joint_targets=self.targets)
        return self.targets

    def command_details(self):
        return self.command


class HexapodTestbedEnv(gymnasium.Env):
    """The hexapod on its terrain, driven by an agent. Options (all keywords):

    - `config`: overrides of the testbed's config (a nested dict, a TOML file's path, or a
      `Config`); the env starts from the defaults with `run.gait = "tripod"`.
    - `estimator`: the estimator spec whose estimate is observed ("ekf"), or None.
    - `action`: "joints" (18 joint position targets, rad, within the joint limits), "feet" (6 x 3
      foot targets in the body frame, m, through the inverse kinematics) or "posture" (roll and
      pitch in rad and height in m added to the built-in pilot's body pose).
    - `control_period`: s an action holds, a multiple of `run.time_step` (0.01 s: 10 physics steps).
    - `privileged`: also observe the true body position, velocities and attitude.
    - `reward_weights`: weights of `default_reward` (forward, tilt, height, fall); `reward`: a
      function of a `Transition` in its place; `termination`: a function of a `Transition` that
      ends the episode (default: a fall).
    - `max_episode_steps`: truncation after this many steps (None: none; `gymnasium.make` adds
      its own time limit, 1000 steps unless given); an episode is also truncated when the body
      comes within TERRAIN_MARGIN of the terrain's edge.
    - `pilot`: the controller spec that action="posture" corrects: "posture" (the built-in pilot
      with its posture loops; the default with an estimator) or "none" (gait, terrain adaptation
      and inverse kinematics only, so that the agent's correction is the whole posture law; the
      default without an estimator). The posture loops level the body on the estimated attitude,
      so over their time constant they take out a correction held constant.
    """

    metadata = {"render_modes": []}

    def __init__(self, config: dict[str, Any] | str | Path | Config | None = None, estimator: str | None = "ekf",
                 action: str = "joints", control_period: float = 0.01, privileged: bool = False,
                 reward_weights: dict[str, float] | None = None,
                 reward: Callable[[Transition], float] | None = None,
                 termination: Callable[[Transition], bool] | None = None,
                 max_episode_steps: int | None = None, pilot: str | None = None, render_mode: str | None = None):
        if render_mode is not None:
            raise ValueError(f"{ENV_ID} does not render (render_mode {render_mode!r})")
        if action not in ACTIONS:
            raise ValueError(f"action must be one of {', '.join(ACTIONS)}, got {action!r}")
        self.config = env_config(config)
        self.estimator_spec = NO_ESTIMATOR if estimator is None else estimator
        check_estimator_spec(self.estimator_spec)
        self.physics_steps = physics_steps(control_period, self.config.run.time_step)
        self.control_period = self.physics_steps * self.config.run.time_step
        self.action = action
        self.privileged = privileged
        unknown = set(reward_weights or {}) - set(DEFAULT_REWARD_WEIGHTS)
        if unknown:
            raise ValueError(f"unknown reward weights {sorted(unknown)} (known: {', '.join(DEFAULT_REWARD_WEIGHTS)})")
        self.reward_weights = {**DEFAULT_REWARD_WEIGHTS, **(reward_weights or {})}
        self.reward_function = reward
        self.termination = termination or fell
        self.max_episode_steps = max_episode_steps
        self.pilot = pilot if pilot is not None else "none" if self.estimator_spec == NO_ESTIMATOR else "posture"
        CONTROLLERS.check_spec(self.pilot)
        self.geometry = LegGeometry.from_config(self.config.robot)
        self.action_space = self._action_space()
        self.observation_space = self._observation_space()
        self.sim = None

    # --- spaces ---------------------------------------------------------------------------------

    def _action_space(self) -> spaces.Box:
        if self.action == "joints":
            lower, upper = np.tile(self.geometry.lower, NUM_LEGS), np.tile(self.geometry.upper, NUM_LEGS)
            return spaces.Box(lower.astype(np.float32), upper.astype(np.float32), dtype=np.float32)
        if self.action == "feet":
            reach = float(np.max(self.geometry.base_distance) + self.geometry.femur + self.geometry.tibia)
            return spaces.Box(-reach, reach, shape=(NUM_LEGS, 3), dtype=np.float32)
        limits = np.array(POSTURE_ACTION_LIMITS, dtype=np.float32)
        return spaces.Box(-limits, limits, dtype=np.float32)

    def _observation_space(self) -> spaces.Dict:
        def vector(size: int) -> spaces.Box:
            return spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)
        observation = {"imu_accel": vector(3), "imu_gyro": vector(3), "joint_positions": vector(NUM_JOINTS),
                       "foot_forces": vector(NUM_LEGS), "foot_contact": spaces.MultiBinary(NUM_LEGS)}
        if self.estimator_spec != NO_ESTIMATOR:
            observation |= {"estimate": vector(4), "estimate_valid": spaces.MultiBinary(4)}
        if self.privileged:
            observation |= {"body_position": vector(3), "body_linear_velocity": vector(3),
                            "body_angular_velocity": vector(3), "body_attitude": vector(3)}
        return spaces.Dict(observation)

    # --- episode --------------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        run_seed = seed if seed is not None else int(self.np_random.integers(2**63 - 1))
        config = self.config.replace(run={"seed": run_seed})
        self.controller = self._controller(config)
        parts = build_parts(config, estimator=self.estimator_spec, controller=self.controller)
        self.sim, self.sensors = parts.sim, parts.sensors
        self.onboard = Onboard(parts)
        self.terrain_bounds = terrain_bounds(parts.sim.terrain)
        self.steps = 0
        self.error = None
        self._tick()            # t = 0: the first samples
        return self._observation(), self._info(fell=False)

    def step(self, action):
        if self.sim is None:
            raise RuntimeError("call reset() before step()")
        ik_limited = self._apply(np.asarray(action, dtype=float))
        if self.action != "posture":
            self.joint_targets = self.controller.targets       # from this physics step on
        previous = self.sim.truth()
        try:
            for _ in range(self.physics_steps):
                self.sim.step(self.joint_targets)
                self._tick()
                if self.sim.body_tilt() > FALL_TILT:
                    break
        except SimulationDiverged as error:
            self.error = str(error)
        self.steps += 1
        transition = self._transition(previous)
        reward = (self.reward_function(transition) if self.reward_function is not None
                  else default_reward(transition, self.reward_weights))
        terminated = bool(self.termination(transition)) or self.error is not None
        truncated = not terminated and (self._left_terrain() or (self.max_episode_steps is not None
                                                                 and self.steps >= self.max_episode_steps))
        info = self._info(transition.fell) | {"ik_limited": ik_limited}
        return self._observation(), float(reward), terminated, truncated, info

    def close(self) -> None:
        self.sim = None
        self.onboard = self.sensors = self.controller = None

    # --- internals ------------------------------------------------------------------------------

    def _controller(self, config: Config) -> AgentController:
        if self.action != "posture":
            return AgentController()
        return CorrectedPilot(CONTROLLERS.build(self.pilot, config), self.geometry)

    def _tick(self) -> None:
        """The sensors, the estimator and the controller after the simulation reached its current state."""
        samples = self.sensors.update(self.sim.truth())
        command, _ = self.onboard.tick(self.sim.time, samples)
        self.joint_targets = command.joint_targets

    def _apply(self, action: np.ndarray) -> bool:
        """The action into the controller; whether a foot target was out of reach."""
        low, high = self.action_space.low, self.action_space.high
        action = np.clip(action.reshape(self.action_space.shape), low, high)
        if self.action == "joints":
            self.controller.targets = action.astype(float)
        elif self.action == "feet":
            self.controller.targets, reachable = joint_targets_or_last(self.geometry, action.astype(float),
                                                                       self.controller.targets)
            return not reachable
        else:
            self.controller.correction = tuple(float(value) for value in action)
        return False

    def _transition(self, previous: Truth) -> Transition:
        truth = self.sim.truth()
        ground = float(self.sim.terrain.height(truth.body_position[:2])[0])
        tilt = self.sim.body_tilt()
        fall = bool(tilt > FALL_TILT or self.sim.body_touches_ground())
        return Transition(previous, truth, truth.t - previous.t, tilt,
                          truth.body_position[2] - ground - self.config.robot.stance_height, fall, self.config)

    def _left_terrain(self) -> bool:
        x, y = self.sim.truth().body_position[:2]
        (x0, y0), (x1, y1) = self.terrain_bounds
        return not (x0 + TERRAIN_MARGIN <= x <= x1 - TERRAIN_MARGIN and y0 + TERRAIN_MARGIN <= y <= y1 - TERRAIN_MARGIN)

    def _observation(self) -> dict[str, np.ndarray]:
        c = self.controller
        imu, encoders, feet = c.imu, c.encoders, c.feet
        observation = {
            "imu_accel": _finite(imu.accel if imu else None, 3),
            "imu_gyro": _finite(imu.gyro if imu else None, 3),
            "joint_positions": _finite(encoders.positions if encoders else None, NUM_JOINTS),
            "foot_forces": _finite(feet.normal_forces if feet else None, NUM_LEGS),
            "foot_contact": (np.asarray(feet.contact, dtype=np.int8) if feet else np.zeros(NUM_LEGS, dtype=np.int8)),
        }
        if self.estimator_spec != NO_ESTIMATOR:
            observation["estimate"], observation["estimate_valid"] = _estimate(c.estimate)
        if self.privileged:
            truth = self.sim.truth()
            observation |= {"body_position": truth.body_position.astype(np.float32),
                            "body_linear_velocity": truth.body_linear_velocity.astype(np.float32),
                            "body_angular_velocity": truth.body_angular_velocity.astype(np.float32),
                            "body_attitude": roll_pitch_yaw(truth.body_rotation[np.newaxis])[0].astype(np.float32)}
        return observation

    def _info(self, fell: bool) -> dict[str, Any]:
        info: dict[str, Any] = {"t": self.sim.time, "fell": fell}
        if self.error is not None:
            info["error"] = self.error
        return info


def env_config(overrides: dict[str, Any] | str | Path | Config | None) -> Config:
    """The env's config: ENV_DEFAULTS over the testbed's defaults, then `overrides`."""
    if isinstance(overrides, Config):
        return overrides
    if isinstance(overrides, (str, Path)):
        return config_module.load(overrides, base=ENV_DEFAULTS)
    return config_module.load(None, overrides, base=ENV_DEFAULTS)


def physics_steps(control_period: float, time_step: float) -> int:
    steps = control_period / time_step
    if round(steps) < 1 or abs(steps - round(steps)) > TIME_STEP_TOLERANCE * steps:
        raise ConfigError(f"control_period {control_period} s is not a multiple of the physics step {time_step} s")
    return int(round(steps))


def terrain_bounds(terrain) -> np.ndarray:
    """((x_min, y_min), (x_max, y_max)) of the terrain's boxes."""
    boxes = terrain.boxes
    half = np.einsum("nij,nj->ni", np.abs(boxes.rotations), boxes.half_extents)
    return np.array([(boxes.centers - half)[:, :2].min(axis=0), (boxes.centers + half)[:, :2].max(axis=0)])


def _finite(values, size: int) -> np.ndarray:
    """A sensor reading as float32, non-finite values (a faulty sensor) and no reading as zeros."""
    if values is None:
        return np.zeros(size, dtype=np.float32)
    return np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)


def _estimate(estimate: Estimate | None) -> tuple[np.ndarray, np.ndarray]:
    """(roll, pitch, yaw, body height) and which of them the estimate holds (a missing or non-finite value: 0, invalid)."""
    values = np.full(4, np.nan)
    if estimate is not None:
        height = estimate.body_height
        values[:] = estimate.roll, estimate.pitch, estimate.yaw, np.nan if height is None else height
    valid = np.isfinite(values)
    return np.where(valid, values, 0.0).astype(np.float32), valid.astype(np.int8)
