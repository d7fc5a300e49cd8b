"""Height maps: .npy and 16-bit .png maps, their boxes against the analytic height, their storage in
the recording (run --from without the file), and every refused map."""

import json
from pathlib import Path

import dartpy as dart
import numpy as np
import pytest
from PIL import Image

from testbed.model.errors import ConfigError
from testbed.runtime import config
from testbed.world.simulation import build_terrain_skeleton
from testbed.world.terrain import HeightmapTerrain, make_terrain

HEIGHTMAP = "testbed.world.terrain:HeightmapTerrain"


def wavy(rows=30, columns=40, cell=0.05) -> np.ndarray:
    y, x = np.mgrid[0:rows, 0:columns] * cell
    return 0.02 * np.sin(3 * x) * np.cos(2 * y)


def map_config(path: Path, spec=HEIGHTMAP, **terrain):
    return config.load(overrides={"run": {"terrain": spec},
                                  "terrain": {"heightmap": str(path), "heightmap_cell": 0.05, **terrain}})


def test_cells_are_placed_rows_along_y_and_centred_on_the_start(tmp_path):
    heights = wavy()
    np.save(tmp_path / "map.npy", heights)
    terrain = make_terrain(HEIGHTMAP, map_config(tmp_path / "map.npy"), np.random.default_rng(0))
    assert terrain.footprint() == pytest.approx((-1.0, 1.0, -0.75, 0.75))
    # cell [row 7, column 31]: x from -1 + 31 * 0.05, y from -0.75 + 7 * 0.05
    assert terrain.height(np.array([[-1 + 31.5 * 0.05, -0.75 + 7.5 * 0.05]]))[0] == heights[7, 31]
    np.testing.assert_array_equal(terrain.heights, heights)
    placed = make_terrain(HEIGHTMAP, map_config(tmp_path / "map.npy", heightmap_origin=[-0.5, -1.0]),
                          np.random.default_rng(0))
    assert placed.footprint() == pytest.approx((-0.5, 1.5, -1.0, 0.5))
    assert placed.height(np.array([[-0.5 + 0.025, -1.0 + 0.025]]))[0] == heights[0, 0]


def test_height_agrees_with_the_dart_shapes(tmp_path):
    np.save(tmp_path / "map.npy", wavy())
    terrain = make_terrain(HEIGHTMAP, map_config(tmp_path / "map.npy"), np.random.default_rng(0))
    detector = dart.collision.BulletCollisionDetector()
    group = detector.createCollisionGroup()
    skeleton = build_terrain_skeleton(terrain, 0.8)     # keep alive: the group does not own it
    group.addShapeFramesOf(skeleton)
    rng = np.random.default_rng(1)
    for x, y in (np.floor(rng.uniform([-1.0, -0.75], [1.0, 0.75], (60, 2)) / 0.05) + 0.5) * 0.05:
        result = dart.collision.RaycastResult()
        assert group.raycast([x, y, 1.0], [x, y, -1.0], dart.collision.RaycastOption(), result)
        assert terrain.height(np.array([[x, y]]))[0] == pytest.approx(result.mRayHits[0].mPoint[2], abs=1e-6)


def test_a_16_bit_png_is_scaled_to_metres(tmp_path):
    units = np.arange(30 * 40, dtype=np.uint16).reshape(30, 40) * 7 % 40
    Image.fromarray(units).save(tmp_path / "map.png")
    terrain = make_terrain(HEIGHTMAP, map_config(tmp_path / "map.png", heightmap_scale=0.001),
                           np.random.default_rng(0))
    np.testing.assert_allclose(terrain.heights, units * 0.001, atol=1e-15)


@pytest.mark.parametrize("write, message", [
    (None, "no file"),
    (lambda p: np.save(p, np.zeros((30, 40), dtype=np.int32)), "int32 values, not floating-point heights"),
    (lambda p: np.save(p, np.zeros(40)), r"shape \(40,\), not a 2-D map"),
    (lambda p: np.save(p, np.zeros((30, 40, 2))), "not a 2-D map"),
    (lambda p: np.save(p, np.where(np.eye(30, 40) > 0, np.nan, 0.0)), "30 NaN or infinite heights"),
    (lambda p: np.save(p, np.zeros((200, 200))), "40000 cells, more than 20000"),
    (lambda p: p.write_bytes(b"not numpy"), "cannot read .* as a .npy array"),
    (lambda p: np.save(p, np.zeros((4, 4))), r"covers x \[-0.100, 0.100\]"),
    (lambda p: np.save(p, np.pad(np.zeros((30, 40)), ((0, 0), (0, 1)), constant_values=0.06)), "6.0 cm step between"),
])
def test_bad_maps_are_refused_when_the_config_loads(tmp_path, write, message):
    path = tmp_path / "map.npy"
    if write is not None:
        write(path)
    with pytest.raises(ConfigError, match=message):
        config.load(overrides={"run": {"terrain": "heightmap"}, "terrain": {"heightmap": str(path)}})


@pytest.mark.parametrize("terrain, message", [
    ({"heightmap": ""}, "terrain.heightmap names no file"),
    ({"heightmap_cell": 0.015}, "heightmap_cell 0.015 m is smaller than the foot"),
    ({"heightmap_cell": -1.0}, "heightmap_cell must be a positive"),
    ({"heightmap_origin": [1.0]}, "heightmap_origin needs 2 numbers"),
    ({"heightmap_scale": 0.0}, "heightmap_scale must be a positive"),
    ({"heightmap": "{dir}/map.txt"}, "neither a .npy nor a .png"),
    ({"heightmap": "{dir}/gray8.png"}, "is a mode L image, not 16-bit grayscale"),
    ({"heightmap": "{dir}"}, "is a directory"),
])
def test_bad_heightmap_keys_are_refused(tmp_path, terrain, message):
    np.save(tmp_path / "map.npy", wavy())
    (tmp_path / "map.txt").write_text("1 2 3")
    Image.fromarray(np.zeros((30, 40), dtype=np.uint8)).save(tmp_path / "gray8.png")
    keys = {"heightmap": str(tmp_path / "map.npy"), **terrain}
    keys["heightmap"] = keys["heightmap"].format(dir=tmp_path)
    with pytest.raises(ConfigError, match=message):
        config.load(overrides={"run": {"terrain": "heightmap"}, "terrain": keys})


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    from testbed.tools.cli import main
    assert main(["run", "--terrain", "heightmap", "--set", f'terrain.heightmap="{tmp_path}/none.npy"']) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"testbed: config error: terrain.heightmap: no file {tmp_path}/none.npy"
    assert not list(tmp_path.iterdir())


def test_the_map_travels_in_the_recording_and_run_from_needs_no_file(tmp_path, monkeypatch):
    from datasets.commands import config_from_mcap
    from datasets.dataset import Dataset
    from datasets.writer import DatasetWriter
    from testbed.model.robot import build_urdf
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    heights = wavy()
    np.save(tmp_path / "map.npy", heights)
    cfg = map_config(tmp_path / "map.npy", spec="heightmap")
    writer = DatasetWriter(tmp_path / "run.mcap")
    writer.describe_run({"terrain": "heightmap"}, cfg, build_urdf(cfg.robot))
    writer.close({}, {"error": ""})
    (tmp_path / "map.npy").unlink()
    restored = config.load(overrides={"run": {"seed": 9}}, base=config_from_mcap(tmp_path / "run.mcap"))
    assert Path(restored.terrain.heightmap).parent == tmp_path / "cache" / "hexapod-testbed" / "heightmaps"
    np.testing.assert_array_equal(restored.terrain.heightmap_heights(), heights)
    assert restored.terrain.heightmap_origin == () and restored.run.seed == 9
    np.testing.assert_array_equal(Dataset(tmp_path / "run.mcap").config.terrain.heightmap_heights(), heights)


def test_a_sweep_run_carries_the_map_and_its_worker_needs_no_file(tmp_path, monkeypatch):
    from datasets.reader import read_recording
    from testbed.tools import sweep
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    heights = wavy()
    np.save(tmp_path / "map.npy", heights)
    base = {"terrain": {"heightmap": str(tmp_path / "map.npy")}, "run": {"duration": 0.3}}
    points = sweep.expand_grid(["heightmap"], [4], ["none"], ["default"])
    (spec,) = sweep.make_specs(points, tmp_path / "runs", base)
    np.save(tmp_path / "map.npy", heights + 0.001)          # the same path, another map: another hash
    (changed,) = sweep.make_specs(points, tmp_path / "runs", base)
    assert changed.config_hash != spec.config_hash
    (tmp_path / "map.npy").unlink()
    row = sweep.execute(spec)
    assert row["error"] == "" and row["fell"] is False
    boxes = read_recording(spec.path).terrain()
    np.testing.assert_allclose(np.sort(boxes.centers[:, 2] + boxes.sizes[:, 2] / 2), np.sort(heights.ravel()),
                               atol=1e-12)
