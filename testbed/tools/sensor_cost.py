"""Cost of the sensors in the run loop: `python -m testbed.tools.sensor_cost` times SensorSuite.update with the
default config at the default physics step, on a still robot."""

from __future__ import annotations

import sys
import time

from sensors.still import still_truth
from sensors.suite import SensorSuite
from testbed.runtime import config as testbed_config


def update_cost(seconds: float = 10.0) -> tuple[float, int]:
    """Wall-clock seconds per simulated second of SensorSuite.update, and the samples it made."""
    config = testbed_config.load()
    suite = SensorSuite.from_config(config)
    step = config.run.time_step
    truths = [still_truth(k * step, foot_force=4.0) for k in range(1, int(round(seconds / step)) + 1)]
    start = time.perf_counter()
    samples = sum(len(suite.update(truth)) for truth in truths)
    return (time.perf_counter() - start) / seconds, samples


def main() -> int:
    config = testbed_config.load()
    seconds = 10.0
    cost, samples = update_cost(seconds)
    updates = seconds / config.run.time_step
    print(f"SensorSuite.update: {cost * 1e3:.1f} ms per simulated second "
          f"({cost * 1e6 * seconds / updates:.1f} us per {config.run.time_step * 1e3:g} ms step, "
          f"{samples / seconds:.0f} samples per simulated second)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
