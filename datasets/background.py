"""Work handed to a forked process on another core while the caller goes on: one value
(`in_background`), a stream of items (`streamed_in_background`), or a stream of items from a
producer that also receives values from the caller (`exchanged_in_background`).

Where processes cannot be forked the work is done inline, with the same results. The processes
ignore SIGINT: the caller handles an interruption, and stops them when it leaves the block.
"""

from __future__ import annotations

import multiprocessing
import pickle
import queue
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from multiprocessing.connection import Connection
from typing import Any, TypeVar

T = TypeVar("T")
_ITEM, _END, _ERROR = range(3)
ITEMS_AHEAD = 32      # items a streaming producer makes before the consumer takes them


def can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods()


@contextmanager
def streamed_in_background(produce: Callable[..., Iterable[T]], *args: Any) -> Iterator[Iterator[T]]:
    """The items of `produce(*args)`, made in the background and handed over through a pipe as they
    come. The producer runs ahead of the consumer by up to ITEMS_AHEAD items (a thread of its
    process sends them meanwhile). The iterator raises the producer's exception where the producer
    raised it. Items must pickle cheaply: arrays, not many small objects."""
    with _in_background(produce, args, with_inbox=False) as (items, _):
        yield items


@contextmanager
def exchanged_in_background(produce: Callable[..., Iterable[T]], *args: Any) -> Iterator[tuple[Iterator[T], "Outbox"]]:
    """As `streamed_in_background`, and the caller sends values to the producer as it goes:
    `produce(inbox, *args)`, the inbox an iterator over the values the caller gives `Outbox.send`,
    which ends with `Outbox.close` (a thread of the producer's process receives them meanwhile).
    Where processes cannot be forked, the producer reads its inbox when the caller has closed it."""
    with _in_background(produce, args, with_inbox=True) as exchange:
        yield exchange


class Outbox:
    """The caller's end of the producer's inbox. A thread sends the values, so that the caller
    goes on while the producer's process takes them."""

    def __init__(self, connection: Connection | None):
        self.inline: list = []          # the values, where the producer runs inline
        self._waiting: queue.Queue | None = None
        if connection is not None:
            self._waiting = queue.Queue()
            threading.Thread(target=self._send_all, args=(connection,), daemon=True).start()

    def send(self, value: Any) -> None:
        self._put((_ITEM, value))

    def close(self) -> None:
        self._put((_END, None))

    def _put(self, message: tuple) -> None:
        if self._waiting is None:
            self.inline.append(message)
        else:
            self._waiting.put(message)

    def _send_all(self, connection: Connection) -> None:
        while True:
            message = self._waiting.get()
            try:
                connection.send(message)
            except (BrokenPipeError, OSError):
                return          # the producer stopped: the items raise why
            if message[0] == _END:
                return


def _inline_inbox(outbox: Outbox) -> Iterator[Any]:
    for kind, value in outbox.inline:
        if kind == _END:
            return
        yield value


@contextmanager
def _in_background(produce: Callable[..., Iterable[T]], args: tuple,
                   with_inbox: bool) -> Iterator[tuple[Iterator[T], Outbox]]:
    if not can_fork():
        outbox = Outbox(None)
        yield iter(produce(_inline_inbox(outbox), *args) if with_inbox else produce(*args)), outbox
        return
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    inbox_receiver, inbox_sender = context.Pipe(duplex=False) if with_inbox else (None, None)
    process = context.Process(target=_send_all, args=(sender, inbox_receiver, produce, args), daemon=True)
    process.start()
    sender.close()
    if inbox_receiver is not None:
        inbox_receiver.close()
    try:
        yield _received(receiver), Outbox(inbox_sender)
    finally:
        receiver.close()
        if inbox_sender is not None:
            inbox_sender.close()
        if process.is_alive():
            process.terminate()
        process.join()


def _send_all(sender: Connection, inbox: Connection | None, produce: Callable[..., Iterable[Any]],
              args: tuple) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)     # `terminate` ends it quietly, whatever the parent's handler
    waiting: queue.Queue = queue.Queue(maxsize=ITEMS_AHEAD)
    sending = threading.Thread(target=_send_from, args=(waiting, sender), daemon=True)
    sending.start()
    if inbox is not None:
        args = (_inbox(inbox), *args)
    try:
        for item in produce(*args):
            waiting.put((_ITEM, item))
        waiting.put((_END, None))
    except BaseException as error:      # noqa: BLE001 - handed to the consumer, who raises it
        waiting.put((_ERROR, _picklable(error)))
    sending.join()


def _send_from(waiting: queue.Queue, sender: Connection) -> None:
    """Send the queued messages until the last one, or until the consumer stops reading (the parent
    then ends this process)."""
    try:
        while True:
            kind, value = waiting.get()
            try:
                sender.send((kind, value))
            except BrokenPipeError:
                return
            except Exception as error:      # noqa: BLE001 - an item that does not pickle: the consumer raises it
                sender.send((_ERROR, _picklable(error)))
                return
            if kind != _ITEM:
                return
    finally:
        sender.close()


def _inbox(connection: Connection) -> Iterator[Any]:
    """The values the caller sends, until it closes the inbox (or ends). A thread receives them from
    now on, as they come, so that the caller never waits on a producer busy with its items."""
    received: queue.Queue = queue.Queue()

    def receive() -> None:
        while True:
            try:
                message = connection.recv()
            except (EOFError, OSError):
                message = (_END, None)
            received.put(message)
            if message[0] == _END:
                return

    threading.Thread(target=receive, daemon=True).start()
    return _values(received)


def _values(received: queue.Queue) -> Iterator[Any]:
    while True:
        kind, value = received.get()
        if kind == _END:
            return
        yield value


def _picklable(error: BaseException) -> BaseException:
    try:
        pickle.dumps(error)
    except Exception:   # noqa: BLE001 - any failure to pickle: the message survives
        return RuntimeError(f"{type(error).__name__}: {error}")
    return error


def _received(receiver: Connection) -> Iterator[Any]:
    while True:
        try:
            kind, value = receiver.recv()
        except EOFError:
            raise RuntimeError("the background process stopped before handing over all its items") from None
        if kind == _END:
            return
        if kind == _ERROR:
            raise value
        yield value
