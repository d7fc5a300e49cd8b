"""`python -m testbed.tools.warmup`: compile the numba kernels of a run into numba's on-disk cache,
so that the first `testbed run` goes at the speed of the next ones. `make run` and `make test` call
it once, after installing.

It simulates a few seconds of the main scenario (the tripod down the step, the EKF, the posture
controller: past the start-up, into the walk), which calls every kernel of the run loop. A kernel
whose source changed since is compiled again by the run that needs it, which reports that time
as `compile_s` (outside its `realtime_factor`).
"""

from __future__ import annotations

import sys
import time

from numba.core.event import Listener, install_listener

from datasets.progress import ProgressRecorder, show_progress
from testbed.runtime import config as config_module
from testbed.runtime.recording import NullRecorder
from testbed.runtime.runner import run

SCENARIO = {"run": {"terrain": "step", "gait": "tripod", "estimator": "ekf", "controller": "posture",
                    "duration": 3.5}}


class CompiledKernels(Listener):
    """Counts the kernels numba compiles (nested ones included) while installed."""

    def __init__(self):
        self.count = 0

    def on_start(self, event) -> None:
        pass

    def on_end(self, event) -> None:
        self.count += 1


def warm_up(quiet: bool = False) -> tuple[int, float]:
    """Run SCENARIO; the number of kernels compiled and the wall time it took."""
    config = config_module.load(None, SCENARIO)
    recorder = ProgressRecorder(NullRecorder(), desc="kernels") if show_progress(quiet) else NullRecorder()
    started = time.perf_counter()
    with install_listener("numba:compile", CompiledKernels()) as compiled:
        run(config, recorder)
    return compiled.count, time.perf_counter() - started


def main() -> int:
    print("compiling kernels, first run only (a few minutes; cached for the next runs)", file=sys.stderr, flush=True)
    count, wall = warm_up()
    print(f"compiled {count} kernels in {wall:.0f} s" if count else f"kernels already compiled ({wall:.1f} s)",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
