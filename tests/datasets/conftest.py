"""Shared fixtures: synthetic runs recorded once per module (building ticks costs ~0.2 ms each)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from datasets.recorder import McapRecorder
from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf

RERUN = Path(sys.executable).with_name("rerun")
# Faults put NaN into samples, drop samples and clear every contact flag: the format must carry all.
FAULTS = ["imu.accel.x.dropout@0.5s+50ms", "encoder.leg2.dropout@0.7s+100ms", "foot.stuck@1.2s+100ms:0"]
SECONDS = 2.0


def faulty_config(estimator: str):
    return synthetic_config(estimator, sensors={"faults": FAULTS, "accel_array": {"layout": "quad"}})


def record(path: Path, config, ticks, metrics: dict | None = None, error: str | None = None) -> McapRecorder:
    recorder = McapRecorder(path)
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    for tick in ticks:
        recorder.record(tick)
    recorder.finish(metrics if metrics is not None else {"roll_rmse_deg": 0.5}, error)
    return recorder


@pytest.fixture(scope="session")
def ekf_run(tmp_path_factory):
    """(config, ticks, path) of a 2 s synthetic run with the EKF, recorded."""
    config = faulty_config("ekf")
    ticks = list(generate_ticks(config, SECONDS))
    path = tmp_path_factory.mktemp("ekf") / "run.mcap"
    record(path, config, ticks)
    return config, ticks, path


def run_rerun(*args: str) -> subprocess.CompletedProcess:
    if not RERUN.exists() and shutil.which("rerun") is None:
        pytest.fail("the rerun command (from rerun-sdk) is missing")
    command = str(RERUN) if RERUN.exists() else "rerun"
    return subprocess.run([command, *args], capture_output=True, text=True, timeout=120)
