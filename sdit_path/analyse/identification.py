"""``sdit-path identify``: the geometry from recordings given with their programs, each
recording matched and aligned to its program first (it runs on its instrument's clock),
as the diagnosis does."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from ..diagnose.recording import align_recording, poor_fit
from ..errormodel.model import ModelOptions
from ..errors import ConfigError
from ..identify.identify import identify
from ..identify.results import Identification
from ..plan.files import PlanFiles
from ..reading.recording import read_trace


def identify_recordings(recordings: Sequence[tuple[str, PlanFiles, str | None]],
                        options: ModelOptions, prior: bool = False, ask: tuple[str, ...] = (),
                        step: Callable[[str], None] = lambda msg: None) -> Identification:
    """``recordings``: (file, its plan, its program or None: the file's ``# program:``
    line names it).  The identification with the recordings as aligned and a warning
    where the model leaves more than their noise."""
    experiments, aligned = [], []
    for path, plan, named in recordings:
        step(f"reading {path}")
        trace = read_trace(path)
        prog = named or trace.header.get("program")
        if not prog:
            raise ConfigError(path, "no '# program:' line; pass --program")
        if prog not in plan.program_names:
            raise ConfigError(path, f"program {prog[:40]!r} is not in the plan "
                                    f"({', '.join(plan.program_names)}); pass --program")
        step(f"aligning {path} to {prog}")
        rec = align_recording(plan, prog, trace, str(path))
        aligned.append(rec)
        experiments.append((plan, prog, rec.trace))
    step("identifying")
    result = identify(experiments, options, prior=prior, ask=tuple(ask))
    noise = max(r.noise_um for r in aligned)
    warnings = []
    if poor_fit(result.noise_std_um, noise):
        warnings.append(
            f"the identified model leaves {result.noise_std_um:.2f} um RMS against "
            f"the recordings' own noise of at most {noise:.2f} um: a recording of another "
            f"program, feed or plan, a set-up that moved during the test, or an effect "
            f"beyond geometry (servo, backlash, drift: see diagnose)")
    return result.with_recordings([{"file": str(p), **r.as_json()}
                                   for (p, _, _), r in zip(recordings, aligned)], warnings)
