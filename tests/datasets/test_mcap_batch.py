"""BatchWriter writes the file that mcap's Writer writes, byte for byte."""

from __future__ import annotations

import io

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from datasets.mcap_batch import BatchWriter


def _messages(seed: int, count: int) -> list[tuple[int, int, bytes, int]]:
    """(channel, log time, data, sequence) over three channels, times not quite in order, data of
    varying length (an empty one included)."""
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.integers(0, 1_000_000, count)) + rng.integers(-500_000, 500_000, count) + 10**9
    return [(int(rng.integers(1, 4)), int(t), rng.bytes(int(rng.integers(0, 300))), int(rng.integers(0, 2**32)))
            for t in times]


def _write(writer_class, messages, chunk_size: int, batch: int) -> bytes:
    stream = io.BytesIO()
    writer = writer_class(stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
    writer.start(profile="test", library="test")
    schema = writer.register_schema("s", "protobuf", b"schema")
    for topic in ("/a", "/b", "/c"):
        writer.register_channel(topic, "protobuf", schema)
    for start in range(0, max(len(messages), 1), batch):     # an empty list: one empty batch
        part = messages[start:start + batch]
        if writer_class is BatchWriter:
            writer.add_messages(part)
        else:
            for channel, log_time, data, sequence in part:
                writer.add_message(channel, log_time, data, log_time, sequence)
        writer.flush()
    writer.add_metadata("m", {"k": "v"})
    writer.finish()
    return stream.getvalue()


@pytest.mark.parametrize("chunk_size, batch", [(8 * 2**20, 500), (4000, 500), (4000, 1), (1, 7)])
def test_batches_write_the_same_bytes_as_one_message_at_a_time(chunk_size, batch):
    """Chunk sizes that close chunks between batches, inside them, and after every message."""
    messages = _messages(seed=batch, count=1500)
    batched = _write(BatchWriter, messages, chunk_size, batch)
    assert batched == _write(Writer, messages, chunk_size, batch)
    read = [(channel.id, message.log_time, message.data, message.sequence)
            for _, channel, message in make_reader(io.BytesIO(batched)).iter_messages(log_time_order=False)]
    assert read == messages


def test_an_empty_batch_writes_nothing():
    assert _write(BatchWriter, [], 4000, 10) == _write(Writer, [], 4000, 10)


def test_a_writer_without_chunks_is_refused():
    with pytest.raises(ValueError, match="chunked"):
        BatchWriter(io.BytesIO(), use_chunking=False)
