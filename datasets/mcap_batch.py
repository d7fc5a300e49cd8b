"""An MCAP writer that takes its messages in batches.

mcap's `Writer.add_message` builds a Message record object and writes it field by field (seven
writes, two seeks), then updates the statistics and the chunk's index one message at a time: about
7 us a message, which at five messages per physics step was most of the recording's cost.
`BatchWriter.add_messages` writes the same records with one `struct.pack` each and updates the
statistics once per batch. The file is the same, byte for byte (tests/datasets/test_mcap_batch.py
holds it to that), so every MCAP reader reads it as before.

It reaches into two private attributes of mcap's Writer (its chunk builder and its statistics);
the byte-for-byte test is what guards that against a change of the mcap package.
"""

from __future__ import annotations

import struct
from collections import Counter
from itertools import islice
from operator import itemgetter

from mcap._chunk_builder import ChunkBuilder
from mcap.opcode import Opcode
from mcap.records import Message, MessageIndex
from mcap.writer import Writer

# A Message record: opcode, record length, channel id, sequence, log time, publish time, then the data.
MESSAGE_HEADER = struct.Struct("<BQHIQQ")
MESSAGE_FIELDS_SIZE = MESSAGE_HEADER.size - 9       # the record length counts what follows opcode and length


class BatchWriter(Writer):
    """mcap's Writer (chunked) with `add_messages`; every other method is the Writer's."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self._Writer__chunk_builder is None:
            raise ValueError("BatchWriter writes chunked files only")
        self._Writer__chunk_builder = BatchChunkBuilder()
        self._chunk_size_limit = self._Writer__chunk_size

    def add_messages(self, messages: list[tuple[int, int, bytes, int]]) -> None:
        """(channel id, log time, data, sequence) messages, each published at its log time: the
        same records as `add_message` called on each in turn."""
        if not messages:
            return
        self._count(messages)
        builder, limit = self._Writer__chunk_builder, self._chunk_size_limit
        start = 0
        while start < len(messages):
            start = builder.add_records(messages, start, limit)
            if builder.count > limit:
                self._Writer__finalize_chunk()

    def _count(self, messages: list[tuple[int, int, bytes, int]]) -> None:
        statistics = self._Writer__statistics
        log_times = list(map(itemgetter(1), messages))
        first, last = min(log_times), max(log_times)
        if statistics.message_count:
            first = min(first, statistics.message_start_time)
        statistics.message_start_time = first
        statistics.message_end_time = max(last, statistics.message_end_time)
        statistics.message_count += len(messages)
        for channel, count in Counter(map(itemgetter(0), messages)).items():
            statistics.channel_message_counts[channel] += count


class BatchChunkBuilder(ChunkBuilder):
    """mcap's ChunkBuilder writing each Message record, and each channel's index, in one piece."""

    def add_message(self, message: Message) -> None:
        self._add(message.channel_id, message.log_time, message.data, message.sequence, message.publish_time)

    def add_records(self, messages: list[tuple[int, int, bytes, int]], start: int, size_limit: int) -> int:
        """Add messages[start:], published at their log times, until the chunk grows past
        `size_limit` bytes; returns the index after the last message added. The records go to the
        chunk's buffer in one write."""
        buffer, indices = self.record_writer._buffer, self.message_indices
        offset = buffer.tell()
        pack, opcode, header_size = MESSAGE_HEADER.pack, Opcode.MESSAGE, MESSAGE_HEADER.size
        records: list[bytes] = []
        end = start
        for channel, log_time, data, sequence in islice(messages, start, None):
            index = indices.get(channel)
            if index is None:
                index = indices[channel] = PackedMessageIndex(channel_id=channel, records=[])
            index.records.append((log_time, offset))
            records += (pack(opcode, MESSAGE_FIELDS_SIZE + len(data), channel, sequence, log_time, log_time), data)
            offset += header_size + len(data)
            end += 1
            if offset > size_limit:
                break
        buffer.write(b"".join(records))
        added = list(map(itemgetter(1), islice(messages, start, end)))
        first, last = min(added), max(added)
        if self.num_messages:
            first, last = min(first, self.message_start_time), max(last, self.message_end_time)
        self.message_start_time, self.message_end_time = first, last
        self.num_messages += end - start
        return end

    def _add(self, channel: int, log_time: int, data: bytes, sequence: int, publish_time: int) -> None:
        if self.num_messages == 0:
            self.message_start_time = log_time
        self.message_start_time = min(self.message_start_time, log_time)
        self.message_end_time = max(self.message_end_time, log_time)
        buffer = self.record_writer._buffer
        index = self.message_indices.get(channel)
        if index is None:
            index = self.message_indices[channel] = PackedMessageIndex(channel_id=channel, records=[])
        index.records.append((log_time, buffer.tell()))
        self.num_messages += 1
        buffer.write(MESSAGE_HEADER.pack(Opcode.MESSAGE, MESSAGE_FIELDS_SIZE + len(data), channel, sequence, log_time,
                                         publish_time))
        buffer.write(data)


class PackedMessageIndex(MessageIndex):
    """mcap's MessageIndex record written with one struct.pack for all its entries."""

    def write(self, stream) -> None:
        entries = [value for entry in self.records for value in entry]
        stream.write(struct.pack(f"<BQHI{len(entries)}Q", Opcode.MESSAGE_INDEX, 6 + 8 * len(entries), self.channel_id,
                                 8 * len(entries), *entries))
