"""A run's height map kept in its recording: the array itself as the attachment `heightmap.npy`,
so that `run --from`, `replay` and `testbed.load` rebuild the terrain without the original file.

Reading a recording's config restores the array to a file of its own under the user's cache
folder (`$XDG_CACHE_HOME/hexapod-testbed/heightmaps/`, named by the array's SHA-256) and points
`terrain.heightmap` at it: the config then loads like any other, in this process and in a sweep's
workers on the same machine.
"""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from testbed.model.errors import UserError

if TYPE_CHECKING:
    from testbed.runtime.config import Config

ATTACHMENT = "heightmap.npy"
MEDIA_TYPE = "application/x-npy"


def attachments_of(config: "Config") -> dict[str, tuple[str, bytes]]:
    """The height map of `config` (its heights in m, after a PNG's scale) as .npy bytes with their
    media type, when it names one."""
    if not config.terrain.heightmap:
        return {}
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(config.terrain.heightmap_heights(), dtype=np.float64), allow_pickle=False)
    return {ATTACHMENT: (MEDIA_TYPE, buffer.getvalue())}


def cache_folder() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "hexapod-testbed" / "heightmaps"


def restored_config(config: dict[str, Any], attachments: dict[str, bytes], source: Path) -> dict[str, Any]:
    """`config` (a recorded config dict) with `terrain.heightmap` pointing at the recorded height
    map, restored to the cache folder; unchanged when the recording holds none."""
    data = attachments.get(ATTACHMENT)
    if data is None:
        return config
    path = _restore(data, source)
    terrain = {**config.get("terrain", {}), "heightmap": str(path)}
    return {**config, "terrain": terrain}


def _restore(data: bytes, source: Path) -> Path:
    path = cache_folder() / f"{hashlib.sha256(data).hexdigest()[:32]}.npy"
    if path.is_file():
        return path
    try:
        np.load(io.BytesIO(data), allow_pickle=False)
    except (OSError, ValueError) as error:
        raise UserError(f"{source}: its recorded height map is unreadable ({error})") from None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(prefix=".heightmap.", dir=path.parent)
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
        os.replace(temporary, path)
    except OSError as error:
        raise UserError(f"{source}: cannot restore its height map to {path.parent} ({error})") from None
    return path
