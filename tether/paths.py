"""Files named on the command line, checked before anything starts: an input that is not a
regular file (a directory, a device, a FIFO that would block the read for ever) and an
output that cannot be written (found otherwise only when the run ends)."""
from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from tether.errors import ConfigError


def not_regular(path: str | Path) -> str:
    """What ``path`` is when it exists but is not a regular file ('a directory', 'a device or
    pipe'); '' for a regular file or nothing at all. Symbolic links are followed.

    Reading a FIFO with no writer blocks in ``open`` until one comes, and ``/dev/zero`` never
    ends: callers refuse these before opening."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return ""
    if stat.S_ISREG(mode):
        return ""
    return "a directory" if stat.S_ISDIR(mode) else "a device or pipe"


def check_writable(path: str | Path, flag: str) -> None:
    """Raise :class:`ConfigError` (``'FLAG PATH: why'``) unless ``path`` can be created or
    overwritten as a file: not a directory, device or pipe; its folder exists or can be made
    (writers make it); the folder takes a new file. Nothing is left behind: an existing file
    is opened for appending without writing, a probe file in the folder is removed."""
    p = Path(path)
    what = not_regular(p)
    if what:
        hint = f" (give a file name, e.g. {p / 'run.mcap'})" if what == "a directory" else ""
        raise ConfigError(f"{flag} {path}: {what}, not a file to write{hint}")
    folder = p.parent
    while not folder.exists() and folder != folder.parent:    # the writer makes the missing folders
        folder = folder.parent
    if not folder.is_dir():
        raise ConfigError(f"{flag} {path}: {folder} is not a folder")
    try:
        if p.exists():
            with open(p, "ab"):
                pass
        else:
            with tempfile.TemporaryFile(dir=folder):
                pass
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: cannot write there: {exc.strerror}") from None
