"""An MCAP writer that takes its messages in batches, and can compress and write its chunks on a
thread of their own.

mcap's `Writer.add_message` builds a Message record object and writes it field by field (seven
writes, two seeks), then updates the statistics and the chunk's index one message at a time: about
7 us a message, which at five messages per physics step was most of the recording's cost.
`BatchWriter.add_messages` writes the same records with one `struct.pack` each and updates the
statistics once per batch; `add_records` takes records already laid out (`datasets.batch_encode`).

With `background=True` a finished chunk is compressed, written and flushed to the file by a writer
thread (zstd's compression, the CRC and the file writes release the GIL, so on a second core they
overlap with the caller's work). Chunks are handed over one batch at a time, in order: handing
over the next batch, and every other write to the file (metadata, attachments, the summary), first
waits for the previous one to be on the file, so the writer thread owns the file from a handover
to that wait and nothing else touches it meanwhile. An error of the writer thread is raised in
the caller's thread by that wait (and by every later one: the file is not written any further).
The thread is not a daemon: a process whose main thread ends without closing the writer still
writes the chunks it handed over. `finish` (or `stop`) ends it.

The file is the same, byte for byte, either way (tests/datasets/test_mcap_batch.py holds it to
mcap's Writer), so every MCAP reader reads it as before. It reaches into private attributes of
mcap's Writer (its chunk builder, statistics, chunk indexes and settings, and the chunk
finalisation that it overrides); the byte-for-byte test is what guards that against a change of
the mcap package.
"""

from __future__ import annotations

import queue
import struct
import threading
import weakref
import zlib
from collections import Counter
from itertools import islice
from operator import itemgetter

import numpy as np
from numba import njit
from mcap._chunk_builder import ChunkBuilder
from mcap.opcode import Opcode
from mcap.records import ChunkIndex, Message, MessageIndex
from mcap.writer import CompressionType, IndexType, Writer

try:
    import lz4.frame  # type: ignore
except ImportError:         # as mcap's Writer: refused there unless installed
    lz4 = None
try:
    import zstandard
except ImportError:
    zstandard = None

# A Message record: opcode, record length, channel id, sequence, log time, publish time, then the data.
MESSAGE_HEADER = struct.Struct("<BQHIQQ")
MESSAGE_FIELDS_SIZE = MESSAGE_HEADER.size - 9       # the record length counts what follows opcode and length
# A Chunk record up to its compression's name: opcode, record length, start and end times,
# uncompressed size and CRC, the name's length.
CHUNK_HEADER = struct.Struct("<BQQQQII")


class BatchWriter(Writer):
    """mcap's Writer (chunked) with `add_messages` and `add_records`, its chunks finished on a
    writer thread if `background`; every other method is the Writer's. `wait()` returns when every
    chunk handed over is on the file."""

    def __init__(self, *args, background: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        if self._Writer__chunk_builder is None:
            raise ValueError("BatchWriter writes chunked files only")
        self._Writer__chunk_builder = BatchChunkBuilder()
        self._chunk_size_limit = self._Writer__chunk_size
        self._background = background
        self._finished: list[tuple] = []        # chunks finished, not yet handed to the writer thread
        self._worker: WriterThread | None = None

    # --- messages -----------------------------------------------------------------------------

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

    def add_records(self, records, ends: np.ndarray, channels: np.ndarray, log_times: np.ndarray) -> None:
        """Message records laid out one after the other in `records` (a bytes-like object), the
        i-th ending at `ends[i]` (int64 array), of channel `channels[i]` and log time `log_times[i]`
        (each message published at its log time): the same as `add_message` of each in turn."""
        count = len(ends)
        if not count:
            return
        if channels.min() < 1 or channels.max() > 0xFFFF or log_times.min() < 0:
            raise ValueError("channel ids are 16-bit and non-zero, log times unsigned")
        statistics = self._count_times(int(log_times.min()), int(log_times.max()), count)
        builder, limit = self._Writer__chunk_builder, self._chunk_size_limit
        counts = statistics.channel_message_counts      # its order is the file's: that of first appearance
        start = 0
        while start < count:
            start = builder.add_laid_out(records, ends, channels, log_times, start, limit, counts)
            if builder.count > limit:
                self._Writer__finalize_chunk()

    def _count(self, messages: list[tuple[int, int, bytes, int]]) -> None:
        log_times = list(map(itemgetter(1), messages))
        statistics = self._count_times(min(log_times), max(log_times), len(messages))
        for channel, count in Counter(map(itemgetter(0), messages)).items():
            statistics.channel_message_counts[channel] += count

    def _count_times(self, first: int, last: int, count: int):
        """Add `count` messages logged from `first` to `last` to the statistics; returns them."""
        statistics = self._Writer__statistics
        if statistics.message_count:
            first = min(first, statistics.message_start_time)
        statistics.message_start_time = first
        statistics.message_end_time = max(last, statistics.message_end_time)
        statistics.message_count += count
        return statistics

    # --- chunks and the file ------------------------------------------------------------------

    def flush(self) -> None:
        """Finish the chunk in progress and put it on the file, flushed; in the background, hand
        it (and any chunk finished before it) to the writer thread and return."""
        self._Writer__finalize_chunk()
        if self._background:
            self._hand_over()
        else:
            super().flush()

    def finish(self) -> None:
        """mcap's Writer's `finish`, the last chunks written first (the data end record holds the
        CRC of everything before it); the writer thread ends."""
        try:
            self._Writer__finalize_chunk()
            self._Writer__flush()
            super().finish()
        finally:
            self.stop()

    def wait(self) -> None:
        """Return when every chunk handed to the writer thread is on the file; raise its error if
        it failed."""
        if self._worker is not None:
            self._worker.wait()
            if self._worker.error is not None:
                raise self._worker.error

    def stop(self) -> None:
        """End the writer thread once it has written what it was given (its error, if any, is
        left to `wait`)."""
        if self._worker is not None:
            self._worker.stop()

    def _Writer__flush(self) -> None:
        """mcap's Writer writes through here (metadata, attachments, the summary): first the
        chunks finished before, in order."""
        self.wait()
        if self._finished:
            self._write_chunks(self._finished)
            self._finished = []
        Writer._Writer__flush(self)

    def _Writer__finalize_chunk(self) -> None:
        """mcap's Writer's `__finalize_chunk`, its compression and writes left to `_write_chunks`
        (at the next flush, here or on the writer thread)."""
        builder = self._Writer__chunk_builder
        if builder.num_messages == 0:
            return
        self._Writer__statistics.chunk_count += 1
        indexes = []
        if self._Writer__index_types & IndexType.MESSAGE:
            indexes = [(channel, index.packed()) for channel, index in builder.message_indices.items()]
        self._finished.append((builder.end(), builder.message_start_time, builder.message_end_time, indexes))
        builder.reset()

    def _hand_over(self) -> None:
        self.wait()
        if not self._finished:
            return
        chunks, self._finished = self._finished, []
        if self._worker is None:
            self._worker = WriterThread()
            weakref.finalize(self, self._worker.end)       # a writer dropped without `finish`
        self._worker.run(lambda: self._write_and_flush(chunks))

    def _write_and_flush(self, chunks: list[tuple]) -> None:
        self._write_chunks(chunks)
        self._Writer__stream.flush()

    def _write_chunks(self, chunks: list[tuple]) -> None:
        """Compress and write finished chunks, each followed by its message indexes, as mcap's
        Writer does, and add their chunk indexes."""
        stream = self._Writer__stream
        compression_type = self._Writer__compression
        for data, start_time, end_time, indexes in chunks:
            if compression_type == CompressionType.LZ4:
                compression, compressed = "lz4", lz4.frame.compress(data)
            elif compression_type == CompressionType.ZSTD:
                compression, compressed = "zstd", zstandard.compress(data)
            else:
                compression, compressed = "", data
            crc = zlib.crc32(data) if self._Writer__enable_crcs else 0
            name = compression.encode()
            header = CHUNK_HEADER.pack(Opcode.CHUNK, CHUNK_HEADER.size - 9 + len(name) + 8 + len(compressed),
                                       start_time, end_time, len(data), crc, len(name)) + name
            header += struct.pack("<Q", len(compressed))
            chunk_start = stream.tell()
            chunk_length = len(header) + len(compressed)
            offsets, position = {}, chunk_start + chunk_length
            for channel, packed in indexes:
                offsets[channel] = position
                position += len(packed)
            written = [header, compressed, *(packed for _, packed in indexes)]
            if self._Writer__enable_data_crcs:
                for part in written:
                    self._Writer__data_section_crc = zlib.crc32(part, self._Writer__data_section_crc)
            stream.write(b"".join(written))
            self._Writer__chunk_indices.append(ChunkIndex(
                message_start_time=start_time, message_end_time=end_time, chunk_start_offset=chunk_start,
                chunk_length=chunk_length, message_index_offsets=offsets,
                message_index_length=position - chunk_start - chunk_length, compression=compression,
                compressed_size=len(compressed), uncompressed_size=len(data)))


class WriterThread:
    """A thread that runs the jobs handed to it one at a time (one thread for the whole file: a
    thread started at each flush made the caller wait for it to start). It ends when `stop`ped,
    or once the main thread has ended and nothing is left to do: a process whose main thread ends
    without closing the file still writes what it handed over, then exits."""

    POLL_S = 0.1        # how often an idle thread looks whether the main thread has ended

    def __init__(self) -> None:
        self.error: BaseException | None = None     # the first job's error; later jobs are not run
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._idle = threading.Event()
        self._idle.set()
        self._thread = threading.Thread(target=self._loop, name="mcap-writer")
        self._thread.start()

    def run(self, job) -> None:
        self._idle.clear()
        self._jobs.put(job)

    def wait(self) -> None:
        self._idle.wait()

    def end(self) -> None:
        """Let the thread end after the jobs handed to it."""
        self._jobs.put(None)

    def stop(self) -> None:
        """End the thread after the jobs handed to it, and wait for it."""
        if self._thread.is_alive():
            self.end()
            self._thread.join()

    def _loop(self) -> None:
        while True:
            try:
                job = self._jobs.get(timeout=self.POLL_S)
            except queue.Empty:
                if threading.main_thread().is_alive():
                    continue
                return
            if job is None:
                return
            try:
                if self.error is None:
                    job()
            except BaseException as error:      # raised in the caller's thread by BatchWriter.wait
                self.error = error
            finally:
                job = None          # holds the writer, whose collection ends this thread
                self._idle.set()


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
        self._times(min(added), max(added), end - start)
        return end

    def add_laid_out(self, records, ends: np.ndarray, channels: np.ndarray, log_times: np.ndarray, start: int,
                     size_limit: int, counts: dict[int, int]) -> int:
        """`BatchWriter.add_records`' messages from `start` on, until the chunk grows past
        `size_limit` bytes; returns the index after the last message added. Adds each channel's
        messages to `counts`."""
        buffer = self.record_writer._buffer
        offset = buffer.tell()
        begin = int(ends[start - 1]) if start else 0
        # the first message whose record takes the chunk past the limit is the last one added
        end = int(np.searchsorted(ends, size_limit - offset + begin, side="right")) + 1
        end = min(max(end, start + 1), len(ends))
        buffer.write(memoryview(records)[begin:int(ends[end - 1])])
        present, bounds, entries = _index_entries(channels[start:end], log_times[start:end], ends[start:end], begin,
                                                  offset)
        indices = self.message_indices
        for at, channel in enumerate(present.tolist()):
            index = indices.get(channel)
            if index is None:
                index = indices[channel] = PackedMessageIndex(channel_id=channel, records=[])
            index.add_entries(entries[bounds[at]:bounds[at + 1]])
            counts[channel] += int(bounds[at + 1] - bounds[at])
        self._times(int(log_times[start:end].min()), int(log_times[start:end].max()), end - start)
        return end

    def _times(self, first: int, last: int, count: int) -> None:
        if self.num_messages:
            first, last = min(first, self.message_start_time), max(last, self.message_end_time)
        self.message_start_time, self.message_end_time = first, last
        self.num_messages += count

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


@njit(cache=True)
def _index_entries(channels, log_times, ends, begin, offset):
    """The message index entries of consecutive records ending at `ends`, the first starting at
    `begin`, moved to start at `offset` in the chunk: channel by channel in order of first
    appearance, the channels, where each one's entries start (and end) in `entries`, and the
    (log time, offset) entries."""
    count = len(channels)
    slot = np.full(0x10000, -1, np.int64)
    present = np.empty(count, np.int64)
    sizes = np.zeros(count + 1, np.int64)
    kinds = 0
    for message in range(count):
        channel = channels[message]
        if slot[channel] < 0:
            slot[channel] = kinds
            present[kinds] = channel
            kinds += 1
        sizes[slot[channel] + 1] += 1
    bounds = np.cumsum(sizes[:kinds + 1])
    filled = bounds[:kinds].copy()
    entries = np.empty((count, 2), np.uint64)
    for message in range(count):
        at = slot[channels[message]]
        entries[filled[at], 0] = log_times[message]
        entries[filled[at], 1] = offset + (ends[message - 1] - begin if message else 0)
        filled[at] += 1
    return present[:kinds], bounds, entries


class PackedMessageIndex(MessageIndex):
    """mcap's MessageIndex record written with one struct.pack for all its entries. Entries come
    as (log time, offset) pairs in `records`, or as arrays from `add_entries`, kept as they are
    until packed."""

    _parts: list[np.ndarray] | None = None      # entries before those in `records`, (n, 2) arrays

    def add_entries(self, entries: np.ndarray) -> None:
        """(n, 2) uint64 (log time, offset) entries, after those added before."""
        self._parts_so_far().append(entries)

    def _parts_so_far(self) -> list[np.ndarray]:
        if self._parts is None:
            self._parts = []
        if self.records:
            self._parts.append(np.array(self.records, "<u8").reshape(-1, 2))
            self.records = []
        return self._parts

    def packed(self) -> bytes:
        """The record: opcode, length, channel id, the entries' length, the entries."""
        if self._parts is None:
            entries = [value for entry in self.records for value in entry]
            return struct.pack(f"<BQHI{len(entries)}Q", Opcode.MESSAGE_INDEX, 6 + 8 * len(entries), self.channel_id,
                               8 * len(entries), *entries)
        data = b"".join(self._parts_so_far())
        return struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 6 + len(data), self.channel_id, len(data)) + data

    def write(self, stream) -> None:
        stream.write(self.packed())
