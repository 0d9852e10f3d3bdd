"""What a diagnosis finds: frozen values with ``to_json()``.

While a diagnosis runs, its findings are drafts (:class:`FindingDraft`, an
:class:`Explanation`) that the selection, the timing and the read-out refine in turn;
:func:`sdit_path.diagnose.diagnose` hands out the frozen :class:`Diagnosis`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from ..arrays import ReadOnlyDict
from .align import Alignment, timing_is_weak
from .effects import EFFECT_NAMES


@dataclass
class FindingDraft:
    """A finding while the diagnosis works on it (see :class:`Finding`)."""

    effect: str
    title: str
    parameters: dict
    nonlinear: dict
    labels: tuple
    rms_before_um: float
    rms_after_um: float
    heldout_rms_before_um: float
    heldout_rms_after_um: float
    delta_bic: float
    runner_up: str | None = None
    runner_up_ratio: float = math.inf
    mimics: list = field(default_factory=list)
    confidence: str = "low"
    where: dict = field(default_factory=dict)
    contribution_rms_um: float = 0.0
    geometry_doubt: bool = False
    ambiguous_with: list = field(default_factory=list)
    separate_by: str = ""
    #: parameters the bar cannot see in this program (not estimated, not reported)
    unseen: list = field(default_factory=list)
    #: parameter -> standard uncertainty (a searched one whose columns could not be made
    #: at the steps around it has none)
    uncertainty: dict = field(default_factory=dict)
    #: parameters the recording does not determine apart from the others' (not reported)
    undetermined: list = field(default_factory=list)
    #: what its timing parameter's profile with the timing leaves open
    #: (:func:`.timing_profiles.profile_timing`; kept for the read-out, not reported)
    profile: "ProfileOpen | None" = None

    def freeze(self) -> "Finding":
        return Finding(**{f.name: _frozen(getattr(self, f.name)) for f in fields(self)
                          if f.name != "profile"})


@dataclass(frozen=True)
class ProfileOpen:
    """What a finding's timing parameter, profiled with the timing, leaves open:
    ``std``, parameter -> the standard uncertainty the values that fit alike imply
    (the timing parameter's own, and what the finding's others move by along them);
    ``slope``, parameter -> how it moves per unit of the timing parameter along the
    profile (what the timing parameter's final uncertainty carries into it)."""

    std: Mapping
    slope: Mapping


@dataclass(frozen=True, slots=True)
class Finding:
    """One effect the recording supports.  ``parameters`` (reported values, in the units
    their names say) with ``uncertainty`` (standard, k=1; a parameter found by a search
    on a grid may have none); ``nonlinear``: the searched parameters its columns were
    made with; ``labels``: its columns' names; RMS of the gap before and after it, on
    the fitted and the held-out stretches; ``delta_bic``: its evidence; ``runner_up``
    and ``runner_up_ratio``: the next-best effect at its selection step and how much
    less it explained; ``mimics``: effects that reproduce its signal (``effect``,
    ``r2``); ``confidence``: high, medium or low; ``where``: where its contribution
    lives; ``ambiguous_with`` and ``separate_by``: effects this recording cannot tell it
    from and the run that would; ``unseen`` and ``undetermined``: parameters not
    reported (the bar cannot see them here; the recording does not determine them)."""

    effect: str
    title: str
    parameters: Mapping
    nonlinear: Mapping
    labels: tuple
    rms_before_um: float
    rms_after_um: float
    heldout_rms_before_um: float
    heldout_rms_after_um: float
    delta_bic: float
    runner_up: str | None
    runner_up_ratio: float
    mimics: tuple
    confidence: str
    where: Mapping
    contribution_rms_um: float
    geometry_doubt: bool
    ambiguous_with: tuple
    separate_by: str
    unseen: tuple
    uncertainty: Mapping
    undetermined: tuple

    def to_json(self, rank: int) -> dict:
        """The finding as the reports write it (``rank``: 1 for the most important)."""
        return {
            "rank": rank, "effect": self.effect, "title": self.title,
            "parameters": self.parameters,
            "parameter_std": {p: self.uncertainty[p] for p in self.parameters
                              if p in self.uncertainty},
            "searched_on_a_grid": [p for p, v in self.parameters.items()
                                   if isinstance(v, float) and p not in self.uncertainty],
            "not_seen_by_the_bar": self.unseen,
            "not_determined": self.undetermined,
            "where": {"segments": self.where.get("segments", []),
                      "time_windows_s": self.where.get("time_windows_s", []),
                      "phase_rms_um": self.where.get("phase_rms_um", {}),
                      "reversal_rms_um": self.where.get("reversal_rms_um", {})},
            "rms_before_um": self.rms_before_um, "rms_after_um": self.rms_after_um,
            "heldout_rms_before_um": self.heldout_rms_before_um,
            "heldout_rms_after_um": self.heldout_rms_after_um,
            "contribution_rms_um": self.contribution_rms_um,
            "delta_bic": self.delta_bic, "confidence": self.confidence,
            "mimics": self.mimics, "runner_up": self.runner_up,
            "ambiguous_with": self.ambiguous_with, "separate_by": self.separate_by,
            "runner_up_evidence_ratio": self.runner_up_ratio,
        }


@dataclass
class Explanation:
    """A diagnosis while it is worked on (see :class:`Diagnosis`)."""

    program: str
    alignment: Alignment
    gap: dict
    findings: list
    unexplained: dict
    noise_um: float
    samples: dict
    series: dict

    def freeze(self) -> "Diagnosis":
        return Diagnosis(self.program, self.alignment, _frozen(self.gap),
                         tuple(f.freeze() for f in self.findings), _frozen(self.unexplained),
                         self.noise_um, _frozen(self.samples),
                         ReadOnlyDict({k: _read_only(v) for k, v in self.series.items()}))


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """The gap between a recording and its program explained.  ``alignment``: where the
    program starts in the recording and the recorder's clock rate, with their standard
    uncertainties; ``gap``: the measured minus the expected reading (RMS, largest, where
    it lives, a set-up step if one was taken out); ``findings``: the effects it supports,
    most important first; ``unexplained``: what they leave (RMS against the noise,
    whether that is significant, where); ``noise_um``: the sensor noise; ``samples``:
    how many were in the program, fitted, held out, empty; ``series``: the arrays the
    pictures draw (program time ``tau``, ``gap``, ``fitted``, ``residual``, trajectory
    sample ``idx``, ``held``)."""

    program: str
    alignment: Alignment
    gap: Mapping
    findings: tuple[Finding, ...]
    unexplained: Mapping
    noise_um: float
    samples: Mapping
    series: Mapping

    def to_json(self) -> dict:
        al = self.alignment
        out = {
            "program": self.program,
            "alignment": {"offset_s": al.offset_s, "clock_ppm": al.clock_ppm,
                          "offset_std_s": al.offset_std_s, "clock_std_ppm": al.clock_std_ppm,
                          "timing_weak": timing_is_weak(al),
                          "widened_by": list(al.widened_by),
                          "note": "measured t = offset_s + program t * (1 + clock_ppm 1e-6); a "
                                  "following delay of the machine is part of the offset"},
            "samples": self.samples,
            "noise_um": self.noise_um,
            "gap": self.gap,
            "findings": [f.to_json(k + 1) for k, f in enumerate(self.findings)],
            "unexplained": self.unexplained,
            "library": list(EFFECT_NAMES),
        }
        return json_clean(out)


def _frozen(value):
    """A read-only copy of a draft's value: mappings as read-only mappings, lists as
    tuples, all the way down."""
    if isinstance(value, Mapping):
        return ReadOnlyDict({k: _frozen(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _read_only(a):
    if isinstance(a, np.ndarray):
        a = a.view()
        a.setflags(write=False)
    return a


def json_clean(v):
    """``v`` as JSON writes it: floats rounded to 6 decimals (None where not finite),
    mappings as dicts, sequences as lists, numpy scalars as Python's."""
    if isinstance(v, float):
        return None if not math.isfinite(v) else round(v, 6)
    if isinstance(v, Mapping):
        return {k: json_clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_clean(x) for x in v]
    if isinstance(v, (np.floating,)):
        return json_clean(float(v))
    if isinstance(v, (np.integer,)):
        return int(v)
    return v
