"""Tuning of the estimators: the `[estimators]` table of `testbed/defaults.toml`.

The values are the estimators' *beliefs* about the sensors and the motion (noise densities,
process noise, gates), not the sensor models themselves. Units are SI (rad, m, s) unless a key
ends in `_deg`. This module imports nothing from the rest of the testbed but its errors, so that
`testbed.runtime.config` can import it without a cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from testbed.model.validation import non_negative, positive, require

ACCEL_BIAS_MODES = ("startup", "always", "never")     # FusionConfig.accel_bias_estimation


def _probability(where: str, value: float) -> None:
    require(math.isfinite(value) and 0.5 <= value < 1.0, f"{where} must lie in [0.5, 1), got {value}")


@dataclass(frozen=True)
class FusionConfig:
    """Models of the IMU + leg-kinematics filter, shared by `ekf` and `ukf`."""
    gyro_noise_density: float          # rad/s/sqrt(Hz)
    gyro_bias_random_walk: float       # rad/s^2/sqrt(Hz)
    gyro_bias_initial_std: float       # rad/s
    gyro_scale_std: float              # scale-factor and cross-axis error, a fraction of the turn
    accel_noise_density: float         # m/s^2/sqrt(Hz)
    accel_bias_initial_std: float      # m/s^2: turn-on offset plus misalignment, per axis
    accel_bias_estimation: str         # ACCEL_BIAS_MODES: when the offset is estimated; else a "consider" state
    accel_bias_random_walk: float      # m/s^3/sqrt(Hz)
    accel_cross_axis_std: float        # rad: the z axis's sensitivity to x and y specific force (misalignment)
    body_accel_std: float              # m/s^2, std of the body acceleration (accelerometer gate, fallback noise)
    initial_tilt_std_deg: float
    initial_yaw_std_deg: float
    initial_velocity_std: float        # m/s
    accel_gate_probability: float      # chi-square gate (3 dof) of a specific force read as gravity's direction
    spike_body_accel: float            # m/s^2: a specific force implying a larger body acceleration is a spike
    gate_recovery_time: float          # s: after this long rejecting, the tilt is reopened as at start
    still_window: float                # s, span of a still-body gravity measurement (estimators/stillness.py)
    still_max_rate_dps: float          # deg/s, largest turn rate of a still body
    still_max_force_change: float      # m/s^2, largest change of the specific force within a still window
    still_force_std: float             # m/s^2, what a still body's specific force varies beyond white noise
    still_rate_std: float              # rad/s, what a standing body still turns beyond the gyro's white noise
    rolling_feet: bool                 # planted foot spheres roll as their tibiae turn (estimators/leg_odometry.py)
    stance_min_force: float            # N: a foot in contact carrying less is not planted yet (or any more)
    foot_position_std: float           # m, stance-foot position from the encoders (noise, compliance)
    foot_slip_std: float               # m/sqrt(s), random walk of a stance foot on the ground
    foot_creep_accel_std: float        # m/s^2, systematic acceleration of the stance feet's creep
    foot_sink_per_newton: float        # m/N: how far a planted foot sinks per newton of load it takes (ground compliance)
    foot_shear_per_newton: float       # m/N: how far a planted foot slides along the ground per newton of load change
    foot_load_time_constant: float     # s: the feet's loads are low-passed with it before their changes move the feet
    foot_gate_probability: float       # chi-square gate (3 dof) of a foot's innovation; beyond it, it slipped
    bias_fault_window: float           # s, span over which the tilt corrections are summed
    bias_fault_probability: float      # chi-square (2 dof) of that sum beyond which the gyro bias changed
    bias_fault_std: float              # rad/s, uncertainty added to the gyro bias when it did
    use_gyro: bool = True              # False: the body rate from the accelerometer array alone (estimators/accel_array.py)

    def __post_init__(self) -> None:
        for name in ("gyro_noise_density", "gyro_bias_initial_std", "accel_noise_density", "accel_bias_initial_std",
                     "accel_cross_axis_std", "body_accel_std", "initial_tilt_std_deg", "initial_yaw_std_deg",
                     "initial_velocity_std", "spike_body_accel", "gate_recovery_time",
                     "foot_position_std", "foot_slip_std", "bias_fault_window", "bias_fault_std"):
            positive(f"estimators.ekf.{name}", getattr(self, name))
        non_negative("estimators.ekf.gyro_bias_random_walk", self.gyro_bias_random_walk)
        non_negative("estimators.ekf.gyro_scale_std", self.gyro_scale_std)
        non_negative("estimators.ekf.foot_creep_accel_std", self.foot_creep_accel_std)
        non_negative("estimators.ekf.foot_sink_per_newton", self.foot_sink_per_newton)
        non_negative("estimators.ekf.foot_shear_per_newton", self.foot_shear_per_newton)
        non_negative("estimators.ekf.foot_load_time_constant", self.foot_load_time_constant)
        non_negative("estimators.ekf.accel_bias_random_walk", self.accel_bias_random_walk)
        non_negative("estimators.ekf.stance_min_force", self.stance_min_force)
        positive("estimators.ekf still window", self.still_window, self.still_max_rate_dps, self.still_max_force_change,
                 self.still_force_std, self.still_rate_std)
        _probability("estimators.ekf.accel_gate_probability", self.accel_gate_probability)
        _probability("estimators.ekf.foot_gate_probability", self.foot_gate_probability)
        _probability("estimators.ekf.bias_fault_probability", self.bias_fault_probability)
        require(self.accel_bias_estimation in ACCEL_BIAS_MODES,
                 f"estimators.ekf.accel_bias_estimation must be one of {', '.join(ACCEL_BIAS_MODES)}, "
                 f"got {self.accel_bias_estimation!r}")
        require(self.initial_tilt_std_deg <= 90 and self.initial_yaw_std_deg <= 90,
                 "estimators.ekf initial attitude std must not exceed 90 deg")


@dataclass(frozen=True)
class TerrainEstimatorConfig:
    """Support plane through the stance feet (used by `ekf` and `ukf`)."""
    slope_random_walk: float           # 1/sqrt(s): how fast the terrain slope under the robot changes
    height_random_walk: float          # m/sqrt(s): how fast the body height above it changes
    change_gate_probability: float     # chi-square (3 dof): beyond it the filter restarts on the new plane

    def __post_init__(self) -> None:
        positive("estimators.terrain.slope_random_walk", self.slope_random_walk)
        positive("estimators.terrain.height_random_walk", self.height_random_walk)
        _probability("estimators.terrain.change_gate_probability", self.change_gate_probability)


@dataclass(frozen=True)
class UkfConfig:
    """Merwe scaled sigma points (filterpy `MerweScaledSigmaPoints`)."""
    alpha: float
    beta: float
    kappa: float
    max_yaw_std_deg: float             # sigma points must stay within +-180 deg of the mean

    def __post_init__(self) -> None:
        require(math.isfinite(self.alpha) and 0 < self.alpha <= 1, f"estimators.ukf.alpha must lie in (0, 1], "
                                                                     f"got {self.alpha}")
        non_negative("estimators.ukf.beta", self.beta)
        non_negative("estimators.ukf.kappa", self.kappa)
        require(math.isfinite(self.max_yaw_std_deg) and 0 < self.max_yaw_std_deg <= 45,
                 f"estimators.ukf.max_yaw_std_deg must lie in (0, 45], got {self.max_yaw_std_deg}")


@dataclass(frozen=True)
class ComplementaryConfig:
    time_constant: float               # s: the accelerometer is trusted below 1 / (2 pi tau) Hz

    def __post_init__(self) -> None:
        positive("estimators.complementary.time_constant", self.time_constant)


@dataclass(frozen=True)
class MadgwickConfig:
    gain: float                        # beta of Madgwick 2010, rad/s

    def __post_init__(self) -> None:
        positive("estimators.madgwick.gain", self.gain)


@dataclass(frozen=True)
class MahonyConfig:
    k_p: float                         # 1/s
    k_i: float                         # 1/s^2

    def __post_init__(self) -> None:
        positive("estimators.mahony.k_p", self.k_p)
        non_negative("estimators.mahony.k_i", self.k_i)


@dataclass(frozen=True)
class VqfConfig:
    tau_acc: float                     # s, low-pass time constant of the inclination correction
    motion_bias_estimation: bool
    rest_bias_estimation: bool
    bias_sigma_init_deg: float         # deg/s, VQF's biasSigmaInit: its prior on the gyro offset
    bias_clip_deg: float               # deg/s, VQF's biasClip: the largest offset it estimates

    def __post_init__(self) -> None:
        positive("estimators.vqf.tau_acc", self.tau_acc)
        positive("estimators.vqf.bias_sigma_init_deg", self.bias_sigma_init_deg)
        positive("estimators.vqf.bias_clip_deg", self.bias_clip_deg)


@dataclass(frozen=True)
class EstimatorsConfig:
    ekf: FusionConfig
    terrain: TerrainEstimatorConfig
    ukf: UkfConfig
    complementary: ComplementaryConfig
    madgwick: MadgwickConfig
    mahony: MahonyConfig
    vqf: VqfConfig
