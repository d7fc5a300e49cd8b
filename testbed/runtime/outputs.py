"""The one rule of every output file of the command line (docs/dataset.md, "Output files"):
missing parent folders are created; an existing file is replaced only with --force; the file is
written under a temporary name beside it and renamed into place when complete."""

from __future__ import annotations

import os
from pathlib import Path

from testbed.model.errors import UserError


def prepare_output(path: Path, option: str, force: bool) -> Path:
    """Check `path` can be written under the rule, creating its missing parent folders; UserError
    (one line, exit 2) if not."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"{option} {_shown(path)} is a directory")
    if (path.exists() or path.is_symlink()) and not force:
        raise UserError(f"{option} {_shown(path)} exists (add --force to replace it)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise UserError(f"{option} {_shown(path)}: a parent of it is not a folder") from None
    except OSError as error:
        raise UserError(f"{option} {_shown(path)}: cannot create its folder ({error.strerror})") from None
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise UserError(f"{option} {_shown(path)}: folder {_shown(path.parent)} is not writable")
    return path


def prepare_folder(path: Path, option: str) -> Path:
    """An output folder: created with its parents if missing; UserError if it is a file or not writable."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise UserError(f"{option} {_shown(path)} is a file, not a folder") from None
    except OSError as error:
        raise UserError(f"{option} {_shown(path)}: cannot create it ({error.strerror})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise UserError(f"{option} {_shown(path)} is not writable")
    return path


def _shown(path: Path) -> str:
    """A path on one line: control characters (a newline in a name) escaped."""
    return str(path).encode("unicode_escape").decode("ascii") if not str(path).isprintable() else str(path)


def write_atomically(path: Path, data: bytes) -> None:
    """`data` into a temporary file beside `path` (its folder created if missing), renamed over it
    when complete; nothing is left behind if the write fails (a full disk)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        with open(temporary, "wb") as stream:
            stream.write(data)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
