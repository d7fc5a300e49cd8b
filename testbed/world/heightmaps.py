"""Height-map files: a `.npy` 2-D float array of heights in m, or a 16-bit grayscale `.png` whose
units are scaled to m. Rows run along y, columns along x; row 0, column 0 is the cell at the map's
origin corner. Any problem with the file is a ConfigError naming it."""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from testbed.model.errors import ConfigError

MAX_CELLS = 20000       # boxes DART and the recorder can take (as rough ground)


def read_heightmap(path: str, scale: float) -> np.ndarray:
    """Heights (rows along y, columns along x) in m, read-only; ConfigError when the file is missing,
    unreadable, or not a finite 2-D float array (a 16-bit grayscale image for .png)."""
    file = Path(path)
    try:
        stat = file.stat()
    except OSError:
        raise ConfigError(f"terrain.heightmap: no file {path}") from None
    if file.is_dir():
        raise ConfigError(f"terrain.heightmap: {path} is a directory")
    return _read(str(file.resolve()), stat.st_mtime_ns, stat.st_size, float(scale))


@lru_cache(maxsize=8)
def _read(path: str, _mtime_ns: int, _size: int, scale: float) -> np.ndarray:
    suffix = os.path.splitext(path)[1].lower()
    if suffix == ".npy":
        heights = _read_npy(path)
    elif suffix == ".png":
        heights = _read_png(path) * scale
    else:
        raise ConfigError(f"terrain.heightmap: {path} is neither a .npy nor a .png file")
    _check_heights(heights, path)
    heights.setflags(write=False)
    return heights


def _read_npy(path: str) -> np.ndarray:
    try:
        heights = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise ConfigError(f"terrain.heightmap: cannot read {path} as a .npy array: {error}") from None
    if not isinstance(heights, np.ndarray) or not np.issubdtype(heights.dtype, np.floating):
        raise ConfigError(f"terrain.heightmap: {path} holds {getattr(heights, 'dtype', type(heights))} values, "
                          f"not floating-point heights in m")
    return heights.astype(np.float64)


def _read_png(path: str) -> np.ndarray:
    try:
        with Image.open(path) as image:
            mode = image.mode
            pixels = np.array(image)
    except (OSError, UnidentifiedImageError) as error:
        raise ConfigError(f"terrain.heightmap: cannot read {path} as a PNG image: {error}") from None
    if mode not in ("I;16", "I;16B", "I;16L") and not (mode == "I" and pixels.ndim == 2 and pixels.min() >= 0
                                                         and pixels.max() <= 65535):
        raise ConfigError(f"terrain.heightmap: {path} is a mode {mode} image, not 16-bit grayscale")
    return pixels.astype(np.float64)


def _check_heights(heights: np.ndarray, path: str) -> None:
    if heights.ndim != 2 or min(heights.shape) < 2:
        raise ConfigError(f"terrain.heightmap: {path} has shape {heights.shape}, not a 2-D map of at least 2 x 2")
    if heights.size > MAX_CELLS:
        raise ConfigError(f"terrain.heightmap: {path} has {heights.size} cells, more than {MAX_CELLS}")
    if not np.isfinite(heights).all():
        raise ConfigError(f"terrain.heightmap: {path} holds {int((~np.isfinite(heights)).sum())} NaN or "
                          f"infinite heights")
