"""glibc's allocator set for a command's process, so that memory freed goes back to the system.

glibc raises its mmap threshold each time a large block is freed (up to 32 MiB), after which
arrays below it come from the heap, which keeps what is freed; and each thread that allocates
gets an arena of its own (the octree's insertion thread, the .bt thread, the preview's), each
keeping its own. bag2world on the CARMEN log peaked at 380-390 MB RSS with both, octree2world on
FR-079 at 388 MB; with the threshold fixed at 1 MiB (arrays from 1 MiB are mapped and unmapped
on their own) and two arenas, 327 and 329 MB, the outputs unchanged. The price is page faults on
fresh mappings: octree2world on FR-079 took 2.27-2.36 s against 1.94-2.07 s (256 KiB: 320 MB and
2.4-2.6 s; 32 MiB: no memory back). Two arenas alone give nothing back. The CLI sets it (a Python
program calling the API keeps its own allocator). Elsewhere than glibc nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: mallopt's parameters (malloc.h).
M_MMAP_THRESHOLD, M_ARENA_MAX = -3, -8
MMAP_THRESHOLD = 1 << 20  # 1 MiB
ARENA_MAX = 2


def give_back_freed_memory() -> bool:
    """Set glibc's mmap threshold and arena count for this process; False where there is no
    glibc (or it refused)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) & bool(mallopt(M_ARENA_MAX, ARENA_MAX))
