"""Re-planning bad segments (the paper's D3): find them, say why, replace their sector's
curves, and write the re-planned plan.

A single 20 deg segment determines nothing about the machine on its own; a segment is
bad for what it adds to, or spoils in, the whole test.  Each reason is a value with a
number and the limit it broke:

- ``clearance``: the smallest distance between parts over the segment (mm), below
  ``clearance_factor`` x the config's safety clearance;
- ``travel_margin``: the smallest distance of any axis to its travel limit (mm or deg);
- ``speed_dip``: the lowest speed while cruising over the programmed feed: the curvature
  caps the speed (a curve the axes cannot follow at the feed);
- ``acceleration``: the largest axis acceleration over its limit: hard accelerations
  are where servo errors grow;
- ``servo_sensitivity``: what a 1 ms lag of one axis changes in the bar reading (RMS
  over the segment, um), over the plan's median: the segment reads dynamics as much as
  geometry;
- ``rotary_rate``: a rotary axis that would turn faster than its limit at the feed;
- ``information``: the segment's share of the information of the combinations the
  whole test determines, per share of the test's time: a segment that costs time and
  adds little.

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

from .config import TILT_OFFSET_MAX_DEG, Config, SectorCurve
from .plan.configure import parse_config
from .errormodel.model import ModelOptions, build_model
from .errors import ConfigError
from .geometry.hemisphere import partition
from .geometry.paths import PathBuilder
from .identify.identify import STRUCTURAL, experiment_gram
from .interference.scene import Scene
from .machine.kinematics import Kinematics
from .parallel import each
from .plan.pipeline import check_layer
from .plan.files import PlanFiles
from .timing.trajectory import axis_values_rad
from .timing.trajectory import Samples, Timer, sample


@dataclass(frozen=True, slots=True)
class Limits:
    """Where a segment's value makes it bad (see the module text)."""

    clearance_factor: float = 3.0
    travel_margin_mm: float = 5.0
    travel_margin_deg: float = 5.0
    speed_ratio: float = 0.9
    acceleration_ratio: float = 0.5
    servo_over_median: float = 1.5
    information_per_time: float = 0.25


@dataclass(frozen=True, slots=True)
class Reason:
    """``fixed``: no curve of the sector's patch can change it (it sits where every
    curve of the sector passes: a node); a set-up change may."""

    kind: str
    value: float
    limit: float
    unit: str
    text: str
    fixed: bool = False

    def as_json(self) -> dict:
        return {"kind": self.kind, "value": self.value, "limit": self.limit, "unit": self.unit,
                "text": self.text, "curve_can_change": not self.fixed}


@dataclass
class LayerEval:
    """One layer as planned with one set of curves: its per-segment values and its
    information block (the Schur complement of its design)."""

    layer: str
    feasible: bool
    infeasible: list[str]
    cycle_s: float
    values: dict[str, dict]  # segment -> name -> value
    segment_info: dict[str, np.ndarray]  # segment -> J^T J (scaled parameters)
    schur: np.ndarray
    samples: Samples | None = None
    #: (parameters, axes): what a 1 ms lag of each axis adds to the normal equations'
    #: right-hand side (set-up eliminated): its bias of the geometry is S^-1 of it
    lag_source: np.ndarray | None = None


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


#: the model the information is measured with: the one ``analyse`` identifies by
#: default (linear errors to first order, squareness, rotary locations)
REVIEW_MODEL = ModelOptions("legendre", 1, 0, True, True)


def evaluate_layer(cfg: Config, layer_name: str, travel: dict, kin: Kinematics,
                   scene: Scene) -> LayerEval:
    """Plan, check and time one layer of ``cfg``; its per-segment values and design.  As
    ``plan --skip-infeasible`` does, infeasible pieces are left out (``infeasible``)
    and the layer planned without them; ``feasible`` says whether that worked."""
    hemi = partition(cfg)
    layer = next(la for la in hemi.layers if la.name == layer_name)
    builder = PathBuilder(cfg, hemi)
    path = builder.layer_path(layer)
    _, checks = check_layer(path, cfg, kin, scene)
    bad = [c.piece_id for c in checks if not c.feasible]
    values: dict[str, dict] = {}
    nodes = [(n.id, np.asarray(n.position_mm)) for n in hemi.nodes]
    for c in checks:
        if c.kind != "segment":
            continue
        at = None
        if c.clearance_point_mm is not None:
            p = np.asarray(c.clearance_point_mm)
            # where every curve of the sector passes: the smallest clearance is the node's
            at = next((nid for nid, xyz in nodes if np.linalg.norm(p - xyz) < NODE_TOL_MM), None)
        values[c.piece_id] = {
            "clearance_mm": c.min_clearance_mm,
            "clearance_pair": None if c.clearance_pair is None else list(c.clearance_pair),
            "clearance_at_node": at,
            "rotary_rate_warnings": len(c.warnings),
            "feasible": c.feasible,
            "violations": [v.describe() for v in c.violations]}
    if bad:
        path = builder.layer_path(layer, frozenset(bad))
        _, rechecked = check_layer(path, cfg, kin, scene)
        if any(not c.feasible for c in rechecked):
            path = None
    if path is None or not path.items:
        return LayerEval(layer_name, False, bad, math.inf, values, {}, np.zeros((0, 0)))
    timer = Timer(cfg, kin)
    timed = timer.time_layer(path)
    s = sample(timed, timer, cfg.timing.sample_rate_hz)
    feeds = {p.id: run.feed_mm_per_min for run in path.runs for p in run.pieces}
    lag = _motion_values(cfg, kin, s, values, feeds)
    info, S, X = _design(cfg, s, travel, layer_name, lag)
    return LayerEval(layer_name, True, bad, float(timed.duration_s), values, info, S, s, X)


def _motion_values(cfg: Config, kin: Kinematics, s: Samples, values: dict,
                   feeds_mm_per_min: dict[str, float]) -> np.ndarray:
    """Travel margin, speed dip, acceleration and servo sensitivity per segment
    (``feeds_mm_per_min``: each segment's programmed feed, its run's); returns the
    reading change of a 1 ms lag of each axis at every sample ``(n, axes)``, um."""
    q = axis_values_rad(s, kin)
    dt = float(s.t_s[1] - s.t_s[0]) if len(s.t_s) > 1 else 1e-3
    qd = np.gradient(q, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    pivot = np.array(cfg.ballbar.pivot_mm)
    ball = kin.forward(q)
    u = (ball - pivot) / np.linalg.norm(ball - pivot, axis=1)[:, None]
    # the reading change of a 1 ms lag of axis i: u . (d ball / d q_i) qdot_i 1 ms
    lag = np.zeros((len(q), q.shape[1]))
    for i in range(q.shape[1]):
        h = 1e-6
        dq = np.zeros(q.shape[1])
        dq[i] = h
        dball = (kin.forward(q + dq) - kin.forward(q - dq)) / (2 * h)
        # lagging by 1 ms the axis is q_dot 1 ms behind: the bar reads u . d ball of it
        lag[:, i] = -np.einsum("nj,nj->n", u, dball) * qd[:, i] * 1e-3 * 1e3  # um
    sens = np.abs(lag)
    feed = cfg.test.feed_mm_per_min / 60.0
    acc_lim = np.array([ax.max_acceleration for ax in kin.axes])  # mm/s^2, rad/s^2
    margins = []
    for j, ax in enumerate(kin.axes):
        lo, hi = ax.travel
        if ax.is_rotary and (hi - lo) >= 2 * math.pi - 1e-9:
            margins.append(None)  # endless
        else:
            margins.append((lo, hi, ax.is_rotary))
    labels = s.segment
    # on the curve (not dwelling, not repositioning around a piece left out)
    moving = np.isin(s.phase, ("accelerate", "cruise", "decelerate"))
    # a speed dip is read away from the stops: beyond the time the slowest axis needs to
    # reach the feed and to settle its acceleration
    a_min = min(ax.max_acceleration for ax in kin.axes if not ax.is_rotary)
    j_min = min(ax.max_jerk for ax in kin.axes if not ax.is_rotary)
    ramp_s = 2.0 * (feed / a_min + a_min / j_min)
    stopped = ~moving | (s.speed_mm_per_s < 1e-3 * feed)
    stopped[[0, -1]] = True  # the program starts and ends at rest
    t_stop = s.t_s[stopped]
    if len(t_stop):
        k = np.clip(np.searchsorted(t_stop, s.t_s), 1, len(t_stop))
        near = np.minimum(np.abs(s.t_s - t_stop[k - 1]),
                          np.abs(t_stop[np.minimum(k, len(t_stop) - 1)] - s.t_s))
    else:
        near = np.full(len(s.t_s), np.inf)
    cruise = (near > ramp_s) & moving
    for sid, v in values.items():
        m = (labels == sid) & moving
        if not m.any():
            continue
        c = m & cruise
        own = feeds_mm_per_min[sid] / 60.0  # its run's, its sector's
        v["min_speed_ratio"] = float(s.speed_mm_per_s[c].min() / own) if c.any() else 1.0
        v["acceleration_ratio"] = float(np.max(np.abs(qdd[m]) / acc_lim))
        v["servo_um_per_ms"] = float(np.sqrt(np.mean(np.max(sens[m], axis=1) ** 2)))
        v["duration_s"] = float(m.sum() * dt)
        lin, rot = [], []
        for j, mg in enumerate(margins):
            if mg is None:
                continue
            lo, hi, is_rot = mg
            d = float(np.min(np.minimum(q[m, j] - lo, hi - q[m, j])))
            (rot if is_rot else lin).append(math.degrees(d) if is_rot else d)
        v["travel_margin_mm"] = min(lin) if lin else None
        v["travel_margin_deg"] = min(rot) if rot else None
    return lag


def _design(cfg: Config, s: Samples, travel: dict, layer: str, lag: np.ndarray
            ) -> tuple[dict, np.ndarray, np.ndarray]:
    """Per-segment information, the layer's Schur complement (set-up eliminated) and
    what a 1 ms lag of each axis adds to the right-hand side, from the timed samples
    (no recording: the design alone)."""
    model = build_model(cfg.machine, travel, REVIEW_MODEL)
    g = experiment_gram(PlanFiles.in_memory(cfg, layer, s), layer, None, model, extra=lag,
                        segment_nuisances=True)
    k = 4  # the set-up: centring and bar length (the lag columns follow)
    B, C = g.B[:, :k], g.C[:k, :k]
    Ci = np.linalg.pinv(C)
    S = 0.5 * ((g.A - B @ Ci @ B.T) + (g.A - B @ Ci @ B.T).T)
    X = g.B[:, k:] - B @ Ci @ g.C[:k, k:]
    # each segment's information once the layer's set-up is eliminated: its rows of the
    # regressors less what the set-up, fitted over the whole layer, takes from them
    M = Ci @ B.T
    info = {}
    for sid, (a, _) in g.segments.items():
        b, c = g.segment_nuisances[sid]
        b, c = b[:, :k], c[:k, :k]
        info[sid] = a - b @ M - M.T @ b.T + M.T @ c @ M
    return info, S, X


#: the noise the servo bias is measured against (um, 1 sigma; a ballbar's typical)
BIAS_NOISE_UM = 0.2


@dataclass
class Review:
    """The whole plan judged: per segment its values and reasons; the test's determined
    directions and information; ``lag_bias``: per axis, the largest bias a 1 ms lag of
    that axis alone puts on a determined combination, in its standard uncertainties at
    ``BIAS_NOISE_UM`` of noise (the geometry read from dynamics)."""

    values: dict[str, dict]
    reasons: dict[str, list[Reason]]
    layers: dict[str, LayerEval]
    directions: np.ndarray  # determined directions (scaled parameters), columns
    information_nats: float
    lag_bias: dict[str, float] = field(default_factory=dict)


def lag_bias(layers: dict[str, LayerEval], Vd: np.ndarray, axis_names) -> dict[str, float]:
    """See :class:`Review`: the bias S^-1 X of a 1 ms lag over the whole test, along the
    determined directions, over their standard uncertainties."""
    ok = [ev for ev in layers.values() if ev.feasible and ev.lag_source is not None]
    if not ok or Vd.shape[1] == 0:
        return {}
    S = sum(ev.schur for ev in ok)
    X = sum(ev.lag_source for ev in ok)
    Mi = np.linalg.pinv(Vd.T @ S @ Vd, hermitian=True)
    bias = Mi @ (Vd.T @ X)  # (directions, axes)
    std = BIAS_NOISE_UM * np.sqrt(np.maximum(np.diag(Mi), 1e-300))
    return {name: float(np.max(np.abs(bias[:, i]) / std)) for i, name in enumerate(axis_names)}


def _logdet(V: np.ndarray, S: np.ndarray) -> float:
    M = V.T @ S @ V
    sign, val = np.linalg.slogdet(0.5 * (M + M.T))
    return float(val) if sign > 0 else -math.inf


def review(cfg: Config, travel: dict, limits: Limits = Limits(), on_step=None,
           kin: Kinematics | None = None, scene: Scene | None = None,
           layers: dict[str, LayerEval] | None = None,
           directions: np.ndarray | None = None) -> Review:
    """Every layer of ``cfg`` evaluated (those in ``layers`` taken as they are) and every
    segment judged.  ``directions``: the determined directions to measure information
    along (default: this plan's own)."""
    kin = kin or Kinematics(cfg.machine)
    scene = scene or Scene(cfg, kin)
    hemi = partition(cfg)
    done = dict(layers or {})
    for la in hemi.layers:
        if la.name not in done:
            if on_step:
                on_step(f"reviewing layer {la.name}")
            done[la.name] = evaluate_layer(cfg, la.name, travel, kin, scene)
    feasible = [ev.schur for ev in done.values() if ev.feasible]
    if not feasible:
        raise ConfigError(cfg.source, "no layer of this plan is feasible: nothing to re-plan")
    S = sum(feasible)
    if directions is None:
        lam, V = np.linalg.eigh(S)
        directions = V[:, lam > max(float(lam.max()), 1e-300) * STRUCTURAL]
    Vd = directions
    values = _with_information(done, Vd)
    return Review(values, judge(cfg, values, limits), done, Vd, _logdet(Vd, S),
                  lag_bias(done, Vd, kin.names))


def _with_information(layers: dict[str, LayerEval], Vd: np.ndarray) -> dict[str, dict]:
    """Every segment's values with its share of the test's information along ``Vd``
    (its set-up-eliminated block over the whole test's) and that share per share of
    the test's time."""
    S = sum(ev.schur for ev in layers.values() if ev.feasible)
    M_inv = np.linalg.pinv(Vd.T @ S @ Vd, hermitian=True)
    total_s = sum(v.get("duration_s", 0.0) for ev in layers.values() for v in ev.values.values())
    values: dict[str, dict] = {}
    for ev in layers.values():
        for sid, v in ev.values.items():
            v = dict(v)
            a = ev.segment_info.get(sid)
            if a is not None and total_s > 0 and v.get("duration_s"):
                share = float(np.trace(M_inv @ (Vd.T @ a @ Vd))) / max(Vd.shape[1], 1)
                v["information_share"] = share
                v["information_per_time"] = share / (v["duration_s"] / total_s)
            values[sid] = v
    return values


def servo_median(values: dict[str, dict]) -> float:
    servo = [v["servo_um_per_ms"] for v in values.values() if v.get("servo_um_per_ms")]
    return float(np.median(servo)) if servo else 0.0


def judge(cfg: Config, values: dict[str, dict], limits: Limits,
          median: float | None = None) -> dict[str, list[Reason]]:
    """Every reason that makes each segment bad (segments with none are left out);
    ``median``: the servo sensitivity's yardstick (default: the median of ``values``)."""
    median = servo_median(values) if median is None else median
    out: dict[str, list[Reason]] = {}
    for sid, v in values.items():
        r = []
        if not v.get("feasible", True):
            r.append(Reason("infeasible", 1.0, 0.0, "",
                            "infeasible: " + "; ".join(v.get("violations", []))[:200]))
        lim = limits.clearance_factor * cfg.check.safety_clearance_mm
        c = v.get("clearance_mm")
        if c is not None and c < lim:
            pair = "/".join(v.get("clearance_pair") or [])
            node = v.get("clearance_at_node")
            if node:
                r.append(Reason("clearance", c, lim, "mm",
                                f"clearance {c:.2f} mm < {lim:.2f} mm ({pair}) at node {node}, "
                                f"where every curve of the sector passes", fixed=True))
            else:
                r.append(Reason("clearance", c, lim, "mm",
                                f"clearance {c:.2f} mm < {lim:.2f} mm" + (f" ({pair})" if pair else "")))
        for key, lim, unit in (("travel_margin_mm", limits.travel_margin_mm, "mm"),
                               ("travel_margin_deg", limits.travel_margin_deg, "deg")):
            m = v.get(key)
            if m is not None and m < lim:
                r.append(Reason("travel_margin", m, lim, unit,
                                f"travel margin {m:.2f} {unit} < {lim:g} {unit}"))
        sp = v.get("min_speed_ratio")
        if sp is not None and sp < limits.speed_ratio:
            r.append(Reason("speed_dip", sp, limits.speed_ratio, "of the feed",
                            f"the curvature caps the speed at {sp:.0%} of the feed"))
        ac = v.get("acceleration_ratio")
        if ac is not None and ac > limits.acceleration_ratio:
            r.append(Reason("acceleration", ac, limits.acceleration_ratio, "of the axis limit",
                            f"an axis accelerates at {ac:.0%} of its limit"))
        sv = v.get("servo_um_per_ms")
        if sv is not None and median > 0 and sv > limits.servo_over_median * median:
            r.append(Reason("servo_sensitivity", sv, limits.servo_over_median * median, "um per ms",
                            f"a 1 ms axis lag moves the reading {sv:.2f} um RMS "
                            f"({sv / median:.1f} x the plan's median)"))
        if v.get("rotary_rate_warnings"):
            n = v["rotary_rate_warnings"]
            r.append(Reason("rotary_rate", float(n), 0.0, "warnings",
                            f"a rotary axis would turn faster than its limit ({n} warning(s))"))
        ip = v.get("information_per_time")
        if ip is not None and ip < limits.information_per_time:
            r.append(Reason("information", ip, limits.information_per_time, "of its time share",
                            f"adds {ip:.2f} of its share of the test's time to the determined "
                            f"combinations' information"))
        if r:
            out[sid] = r
    return out


#: a segment's smallest clearance closer than this to a node (mm) is the node's
NODE_TOL_MM = 1e-3

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
    evaluated = each(lambda k: evaluate_layer(with_overrides(cfg, {**_current(cfg), sector: curves[k]}),
                                              layer, travel, kin, scene),
                     [Candidate(sector, c, base).label for c in curves], jobs,
                     on_step or (lambda msg: None), f"trying {sector}: {{label}}")
    out = []
    for curve, ev in zip([None] + curves, [base] + evaluated):
        cand = Candidate(sector, curve, ev)
        if ev.feasible:
            cand.information_nats = _logdet(rev.directions, S_rest + ev.schur)
            cand.lag_bias = max(lag_bias({**rev.layers, layer: ev}, rev.directions,
                                         kin.names).values(), default=math.inf)
            whole = _with_information({**rev.layers, layer: ev}, rev.directions)
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


def _current(cfg: Config) -> dict[str, SectorCurve]:
    return {o.sector: o for o in cfg.test.curve.overrides}


@dataclass
class Replan:
    before: Review
    after: Review
    config: Config  # with the chosen overrides
    chosen: dict[str, Candidate]  # sector -> the chosen curve
    tried: dict[str, list[Candidate]]  # sector -> every candidate, best first
    asked: list[str]  # segments named by the user (empty: found)
    setup: dict[str, list[dict]] = field(default_factory=dict)  # layer -> set-up changes tried


#: set-up changes tried for a layer whose infeasible segments no curve in their patch
#: makes feasible (each planned: the layer's lower track raised, the pivot raised, a
#: longer tool)
TRACK_RAISE_DEG = (2.0, 5.0, 10.0)
#: with moving rotary axes, changes of the schedule's tilt at the equator (deg)
EQUATOR_TILT_DEG = (-10.0, 10.0)
PIVOT_RAISE_MM = (20.0, 50.0)
TOOL_LONGER_MM = (20.0, 50.0)


def _edit(text: str, section: str, key: str, value: str) -> str | None:
    """``text`` with ``key = value`` in ``[section]`` (None if the key is not there)."""
    m = re.search(r"(?m)^\[" + re.escape(section) + r"\]\s*$", text)
    if m is None:
        return None
    nxt = re.search(r"(?m)^\s*\[", text[m.end():])
    end = m.end() + (nxt.start() if nxt else len(text) - m.end())
    block, n = re.subn(r"(?m)^" + re.escape(key) + r"\s*=.*$", f"{key} = {value}",
                       text[m.end():end], count=1)
    return text[:m.end()] + block + text[end:] if n else None


def setup_changes(cfg: Config, layer: str, segments: list[str], travel: dict,
                  on_step=None, clearance: float | None = None) -> list[dict]:
    """Which set-up change makes ``segments`` of ``layer`` feasible (with ``clearance``,
    mm: also clear by that much), each found by planning the layer with it: its lower
    track raised, the pivot raised, a longer tool, and with moving rotary axes the tilt
    at the equator changed."""
    t = cfg.test
    names = "ABCDEFGHIJKLMNOPQRSTUVWXY"
    i = names.index(layer)
    elev = list(t.track_elevations_deg)
    trials = []
    for d in TRACK_RAISE_DEG:
        e = elev[:i] + [elev[i] + d] + elev[i + 1:]
        if all(b > a for a, b in zip(e, e[1:])) and e[-1] < 90:
            trials.append((f"track {layer} at {e[i]:g} deg instead of {elev[i]:g}",
                           "test", "track_elevations_deg", "[" + ", ".join(f"{x:g}" for x in e) + "]"))
    px, py, pz = cfg.ballbar.pivot_mm
    for d in PIVOT_RAISE_MM:
        trials.append((f"pivot {d:g} mm higher (Z {pz + d:g})", "ballbar", "pivot_mm",
                       f"[{px!r}, {py!r}, {pz + d!r}]"))
    for d in TOOL_LONGER_MM:
        trials.append((f"tool {d:g} mm longer ({cfg.machine.tool_length_mm + d:g} mm)", "machine",
                       "tool_length_mm", repr(cfg.machine.tool_length_mm + d)))
    if t.rotary.schedule == "moving":
        now = math.degrees(t.rotary.tilt_at_equator_rad)
        for d in EQUATOR_TILT_DEG:
            trials.append((f"tilt at the equator {now + d:g} deg instead of {now:g}", "test.rotary",
                           "tilt_at_equator_deg", f"{now + d:g}"))
    out = []
    for label, section, key, value in trials:
        text = _edit(cfg.text, section, key, value)
        if text is None:
            out.append({"change": label, "planned": False, "why": f"{section}.{key} is not in the config"})
            continue
        if on_step:
            on_step(f"trying a set-up change for layer {layer}: {label}")
        try:
            c2 = parse_config(text, cfg.source)
            kin = Kinematics(c2.machine)
            ev = evaluate_layer(c2, layer, travel, kin, Scene(c2, kin))
        except (ConfigError, ValueError) as exc:
            out.append({"change": label, "planned": False, "why": str(exc)[:200]})
            continue
        still = [sid for sid in segments if not ev.values.get(sid, {}).get("feasible", False)]
        clear = [ev.values[sid]["clearance_mm"] for sid in segments
                 if ev.values.get(sid, {}).get("clearance_mm") is not None]
        low = min(clear) if clear else None
        out.append({"change": label, "planned": True, "config": f"[{section}] {key} = {value}",
                    "feasible": not still and (clearance is None
                                               or (low is not None and low >= clearance)),
                    "still_infeasible": still, "layer_feasible": ev.feasible,
                    "min_clearance_mm": low,
                    **({"clearance_needed_mm": clearance} if clearance is not None else {})})
    return out


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
    new_cfg = with_overrides(cfg, {**_current(cfg), **changes}, remeasure) if changes else cfg
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


def report_json(r: Replan) -> dict:
    return _finite(_report_json(r))


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


def report_text(r: Replan) -> str:
    j = report_json(r)
    fmt = lambda v, f: "?" if v is None else format(v, f)  # noqa: E731
    lines = []
    nb = len(r.before.reasons)
    if r.asked:
        lines.append(f"Segments named: {', '.join(r.asked)}.")
    lines.append(f"Bad segments as planned: {nb}" + ("." if nb else " (none: nothing to re-plan)."))
    for sid, rs in r.before.reasons.items():
        lines.append(f"  {sid}: " + "; ".join(x.text for x in rs))
    for s in j["sectors"]:
        lines.append("")
        lines.append(f"SECTOR {s['sector']}: chosen {s['chosen']}")
        lines.append(f"  {'segment':8} {'reasons before':44} reasons after")
        for sid, ba in s["segments"].items():
            b = ", ".join(x["kind"] for x in ba["before"]["reasons"]) or "-"
            a = ", ".join(x["kind"] for x in ba["after"]["reasons"]) or "-"
            lines.append(f"  {sid:8} {b:44} {a}")
        lines.append("  candidates (best first): " + "; ".join(
            f"{c['curve']}: " + ("cannot be planned" if not c["feasible"] else
                                 f"cleared {'+'.join(c['cleared']) or 'nothing'}, "
                                 f"information {fmt(c['information_nats'], '.3f')} nats, lag "
                                 f"bias {fmt(c['lag_bias_std'], '.1f')} std, layer "
                                 f"{fmt(c['layer_cycle_s'], '.1f')} s")
            for c in s["candidates"][:6]) + (" ..." if len(s["candidates"]) > 6 else ""))
    for layer, tried in r.setup.items():
        lines.append("")
        works = [x for x in tried if x.get("feasible")]
        need = next((x["clearance_needed_mm"] for x in tried if "clearance_needed_mm" in x), None)
        what = ("makes its infeasible segments feasible" if need is None else
                f"changes the clearance at its nodes (needed: {need:.2f} mm)")
        lines.append(f"LAYER {layer}: no curve in the patch {what}; "
                     + ("these set-up changes would (each planned): " + "; ".join(
                         f"{x['change']} ({x['config']}, clearance {x['min_clearance_mm']:.2f} mm)"
                         if x.get("min_clearance_mm") is not None else
                         f"{x['change']} ({x['config']})" for x in works)
                        if works else "none of the set-up changes tried would: " + "; ".join(
                            f"{x['change']}: " + (_short_of(x) if x.get("planned")
                                                  else x.get("why", "")) for x in tried)))
    info = j["information_nats"]
    lines.append("")
    lines.append(f"WHOLE TEST: information of the {j['determined_combinations']} determined "
                 f"combinations {fmt(info['before'], '.3f')} -> {fmt(info['after'], '.3f')} nats "
                 f"(their geometric-mean standard uncertainty x "
                 f"{fmt(info['geometric_mean_std_factor'], '.3f')}); a 1 ms lag of one axis "
                 f"biases them by at most "
                 + ", ".join(f"{a} {fmt(j['lag_bias_std']['before'].get(a), '.1f')} -> "
                             f"{fmt(j['lag_bias_std']['after'].get(a), '.1f')}"
                             for a in j["lag_bias_std"]["before"])
                 + f" std (at {BIAS_NOISE_UM} um noise); cycle "
                 f"{j['cycle_s']['before']:.1f} -> {j['cycle_s']['after']:.1f} s; bad segments "
                 f"{len(j['bad_segments_before'])} -> {len(j['bad_segments_after'])}.")
    return "\n".join(lines) + "\n"


def _short_of(x: dict) -> str:
    """What a planned set-up change left short of."""
    if x.get("still_infeasible"):
        return ", ".join(x["still_infeasible"][:4]) + " still infeasible"
    low = x.get("min_clearance_mm")
    return "clearance " + ("unknown" if low is None else f"{low:.2f} mm")


def pictures(r: Replan) -> dict[str, bytes]:
    """Per re-planned layer, ``<layer>_replan.png``: the layer seen from above the pivot
    (azimuth around, elevation outwards from the pole), the curves as planned in grey and
    as re-planned in blue, each bad segment in red with its reasons."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    layers = sorted({s[0] for s in r.tried})
    for name in layers:
        b, a = r.before.layers[name], r.after.layers[name]
        fig, ax = plt.subplots(figsize=(7.5, 7.5))
        for ev, style in ((b, dict(color="0.6", lw=1.0, label="as planned")),
                          (a, dict(color="tab:blue", lw=1.2, label="re-planned"))):
            if ev.samples is None:
                continue
            x, y = _polar_view(r.config, ev.samples)
            moving = ev.samples.phase != "dwell"
            ax.plot(np.where(moving, x, np.nan), np.where(moving, y, np.nan), **style)
        if b.samples is not None:
            x, y = _polar_view(r.config, b.samples)
            for sid, rs in r.before.reasons.items():
                if sector_of(sid)[0] != name:
                    continue
                m = b.samples.segment == sid
                if not m.any():
                    continue
                ax.plot(np.where(m, x, np.nan), np.where(m, y, np.nan), color="tab:red", lw=2.0)
                k = np.flatnonzero(m)[len(np.flatnonzero(m)) // 2]
                ax.annotate(f"{sid}: " + ", ".join(x.kind for x in rs), (x[k], y[k]), fontsize=7,
                            color="tab:red", xytext=(4, 4), textcoords="offset points")
        # what was chosen per sector: a feed alone leaves the curve where it was
        chosen = [f"{sec}: {c.label}" for sec, c in sorted(r.chosen.items()) if sec[0] == name]
        if chosen:
            ax.text(0.01, 0.01, "chosen - " + "; ".join(chosen), transform=ax.transAxes,
                    fontsize=7, color="tab:blue", va="bottom")
        ax.set_aspect("equal")
        ax.set_title(f"layer {name}: curves as planned (grey) and re-planned (blue); bad "
                     f"segments in red", fontsize=9)
        ax.set_xlabel("90 deg - elevation, along the azimuth (deg)")
        ax.legend(loc="upper right", fontsize=8)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
        plt.close(fig)
        out[f"{name}_replan.png"] = buf.getvalue()
    return out


def _polar_view(cfg: Config, s: Samples) -> tuple[np.ndarray, np.ndarray]:
    """Ball positions seen from above the pivot: the distance from the pole in degrees
    of elevation, along the azimuth."""
    p = s.ball_mm - np.array(cfg.ballbar.pivot_mm)
    r = np.linalg.norm(p, axis=1)
    colat = 90.0 - np.degrees(np.arcsin(np.clip(p[:, 2] / r, -1, 1)))
    az = np.arctan2(p[:, 1], p[:, 0])
    return colat * np.cos(az), colat * np.sin(az)
