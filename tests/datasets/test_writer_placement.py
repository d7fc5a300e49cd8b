"""The writer process keeps off the CPU that the run loop runs on, where it may use another."""

from __future__ import annotations

import os

import pytest

from datasets.recorder import run_description
from datasets.writer import WriterProcess, running_cpu
from tests.datasets.ticks import synthetic_config, terrain_and_urdf

linux_only = pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or running_cpu() is None,
                                reason="CPU affinity and /proc are Linux's")


@linux_only
def test_the_running_cpu_is_one_the_process_may_use():
    assert running_cpu() in os.sched_getaffinity(0)


@linux_only
def test_the_writer_keeps_off_the_given_cpu_when_it_may_use_another(tmp_path):
    allowed = os.sched_getaffinity(0)
    config = synthetic_config()
    _, urdf = terrain_and_urdf(config)
    writer = WriterProcess(tmp_path / "run.mcap", run_description(config, 1, 200.0), config, urdf)
    try:
        assert os.sched_getaffinity(writer.pid) == allowed
        writer.keep_off_cpu(None)
        assert os.sched_getaffinity(writer.pid) == allowed
        cpu = min(allowed)
        writer.keep_off_cpu(cpu)
        assert os.sched_getaffinity(writer.pid) == (allowed - {cpu} or allowed)
    finally:
        writer.close({}, {"error": ""})
    assert (tmp_path / "run.mcap").exists()
