"""Work in a forked process beside the caller (`datasets.background`): every item in order, the
producer's exception raised where it was raised, the process stopped when the caller leaves."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from datasets import background
from datasets.background import exchanged_in_background, streamed_in_background
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


def marking_the_end(count: int, done):
    for k in range(count):
        yield np.full(2**14, k, dtype=float)     # 128 kB: more than a pipe holds
    done.write_text("made")


def test_the_producer_runs_ahead_of_a_slow_consumer(tmp_path):
    done, count = tmp_path / "done", background.ITEMS_AHEAD - 2
    with streamed_in_background(marking_the_end, count, done) as items:
        assert next(items)[0] == 0
        deadline = time.monotonic() + 30.0
        while not done.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert done.exists()            # every item made while the consumer holds the first
        assert [item[0] for item in items] == list(range(1, count))


def unpicklable_second(_):
    yield 1
    yield lambda: None


def test_an_item_that_does_not_pickle_is_raised_after_the_items_before_it():
    received = []
    with pytest.raises(Exception, match="pickle"):
        with streamed_in_background(unpicklable_second, None) as items:
            received.extend(items)
    assert received == [1]


def counting_then_reading(inbox, count: int):
    yield from range(count)
    yield [value[0] for value in inbox]


@pytest.mark.parametrize("fork", [True, False])
def test_the_caller_sends_values_back_while_the_producer_works(monkeypatch, fork):
    """Values larger than a pipe holds, sent before the producer reads them: the caller never waits."""
    monkeypatch.setattr(background, "can_fork", lambda: fork)
    with exchanged_in_background(counting_then_reading, 3) as (items, outbox):
        assert [next(items) for _ in range(3)] == [0, 1, 2]
        started = time.monotonic()
        for k in range(40):
            outbox.send(np.full(2**15, k, dtype=float))
        assert time.monotonic() - started < 5.0
        outbox.close()
        assert next(items) == list(range(40))
