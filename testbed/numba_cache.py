"""Where numba keeps the compiled kernels (`@njit(cache=True)`): beside the sources when their
folders are writable (numba's own choice), else in the user's cache folder (platformdirs), else in
a temporary folder for this process (compiled once per process, not kept). numba reads
NUMBA_CACHE_DIR when it is first imported, so `configure` runs from `testbed/__init__.py`, before
any kernel module imports numba; a NUMBA_CACHE_DIR set by the user is left as it is."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

PACKAGES = ("testbed", "sensors", "estimators", "datasets")


def configure() -> None:
    if "NUMBA_CACHE_DIR" in os.environ or "numba" in sys.modules:
        return
    install = Path(__file__).resolve().parent.parent
    if all(_writable_pycache(install / package) for package in PACKAGES if (install / package).is_dir()):
        return
    os.environ["NUMBA_CACHE_DIR"] = str(_user_cache() or tempfile.mkdtemp(prefix="hexapod-testbed-numba-"))


def _writable_pycache(folder: Path) -> bool:
    pycache = folder / "__pycache__"
    return os.access(pycache, os.W_OK | os.X_OK) if pycache.exists() else os.access(folder, os.W_OK | os.X_OK)


def _user_cache() -> Path | None:
    try:
        import platformdirs
        folder = Path(platformdirs.user_cache_dir("hexapod-testbed")) / "numba"
        folder.mkdir(parents=True, exist_ok=True)
    except (ImportError, OSError):
        return None
    return folder if os.access(folder, os.W_OK | os.X_OK) else None
