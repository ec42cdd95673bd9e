"""Give freed heap memory back to the operating system.

A long-running service that allocates many short-lived buffers from several threads (NumPy
temporaries on the main thread, Zenoh's receive threads) leaves glibc's arenas holding free
pages: resident memory creeps up in steps although the live heap stays flat (bench/soak.py,
docs/reliability.md). ``malloc_trim(0)`` returns those pages; it takes 1-4 ms with 2,000 devices.
"""
from __future__ import annotations

import ctypes
import ctypes.util

_libc = None
try:
    _name = ctypes.util.find_library("c")
    _lib = ctypes.CDLL(_name) if _name else None
    if _lib is not None and hasattr(_lib, "malloc_trim"):  # glibc only (not musl, not macOS)
        _libc = _lib
except OSError:
    pass


def release_free_heap() -> bool:
    """Return free heap pages to the OS; False where the C library cannot (then a no-op)."""
    if _libc is None:
        return False
    _libc.malloc_trim(0)
    return True
