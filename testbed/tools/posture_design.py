"""Design of the posture loops (docs/control.md): identify the plant in simulation, analyse the
discrete PI loops with python-control, report margins and draw the Bode plot.

Plant: the body's true roll, pitch or height response to a step of the posture correction (the
body-frame foot targets turned or shifted by the step) on the standing robot, fitted by a first
order lag with dead time, K exp(-L s) / (tau s + 1): the servos' position loop (servo_gain) and
the legs' and contacts' compliance. The estimator is fast next to it (the EKF follows the gyro
at 1 kHz) and is left out of the model; its lag would show up as extra dead time.

    python -m testbed.tools.posture_design [--plot docs/img/posture_bode.png]
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

import control
import numpy as np
from scipy.optimize import least_squares

from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.model.kinematics import foot_positions, inverse_kinematics_all
from testbed.control.posture import correction_rotation
from testbed.runtime.runner import build_simulation, true_roll_pitch

AXES = ("roll", "pitch", "height")
STEP = {"roll": math.radians(1.0), "pitch": math.radians(1.0), "height": 0.005}   # rad, rad, m
SETTLE = 0.5        # s standing before the step
RECORD = 0.4        # s of response after it


@dataclass(frozen=True)
class FirstOrderDeadTime:
    gain: float         # body response per unit of command
    time_constant: float    # s
    dead_time: float    # s

    def response(self, t: np.ndarray) -> np.ndarray:
        """Unit step response."""
        shifted = np.clip(t - self.dead_time, 0.0, None)
        return self.gain * (1.0 - np.exp(-shifted / self.time_constant))

    def discrete(self, dt: float) -> control.TransferFunction:
        """Zero-order-hold discretisation, the dead time as whole samples of delay."""
        lag = control.sample_system(control.tf([self.gain], [self.time_constant, 1.0]), dt, method="zoh")
        delay = control.tf([1.0], [1.0] + [0.0] * int(round(self.dead_time / dt)), dt)
        return lag * delay


def step_response(config: Config, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """(t, response / step) of the standing robot on flat ground to a step of one correction."""
    config = config.replace(run={"terrain": "flat", "gait": "stand", "controller": "none", "estimator": "none"})
    sim = build_simulation(config)
    feet = foot_positions(sim.geometry, sim.standing_targets)
    stepped = feet @ correction_rotation(STEP["roll"] if axis == "roll" else 0.0,
                                         STEP["pitch"] if axis == "pitch" else 0.0)
    stepped[:, 2] -= STEP["height"] if axis == "height" else 0.0
    stepped_targets = inverse_kinematics_all(sim.geometry, stepped)
    dt = config.run.time_step
    times, values = [], []
    for k in range(int(round((SETTLE + RECORD) / dt))):
        stepping = k * dt >= SETTLE
        sim.step(stepped_targets if stepping else sim.standing_targets)
        truth = sim.truth()
        roll, pitch = true_roll_pitch(truth)
        times.append(truth.t - SETTLE)
        values.append({"roll": roll, "pitch": pitch, "height": truth.body_position[2]}[axis])
    t, v = np.array(times), np.array(values)
    before = v[(t > -0.1) & (t <= 0.0)].mean()
    after = t > 0.0
    return t[after], (v[after] - before) / STEP[axis]


def fit_plant(t: np.ndarray, response: np.ndarray) -> FirstOrderDeadTime:
    def residual(p):
        return FirstOrderDeadTime(*p).response(t) - response
    fit = least_squares(residual, x0=[response[-20:].mean(), 0.02, 0.002],
                        bounds=([0.1, 1e-3, 0.0], [2.0, 1.0, 0.05]))
    return FirstOrderDeadTime(*fit.x)


def margins(loop: control.TransferFunction) -> tuple[float, float, float, float]:
    """Gain margin (absolute), phase margin (deg), phase and gain crossover frequencies (rad/s),
    from the loop's frequency response on a dense grid up to Nyquist (python-control's polynomial
    method loses the crossover of a slow integrator sampled at 1 kHz)."""
    omega = np.logspace(-3, math.log10(0.999 * math.pi / loop.dt), 4000)
    gain_margin, phase_margin, _, phase_crossover, gain_crossover, _ = control.stability_margins(
        control.frd(loop, omega))
    return gain_margin, phase_margin, phase_crossover, gain_crossover


def pi_controller(kp: float, ki: float, dt: float) -> control.TransferFunction:
    """C(z) = kp + ki dt z / (z - 1): testbed.control.posture.PiLoop's backward-Euler integrator."""
    return control.tf([kp + ki * dt, -kp], [1.0, -1.0], dt)


@dataclass(frozen=True)
class LoopReport:
    axis: str
    plant: FirstOrderDeadTime
    kp: float
    ki: float
    gain_margin_db: float
    phase_margin_deg: float
    crossover_rad_s: float
    loop: control.TransferFunction


def analyse(config: Config, axis: str) -> LoopReport:
    t, response = step_response(config, axis)
    plant = fit_plant(t, response)
    posture = config.posture
    kp, ki = (posture.height_kp, posture.height_ki) if axis == "height" else (posture.tilt_kp, posture.tilt_ki)
    loop = pi_controller(kp, ki, config.run.time_step) * plant.discrete(config.run.time_step)
    gain_margin, phase_margin, _, crossover = margins(loop)
    return LoopReport(axis, plant, kp, ki, 20.0 * math.log10(gain_margin), phase_margin, crossover, loop)


def bode_figure(reports: list[LoopReport], path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    omega = np.logspace(-1.5, math.log10(math.pi / reports[0].loop.dt), 400)
    figure, (magnitude_axis, phase_axis) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    for report in reports:
        magnitude, phase, _ = control.frequency_response(report.loop, omega)
        label = f"{report.axis}: GM {report.gain_margin_db:.1f} dB, PM {report.phase_margin_deg:.0f} deg"
        magnitude_axis.semilogx(omega, 20 * np.log10(magnitude), label=label)
        phase_axis.semilogx(omega, np.degrees(np.unwrap(phase)), label=report.axis)
    magnitude_axis.axhline(0.0, color="grey", lw=0.8)
    phase_axis.axhline(-180.0, color="grey", lw=0.8)
    magnitude_axis.set_ylabel("|L| (dB)")
    phase_axis.set_ylabel("phase of L (deg)")
    phase_axis.set_xlabel("frequency (rad/s)")
    magnitude_axis.legend(fontsize=8)
    magnitude_axis.set_title("Posture loops: open loop L = C(z) P(z), plant identified in simulation")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plot", help="write the Bode plot here (PNG)")
    args = parser.parse_args(argv)
    config = config_module.load()
    reports = [analyse(config, axis) for axis in AXES]
    print("| loop | plant K | tau (ms) | dead time (ms) | kp | ki (1/s) | gain margin (dB) | phase margin (deg) | crossover (rad/s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in reports:
        print(f"| {r.axis} | {r.plant.gain:.3f} | {r.plant.time_constant * 1e3:.1f} | {r.plant.dead_time * 1e3:.1f} | "
              f"{r.kp:g} | {r.ki:g} | {r.gain_margin_db:.1f} | {r.phase_margin_deg:.1f} | {r.crossover_rad_s:.1f} |")
    if args.plot:
        bode_figure(reports, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
