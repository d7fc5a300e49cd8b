"""The Python API for notebooks and scripts (`testbed.run`, `testbed.load`, `testbed.replay`),
the same runs as the command line's `testbed run` and `testbed replay` (docs/extending.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from datasets.dataset import Dataset, load
from datasets.progress import ProgressRecorder
from datasets.recorder import McapRecorder
from datasets.replay import replay as replay_recording
from estimators.base import Estimator
from testbed.control.controller import Controller
from testbed.runtime import config as config_module
from testbed.runtime.config import Config
from testbed.runtime.recording import NullRecorder, Recorder
from testbed.runtime.runner import build_parts
from testbed.runtime.runner import run as run_loop
from testbed.world.terrain import Terrain

__all__ = ["Result", "run", "load", "replay", "Dataset", "make_config"]

@dataclass(frozen=True)
class Result:
    """What a run or a replay gives back: its metrics (the dict `testbed run --metrics` writes),
    the MCAP file when one was written, and why the run stopped early or why only part of the
    replayed file was readable (None when neither)."""
    metrics: dict
    path: Path | None = None
    error: str | None = None

    def load(self) -> Dataset:
        """The recorded run (`testbed.load(result.path)`)."""
        if self.path is None:
            raise ValueError("this result was not recorded: pass out=PATH.mcap to record it")
        return load(self.path)


def make_config(overrides: dict[str, Any] | str | Path | Config | None = None) -> Config:
    """A Config: the defaults (testbed/defaults.toml) with `overrides` (a nested dict such as
    `{"run": {"terrain": "step"}}`, or a TOML file's path) merged over them; a Config as it is."""
    if isinstance(overrides, Config):
        return overrides
    if isinstance(overrides, (str, Path)):
        return config_module.load(overrides)
    return config_module.load(None, overrides)


def run(overrides: dict[str, Any] | str | Path | Config | None = None, *,
        estimator: Estimator | str | None = None, controller: Controller | str | None = None,
        terrain: Terrain | str | None = None, out: str | Path | None = None, progress: bool = False) -> Result:
    """Simulate one scenario, as `testbed run` does. `estimator`, `controller` and `terrain`
    replace the config's: a registered name, a `MODULE:CLASS` spec, or an instance. With `out`,
    the run is recorded to that MCAP file. A run that stops early (a diverging simulation, a
    plugin that fails) gives its metrics so far and `Result.error`; Ctrl-C closes the file and
    raises KeyboardInterrupt."""
    config = make_config(overrides)
    parts = build_parts(config, estimator, controller, terrain)    # a bad plugin stops here, before any file
    path = None if out is None else Path(out)
    recorder: Recorder = NullRecorder() if path is None else McapRecorder(path)
    if progress:
        recorder = ProgressRecorder(recorder)
    outcome = run_loop(config, recorder, parts=parts)
    if outcome.interrupted:
        raise KeyboardInterrupt(outcome.error)
    return Result(outcome.metrics, path, outcome.error)


def replay(dataset: Dataset | str | Path, estimator: str | type[Estimator], out: str | Path | None = None) -> Result:
    """The recorded sensor streams through `estimator` (a registered name, a `MODULE:CLASS` spec,
    or an Estimator subclass, built from the recorded config as `testbed replay` builds it),
    scored against the recorded truth; with `out`, the run with the new estimates is written there."""
    path = dataset.path if isinstance(dataset, Dataset) else Path(dataset)
    result = replay_recording(path, _estimator_spec(estimator), out)
    return Result(result.metrics, None if out is None else Path(out), result.truncation_note)


def _estimator_spec(estimator: str | type[Estimator]) -> str:
    if isinstance(estimator, str):
        return estimator
    if isinstance(estimator, type) and issubclass(estimator, Estimator):
        return f"{estimator.__module__}:{estimator.__qualname__}"
    raise TypeError(f"replay takes an estimator name, a MODULE:CLASS spec or an Estimator subclass, "
                    f"not {estimator!r}: the recorded config builds it")
