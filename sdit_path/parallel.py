"""Per-item work in forked worker processes (everything built so far is shared), the
results in the items' order: the recordings of ``analyse``, the candidate curves of
``replan``."""

from __future__ import annotations

import multiprocessing
import os

_JOB = None


def _run(k: int):
    try:
        return True, _JOB(k)
    except Exception as exc:  # handed back whole: the parent raises it
        return False, (type(exc), str(exc), dict(exc.__dict__))


def _reraise(failure):
    cls, text, state = failure
    exc = cls.__new__(cls)
    Exception.__init__(exc, text)
    exc.__dict__.update(state)
    raise exc


def resident_mb() -> float:
    """This process' resident memory now (MB; 0 where /proc cannot tell)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def jobs_within(memory_mb: float | None, job_mb: float, jobs: int) -> int:
    """How many of ``jobs`` workers, each taking ``job_mb`` beside what this process
    holds now (shared with them), fit in ``memory_mb`` for all processes together; one
    at least (None: no bound)."""
    if memory_mb is None or jobs <= 1:
        return jobs
    free = memory_mb - resident_mb()
    return max(1, min(jobs, int(free // max(job_mb, 1e-9))))


def default_jobs() -> int:
    """Worker processes: one per core."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def each(job, labels: list[str], jobs: int, step, what: str,
         sizes: list[float] | None = None, arrived=None) -> list:
    """``job(k)`` for every item, in ``jobs`` worker processes (forked: everything built
    so far is shared), the results in the items' order; with ``sizes`` (the work each
    takes, roughly), the largest are started first, so that no worker is left with a
    long one at the end.  The progress names each item as its turn comes.  Each job is
    computed alone, so the results do not depend on how many workers there are (with
    BLAS at one thread per process, as ``analyse`` runs it, the same bytes).

    ``arrived(k, result, idle)``, if given, is called in this process as each result
    comes back; ``idle`` is True once fewer items are left than workers (a core is free
    for the caller's own work on what has arrived)."""
    global _JOB
    jobs = min(jobs, len(labels))
    if jobs <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        out = []
        for k, label in enumerate(labels):
            step(what.format(label=label))
            out.append(job(k))
            if arrived is not None:
                arrived(k, out[-1], False)
        return out
    order = list(range(len(labels)))
    if sizes:
        order.sort(key=lambda k: -sizes[k])
    _JOB = job
    out: list = [None] * len(labels)
    try:
        with multiprocessing.get_context("fork").Pool(jobs) as pool:
            step(what.format(label=labels[order[0]]))
            for i, (ok, value) in enumerate(pool.imap(_run, order)):
                if i:  # the first is announced as the pool starts
                    step(what.format(label=labels[order[i]]))
                if not ok:
                    _reraise(value)
                out[order[i]] = value
                if arrived is not None:
                    arrived(order[i], value, len(order) - i - 1 < jobs)
    finally:
        _JOB = None
    return out
