"""A recorder for tests: keeps every tick of a run (testbed.runtime.runner.run) and how it finished."""

from testbed.runtime.recording import NullRecorder


class Collect(NullRecorder):
    def __init__(self):
        self.ticks = []
        self.finished = None

    def record(self, tick):
        self.ticks.append(tick)

    def finish(self, metrics, error):
        self.finished = (metrics, error)
