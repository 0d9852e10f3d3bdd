"""Keeping freed memory for reuse while a long numerical job runs, within a bound.

The diagnosis builds and drops tall matrices by the thousand (a recording's model at
120,000 samples by 70 columns is 67 MB).  glibc hands every block above its mmap
threshold (128 kB at first) back to the kernel when it is freed, and the next one
arrives as fresh zeroed pages: faulting them in took a good part of a long analysis'
time.  While :func:`reusing_freed_memory` is active, blocks up to 32 MB (glibc's
largest threshold) come from the heap and are reused once freed; larger ones are mapped
and unmapped as before, and at most ``keep_bytes`` of free memory is kept at the heap's
top.  Freed memory inside the heap is returned to the kernel by
:func:`release_freed_memory`, called where a stage ends (a recording diagnosed): kept
for ever it made the resident memory only grow, by hundreds of MB a recording.  The
output is the same byte for byte either way.  Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools

# mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
_M_MMAP_MAX = -4

# glibc's defaults, put back afterwards
_DEFAULTS = {_M_MMAP_MAX: 65536, _M_TRIM_THRESHOLD: 128 * 1024, _M_TOP_PAD: 128 * 1024,
             _M_MMAP_THRESHOLD: 128 * 1024}

#: glibc's largest mmap threshold on 64-bit systems (DEFAULT_MMAP_THRESHOLD_MAX)
_LARGEST_THRESHOLD = 32 << 20

#: the settings made here (glibc has no getter): what a nested block puts back
_current = dict(_DEFAULTS)


def _set(mallopt, param: int, value: int) -> None:
    mallopt(param, value)
    _current[param] = value


@functools.cache
def _libc():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt.argtypes, libc.mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
        libc.malloc_trim.argtypes, libc.malloc_trim.restype = (ctypes.c_size_t,), ctypes.c_int
    except (OSError, AttributeError):
        return None
    return libc


def _mallopt():
    libc = _libc()
    return None if libc is None else libc.mallopt


@contextlib.contextmanager
def _settings(values: dict[int, int]):
    """Within the block the mallopt ``values`` (parameter: value), what was set
    before put back afterwards and the freed pages given back."""
    mallopt = _mallopt()
    if mallopt is None:
        yield
        return
    before = dict(_current)
    for param, value in values.items():
        _set(mallopt, param, value)
    try:
        yield
    finally:
        for p, value in before.items():
            _set(mallopt, p, value)
        release_freed_memory()


def reusing_freed_memory(keep_bytes: int = 128 << 20):
    """Within the block (and in processes forked in it), allocations up to 32 MB are
    served from the heap and freed memory is kept for the next one, at most
    ``keep_bytes`` of it at the heap's top."""
    return _settings({_M_MMAP_THRESHOLD: _LARGEST_THRESHOLD,
                      _M_TRIM_THRESHOLD: min(keep_bytes, 2**31 - 1),
                      _M_TOP_PAD: min(keep_bytes // 2, 2**31 - 1)})


def mapping_large_blocks(threshold: int = 4 << 20):
    """Within the block, allocations above ``threshold`` are mapped, and handed back
    to the kernel when freed: a tall program's arrays (27 MB each an hour at 1 kHz,
    made and dropped by the hundred) otherwise stay in the heap once freed, hundreds of
    MB of them between two :func:`release_freed_memory`."""
    return _settings({_M_MMAP_THRESHOLD: threshold})


def release_freed_memory() -> None:
    """Give the heap's free pages back to the kernel (glibc's ``malloc_trim``): where a
    stage has let its arrays go."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)
