"""``sdit-path diagnose``: one recording of a named program, matched and aligned as every
command that reads a recording does it, then diagnosed."""

from __future__ import annotations

import contextlib
from collections.abc import Callable

from ..diagnose import Diagnosis, diagnose
from ..diagnose.align import AlignmentError
from ..diagnose.recording import align_recording
from ..errormodel.errorset import ErrorSet
from ..heap import mapping_large_blocks, release_freed_memory
from ..plan.files import PlanFiles
from ..reading.context import Context, build_context
from ..reading.trace import Trace


def diagnose_recording(plan: PlanFiles, program: str, trace: Trace, label: str,
                       model: ErrorSet | None = None,
                       step: Callable[[str], None] = lambda msg: None
                       ) -> tuple[Diagnosis, Context]:
    """The diagnosis of ``trace`` (the file ``label``) against ``program`` and the reading
    ``model`` predicts, and the program's context (for the pictures)."""
    ctx = build_context(plan, program)
    # the trajectory as read (what the context holds of it stays) and what making the
    # context freed: let go before the matching (0.15 GB an hour at 1 kHz)
    plan.let_go()
    release_freed_memory()
    with mapping_large_blocks() if ctx.tall else contextlib.nullcontext():
        step("matching the recording to its program")
        # (the alignment kept, the recording as aligned let go: a copy of it)
        first = align_recording(plan, program, trace, label, ctx).alignment
        release_freed_memory()  # (what the matching freed)
        try:
            # with a geometric model the search is made again with what it predicts
            result = diagnose(plan, program, trace, model, progress=step, ctx=ctx,
                              alignment=first if model is None else None)
        except AlignmentError as exc:
            raise AlignmentError(f"{label}: {exc}") from None
    return result, ctx
