"""codac, imported and called without changing the rest of the process's arithmetic.

Importing codac (2.1, through its interval back-end) switches the CPU's floating-point
rounding mode to *upward* for the whole process and leaves it there: every later numpy
or Python float operation then rounds up (``1.0 + 1e-17 != 1.0``), so results change with
whether some node happened to import codac, and replays stop being bit-identical. Measured
here with ``fegetround()``: 0 (to nearest) before ``import codac``, 2048 (upward) after.

:func:`codac_calls` gives codac the mode it set at import for the duration of a block and
puts the caller's mode back afterwards. Every use of codac in this repository goes through it.
"""
from __future__ import annotations

import ctypes
import ctypes.util
from contextlib import contextmanager
from typing import Any, Iterator

_LIBM = ctypes.CDLL(ctypes.util.find_library("m"))
_CODAC: Any = None
_CODAC_MODE: int | None = None


def rounding_mode() -> int:
    """The C ``fegetround()`` value (0: to nearest on x86-64 and aarch64)."""
    return int(_LIBM.fegetround())


def _load() -> Any:
    global _CODAC, _CODAC_MODE
    if _CODAC is None:
        before = rounding_mode()
        import codac
        _CODAC, _CODAC_MODE = codac, rounding_mode()
        _LIBM.fesetround(before)
    return _CODAC


def available() -> bool:
    try:
        _load()
    except ImportError:
        return False
    return True


@contextmanager
def codac_calls() -> Iterator[Any]:
    """``with codac_calls() as codac: ...``: codac runs in the rounding mode it expects; the
    caller's mode is restored on exit, exception or not."""
    codac = _load()
    before = rounding_mode()
    _LIBM.fesetround(_CODAC_MODE)
    try:
        yield codac
    finally:
        _LIBM.fesetround(before)
