"""Peak memory beside time: every benchmark prints it last (the tools run on a shop PC
with 8 GB and other work open)."""

from __future__ import annotations

import resource


def peak_memory_line() -> str:
    """This process's peak resident memory and its largest child's (MB)."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return (f"peak memory: {own:.0f} MB this process"
            + (f", {child:.0f} MB its largest child process" if child else ""))
