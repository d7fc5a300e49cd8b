"""Allan deviation plots of the default IMU for docs/sensors.md: `python -m testbed.tools.allan_plot`.

Simulates a still, level IMU for one hour at its configured rate (the vectorised path of the
same model the run uses), and draws each axis's overlapping Allan deviation, the noise terms
fitted to it, and the curve the configured terms predict.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 (the backend must be chosen first)
import numpy as np  # noqa: E402

from sensors.allan import NoiseTerms, allan_deviation, fit_noise_terms, model_deviation  # noqa: E402
from sensors.config import InertialAxesConfig  # noqa: E402
from sensors.imu import Imu  # noqa: E402
from sensors.motion import MotionCache  # noqa: E402
from sensors.still import still_truth  # noqa: E402
from testbed.runtime import config as testbed_config  # noqa: E402

MICRO_G = 9.80665e-6                    # m/s^2
DEG_PER_HOUR = math.radians(1) / 3600   # rad/s


def configured_terms(axes: InertialAxesConfig) -> NoiseTerms:
    return NoiseTerms(axes.noise_density, axes.bias_instability, axes.rate_random_walk)


def plot_sensor(path: Path, title: str, tau: np.ndarray, deviation: np.ndarray, axes: InertialAxesConfig,
                unit: float, unit_name: str) -> NoiseTerms:
    fitted = fit_noise_terms(tau, deviation, tau_max=tau[-1] / 10)
    long_tau = np.logspace(math.log10(tau[0]), 5, 200)
    figure, plot = plt.subplots(figsize=(7, 4.5))
    for column, axis_name in enumerate("xyz"):
        plot.loglog(tau, deviation[:, column] / unit, lw=1, label=f"simulated, {axis_name} axis")
    plot.loglog(tau, model_deviation(tau, fitted) / unit, "k-", lw=1.5,
                label=f"fit: N = {fitted.noise_density / unit:.3g} {unit_name}·√s, B = {fitted.bias_instability / unit:.3g} {unit_name}")
    configured = configured_terms(axes)
    plot.loglog(long_tau, model_deviation(long_tau, configured) / unit, "k--", lw=1,
                label=f"configured: N = {configured.noise_density / unit:.3g}, B = {configured.bias_instability / unit:.3g}")
    plot.axhline(0.664 * axes.bias_instability / unit, color="grey", ls=":", lw=1, label="0.664 B (flicker floor)")
    plot.set(xlabel="averaging time tau (s)", ylabel=f"Allan deviation ({unit_name})", title=title)
    plot.grid(True, which="both", alpha=0.3)
    plot.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return fitted


def write_allan_plots(directory: Path, hours: float = 1.0, seed: int = 0) -> dict[str, NoiseTerms]:
    config = testbed_config.load()
    imu_config = config.sensors.imu
    imu = Imu(imu_config, seed, (), MotionCache(config.run.gravity))
    _, accel, gyro = imu.record(still_truth(), int(hours * 3600 * imu_config.rate))
    tau, deviation = allan_deviation(np.hstack((accel, gyro)), imu_config.rate)
    directory.mkdir(parents=True, exist_ok=True)
    return {
        "accel": plot_sensor(directory / "allan_accel.png", f"BMI088 accelerometer model, {hours:g} h still",
                             tau, deviation[:, :3], imu_config.accel, MICRO_G, "µg"),
        "gyro": plot_sensor(directory / "allan_gyro.png", f"BMI088 gyro model, {hours:g} h still",
                            tau, deviation[:, 3:], imu_config.gyro, DEG_PER_HOUR, "°/h"),
    }


def main(argv: list[str] | None = None) -> int:
    directory = Path(argv[0] if argv else "docs/img")
    for sensor, terms in write_allan_plots(directory).items():
        print(f"{sensor}: fitted {terms}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
