"""Reviewing a plan: every layer planned, checked and timed again exactly as ``plan``
does, each segment's values, and the reasons it is bad.

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
  whole test determines, per share of the test's time, against the median of its
  layer's test segments: a segment that adds far less for its time than its neighbours
  on the same band of the sphere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..config import Config
from ..errormodel.model import ModelOptions, build_model
from ..errors import ConfigError
from ..geometry.hemisphere import TEST_SEGMENT, partition
from ..geometry.paths import PathBuilder
from ..identify.identify import STRUCTURAL, experiment_gram
from ..interference.scene import Scene
from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..plan.pipeline import check_layer
from ..timing.trajectory import Samples, Timer, axis_values_rad, sample




@dataclass(frozen=True, slots=True)
class Limits:
    """Where a segment's value makes it bad (see the module text)."""

    clearance_factor: float = 3.0
    travel_margin_mm: float = 5.0
    travel_margin_deg: float = 5.0
    speed_ratio: float = 0.9
    acceleration_ratio: float = 0.5
    servo_over_median: float = 1.5
    #: a test segment's information per time share below this share of its layer's
    #: median: a curve its neighbours on the same band of the sphere do better.  (A
    #: whole layer low in information is the sphere's geometry, the cap seeing little of
    #: the linear axes, not a curve to re-plan.)
    information_of_layer: float = 0.1


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


#: the model the information is measured with: the one ``analyse`` identifies by
#: default (linear errors to first order, squareness, rotary locations)
REVIEW_MODEL = ModelOptions("legendre", 1, 0, True, True)


#: a segment's smallest clearance closer than this to a node (mm) is the node's
NODE_TOL_MM = 1e-3


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


def logdet(V: np.ndarray, S: np.ndarray) -> float:
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
    values = with_information(done, Vd)
    return Review(values, judge(cfg, values, limits), done, Vd, logdet(Vd, S),
                  lag_bias(done, Vd, kin.names))


def with_information(layers: dict[str, LayerEval], Vd: np.ndarray) -> dict[str, dict]:
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
    layer_info: dict[str, list[float]] = {}
    for sid, v in values.items():
        m = TEST_SEGMENT.match(sid)
        if m and v.get("information_per_time") is not None:
            layer_info.setdefault(m.group(1), []).append(v["information_per_time"])
    info_median = {k: float(np.median(x)) for k, x in layer_info.items()}
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
        m = TEST_SEGMENT.match(sid)
        lay = info_median.get(m.group(1)) if m else None
        if ip is not None and lay and ip < limits.information_of_layer * lay:
            lim = limits.information_of_layer * lay
            r.append(Reason("information", ip, lim, "of its time share",
                            f"adds {ip:.3f} of its share of the test's time to the determined "
                            f"combinations' information, {ip / lay:.0%} of its layer's median "
                            f"({lay:.3f}): its neighbours on the same band do better"))
        if r:
            out[sid] = r
    return out
