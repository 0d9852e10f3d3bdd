"""``sdit-path replan``: the plan reviewed, the bad segments' sectors (or those named)
re-planned, and the plan reviewed again with the chosen curves; the result frozen, with
``to_json()``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from ..config import Config
from ..errors import ConfigError
from ..interference.scene import Scene
from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..plan.pipeline import PlanResult, plan
from .candidates import (OVERRIDE_KEYS, Candidate, choose, current_overrides, sector_of,
                         with_overrides)
from .evaluate import BIAS_NOISE_UM, Limits, Reason, Review, review
from .setup import setup_changes




@dataclass(frozen=True)
class Replan:
    """A re-plan: the plan's review ``before`` and ``after`` (with the chosen curves),
    the re-planned ``config`` (the chosen overrides), per sector the ``chosen`` curve and
    every one ``tried`` (best first), the segments the user ``asked`` for (empty: the
    bad ones were found) and, per layer, the ``setup`` changes tried."""

    before: Review
    after: Review
    config: Config  # with the chosen overrides
    chosen: dict[str, Candidate]  # sector -> the chosen curve
    tried: dict[str, list[Candidate]]  # sector -> every candidate, best first
    asked: list[str]  # segments named by the user (empty: found)
    setup: dict[str, list[dict]] = field(default_factory=dict)  # layer -> set-up changes tried

    @property
    def changed(self) -> bool:
        """Does any sector get a new curve?  (If not, the re-planned plan would be the
        old one: nothing is written.)"""
        return any(c.curve is not None for c in self.chosen.values())

    def to_json(self) -> dict:
        """The re-plan as ``replan.json`` and the plan's manifest hold it (JSON has no
        infinities: a value that is not finite is null)."""
        return _finite(_report_json(self))


def analysis_reasons(plan: PlanFiles, analysis: dict, source: str,
                     factor: float = 2.0) -> dict[str, list[Reason]]:
    """Segments where an analysis of recordings of this plan left a residual no effect
    of the library explains: RMS over the segment above ``factor`` x the recording's
    noise."""
    recs = analysis.get("recordings") if isinstance(analysis, dict) else None
    if not isinstance(recs, list) or not recs:
        raise ConfigError(source, "expected the analysis.json written by sdit-path analyse "
                                  "(no 'recordings')")
    mine = [r for r in recs if isinstance(r, dict) and r.get("program") in plan.program_names]
    if not mine:
        raise ConfigError(source, f"none of its recordings is of a program of this plan "
                                  f"({', '.join(plan.program_names)}): an analysis of another plan?")
    out: dict[str, list[Reason]] = {}
    for r in mine:
        d = r.get("diagnosis") or {}
        u = d.get("unexplained") or {}
        noise = float(d.get("noise_um") or 0.0)
        if not u.get("significant") or noise <= 0:
            continue
        for sid, rms in ((u.get("where") or {}).get("segment_rms_um") or {}).items():
            if isinstance(rms, (int, float)) and rms > factor * noise and "-" in sid \
                    and sid.split("-")[0][1:].isdigit():
                out.setdefault(sid, []).append(Reason(
                    "residual", float(rms), factor * noise, "um RMS",
                    f"{r['program']}: {rms:.2f} um RMS left unexplained ({rms / noise:.1f} x the "
                    f"recording's noise)"))
    return out


def analysis_file_reasons(plan: PlanFiles, path: str) -> dict[str, list[Reason]]:
    """:func:`analysis_reasons` of the ``analysis.json`` at ``path`` (one line naming it
    where it is not one)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(path, f"expected the analysis.json written by "
                                f"sdit-path analyse ({type(exc).__name__})") from None
    return analysis_reasons(plan, data, path)


def replanned_plan(old: PlanFiles, result: "Replan", on_step=None) -> PlanResult:
    """The re-planned plan: ``result``'s config planned as ``plan`` does; segments the
    old plan left out as infeasible (``--skip-infeasible``) stay out when no curve made
    them feasible."""
    skip = any(s.get("status") == "omitted" for s in old.manifest.get("segments", []))
    return plan(result.config, on_step=on_step, skip_infeasible=skip)


def replan(plan: PlanFiles, segments: list[str] | None = None, limits: Limits = Limits(),
           on_step=None, measured: dict[str, list[Reason]] | None = None,
           on_stage=None, jobs: int = 1) -> Replan:
    """The plan reviewed, the bad segments' sectors (or those of ``segments``)
    re-planned, and the plan reviewed again with the chosen curves.  ``measured``: the
    reasons an analysis of recordings gives (:func:`analysis_reasons`).  A sector whose
    every reason is ``fixed`` (no curve of its patch can change it) is not searched: its
    layer gets the set-up changes that would clear it, each planned.  ``on_step``: what
    is going on; ``on_stage``: each sector's search as it starts; ``jobs``: worker
    processes for the candidates (the result is the same for any number)."""
    cfg = plan.config
    known = [s.get("id") for s in plan.manifest.get("segments", []) if isinstance(s, dict)]
    for sid in segments or []:
        if sid not in known:
            raise ConfigError("--segment", f"{sid[:40]!r} is not a segment of this plan "
                                           f"(segments such as {known[0] if known else 'D3-2'})")
    travel = plan.tested_travel()
    kin = Kinematics(cfg.machine)
    scene = Scene(cfg, kin)
    before = review(cfg, travel, limits, on_step, kin, scene)
    for sid, rs in (measured or {}).items():
        if sid in before.values:
            before.reasons.setdefault(sid, []).extend(rs)
    bad = list(dict.fromkeys(segments)) if segments else sorted(before.reasons)
    sectors: dict[str, list[Reason]] = {}
    for sid in bad:
        sectors.setdefault(sector_of(sid), []).extend(before.reasons.get(sid, []))
    tried, chosen = {}, {}
    # named segments are searched whatever their reasons (the user asked)
    fixed = {sector for sector, rs in sectors.items()
             if not segments and rs and all(r.fixed for r in rs)}
    order = sorted(set(sectors) - fixed, key=lambda x: (x[0], int(x[1:])))
    for k, sector in enumerate(order, start=1):
        if on_stage:
            on_stage(f"re-planning sector {sector} ({k} of {len(order)})")
        ranked = choose(cfg, before, sector, sectors[sector], travel, limits, kin, scene, on_step,
                        jobs)
        tried[sector] = ranked
        chosen[sector] = ranked[0]
    # a sector whose infeasible segments no curve in the patch makes feasible: the
    # set-up changes that would, per layer
    setup: dict[str, list[dict]] = {}
    stuck: dict[str, list[str]] = {}
    for sector, ranked in tried.items():
        if "infeasible" in {r.kind for r in sectors[sector]} and (
                not ranked[0].evaluation.feasible or "infeasible" in ranked[0].remaining):
            stuck.setdefault(sector[0], []).extend(
                sid for sid in before.values if sector_of(sid) == sector
                and not before.values[sid].get("feasible", True))
    for layer, segs in stuck.items():
        setup[layer] = setup_changes(cfg, layer, segs, travel, on_step)
    # reasons no curve can change (a clearance at a node): the set-up changes that clear
    # them, per layer
    held: dict[str, list[str]] = {}
    for sid, rs in before.reasons.items():
        if sector_of(sid) in sectors and any(r.fixed for r in rs):
            held.setdefault(sid[0], []).append(sid)
    for layer, segs in sorted(held.items()):
        if layer not in setup:
            if on_stage:
                on_stage(f"set-up changes for layer {layer}")
            setup[layer] = setup_changes(cfg, layer, sorted(segs), travel, on_step,
                                         clearance=limits.clearance_factor
                                         * cfg.check.safety_clearance_mm)
    changes = {s: c.curve for s, c in chosen.items() if c.curve is not None}
    # the sectors whose curves changed get a re-measure program of their layer, unless
    # a piece of theirs is still infeasible (it would be left out of the layer program)
    remeasure = tuple(sorted((s for s in changes if "infeasible" not in chosen[s].remaining),
                             key=lambda x: (x[0], int(x[1:]))))
    new_cfg = with_overrides(cfg, {**current_overrides(cfg), **changes}, remeasure) if changes else cfg
    if on_step:
        on_step("reviewing the re-planned plan")
    keep = {name: ev for name, ev in before.layers.items()
            if name not in {s[0] for s in changes}}
    after = review(new_cfg, travel, limits, None, kin, Scene(new_cfg, kin), keep, before.directions)
    return Replan(before, after, new_cfg, chosen, tried, list(segments or []), setup)


def _finite(x):
    """JSON has no infinities: a value that is not finite is null."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x


def _report_json(r: Replan) -> dict:
    def seg(rev: Review, sid: str) -> dict:
        v = {k: x for k, x in rev.values.get(sid, {}).items() if k != "violations"}
        return {"values": v, "reasons": [x.as_json() for x in rev.reasons.get(sid, [])]}

    k = r.before.directions.shape[1]
    gain = r.after.information_nats - r.before.information_nats
    sectors = []
    for sector, ranked in r.tried.items():
        ids = sorted(sid for sid in r.before.values if sector_of(sid) == sector)
        sectors.append({
            "sector": sector,
            "chosen": ranked[0].label,
            "segments": {sid: {"before": seg(r.before, sid), "after": seg(r.after, sid)}
                         for sid in ids},
            "candidates": [{"curve": c.label, "feasible": c.evaluation.feasible,
                            "infeasible_pieces": c.evaluation.infeasible,
                            "cleared": c.cleared, "remaining": c.remaining,
                            "information_nats": c.information_nats if c.evaluation.feasible else None,
                            "lag_bias_std": c.lag_bias if c.evaluation.feasible else None,
                            "layer_cycle_s": c.evaluation.cycle_s if c.evaluation.feasible else None}
                           for c in ranked]})
    return {
        "objective": ("feasible; then the most of the sector's reasons cleared; then the "
                      "largest log-determinant of the information of the combinations the "
                      "test determines (nats; within 0.05 a tie); then the smaller bias of a "
                      "1 ms axis lag on them; then the shorter layer; the sector as planned "
                      "stays when nothing clears more or brings more than a tie"),
        "determined_combinations": k,
        "information_nats": {"before": r.before.information_nats, "after": r.after.information_nats,
                             "gain": gain,
                             "geometric_mean_std_factor": (math.exp(-gain / (2 * k))
                                                           if k and math.isfinite(gain) else None)},
        "lag_bias_std": {"noise_um": BIAS_NOISE_UM, "lag_ms": 1.0,
                         "before": r.before.lag_bias, "after": r.after.lag_bias,
                         "meaning": "per axis, the largest bias a 1 ms lag of that axis alone "
                                    "puts on a determined combination, in its standard "
                                    "uncertainties at this noise"},
        "cycle_s": {"before": sum(ev.cycle_s for ev in r.before.layers.values() if ev.feasible),
                    "after": sum(ev.cycle_s for ev in r.after.layers.values() if ev.feasible)},
        "segments_named": r.asked,
        "bad_segments_before": {sid: [x.as_json() for x in rs] for sid, rs in r.before.reasons.items()},
        "bad_segments_after": {sid: [x.as_json() for x in rs] for sid, rs in r.after.reasons.items()},
        "sectors": sectors,
        "setup_changes": r.setup,
        "overrides": [{k2: getattr(o, k2) for k2 in ("sector",) + OVERRIDE_KEYS
                       if getattr(o, k2) is not None}
                      for o in r.config.test.curve.overrides],
    }
