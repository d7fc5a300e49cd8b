"""Adding a part is one module plus one registration line (docs/extending.md): a package that
declares an entry point in a registry's group is listed by name beside the built-ins, accepted by
config validation and the CLI, and runs. The package here is a folder on PYTHONPATH with a module
and an `.dist-info/entry_points.txt`, which is what an installed package provides."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from datasets.reader import read_recording

TESTBED = [sys.executable, "-m", "testbed.tools.cli"]
ROOT = Path(__file__).resolve().parents[2]     # this checkout's code, ahead of any installed copy

MODULE = textwrap.dedent('''
    import numpy as np

    from estimators import Estimate, Estimator
    from sensors import ImuSample
    from testbed.control.gait import GaitPattern
    from testbed.world.terrain import BASE_DEPTH, Boxes, Terrain

    # a gait: two legs at a time, front pair, middle pair, rear pair
    PAIRS = GaitPattern(duty=2 / 3, swing_start=(0.0, 1 / 3, 2 / 3, 2 / 3, 1 / 3, 0.0), period=1.2)


    class Plateau(Terrain):
        """Level ground with a 1 cm plateau from x = 0.4 m on."""
        def __init__(self, config):
            x0, x1, y0, y1 = config.extent
            centers = np.array([[(x0 + 0.4) / 2, 0.0, -BASE_DEPTH / 2], [(0.4 + x1) / 2, 0.0, (0.01 - BASE_DEPTH) / 2]])
            halves = np.array([[(0.4 - x0) / 2, (y1 - y0) / 2, BASE_DEPTH / 2],
                               [(x1 - 0.4) / 2, (y1 - y0) / 2, (0.01 + BASE_DEPTH) / 2]])
            super().__init__(config, Boxes(centers, halves, np.repeat(np.eye(3)[None], 2, axis=0)))

        def height(self, xy):
            return np.where(np.atleast_2d(xy)[:, 0] < 0.4, 0.0, 0.01)


    class GyroOnly(Estimator):
        """Integrates the gyro from a level start."""
        def __init__(self):
            self.roll = self.pitch = 0.0
            self.t = None

        def update(self, sample):
            if not isinstance(sample, ImuSample):
                return None
            dt = 0.0 if self.t is None else sample.t - self.t
            self.t = sample.t
            self.roll += sample.gyro[0] * dt
            self.pitch += sample.gyro[1] * dt
            return Estimate(t=sample.t, quaternion=np.array([0.0, 0.0, 0.0, 1.0]), roll=self.roll,
                            pitch=self.pitch, yaw=0.0)
    ''')

ENTRY_POINTS = textwrap.dedent('''
    [hexapod_testbed.estimators]
    gyro_only = my_parts:GyroOnly

    [hexapod_testbed.terrains]
    plateau = my_parts:Plateau

    [hexapod_testbed.gaits]
    pairs = my_parts:PAIRS
    ''')


@pytest.fixture(scope="module")
def package(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("site")
    (folder / "my_parts.py").write_text(MODULE)
    info = folder / "my_parts-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-parts\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    return folder


def run_cli(arguments: list[str], package: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join((str(package), str(ROOT))))
    return subprocess.run(TESTBED + arguments, capture_output=True, text=True, timeout=300, env=env, cwd=cwd)


def test_registered_names_are_listed_beside_the_built_ins(package, tmp_path):
    help_text = " ".join(run_cli(["run", "--help"], package, tmp_path).stdout.split())
    assert "flat | heightmap | plateau | rough" in help_text
    assert "pairs" in help_text and "gyro_only" in help_text


def test_a_registered_terrain_gait_and_estimator_run_by_name(package, tmp_path):
    result = run_cli(["run", "--terrain", "plateau", "--gait", "pairs", "--estimator", "gyro_only", "--speed", "0.06",
                      "--duration", "5", "--out", str(tmp_path / "r.mcap"), "--metrics", str(tmp_path / "m.json")],
                     package, tmp_path)
    assert result.returncode == 0, result.stderr
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["fell"] is False and metrics["distance_m"] > 0.05
    assert 0 < metrics["roll_rmse_deg"] < 5.0 and 0 < metrics["pitch_rmse_deg"] < 5.0    # a drifting gyro, scored


SENSOR_ENTRY_POINTS = textwrap.dedent('''
    [hexapod_testbed.sensors]
    barometer = my_sensor:Barometer
    ''')


@pytest.fixture(scope="module")
def sensor_package(tmp_path_factory) -> Path:
    """examples/my_sensor.py (a barometer) registered as a sensor."""
    folder = tmp_path_factory.mktemp("sensor-site")
    example = ROOT / "examples" / "my_sensor.py"
    (folder / "my_sensor.py").write_text(example.read_text())
    info = folder / "my_sensor-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-sensor\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(SENSOR_ENTRY_POINTS)
    return folder


def test_a_registered_sensor_is_recorded_on_its_own_topic_listed_and_replayed(sensor_package, tmp_path, monkeypatch):
    run = tmp_path / "r.mcap"
    result = run_cli(["run", "--estimator", "ekf", "--duration", "1", "--out", str(run)], sensor_package, tmp_path)
    assert result.returncode == 0, result.stderr
    info = run_cli(["info", str(run)], sensor_package, tmp_path)
    assert info.returncode == 0, info.stderr
    assert "/sensors/my_sensor.BaroSample" in info.stdout
    replay = run_cli(["replay", str(run), "--estimator", "ekf", "--metrics", str(tmp_path / "m.json")],
                     sensor_package, tmp_path)
    assert replay.returncode == 0, replay.stderr
    assert json.loads((tmp_path / "m.json").read_text())["roll_rmse_deg"] > 0

    monkeypatch.syspath_prepend(str(sensor_package))
    barometer = [s for s in read_recording(run).samples() if type(s).__name__ == "BaroSample"]
    assert len(barometer) == 51 and all(type(s).__module__ == "my_sensor" for s in barometer)    # 50 Hz, t = 0 to 1 s
