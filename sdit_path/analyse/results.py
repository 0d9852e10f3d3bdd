"""What ``analyse`` hands out: every recording matched, aligned and diagnosed, and the
geometry identified from all of them with the effects found; frozen, with
``to_json()``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from ..diagnose import Diagnosis
from ..diagnose.recording import AlignedRecording
from ..identify.results import Identification
from ..reading.trace import Trace


def recording_header(header: dict, longest: int = 120) -> dict:
    """The recording's ``# key: value`` lines as the report shows them: text only,
    control characters out, each cut to ``longest`` characters."""
    out = {}
    for k, v in list(header.items())[:40]:
        key = "".join(ch for ch in str(k) if ch.isprintable())[:40]
        out[key] = "".join(ch for ch in str(v) if ch.isprintable())[:longest]
    return out


@dataclass(frozen=True, slots=True)
class Analysed:
    """One recording: its ``label`` (the file), its ``program`` and how it was chosen
    (``matched``), its first alignment (``aligned``), its ``diagnosis``, the recording on
    program time by the diagnosis' alignment (``trace``) and the diagnosis' ``pictures``
    (name -> PNG, when drawn).  (The program's context, a hundred MB at 1 kHz, is not
    kept: the analysis lets it go once the recording is diagnosed.)"""

    label: str
    program: str
    matched: str
    aligned: AlignedRecording
    diagnosis: Diagnosis
    trace: Trace
    pictures: Mapping[str, bytes]


@dataclass(frozen=True, slots=True)
class AnalysisResult:
    """The recordings of one test analysed together: ``recordings`` in the order given,
    ``geometry`` (identified with the effects found as nuisances), ``warnings`` (one
    line each) and per recording the ``timing`` its program was read with (``model``:
    ``plan`` or the control's, then ``runs``: each run's planned and control time)."""

    recordings: tuple[Analysed, ...]
    geometry: Identification
    warnings: tuple[str, ...]
    timing: tuple[dict, ...] = ()

    def to_json(self) -> dict:
        geometry = self.geometry.to_json()
        per = []
        across: dict[str, list] = {}
        for k, a in enumerate(self.recordings):
            dj = a.diagnosis.to_json()
            for f in dj["findings"]:
                across.setdefault(f["effect"], []).append(
                    {"recording": a.label, "program": a.program, "confidence": f["confidence"],
                     "parameters": f["parameters"], "parameter_std": f["parameter_std"],
                     "contribution_rms_um": f["contribution_rms_um"]})
            per.append({"file": a.label, "program": a.program, "matched": a.matched,
                        "header": recording_header(a.trace.header),
                        "first_alignment": a.aligned.as_json(), "diagnosis": dj,
                        "nuisances": geometry["nuisances"][k],
                        "timing": self.timing[k] if k < len(self.timing) else {"model": "plan"}})
        return {"recordings": per, "geometry": geometry,
                "aliasing": geometry.get("aliasing", []),
                "across_recordings": across, "warnings": list(self.warnings)}
