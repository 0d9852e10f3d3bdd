"""An analysis read back from its folder (``analysis.json`` and ``aligned/``) for the
report, checked against the plan it claims to be of."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import ConfigError, SditError
from ..plan.files import PlanFiles
from ..reading.recording import read_trace

#: the fields the report reads, per recording and of the geometry
_RECORDING = ("file", "program", "diagnosis", "nuisances")
_DIAGNOSIS = ("alignment", "noise_um", "gap", "findings", "unexplained")
_GEOMETRY = ("model", "rank", "determined", "combinations")


def aligned_name(program: str, label: str) -> str:
    """The file ``analyse`` writes a recording on its program's time to, in ``aligned/``."""
    stem = Path(label).stem or "recording"
    stem = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in stem)[:60]
    return f"{program}_{stem}.csv"


def load_analysis(path: str, plan: PlanFiles, plan_sha256: str
                  ) -> tuple[dict, list[tuple[str, np.ndarray, np.ndarray]]]:
    """The analysis at ``path`` and, per recording, its program and the recording on
    program time (``aligned/``); refused with one line when it is not an analysis, is
    of another plan, or its folder lacks an aligned recording."""
    where = str(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(where, f"expected the analysis.json written by sdit-path analyse "
                                 f"({type(exc).__name__})") from None
    _check(data, where)
    said = data.get("plan", {}).get("plan_json_sha256") if isinstance(data.get("plan"),
                                                                      dict) else None
    if said is not None and said != plan_sha256:
        raise ConfigError(where, "an analysis of another plan (its plan.json sha256 "
                                 f"{str(said)[:12]}... differs from this plan's "
                                 f"{plan_sha256[:12]}...)")
    programs = set(plan.program_names)
    traces = []
    for r in data["recordings"]:
        if r["program"] not in programs:
            raise ConfigError(where, f"recording {str(r['file'])[:60]!r} is of "
                                     f"{str(r['program'])[:40]!r}, not a program of this plan")
        aligned = Path(path).parent / "aligned" / aligned_name(r["program"], str(r["file"]))
        if not aligned.is_file():
            raise ConfigError(where, f"expected {aligned} beside it (analyse writes each "
                                     f"recording on its program's time there)")
        try:
            t = read_trace(aligned)
        except SditError as exc:
            raise ConfigError(str(aligned), str(exc)) from None
        traces.append((r["program"], np.asarray(t.t_s, float), np.asarray(t.delta_l_um, float)))
    return data, traces


def _check(data, where: str) -> None:
    def need(obj, keys, what):
        if not isinstance(obj, dict):
            raise ConfigError(where, f"expected {what} as an object; not an analysis.json of "
                                     f"sdit-path analyse")
        for k in keys:
            if k not in obj:
                raise ConfigError(where, f"{what} lacks {k!r}; not an analysis.json of "
                                         f"sdit-path analyse")

    need(data, ("recordings", "geometry", "across_recordings"), "the file")
    if not isinstance(data["recordings"], list) or not data["recordings"]:
        raise ConfigError(where, "expected at least one recording")
    for k, r in enumerate(data["recordings"]):
        need(r, _RECORDING, f"recordings[{k}]")
        need(r["diagnosis"], _DIAGNOSIS, f"recordings[{k}].diagnosis")
    need(data["geometry"], _GEOMETRY, "geometry")
