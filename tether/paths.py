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
    """Raise :class:`ConfigError` (``'FLAG PATH: why'``; ``'PATH: why'`` when ``flag`` is empty) unless ``path`` can be created or
    overwritten as a file: not a directory, FIFO or block device (a character device such as
    ``/dev/null`` is accepted); its folder exists or can be made (writers make it); the folder
    takes a new file. Nothing is left behind: an existing file
    is opened for appending without writing, a probe file in the folder is removed."""
    p = Path(path)
    at = f"{flag} {path}" if flag else str(path)
    what = not_regular(p)
    if what == "a directory":
        raise ConfigError(f"{at}: a directory, not a file to write (give a file name, e.g. {p / 'run.mcap'})")
    if what:
        mode = os.stat(p).st_mode
        if stat.S_ISCHR(mode):                 # /dev/null: a run whose output is discarded
            return
        why = ("a FIFO: opening it waits for a reader" if stat.S_ISFIFO(mode) else
               "a block device: writing would overwrite the disk" if stat.S_ISBLK(mode) else "a socket")
        raise ConfigError(f"{at}: {why} (give a regular file)")
    folder = p.parent
    while not folder.exists() and folder != folder.parent:    # the writer makes the missing folders
        folder = folder.parent
    if not folder.is_dir():
        raise ConfigError(f"{at}: {folder} is not a folder")
    try:
        if p.exists():
            with open(p, "ab"):
                pass
        else:
            with tempfile.TemporaryFile(dir=folder):
                pass
    except OSError as exc:
        raise ConfigError(f"{at}: cannot write there: {exc.strerror}") from None
