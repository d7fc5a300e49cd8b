"""Damaged and foreign MCAP files, made from a small recorded run: records swapped, cut, or
re-encoded."""

from __future__ import annotations

import json
import lzma
import struct
import zlib
from pathlib import Path

import zstandard

from datasets import schemas
from datasets.recorder import McapRecorder, run_description
from datasets.writer import DatasetWriter, RunDescription, package_versions
from tests.datasets.ticks import generate_ticks, synthetic_config, terrain_and_urdf

MAGIC = 8
HEADER = struct.Struct("<BQ")
CHUNK_OPCODE, METADATA_OPCODE, ATTACHMENT_OPCODE = 0x06, 0x0C, 0x09


def record_run(path: Path, seconds: float = 1.5) -> Path:
    config = synthetic_config("complementary")
    recorder = McapRecorder(path, flush_period=0.25)
    terrain, urdf = terrain_and_urdf(config)
    recorder.start(config, urdf, terrain)
    for tick in generate_ticks(config, seconds):
        recorder.record(tick)
    recorder.finish({"roll_rmse_deg": 0.5}, None)
    return path


def records(data: bytes):
    """(offset, opcode, length of the body) of every record after the magic."""
    offset = MAGIC
    while offset + HEADER.size <= len(data) - MAGIC:
        opcode, length = HEADER.unpack_from(data, offset)
        yield offset, opcode, length
        offset += HEADER.size + length


def first(data: bytes, opcode: int, nth: int = 0) -> tuple[int, int]:
    found = [(offset, length) for offset, code, length in records(data) if code == opcode]
    return found[nth]


def chunk_fields(data: bytes, offset: int) -> dict:
    body = offset + HEADER.size
    start, end, size, crc = struct.unpack_from("<QQQI", data, body)
    (name_length,) = struct.unpack_from("<I", data, body + 28)
    compression = data[body + 32:body + 32 + name_length].decode()
    (records_length,) = struct.unpack_from("<Q", data, body + 32 + name_length)
    payload = data[body + 40 + name_length:body + 40 + name_length + records_length]
    return {"start": start, "end": end, "size": size, "crc": crc, "compression": compression, "records": payload}


def chunk_bytes(start: int, end: int, size: int, crc: int, compression: str, payload: bytes) -> bytes:
    name = compression.encode()
    body = struct.pack("<QQQI", start, end, size, crc) + struct.pack("<I", len(name)) + name \
        + struct.pack("<Q", len(payload)) + payload
    return HEADER.pack(CHUNK_OPCODE, len(body)) + body


def with_first_chunk(data: bytes, make) -> bytes:
    """The file up to its first chunk, then `make(fields of that chunk, its records)` in its place
    (the rest dropped: the reader stops at the replaced chunk or reads it)."""
    offset, length = first(data, CHUNK_OPCODE)
    fields = chunk_fields(data, offset)
    plain = zstandard.ZstdDecompressor().decompress(fields["records"], max_output_size=fields["size"])
    return data[:offset] + make(fields, plain)


def lzma_chunk(data: bytes) -> bytes:
    return with_first_chunk(data, lambda f, plain: chunk_bytes(f["start"], f["end"], len(plain), zlib.crc32(plain),
                                                                "lzma", lzma.compress(plain)))


def zstd_bomb(data: bytes, expanded: int = 512 * 2**20) -> bytes:
    """The first chunk's records followed by `expanded` zero bytes, zstd-compressed (a few kB),
    declared as the records' size."""
    def bomb(fields, plain):
        compressor = zstandard.ZstdCompressor(level=3).compressobj()
        parts = [compressor.compress(plain)]
        zeros = bytes(2**24)
        for _ in range(expanded // len(zeros)):
            parts.append(compressor.compress(zeros))
        parts.append(compressor.flush())
        return chunk_bytes(fields["start"], fields["end"], len(plain), 0, "zstd", b"".join(parts))
    return with_first_chunk(data, bomb)


def cut_before_config(data: bytes) -> bytes:
    offset, _ = first(data, METADATA_OPCODE, 1)       # "run" first, then "config"
    return data[:offset]


def written(path: Path, *, config_json: str | None = None, urdf: str | None = None, metrics_json: str | None = None,
            messages: list[tuple[str, int, bytes]] = (), urdf_bytes: bytes | None = None) -> Path:
    """A file of the dataset format with the given parts replaced."""
    config = synthetic_config("complementary")
    _, real_urdf = terrain_and_urdf(config)
    description = RunDescription(run_description(config, 5, 200.0),
                                 config_json if config_json is not None else json.dumps(config.to_dict()),
                                 config.to_toml(), urdf if urdf is not None else real_urdf, package_versions())
    dataset = DatasetWriter(path)
    dataset.describe(description)
    dataset.write([(dataset.channels[topic], ns, payload, 0) for topic, ns, payload in messages], flush=True)
    dataset.close({"roll_rmse_deg": 0.5}, {"error": ""})
    if metrics_json is not None or urdf_bytes is not None:
        data = path.read_bytes()
        if metrics_json is not None:
            data = data.replace(b'{"roll_rmse_deg": 0.5}', metrics_json.encode().ljust(22)[:22])
        if urdf_bytes is not None:
            data = data.replace(real_urdf.encode()[:len(urdf_bytes)], urdf_bytes)
        path.write_bytes(data)
    return path


def topics_of(recorded: Path) -> list[tuple[str, int, bytes]]:
    from datasets.reader import read_recording
    recording = read_recording(recorded)
    return [(topic, log_ns, data) for topic, entries in recording.messages.items()
            if topic in {t.name for t in schemas.TOPICS} for log_ns, _, data in entries]
