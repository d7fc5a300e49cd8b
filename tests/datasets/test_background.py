"""Work in a forked process beside the caller (`datasets.background`): every item in order, the
producer's exception raised where it was raised, the process stopped when the caller leaves."""

from __future__ import annotations

import os

import numpy as np
import pytest

from datasets import background
from datasets.background import streamed_in_background
from testbed.model.errors import UserError


def squares(count: int):
    for k in range(count):
        yield k, np.full(1000, k * k, dtype=float), os.getpid()


def failing_after(count: int):
    yield from range(count)
    raise UserError("the file ends here")


def test_every_item_comes_in_order_from_another_process():
    with streamed_in_background(squares, 50) as items:
        received = list(items)
    assert [k for k, _, _ in received] == list(range(50))
    assert all(np.all(values == k * k) for k, values, _ in received)
    assert {pid for _, _, pid in received} == {received[0][2]} != {os.getpid()}


def test_the_producers_error_is_raised_after_its_items():
    received = []
    with pytest.raises(UserError, match="the file ends here"):
        with streamed_in_background(failing_after, 3) as items:
            received.extend(items)
    assert received == [0, 1, 2]


def test_leaving_early_stops_the_producer():
    with streamed_in_background(squares, 10**6) as items:
        first = next(items)
        pid = first[2]
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_without_fork_the_items_are_made_inline(monkeypatch):
    monkeypatch.setattr(background, "can_fork", lambda: False)
    with streamed_in_background(squares, 3) as items:
        assert [pid for _, _, pid in items] == [os.getpid()] * 3
