"""``plan.json``: what was planned and written, for people and for later stages."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import PurePath

from .. import __version__
from ..nc.words import count_blocks
from .files import sealed
from .pipeline import PlanResult

FORMAT = "sdit-path/plan"
FRAMES = {"table": "ball centre in the table frame (work offset)",
          "traori": "ball centre in the table frame, 5-axis transformation (TRAORI) on, "
                    "rotary axes programmed",
          "tcpm": "ball centre in the table frame (work offset), tool centre point control "
                  "on, rotary axes programmed as machine angles",
          "machine": "machine axis values (zero work offset)"}
FORMAT_VERSION = 1


def _mm(v) -> list[float]:
    return [round(float(x), 6) + 0.0 for x in v]


def _deg(rad: float) -> float:
    return round(math.degrees(rad), 9) + 0.0


def manifest(result: PlanResult, files: dict[str, str | bytes] | None = None) -> dict:
    """The manifest of ``result``; ``files`` (relative path -> content) are the other
    files of the plan directory, each fingerprinted (sha256) under ``files``, so that a
    later stage can refuse a plan whose files were edited or swapped."""
    cfg, hemi = result.config, result.hemisphere
    controllers = cfg.post.controllers
    dev: dict[str, dict[str, float]] = {}
    for prog in result.programs:
        for piece, d in prog.built.piece_deviation_mm.items():
            slot = dev.setdefault(piece, {})
            slot[prog.controller] = max(slot.get(prog.controller, 0.0), d)
    lengths, kinds = {}, {}
    for path in result.paths:
        for run in path.runs:
            for p in run.pieces:
                lengths[p.id] = p.length_mm
                kinds[p.id] = p.kind
    checks = {c.piece_id: c for la in result.layers for c in la.checks}
    timed = {la.path.layer: la.timed for la in result.layers if la.timed is not None}
    omitted = {pid for la in result.layers for pid in la.path.omitted}

    def check_entry(pid: str) -> dict:
        c = checks.get(pid)
        if c is None:
            return {}
        out = {"feasible": c.feasible, "violations": [v.describe() for v in c.violations],
               "warnings": [v.describe() for v in c.warnings]}
        if c.min_clearance_mm is not None:
            out["min_clearance_mm"] = round(c.min_clearance_mm, 4) + 0.0
            out["clearance_pair"] = list(c.clearance_pair)
            out["clearance_at_ball_mm"] = list(c.clearance_point_mm)
        return out

    def deviation_um(piece: str) -> dict[str, float]:
        return {c: round(dev[piece][c] * 1e3, 6) for c in controllers if c in dev.get(piece, {})}

    segments = []
    for layer in hemi.layers:
        for s in layer.segments:
            segments.append({
                "id": s.id, "layer": s.layer, "sector": s.sector, "subsegment": s.subsegment,
                "azimuth_deg": [_deg(s.azimuth_start_rad), _deg(s.azimuth_end_rad)],
                "elevation_deg": [_deg(s.lower_elevation_rad), _deg(s.upper_elevation_rad)],
                "status": "omitted" if s.id in omitted else "planned",
                "length_mm": round(lengths[s.id], 6) if s.id in lengths else None,
                "feed_mm_per_min": cfg.test.feed_mm_per_min,
                "max_radial_deviation_um": deviation_um(s.id),
                "check": check_entry(s.id),
            })
    transit_ids = sorted({k for k, v in kinds.items() if v == "transit"} |
                         {c.piece_id for c in checks.values() if c.kind == "transit"})
    transits = [{"id": pid, "status": "omitted" if pid in omitted else "planned",
                 "length_mm": round(lengths[pid], 6) if pid in lengths else None,
                 "feed_mm_per_min": cfg.test.feed_mm_per_min,
                 "max_radial_deviation_um": deviation_um(pid), "check": check_entry(pid)}
                for pid in transit_ids]
    programs = []
    for prog in result.programs:
        path = next(p for p in result.paths if p.layer == prog.layer)
        text = prog.text
        dwelled = [d.node_id for d in path.dwells]
        programs.append({
            "file": prog.file, "controller": prog.controller, "layer": prog.layer,
            "name": prog.built.program.name,
            "frame": {"coordinates": FRAMES[prog.built.program.frame],
                      "name": prog.built.program.frame,
                      "work_offset": cfg.post.work_offset, "units": "mm, deg"},
            "start_node": path.start_node,
            "segment_order": list(path.segment_order()),
            "dwell_nodes": dwelled,
            "remounts": sum(1 for i in path.items if type(i).__name__ == "Remount"),
            "blocks": count_blocks(text),
            "path_length_mm": round(sum(r.length_mm for r in path.runs), 6),
            "max_radial_deviation_um": round(prog.built.max_deviation_mm * 1e3, 6),
            "cycle_time_s": round(timed[prog.layer].duration_s, 4) if prog.layer in timed else None,
            "motion_time_s": round(timed[prog.layer].motion_s, 4) if prog.layer in timed else None,
            "trajectory": (f"trajectories/{prog.built.program.name}.csv.gz"
                           if cfg.timing.export_trajectories and prog.layer in timed else None),
            "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(),
        })
    limits = {c: round(max(p.built.program.tolerance_mm for p in result.programs
                           if p.controller == c) * 1e3, 6) for c in controllers
              if any(p.controller == c for p in result.programs)}
    summary = {c: {"max_radial_deviation_um": round(max(
        (p.built.max_deviation_mm for p in result.programs if p.controller == c)) * 1e3, 6)}
        for c in controllers}
    for c in controllers:
        if c in limits:
            summary[c]["tolerance_um"] = limits[c]
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "generator": f"sdit-path {__version__}",
        "config": {"file": PurePath(cfg.source).name,
                   "sha256": hashlib.sha256(cfg.text.encode("utf-8")).hexdigest()},
        "machine": cfg.machine.name,
        "frame": {"coordinates": "table frame (the pivot and the sphere are given in it)",
                  "work_offset": cfg.post.work_offset, "units": "mm",
                  "azimuth": "degrees from +X, counter-clockwise seen from +Z"},
        "sphere": {"centre_mm": _mm(hemi.centre_mm), "radius_mm": hemi.radius_mm},
        "test": {"feed_mm_per_min": cfg.test.feed_mm_per_min, "dwell_s": cfg.test.dwell_s,
                 "passes": list(cfg.test.passes), "transit": cfg.test.transit,
                 "projection": cfg.test.projection,
                 "curve": {"amplitude": cfg.test.curve.amplitude,
                           "waves_per_sector": cfg.test.curve.waves_per_sector,
                           "cap_elevation_deg": cfg.test.curve.cap_elevation_deg,
                           **({"overrides": [
                               {k: v for k, v in (("sector", o.sector), ("amplitude", o.amplitude),
                                                  ("waves_per_sector", o.waves_per_sector),
                                                  ("projection", o.projection)) if v is not None}
                               for o in cfg.test.curve.overrides]}
                              if cfg.test.curve.overrides else {})}},
        "tracks": [{"name": t.name, "elevation_deg": _deg(t.elevation_rad)} for t in hemi.tracks],
        "nodes": [{"id": n.id, "track": n.track, "azimuth_deg": _deg(n.azimuth_rad),
                   "elevation_deg": _deg(n.elevation_rad), "position_mm": _mm(n.position_mm),
                   "dwell_s": cfg.test.dwell_s} for n in hemi.nodes],
        "layers": [{"name": la.name, "lower_track": la.lower_track, "upper_track": la.upper_track,
                    "elevation_deg": [_deg(la.lower_elevation_rad), _deg(la.upper_elevation_rad)],
                    "is_cap": la.is_cap, "segments": [s.id for s in la.segments],
                    "omitted": list(lp.path.omitted), "programmed": bool(lp.path.items),
                    **({"operator_sequence": _operator(lp)} if lp.operator is not None else {})}
                   for la, lp in zip(hemi.layers, result.layers)],
        "segments": segments,
        "transits": transits,
        "programs": programs,
        "master_programs": [{"file": m.file, "controller": m.controller,
                             "name": m.built.program.name,
                             "layers": [lp.path.layer for lp in result.layers
                                        if lp.path.items and not lp.path.remeasure],
                             "blocks": count_blocks(m.text),
                             "sha256": hashlib.sha256(m.text.encode("utf-8")).hexdigest()}
                            for m in result.masters],
        **({"no_master_program": {c: why for c, why in result.no_master}}
           if result.no_master else {}),
        "summary": summary,
        "tested_travel": _tested_travel(result),
        "files": {rel: _sha256(content) for rel, content in sorted((files or {}).items())
                  if rel != "plan.json"},
    }


def _operator(lp) -> dict:
    """The way to the bar and back: every leg, where it goes (the ball centre, table
    frame) and its smallest clearance with the bar not mounted; the first two leave from
    wherever the machine stands and are not checked."""
    seq = lp.operator
    legs = []
    for check in lp.leg_checks:
        leg = check.leg
        phase = "approach" if any(leg is x for x in seq.approach) else "retract"
        entry = {"phase": phase, "move": leg.name, "to_mm": _mm(leg.end_mm),
                 "checked": leg.checked}
        if leg.checked:
            entry["from_mm"] = _mm(leg.points_mm[0])
            if check.min_clearance_mm is not None:
                entry["min_clearance_mm"] = round(check.min_clearance_mm, 4) + 0.0
                entry["clearance_pair"] = list(check.clearance_pair)
            entry["violations"] = list(check.violations)
        legs.append(entry)
    return {"safe_z_mm": round(seq.safe_z_mm, 6) + 0.0,
            "rotary_deg": {n: _deg(v) for n, v in seq.angles_rad},
            "stops": ["after the approach: mount the bar, start the recording",
                      "after the last dwell: stop the recording, take the bar off"],
            "legs": legs}


def _sha256(content: str | bytes) -> str:
    data = content if isinstance(content, bytes) else content.encode("utf-8")
    return hashlib.sha256(data).hexdigest()


def _tested_travel(result: PlanResult) -> dict[str, list[float]]:
    """Range of every linear axis over all checked poses (mm): the interval the
    error model's Legendre bases are scaled to."""
    import numpy as np

    from ..machine.kinematics import Kinematics

    kin = Kinematics(result.config.machine)
    qs = [rp.q for la in result.layers for rp in la.poses]
    if not qs:
        return {}
    q = np.vstack(qs)
    return {kin.names[i]: [round(float(q[:, i].min()), 6), round(float(q[:, i].max()), 6)]
            for i in kin.linear}


def manifest_text(result: PlanResult, files: dict[str, str | bytes] | None = None) -> str:
    return json.dumps(sealed(manifest(result, files)), indent=2, ensure_ascii=False) + "\n"


def plan_directory_files(result: PlanResult, on_step=None) -> dict[str, str | bytes]:
    """Every file of a plan directory (relative path -> content): the programs, the
    trajectories (gzip-compressed CSV: ``pandas.read_csv`` and ``numpy.loadtxt`` read
    them as they are), the config the later stages rebuild the machine from, and plan.json
    with the fingerprints of all the others."""
    from .pipeline import trajectory_files

    import gzip

    files: dict[str, str | bytes] = {p.file: p.text for p in (*result.programs, *result.masters)}
    for rel, text in trajectory_files(result, on_step=on_step).items():
        # gzip level 1: a quarter of the CSV's size in a third of a second per layer;
        # mtime 0 and no file name keep the bytes reproducible
        files[rel + ".gz"] = gzip.compress(text.encode("utf-8"), compresslevel=1, mtime=0)
    files["config.toml"] = result.config.text
    files["plan.json"] = manifest_text(result, files)
    return files
