"""limbstream.heap gives the pages of freed C heap blocks back (glibc)."""
from __future__ import annotations

import ctypes
import ctypes.util
import platform

import pytest

from limbstream import heap


def rss_mib() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_freed_heap_pages_are_returned():
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.malloc.restype = ctypes.c_void_p
    libc.free.argtypes = [ctypes.c_void_p]
    blocks = [libc.malloc(1024) for _ in range(100_000)]  # 100 MiB of small blocks: heap, not mmap
    for b in blocks:
        ctypes.memset(b, 1, 1024)  # touch: resident
    keep = libc.malloc(1024)       # a live block above them stops free() from shrinking the heap
    for b in blocks:
        libc.free(b)
    before = rss_mib()
    assert heap.release_free_heap() is True
    after = rss_mib()
    libc.free(keep)
    assert before - after > 50, f"RSS {before:.0f} -> {after:.0f} MiB: free pages not returned"

