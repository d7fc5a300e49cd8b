"""Plugins by MODULE:CLASS: bad specs stop before anything is written (exit 2, one line); a plugin
that fails during the run stops it with exit 1 and a valid recording; plugins are recorded and
found again by `run --from` and `replay`."""

import hashlib
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from mcap.reader import make_reader

TESTBED = [sys.executable, "-m", "testbed.tools.cli"]

PLUGINS = textwrap.dedent('''
    import numpy as np
    import testbed
    from estimators import Estimate, Estimator
    from sensors import ImuSample

    raise_on_import = False


    class NotAPart:
        pass


    class BrokenInit(Estimator):
        def __init__(self):
            raise RuntimeError("no calibration file")


    class FailsLater(Estimator):
        """A level estimate until t = 0.5 s, then an exception."""
        def update(self, sample):
            if not isinstance(sample, ImuSample):
                return None
            if sample.t > 0.5:
                raise ValueError("singular matrix")
            return Estimate(t=sample.t, quaternion=np.array([0.0, 0.0, 0.0, 1.0]), roll=0.0, pitch=0.0, yaw=0.0)


    class WrongShape(testbed.Controller):
        def tick(self, t, samples, estimate):
            return np.zeros(17) if t > 0.3 else None


    class NotFinite(testbed.Controller):
        def start(self, joints):
            self.joints = np.array(joints)

        def tick(self, t, samples, estimate):
            return self.joints * np.nan if t > 0.3 else self.joints
    ''')


@pytest.fixture(scope="module")
def plugin_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("plugins")
    (folder / "bad_plugins.py").write_text(PLUGINS)
    (folder / "explodes_on_import.py").write_text("raise ImportError('needs torch')\n")
    return folder


def run_cli(arguments: list[str], plugin_dir: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(plugin_dir))
    return subprocess.run(TESTBED + arguments, capture_output=True, text=True, timeout=300, env=env, cwd=cwd)


@pytest.mark.parametrize("option, spec, message", [
    ("--estimator", "kalman", "unknown estimator 'kalman'"),
    ("--estimator", "no_such_module:Filter", "no module named 'no_such_module'"),
    ("--estimator", "bad_plugins:Missing", "module 'bad_plugins' has no 'Missing'"),
    ("--estimator", "bad_plugins:NotAPart", "is not a subclass of estimators.Estimator"),
    ("--estimator", "bad_plugins:WrongShape", "is not a subclass of estimators.Estimator"),
    ("--estimator", "bad_plugins:BrokenInit", "could not be built: RuntimeError: no calibration file"),
    ("--estimator", "explodes_on_import:Filter", "needs torch"),
    ("--estimator", "bad plugins:Filter", "is not MODULE:CLASS"),
    ("--controller", "bad_plugins:FailsLater", "is not a subclass of testbed.Controller"),
    ("--terrain", "bad_plugins:NotAPart", "is not a subclass of testbed.Terrain"),
])
def test_a_bad_spec_is_one_line_exit_2_and_nothing_written(option, spec, message, plugin_dir, tmp_path):
    result = run_cli(["run", option, spec, "--duration", "0.5", "--out", str(tmp_path / "r.mcap")],
                         plugin_dir, tmp_path)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and spec in lines[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("option, spec, message", [
    ("--estimator", "bad_plugins:FailsLater", "ValueError: singular matrix"),
    ("--controller", "bad_plugins:WrongShape", "returned shape (17,)"),
    ("--controller", "bad_plugins:NotFinite", "returned non-finite targets"),
])
def test_a_plugin_failing_during_the_run_exits_1_with_a_valid_recording(option, spec, message, plugin_dir,
                                                                        tmp_path):
    out = tmp_path / "r.mcap"
    result = run_cli(["run", option, spec, "--duration", "2", "--out", str(out), "--metrics",
                          str(tmp_path / "m.json")], plugin_dir, tmp_path)
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and spec in lines[0]
    with out.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 100
        last = max(message.log_time for _, _, message in reader.iter_messages(topics=["/sensors/imu"]))
    assert 0.25e9 <= last <= 0.7e9
    assert json.loads((tmp_path / "m.json").read_text())["sim_time_s"] < 1.0


def test_a_missing_plugin_stops_run_from_and_replay_but_not_info(plugin_dir, tmp_path):
    examples = Path(__file__).resolve().parents[2] / "examples"
    recorded = tmp_path / "e.mcap"
    assert run_cli(["run", "--estimator", "my_estimator:MyComplementary", "--duration", "1", "--out",
                        str(recorded)], examples, tmp_path).returncode == 0
    for arguments in (["run", "--from", str(recorded), "--duration", "0.5", "--out", str(tmp_path / "again.mcap")],
                      ["replay", str(recorded), "--estimator", "my_estimator:MyComplementary"]):
        result = run_cli(arguments, plugin_dir, tmp_path)
        assert result.returncode == 2
        assert result.stderr.strip() == ("testbed: estimator 'my_estimator:MyComplementary': no module named "
                                         "'my_estimator' (is it on PYTHONPATH or installed?)")
    assert not (tmp_path / "again.mcap").exists()
    info = run_cli(["info", str(recorded)], plugin_dir, tmp_path)
    digest = hashlib.sha256((examples / "my_estimator.py").read_bytes()).hexdigest()
    assert info.returncode == 0
    assert f"plugin estimator: my_estimator:MyComplementary ({examples / 'my_estimator.py'}, sha256 {digest[:12]})" \
        in info.stdout


def test_the_recording_names_each_part_with_its_file_hash_and_package(plugin_dir, tmp_path):
    out = tmp_path / "r.mcap"
    assert run_cli(["run", "--controller", "bad_plugins:WrongShape", "--duration", "0.2", "--out", str(out)],
                   plugin_dir, tmp_path).returncode == 0
    with out.open("rb") as stream:
        run = next(m.metadata for m in make_reader(stream).iter_metadata() if m.name == "run")
    parts = json.loads(run["parts"])
    assert parts["controller"]["target"] == "bad_plugins:WrongShape" and parts["controller"]["distribution"] is None
    assert parts["controller"]["module_sha256"] == hashlib.sha256((plugin_dir / "bad_plugins.py").read_bytes()).hexdigest()
    assert parts["terrain"]["target"] == "testbed.world.terrain:FlatTerrain"
    assert parts["terrain"]["distribution"] == "hexapod-testbed" and parts["terrain"]["version"]


def test_each_kind_names_a_base_class_a_user_can_import():
    """The wrong-kind error says which class to subclass; that name imports as written."""
    import importlib

    from estimators.registry import ESTIMATORS
    from sensors.sensor import SENSORS
    from testbed.control.controller import CONTROLLERS
    from testbed.control.posture import POSTURE_LAWS
    from testbed.world.contact import CONTACT_MODELS
    from testbed.world.terrain import TERRAINS

    for registry in (ESTIMATORS, SENSORS, CONTROLLERS, POSTURE_LAWS, CONTACT_MODELS, TERRAINS):
        module, _, name = registry.expected.removeprefix("a subclass of ").rpartition(".")
        base = getattr(importlib.import_module(module), name)
        assert registry.accepts(type("Part", (base,), {}))
