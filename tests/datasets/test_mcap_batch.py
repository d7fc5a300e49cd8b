"""BatchWriter writes the file that mcap's Writer writes, byte for byte."""

from __future__ import annotations

import gc
import io
import threading

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from datasets.mcap_batch import MESSAGE_FIELDS_SIZE, MESSAGE_HEADER, BatchWriter


def _messages(seed: int, count: int) -> list[tuple[int, int, bytes, int]]:
    """(channel, log time, data, sequence) over three channels, times not quite in order, data of
    varying length (an empty one included)."""
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.integers(0, 1_000_000, count)) + rng.integers(-500_000, 500_000, count) + 10**9
    return [(int(rng.integers(1, 4)), int(t), rng.bytes(int(rng.integers(0, 300))), int(rng.integers(0, 2**32)))
            for t in times]


def _laid_out(messages) -> tuple[bytes, np.ndarray, np.ndarray, np.ndarray]:
    """`BatchWriter.add_records`' arguments for the messages."""
    records = [MESSAGE_HEADER.pack(5, MESSAGE_FIELDS_SIZE + len(data), channel, sequence, log_time, log_time) + data
               for channel, log_time, data, sequence in messages]
    return (b"".join(records), np.cumsum([len(record) for record in records], dtype=np.int64),
            np.array([message[0] for message in messages], np.int64).reshape(-1),
            np.array([message[1] for message in messages], np.int64).reshape(-1))


def _write(writer_class, messages, chunk_size: int, batch: int, how: str = "tuples", background: bool = False,
           compression=CompressionType.ZSTD) -> bytes:
    """The file of the messages written `batch` at a time, each batch flushed: with mcap's Writer one
    by one, or with BatchWriter as tuples, laid-out records, or one then the other by turns."""
    stream = io.BytesIO()
    options = {"background": background} if writer_class is BatchWriter else {}
    writer = writer_class(stream, chunk_size=chunk_size, compression=compression, **options)
    writer.start(profile="test", library="test")
    schema = writer.register_schema("s", "protobuf", b"schema")
    for topic in ("/a", "/b", "/c"):
        writer.register_channel(topic, "protobuf", schema)
    for number, start in enumerate(range(0, max(len(messages), 1), batch)):     # an empty list: one empty batch
        part = messages[start:start + batch]
        if writer_class is not BatchWriter:
            for channel, log_time, data, sequence in part:
                writer.add_message(channel, log_time, data, log_time, sequence)
        elif how == "tuples" or (how == "both" and number % 2):
            writer.add_messages(part)
        elif how == "both":     # half of the batch each way, without a flush between
            writer.add_records(*_laid_out(part[:len(part) // 2]))
            writer.add_messages(part[len(part) // 2:])
        else:
            writer.add_records(*_laid_out(part))
        writer.flush()
    writer.add_metadata("m", {"k": "v"})
    writer.finish()
    return stream.getvalue()


@pytest.mark.parametrize("how", ["tuples", "records", "both"])
@pytest.mark.parametrize("background", [False, True])
@pytest.mark.parametrize("chunk_size, batch", [(8 * 2**20, 500), (4000, 500), (4000, 1), (1, 7)])
def test_batches_write_the_same_bytes_as_one_message_at_a_time(chunk_size, batch, background, how):
    """Chunk sizes that close chunks between batches, inside them, and after every message; the
    chunks written on the caller's thread or on the writer thread."""
    messages = _messages(seed=batch, count=1500)
    batched = _write(BatchWriter, messages, chunk_size, batch, how, background)
    assert batched == _write(Writer, messages, chunk_size, batch)
    read = [(channel.id, message.log_time, message.data, message.sequence)
            for _, channel, message in make_reader(io.BytesIO(batched)).iter_messages(log_time_order=False)]
    assert read == messages


@pytest.mark.parametrize("compression", [CompressionType.NONE, CompressionType.LZ4])
def test_other_compressions_write_the_same_bytes(compression):
    pytest.importorskip("lz4") if compression == CompressionType.LZ4 else None
    messages = _messages(seed=3, count=300)
    assert (_write(BatchWriter, messages, 4000, 50, "both", True, compression)
            == _write(Writer, messages, 4000, 50, compression=compression))


def test_data_section_crcs_are_those_of_mcaps_writer():
    messages = _messages(seed=4, count=300)
    files = []
    for writer_class, options in ((Writer, {}), (BatchWriter, {"background": True})):
        stream = io.BytesIO()
        writer = writer_class(stream, chunk_size=3000, enable_data_crcs=True, **options)
        writer.start()
        channel = writer.register_channel("/a", "json", 0)
        for index, (_, log_time, data, sequence) in enumerate(messages):
            writer.add_message(channel, log_time, data, log_time, sequence)
            if index % 40 == 0:
                writer.flush()
        writer.finish()
        files.append(stream.getvalue())
    assert files[0] == files[1]


@pytest.mark.parametrize("background", [False, True])
def test_an_empty_batch_writes_nothing(background):
    assert _write(BatchWriter, [], 4000, 10, "records", background) == _write(Writer, [], 4000, 10)


class FailingStream(io.BytesIO):
    def __init__(self, fail_after: int):
        super().__init__()
        self.writes = fail_after

    def write(self, data):
        self.writes -= 1
        if self.writes < 0:
            raise OSError(28, "No space left on device")
        return super().write(data)


def test_an_error_of_the_writer_thread_is_raised_in_the_callers_thread():
    stream = FailingStream(fail_after=2)     # the magic and the header
    writer = BatchWriter(stream, background=True)
    writer.start()
    channel = writer.register_channel("/a", "json", 0)
    writer.add_messages([(channel, 1, b"{}", 0)])
    writer.flush()      # the chunk's write fails on the writer thread
    writer.add_messages([(channel, 2, b"{}", 0)])
    with pytest.raises(OSError, match="No space left"):
        writer.flush()
    with pytest.raises(OSError, match="No space left"):     # and at every later write
        writer.finish()


def test_a_writer_without_chunks_is_refused():
    with pytest.raises(ValueError, match="chunked"):
        BatchWriter(io.BytesIO(), use_chunking=False)


def _writer_threads() -> int:
    return sum(thread.name == "mcap-writer" for thread in threading.enumerate())


def test_the_writer_thread_ends_with_finish_or_with_a_writer_dropped_unfinished():
    before = _writer_threads()
    for finish in (True, False):
        writer = BatchWriter(io.BytesIO(), background=True)
        writer.start()
        channel = writer.register_channel("/a", "json", 0)
        writer.add_messages([(channel, 1, b"{}", 0)])
        writer.flush()
        assert _writer_threads() == before + 1
        if finish:
            writer.finish()
        else:
            writer.wait()
            thread = writer._worker._thread
            del writer
            gc.collect()
            thread.join(timeout=5)
        assert _writer_threads() == before
