"""Curves tried for a bad segment's sector, and the objective that chooses among them.

Candidates for a bad segment's sector (same nodes, inside the same patch, on the
sphere, tangent-continuous with the neighbours: see
:class:`..config.SectorCurve`) are planned like any layer (reach, interference,
timing) and chosen by a documented objective, in this order: feasible; clearing the
most of the sector's reasons; then the largest information of the whole test's
determined combinations (log-determinant of their information matrix, nats: +0.1 makes
their geometric-mean standard uncertainty exp(-0.1 / 2k) times smaller, k the
combinations), gains within 0.05 nats counting as a tie; then the smaller bias a 1 ms lag
of one axis puts on them (in their standard uncertainties at 0.2 um of noise); then the
shorter layer.  The sector as planned is a candidate too: it
stays when nothing does better.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field

import numpy as np

from ..config import TILT_OFFSET_MAX_DEG, Config, SectorCurve
from ..interference.scene import Scene
from ..machine.kinematics import Kinematics
from ..parallel import each
from ..plan.configure import parse_config
from .evaluate import (LayerEval, Limits, Reason, Review, evaluate_layer, judge, lag_bias, logdet,
                       servo_median, with_information)




@dataclass
class Candidate:
    sector: str
    curve: SectorCurve | None  # None: the sector as planned
    evaluation: LayerEval
    information_nats: float = 0.0
    cleared: list[str] = field(default_factory=list)
    remaining: list[str] = field(default_factory=list)
    lag_bias: float = math.inf  # the largest over the axes (see Review)

    @property
    def label(self) -> str:
        if self.curve is None:
            return "as planned"
        c = self.curve
        parts = [f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in
                 (("amplitude", c.amplitude), ("waves", c.waves_per_sector),
                  ("projection", c.projection)) if v is not None]
        if c.feed_mm_per_min is not None:
            parts.append(f"feed {c.feed_mm_per_min:g} mm/min")
        if c.tilt_offset_deg is not None:
            parts.append(f"tilt offset {c.tilt_offset_deg:g} deg")
        if c.crest_at is not None:
            parts.append(f"crest at {c.crest_at:g} of the sector")
        return ", ".join(parts)


#: information gains below this (nats) are a tie: 0.05 nats changes the geometric-mean
#: standard uncertainty of k determined combinations by exp(-0.025 / k), 0.8 % for k = 3
INFORMATION_TIE = 0.05


#: the curves tried for a sector: amplitude x waves x projection
AMPLITUDES = (1.0, 0.7, 0.4)


WAVES = (1, 2)


#: the keys of ``[[test.curve.override]]`` besides the sector, as ``SectorCurve`` names them
OVERRIDE_KEYS = ("amplitude", "waves_per_sector", "projection", "feed_mm_per_min",
                 "tilt_offset_deg", "crest_at")


def sector_of(segment_id: str) -> str:
    return segment_id.split("-", 1)[0]


def with_overrides(cfg: Config, overrides: dict[str, SectorCurve],
                   remeasure: tuple[str, ...] | None = None) -> Config:
    """``cfg`` with these sectors' overrides in place of any it had for them, and with
    ``remeasure`` (when given) as its re-measure sectors: its text gets the tables (a
    config written out reproduces the plan, the re-measure programs included)."""
    text = _drop_overrides(cfg.text, set(overrides))
    if remeasure is not None:
        text = _drop_table(text, "test.remeasure")
        if remeasure:
            text = (text.rstrip("\n") + "\n\n[test.remeasure]  # written by sdit-path replan\n"
                    + "sectors = [" + ", ".join(f'"{x}"' for x in remeasure) + "]\n")
    for sector in sorted(overrides, key=lambda s: (s[0], int(s[1:]))):
        o = overrides[sector]
        lines = ['\n[[test.curve.override]]  # re-planned by sdit-path replan', f'sector = "{sector}"']
        for key in OVERRIDE_KEYS:
            v = getattr(o, key)
            if v is not None:
                lines.append(f'{key} = "{v}"' if isinstance(v, str) else f"{key} = {v!r}")
        text = text.rstrip("\n") + "\n" + "\n".join(lines) + "\n"
    return parse_config(text, cfg.source)


def _tables(text: str) -> list[str]:
    """The config text cut before every table header (the first part: before any)."""
    return re.split(r"(?m)^(?=\s*\[)", text)


def _drop_overrides(text: str, sectors: set[str]) -> str:
    """The config text without the ``[[test.curve.override]]`` tables of ``sectors``."""
    def sector(part: str):
        try:
            return tomllib.loads(part.split("\n", 1)[1] if "\n" in part else "").get("sector")
        except tomllib.TOMLDecodeError:
            return None

    header = re.compile(r"\s*\[\[\s*test\.curve\.override\s*\]\]")
    return "".join(p for p in _tables(text) if not (header.match(p) and sector(p) in sectors))


def _drop_table(text: str, name: str) -> str:
    """The config text without the table ``[name]`` (header to the next header)."""
    header = re.compile(r"\s*\[\s*" + re.escape(name) + r"\s*\]")
    return "".join(p for p in _tables(text) if not header.match(p))


#: reasons a lower feed answers (the curve as it is, slower): lag errors grow with the
#: speed, accelerations with its square, a rotary rate with it
DYNAMIC = ("servo_sensitivity", "acceleration", "rotary_rate")


#: the sector's feed is tried at these fractions where a reason is dynamic
FEED_FRACTIONS = (0.7, 0.5)


#: reasons another pose may answer: a crest moved within the sector (other directions of
#: the bar, other places of the ball) or, on moving rotary axes, a tilt of the table over
#: the patch (the same ball path: other clearances, other axis positions, other
#: information on the rotary axes)
POSE = ("infeasible", "clearance", "travel_margin", "information", "residual")


#: where the wave crests (fraction of the sector) in the candidates for a pose reason
CRESTS = (0.35, 0.5, 0.65)


#: the tilt offsets (deg, added to the sector's own) tried where a reason is about poses
TILT_OFFSETS_DEG = (-10.0, 10.0)


def candidates_for(cfg: Config, sector: str, kinds: set[str] = frozenset()) -> list[SectorCurve]:
    """The curves tried for ``sector`` (each keeps the sector's own feed, tilt offset and
    crest, if it has them); where one of ``kinds`` is dynamic, also the curve as it is
    at lower feeds; where one is about the poses (clearance, travel, interference,
    information, a residual), also the curve with its crest moved, and, where the rotary
    axes move, the curve as it is with the table tilted away from its schedule over the
    patch."""
    now = cfg.test.curve.for_sector(sector[0], int(sector[1:]), cfg.test.projection)
    own = cfg.test.curve.override(sector) or SectorCurve(sector)
    feed, tilt, crest = own.feed_mm_per_min, own.tilt_offset_deg, own.crest_at
    out = []
    for proj in dict.fromkeys((cfg.test.projection, "stereographic", "vertical")):
        for amp in AMPLITUDES:
            for waves in WAVES:
                if (amp, waves, proj) == now:
                    continue
                out.append(SectorCurve(sector, amp, waves, proj, feed, tilt, crest))
    if kinds & set(DYNAMIC):
        base = cfg.test.curve.feed_for(f"{sector}-1", cfg.test.feed_mm_per_min)
        for k in FEED_FRACTIONS:
            f = float(max(1.0, round(base * k)))
            if f < base:
                out.append(SectorCurve(sector, *now, f, tilt, crest))
    if kinds & set(POSE):
        for c in CRESTS:
            if c != (crest or 0.5):
                out.append(SectorCurve(sector, *now, feed, tilt, None if c == 0.5 else c))
        if cfg.test.rotary.schedule == "moving":
            for d in TILT_OFFSETS_DEG:
                t = (tilt or 0.0) + d
                if abs(t) <= TILT_OFFSET_MAX_DEG:
                    out.append(SectorCurve(sector, *now, feed, t if t else None, crest))
    return out


def choose(cfg: Config, rev: Review, sector: str, reasons: list[Reason], travel: dict,
           limits: Limits, kin: Kinematics, scene: Scene, on_step=None,
           jobs: int = 1) -> list[Candidate]:
    """Every candidate of ``sector`` evaluated (in ``jobs`` worker processes) and
    ranked (best first; the sector as planned among them)."""
    layer = sector[0]
    base = rev.layers[layer]
    S_rest = sum((ev.schur for name, ev in rev.layers.items() if name != layer and ev.feasible),
                 np.zeros_like(base.schur) if base.feasible else 0.0)
    kinds = {r.kind for r in reasons}
    seg_ids = [sid for sid in base.values if sector_of(sid) == sector]
    curves = candidates_for(cfg, sector, kinds)
    evaluated = each(lambda k: evaluate_layer(with_overrides(cfg, {**current_overrides(cfg), sector: curves[k]}),
                                              layer, travel, kin, scene),
                     [Candidate(sector, c, base).label for c in curves], jobs,
                     on_step or (lambda msg: None), f"trying {sector}: {{label}}")
    out = []
    for curve, ev in zip([None] + curves, [base] + evaluated):
        cand = Candidate(sector, curve, ev)
        if ev.feasible:
            cand.information_nats = logdet(rev.directions, S_rest + ev.schur)
            cand.lag_bias = max(lag_bias({**rev.layers, layer: ev}, rev.directions,
                                         kin.names).values(), default=math.inf)
            whole = with_information({**rev.layers, layer: ev}, rev.directions)
            vals = {sid: whole[sid] for sid in seg_ids if sid in whole}
            # judged against the plan's yardstick of servo sensitivity
            still = judge(cfg, vals, limits, servo_median(rev.values))
            left = {r.kind for rs in still.values() for r in rs}
            cand.cleared = sorted(kinds - left)
            cand.remaining = sorted(left)
        out.append(cand)
    out.sort(key=lambda c: (not c.evaluation.feasible, -len(c.cleared), len(c.remaining),
                            -c.information_nats, c.evaluation.cycle_s, c.curve is not None))
    # among the leaders (as feasible, clearing as much), information within
    # INFORMATION_TIE of the best is a tie: the shorter layer wins, the sector as
    # planned on equal time
    lead = [c for c in out if (c.evaluation.feasible, c.cleared, c.remaining)
            == (out[0].evaluation.feasible, out[0].cleared, out[0].remaining)]
    if out[0].evaluation.feasible:
        near = [c for c in lead if c.information_nats >= out[0].information_nats - INFORMATION_TIE]
        # with nothing cleared, the sector stays as planned unless a curve brings more
        # than a tie of information (a second saved is not worth a new curve)
        planned = next((c for c in near if c.curve is None), None)
        best = planned if planned is not None and not planned.cleared else \
            min(near, key=lambda c: (round(c.lag_bias, 1), round(c.evaluation.cycle_s, 1),
                                     c.curve is not None))
        out.remove(best)
        out.insert(0, best)
    return out


def current_overrides(cfg: Config) -> dict[str, SectorCurve]:
    return {o.sector: o for o in cfg.test.curve.overrides}
