"""Keep a long-running service's resident memory at its live heap (glibc).

The aggregator allocates short-lived NumPy temporaries every tick while Zenoh's threads
allocate message buffers; glibc's arenas keep the pages of freed blocks. The aggregator's RSS
crept up in steps (+14 % in 30 min with 2,000 devices) while its live heap stayed flat
(mallinfo2: 44-45 MiB in use, free arena space growing; docs/reliability.md).
:func:`release_free_heap` (``malloc_trim``, 1-4 ms with 2,000 devices) returns those pages.
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
