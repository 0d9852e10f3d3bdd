"""Keeping freed memory for reuse while a long numerical job runs.

The diagnosis builds and drops tall matrices by the thousand (a recording's model at
120,000 samples by 70 columns is 67 MB).  glibc hands every block above its mmap
threshold back to the kernel when it is freed, and the next one arrives as fresh
zeroed pages: faulting them in takes a good part of a long analysis' time.  While
:func:`reusing_freed_memory` is active, large blocks come from the heap and stay there
once freed (the peak resident memory hardly grows, and the output is the same byte for
byte).  Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util

# mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
_M_MMAP_MAX = -4

# glibc's defaults, put back afterwards
_DEFAULTS = ((_M_MMAP_MAX, 65536), (_M_TRIM_THRESHOLD, 128 * 1024), (_M_TOP_PAD, 128 * 1024),
             (_M_MMAP_THRESHOLD, 128 * 1024))


def _mallopt():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        fn = libc.mallopt
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return fn


@contextlib.contextmanager
def reusing_freed_memory(top_pad_bytes: int = 512 << 20):
    """Within the block (and in processes forked in it), large allocations are served
    from the heap and freed memory is kept for the next one instead of being returned
    to the kernel; ``top_pad_bytes``: how far the heap grows at once (address space,
    not memory, until it is used)."""
    mallopt = _mallopt()
    if mallopt is None:
        yield
        return
    mallopt(_M_MMAP_MAX, 0)
    mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
    mallopt(_M_TOP_PAD, min(top_pad_bytes, 2**31 - 1))
    try:
        yield
    finally:
        for param, value in _DEFAULTS:
            mallopt(param, value)
