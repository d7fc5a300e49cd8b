"""Environments a user will have: an install in a read-only folder (numba then caches its kernels
in the user's cache folder, or compiles them without a cache), and the bench cache's default in the
user's cache folder. Read-only folders are read-only bind mounts: the tests run as root (which
file permissions do not stop) and are skipped otherwise."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import platformdirs
import pytest

from tests.reliability.cli_process import ROOT
from testbed.tools import bench

PACKAGES = ("testbed", "sensors", "estimators", "datasets")
KERNEL_CALL = ("import numpy as np, os; from sensors.foot import saturated; "
               "print(saturated(np.array([3.0, -3.0, 0.5]), 1.0).tolist()); print(os.environ.get('NUMBA_CACHE_DIR'))")


def read_only_copy(tmp_path: Path, name: str) -> Path:
    """A folder of `name` bind-mounted read-only over itself; skip unless root can mount."""
    if os.geteuid() != 0:
        pytest.skip("read-only bind mounts need root")
    folder = tmp_path / name
    folder.mkdir(exist_ok=True)
    if subprocess.run(["mount", "--bind", str(folder), str(folder)], capture_output=True).returncode != 0:
        pytest.skip("cannot bind-mount here")
    subprocess.run(["mount", "-o", "remount,bind,ro", str(folder)], check=True)
    return folder


@pytest.fixture
def read_only_install(tmp_path):
    source = tmp_path / "install"
    source.mkdir()
    for package in PACKAGES:
        shutil.copytree(ROOT / package, source / package, ignore=shutil.ignore_patterns("__pycache__"))
    install = read_only_copy(tmp_path, "install")
    yield install
    subprocess.run(["umount", str(install)], check=False)


def call_kernel(install: Path, cache_home: Path) -> subprocess.CompletedProcess:
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=str(install), XDG_CACHE_HOME=str(cache_home))
    return subprocess.run([sys.executable, "-c", KERNEL_CALL], capture_output=True, text=True, env=env, timeout=300,
                          cwd=install)


def test_a_read_only_install_caches_kernels_in_the_user_cache_folder(read_only_install, tmp_path):
    result = call_kernel(read_only_install, tmp_path / "cache-home")
    assert result.returncode == 0, result.stderr
    values, cache_dir = result.stdout.splitlines()
    assert values == "[1.0, -1.0, 0.5]"
    assert Path(cache_dir) == tmp_path / "cache-home" / "hexapod-testbed" / "numba"
    assert any(path.suffix == ".nbi" for path in Path(cache_dir).rglob("*"))       # the kernel's cache index


def test_without_any_writable_cache_folder_kernels_compile_uncached(read_only_install, tmp_path):
    cache_home = read_only_copy(tmp_path, "cache-home")
    try:
        result = call_kernel(read_only_install, cache_home)
    finally:
        subprocess.run(["umount", str(cache_home)], check=False)
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    values, cache_dir = result.stdout.splitlines()
    assert values == "[1.0, -1.0, 0.5]" and not Path(cache_dir).is_relative_to(cache_home)


def test_the_bench_cache_defaults_to_the_user_cache_folder():
    assert bench.CACHE == Path(platformdirs.user_cache_dir("hexapod-testbed")) / "bench"
    assert not bench.CACHE.is_relative_to(ROOT)
