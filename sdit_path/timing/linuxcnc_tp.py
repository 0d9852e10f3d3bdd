"""What LinuxCNC 2.9 does with our programs' motion, servo period by servo period.

A model of the control's motion planning for the blocks our LinuxCNC post-processor
writes (G1 lines in G93 inverse time or G94 units per minute, G64 P blending, G4
dwells), ported from LinuxCNC 2.9.0~pre1 (commit f1270d6ed7, Debian's
``linuxcnc-uspace``) and checked against it by ``validation/linuxcnc_tp_check.py``:

* canon (``emccanon.cc``): each block's requested velocity, its axis-limited maximum
  velocity and its acceleration (``getStraightVelocity``, ``getStraightAcceleration``:
  every axis' own limit scaled along the move, the XYZ length as the path length of a
  move with XYZ motion); inverse time F is ``1/minutes`` of the block, so the rate is
  its XYZ length times F (``inverse_time_rate_straight``);
* ``tpAddLine``: the tangent check (``tpSetupTangent``, the kink ratio), blend arcs
  between pure XYZ lines (``tpCreateLineLineBlend``, spherical arcs), the choice
  between parabolic, tangent and arc blends (``tpChooseBestBlend``) and the look-ahead
  (``tpRunOptimization``, lazy, ``ARC_BLEND_OPTIMIZATION_DEPTH`` deep);
* ``tpRunCycle``: trapezoidal or ramped acceleration per servo period, parabolic
  blending of the current and the next segment, split cycles at segment ends.

Facts the model rests on (measured on the control): motion advances exactly one servo
period per tick; the task hands the motion one segment per servo period (each command
waits for the motion's acknowledgement), the first in the period the stretch starts,
so at a stretch's start the planner sees the queue fill up while it moves; a dwell
drains the queue, so every stretch between two dwells starts and ends at rest; the
program line HAL shows lags the motion by one period.

Positions are program coordinates in the control's units (mm, deg), work offsets
zero (as the oracle runs them).  A segment with rotary motion never gets a tangent or
arc blend in 2.9 (``tcRotaryMotionCheck``): it blends parabolically at half the
acceleration and is planned to be able to stop at its end.

Not modelled (refused by :func:`stretches`): G0, arcs (G2/G3), G61/G61.1, naive CAM
merging (G64 with Q > 0), G91, G20, G95, cutter and tool length compensation,
spindle and coolant; a program stop (M0, M1) is a standstill whose length the operator
decides; feed override is 100 %.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..program_marks import TEST_BEGINS, TEST_ENDS

#: the order of LinuxCNC's pose: XYZ, ABC, UVW
POSE_AXES = "XYZABCUVW"
_ROTARY = frozenset("ABC")

# tp_types.h, tc_types.h, blendmath.h, spherical_arc.h, posemath.h, tcq.c
_TP_VEL_EPSILON = 1e-8
_TP_POS_EPSILON = 1e-12
_TP_TIME_EPSILON = 1e-12
_TP_ANGLE_EPSILON = 1e-6
_TP_MIN_ARC_ANGLE = 1e-3
_TP_MIN_ARC_LENGTH = 1e-6
_TP_MIN_SEGMENT_CYCLES = 1.02
_TP_OPTIMIZATION_CUTOFF = 4
_BLEND_DIST_FRACTION = 0.5
_BLEND_ACC_RATIO_TANGENTIAL = 0.5
_BLEND_ACC_RATIO_NORMAL = math.sqrt(1.0 - 0.5 * 0.5)
_ARC_MIN_RADIUS = 1e-12
_ARC_MIN_ANGLE = 1e-6
_CART_FUZZ = 1e-8
_TC_QUEUE_SIZE = 2000
_TC_QUEUE_MARGIN = 220
_SHARP_CORNER_EPSILON = (math.pi * (2.0 / 180.0)) ** 2
_MIN_COS_THETA = math.cos(math.pi / 2.0 - _TP_MIN_ARC_ANGLE)

# term conditions (tc_types.h)
_STOP, _EXACT, _PARABOLIC, _TANGENT = 0, 1, 2, 3
# segment kinds
_LINE, _ARC = 0, 1


# ----------------------------------------------------------------------------- limits

@dataclass(frozen=True, slots=True)
class ControlLimits:
    """The control's limits as its INI gives them, in program units.

    ``axes`` are the program's coordinates (``("X", "Y", "Z")``, ``("X", "Y", "B", "C",
    "Z")``); ``max_velocity_per_s`` and ``max_acceleration_per_s2`` are ``(m,)``, per
    axis in that order, mm/s and mm/s^2 for linear axes, deg/s and deg/s^2 for rotary
    ones ([AXIS_*] MAX_VELOCITY, MAX_ACCELERATION).  ``max_linear_velocity_mm_per_s`` is
    [TRAJ] MAX_LINEAR_VELOCITY (the planner's tool-tip velocity limit); the rest are
    [TRAJ] ARC_BLEND_* and [DISPLAY] MAX_FEED_OVERRIDE with LinuxCNC's defaults.
    ``segment_interval_cycles`` is how many servo periods apart the task hands the
    motion two segments (1: one acknowledged command per period)."""

    axes: tuple[str, ...]
    max_velocity_per_s: tuple[float, ...]
    max_acceleration_per_s2: tuple[float, ...]
    max_linear_velocity_mm_per_s: float = math.inf
    servo_period_s: float = 0.001
    arc_blend_enable: bool = True
    optimization_depth: int = 50
    gap_cycles: int = 4
    ramp_frequency_hz: float = 100.0
    kink_ratio: float = 0.1
    max_feed_scale: float = 1.0
    segment_interval_cycles: int = 1

    def __post_init__(self):
        axes = tuple(a.upper() for a in self.axes)
        object.__setattr__(self, "axes", axes)
        bad = [a for a in axes if len(a) != 1 or a not in POSE_AXES]
        if bad or len(set(axes)) != len(axes):
            raise ValueError(f"axes must be distinct letters of {POSE_AXES}, got {self.axes}")
        for name in ("max_velocity_per_s", "max_acceleration_per_s2"):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != len(axes) or any(not v > 0 for v in values):
                raise ValueError(f"{name} needs one positive value per axis of {axes}, "
                                 f"got {values}")
            object.__setattr__(self, name, values)
        if self.servo_period_s <= 0 or self.segment_interval_cycles < 1:
            raise ValueError("servo_period_s must be positive and segment_interval_cycles >= 1")

    @classmethod
    def from_machine(cls, machine, axes: tuple[str, ...], **traj) -> ControlLimits:
        """The limits of ``machine`` (a :class:`~sdit_path.config.model.MachineConfig`)
        for the coordinates ``axes`` as the oracle's INI writes them: every value in mm
        or deg with six significant digits (``%g``), MAX_LINEAR_VELOCITY the fastest
        linear axis of the machine."""
        def ini(v: float) -> float:
            return float(f"{v:g}")

        vel = tuple(ini(machine.axis(a).to_display(machine.axis(a).max_velocity)) for a in axes)
        acc = tuple(ini(machine.axis(a).to_display(machine.axis(a).max_acceleration))
                    for a in axes)
        lin = [machine.axis(a).max_velocity for a in axes if not machine.axis(a).is_rotary]
        traj.setdefault("max_linear_velocity_mm_per_s", ini(max(lin)) if lin else math.inf)
        return cls(tuple(axes), vel, acc, **traj)

    def pose_limits(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Velocity and acceleration limits in LinuxCNC's pose order (XYZABCUVW), 0 for
        an axis the machine does not have."""
        vel, acc = [0.0] * 9, [0.0] * 9
        for a, v, x in zip(self.axes, self.max_velocity_per_s, self.max_acceleration_per_s2):
            vel[POSE_AXES.index(a)], acc[POSE_AXES.index(a)] = v, x
        return tuple(vel), tuple(acc)


# ---------------------------------------------------------------------------- parsing

@dataclass(frozen=True, slots=True)
class Stretch:
    """The motion between two standstills of a program (dwells, the program's end).

    ``start : (m,) float`` is the pose it starts from and ``end : (k, m) float`` every
    G1 block's end pose (program units, in the order of ``axes``); per block
    ``line : (k,) int`` its program line (1 = the file's first line),
    ``inverse_time : (k,) bool`` G93 (F in 1/min) or G94 (F in units/min),
    ``f_word : (k,) float`` the F in effect and ``tolerance_mm : (k,) float`` the G64 P
    in effect.  ``dwell_after_s`` is the dwell that ends it (0 at the program's end)."""

    axes: tuple[str, ...]
    start: np.ndarray
    end: np.ndarray
    line: np.ndarray
    inverse_time: np.ndarray
    f_word: np.ndarray
    tolerance_mm: np.ndarray
    dwell_after_s: float

    def __post_init__(self):
        for name in ("start", "end", "line", "inverse_time", "f_word", "tolerance_mm"):
            arr = np.array(getattr(self, name))
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def first_line(self) -> int:
        return int(self.line[0])

    @property
    def last_line(self) -> int:
        return int(self.line[-1])


_COMMENT = re.compile(r"\([^)]*\)")
_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_ACCEPTED_G = {17.0, 21.0, 40.0, 49.0, 54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 80.0, 90.0}


def _refuse(number: int, raw: str, why: str) -> ValueError:
    return ValueError(f"line {number}: {why} (not modelled): {raw.strip()!r}")


def stretches(text: str, axes: tuple[str, ...], start=None) -> list[Stretch]:
    """Our program ``text`` cut into the stretches of motion between dwells.

    ``axes`` are the program's coordinates, in the order positions are given back.
    The first stretch starts from ``start`` (``(m,)``), by default the pose of the
    program's first G1 block (the oracle moves there by MDI before it runs the
    program; an axis that block leaves out is at 0).  A stretch without a move (the
    program's first G1 to where the machine already is) is left out, and so is the
    operator's way to the bar and back, before and after the comments
    :data:`~sdit_path.program_marks.TEST_BEGINS` and ``TEST_ENDS``.  Raises
    ``ValueError`` naming the line for anything the model does not cover: G0, G2/G3,
    G61/G61.1, G64 with Q > 0, G91, G20, G95, G41/G42, G43, M codes but M0, M1 (a
    standstill, like a dwell of 0 s), M2, M30 and M5,
    S and T words, axis words of other axes, F missing in G93, a zero feed."""
    axes = tuple(a.upper() for a in axes)
    index = {a: i for i, a in enumerate(axes)}
    lines = text.splitlines()
    parsed: list[tuple[int, str, dict[str, list[float]]]] = []
    for number, raw in enumerate(lines, start=1):
        body = _COMMENT.sub(" ", raw).split(";", 1)[0].strip().upper()
        if not body or body == "%":
            continue
        if "(" in body or ")" in body:
            raise _refuse(number, raw, "an unclosed comment")
        if body.startswith("/"):
            raise _refuse(number, raw, "block delete")
        words: dict[str, list[float]] = {}
        rest = _WORD.sub(lambda m: words.setdefault(m.group(1), []).append(float(m.group(2)))
                         or "", body)
        if rest.strip():
            raise _refuse(number, raw, f"text that is no word ({rest.strip()!r})")
        parsed.append((number, raw, words))

    pose = np.zeros(len(axes))
    if start is not None:
        pose = np.asarray(start, dtype=float).copy()
        if pose.shape != (len(axes),):
            raise ValueError(f"start must have one value per axis of {axes}")
    else:
        for _, _, words in parsed:
            if 1.0 in words.get("G", []) and any(a in words for a in POSE_AXES):
                for a, (v,) in ((a, words[a]) for a in axes if a in words):
                    pose[index[a]] = v
                break

    out: list[Stretch] = []
    # the operator's way to the bar and back, framed by our comments: not the test's
    marks = {TEST_BEGINS: 0, TEST_ENDS: 0}
    for number, raw in enumerate(lines, start=1):
        low = raw.lower()
        for mark in marks:
            if not marks[mark] and mark in low:
                marks[mark] = number
    begins, ends = marks[TEST_BEGINS], marks[TEST_ENDS] or len(lines) + 1
    block: dict[str, list] = {k: [] for k in ("end", "line", "inv", "f", "tol")}
    stretch_start = pose.copy()
    motion, inverse, feed, tolerance = None, False, 0.0, 0.0
    testing = begins == 0

    def close(dwell_s: float) -> None:
        nonlocal stretch_start, block
        if block["end"] and testing:
            end = np.array(block["end"])
            steps = np.abs(np.diff(np.vstack([stretch_start, end]), axis=0))
            if np.any(steps >= _CART_FUZZ):
                out.append(Stretch(axes, stretch_start, end, np.array(block["line"]),
                                   np.array(block["inv"]), np.array(block["f"]),
                                   np.array(block["tol"]), dwell_s))
        block = {k: [] for k in block}
        stretch_start = pose.copy()

    for number, raw, words in parsed:
        if not testing and number > begins:
            close(0.0)
            testing = True
        if number > ends:
            close(0.0)
            return out
        for letter in words:
            if len(words[letter]) > 1 and letter != "G" and letter != "M":
                raise _refuse(number, raw, f"{letter} given twice")
        gs, ms = words.get("G", []), words.get("M", [])
        dwell = None
        for g in gs:
            if g in _ACCEPTED_G:
                continue
            if g == 1.0:
                motion = 1
            elif g == 93.0:
                inverse = True
            elif g == 94.0:
                inverse, feed = False, 0.0
            elif g == 64.0:
                q = words.get("Q", [0.0])[0]
                if q != 0.0 or ("P" in words and "Q" not in words):
                    raise _refuse(number, raw, "G64 with naive CAM merging (Q > 0)")
                tolerance = words.get("P", [0.0])[0]
            elif g == 4.0:
                if "P" not in words:
                    raise _refuse(number, raw, "G4 without P")
                dwell = words["P"][0]
            elif g == 0.0:
                raise _refuse(number, raw, "G0 rapid")
            elif g in (2.0, 3.0):
                raise _refuse(number, raw, "an arc move")
            else:
                raise _refuse(number, raw, f"G{g:g}")
        for m in ms:
            if m in (2.0, 30.0):
                if any(a in words for a in POSE_AXES):
                    raise _refuse(number, raw, "motion with a program end")
                close(0.0)
                return out
            if m in (0.0, 1.0):  # a program stop: the motion stands still until cycle start
                if any(a in words for a in POSE_AXES):
                    raise _refuse(number, raw, "motion with a program stop")
                close(0.0)
                continue
            if m != 5.0:
                raise _refuse(number, raw, f"M{m:g}")
        for letter in ("S", "T", "R", "D", "H", "I", "J", "K", "L"):
            if letter in words:
                raise _refuse(number, raw, f"a {letter} word")
        if "F" in words:
            feed = words["F"][0]
        moves = [a for a in POSE_AXES if a in words]
        if dwell is not None:
            if moves:
                raise _refuse(number, raw, "a dwell and a move in one block")
            close(dwell)
            continue
        if not moves:
            continue
        if any(a not in index for a in moves):
            raise _refuse(number, raw, f"an axis word of none of the axes {''.join(axes)}")
        if motion != 1:
            raise _refuse(number, raw, "axis words without G1 in effect")
        if inverse and "F" not in words:
            raise ValueError(f"line {number}: G93 needs an F word in every G1 block: "
                             f"{raw.strip()!r}")
        if not feed > 0:
            raise ValueError(f"line {number}: G1 with a zero feed: {raw.strip()!r}")
        for a in moves:
            pose[index[a]] = words[a][0]
        block["end"].append(pose.copy())
        block["line"].append(number)
        block["inv"].append(inverse)
        block["f"].append(feed)
        block["tol"].append(tolerance)
    close(0.0)
    return out


# ------------------------------------------------------------------------------ canon

@dataclass(frozen=True, slots=True)
class CanonMoves:
    """The moves canon hands the motion for a stretch (``flush_segments``): per sent
    block ``end : (k, m)`` its end pose, ``vel : (k,)`` the requested velocity,
    ``ini_maxvel : (k,)`` the axis-limited velocity and ``acc : (k,)`` the
    acceleration, along the XYZ path (mm/s, mm/s^2) or, for a move of rotary axes
    only, along the rotary one (deg/s, deg/s^2); ``line : (k,)`` the program line.
    Blocks that move no axis by 1e-8 or more are not sent."""

    end: np.ndarray
    vel: np.ndarray
    ini_maxvel: np.ndarray
    acc: np.ndarray
    line: np.ndarray

    def __post_init__(self):
        for name in ("end", "vel", "ini_maxvel", "acc", "line"):
            arr = np.array(getattr(self, name))
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


def canon_moves(stretch: Stretch, limits: ControlLimits) -> CanonMoves:
    """What canon makes of ``stretch``'s blocks with the axis limits of ``limits``."""
    if tuple(stretch.axes) != tuple(limits.axes):
        raise ValueError(f"the stretch's axes {stretch.axes} are not the limits' {limits.axes}")
    vmax, amax = limits.pose_limits()
    valid = [a in limits.axes for a in POSE_AXES]
    cols = [POSE_AXES.index(a) for a in stretch.axes]
    here = np.zeros(9)
    here[cols] = stretch.start
    rows: dict[str, list] = {k: [] for k in ("end", "vel", "ini", "acc", "line")}
    for k in range(len(stretch.end)):
        end = here.copy()
        end[cols] = stretch.end[k]
        raw = np.abs(end - here)
        d = [raw[i] if valid[i] and raw[i] >= _CART_FUZZ else 0.0 for i in range(9)]
        cart = any(d[i] > 0.0 for i in (0, 1, 2, 6, 7, 8))
        ang = any(d[i] > 0.0 for i in (3, 4, 5))
        # interp: the feed rate in units/s (inverse time: the block's length times F)
        if stretch.inverse_time[k]:
            if max(raw[0], raw[1], raw[2]) > 1e-7:
                length = math.sqrt(raw[0] ** 2 + raw[1] ** 2 + raw[2] ** 2)
            elif max(raw[6], raw[7], raw[8]) > 1e-7:
                length = math.sqrt(raw[6] ** 2 + raw[7] ** 2 + raw[8] ** 2)
            else:
                length = math.sqrt(raw[3] ** 2 + raw[4] ** 2 + raw[5] ** 2)
            rate = max(0.1, length * float(stretch.f_word[k])) / 60.0
        else:
            rate = float(stretch.f_word[k]) / 60.0
        if cart:
            dtot = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) if (d[0] or d[1] or d[2]) \
                else math.sqrt(d[6] ** 2 + d[7] ** 2 + d[8] ** 2)
            use = range(9) if ang else (0, 1, 2, 6, 7, 8)
        elif ang:
            dtot = math.sqrt(d[3] ** 2 + d[4] ** 2 + d[5] ** 2)
            use = (3, 4, 5)
        else:
            here = end
            continue  # a move to nowhere: acceleration 0, canon sends nothing
        tv = max(d[i] / vmax[i] for i in use if d[i])
        ta = max(d[i] / amax[i] for i in use if d[i])
        axis_vel = dtot / tv if tv > 0 else rate
        acc = dtot / ta if ta > 0 else 0.0
        vel = min(axis_vel, rate)
        if vel and acc:
            rows["end"].append(end[cols])
            rows["vel"].append(vel)
            rows["ini"].append(axis_vel)
            rows["acc"].append(acc)
            rows["line"].append(int(stretch.line[k]))
        here = end
    m = len(stretch.axes)
    return CanonMoves(np.array(rows["end"]).reshape(-1, m), np.array(rows["vel"]),
                      np.array(rows["ini"]), np.array(rows["acc"]),
                      np.array(rows["line"], dtype=int))


# ---------------------------------------------------------------------------- planner

class _Seg:
    """One queued trajectory segment (LinuxCNC's TC_STRUCT, the fields we use)."""

    __slots__ = (
        "index", "line", "kind", "start", "end", "delta", "target", "nominal_length",
        "ux", "uy", "uz", "rotary", "pure_rotary", "reqvel", "maxvel", "maxaccel", "term",
        "tolerance", "kink_vel", "kink_reduce", "kink_reduce_prev", "blend_prev",
        "finalized", "finalvel", "progress", "currentvel", "cycle_time", "active",
        "blending_next", "on_final_decel", "vel_at_blend_start", "blend_vel",
        "is_blending", "splitting", "term_vel", "remove", "ramp", "at_max",
        "acc_ratio_tan", "arc")

    def __init__(self):
        self.kink_vel = -1.0
        self.kink_reduce = self.kink_reduce_prev = 0.0
        self.blend_prev = self.finalized = self.active = self.blending_next = False
        self.on_final_decel = self.is_blending = self.splitting = self.remove = False
        self.ramp = self.at_max = False
        self.finalvel = self.progress = self.currentvel = 0.0
        self.vel_at_blend_start = self.blend_vel = self.term_vel = 0.0
        self.acc_ratio_tan = _BLEND_ACC_RATIO_TANGENTIAL
        self.arc = None
        self.rotary = self.pure_rotary = False


class _Arc:
    """A blend arc's geometry (LinuxCNC's SphericalArc)."""

    __slots__ = ("start", "end", "center", "r_start", "r_end", "radius", "angle", "s_angle",
                 "u_tan", "line_length")


def _unit(v):
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return (v[0] / n, v[1] / n, v[2] / n), n


def _inscribed_diameter(normal, bounds) -> float | None:
    """calculateInscribedDiameter: the limit in the plane with unit ``normal``."""
    if abs(1.0 - (normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)) > math.sqrt(_TP_POS_EPSILON):
        return None
    extents = []
    for i in range(3):
        p = [-normal[i] * normal[j] for j in range(3)]
        p[i] += 1.0
        p = [abs(c) for c in p]
        p[i] = max(p[i], _TP_POS_EPSILON)
        scale = math.sqrt(p[0] ** 2 + p[1] ** 2 + p[2] ** 2)
        extents.append(bounds[i] / scale if bounds[i] != 0 else 0.0)
    diameter = max(extents)
    for i in range(3):
        if bounds[i] != 0:
            diameter = min(diameter, extents[i])
    return diameter


class _Planner:
    """LinuxCNC's trajectory planner (tp.c, tc.c, blendmath.c) for G1 lines."""

    def __init__(self, limits: ControlLimits, start9: list[float]):
        self.lim = limits
        self.dt = limits.servo_period_s
        vel, acc = limits.pose_limits()
        self.vel_bound = vel[:3]
        self.acc_bound = acc[:3]
        self.v_limit = limits.max_linear_velocity_mm_per_s
        self.max_scale = limits.max_feed_scale
        self.kink_ratio = min(max(limits.kink_ratio, 0.001), 0.7071)
        self.queue: list[_Seg] = []
        self.segments: list[_Seg] = []
        self.goal = list(start9)
        self.exec_line = 0
        self.last_done: _Seg | None = None
        self.blend_arc_lines: list[int] = []
        self.attempted_arc_lines: list[int] = []

    # --------------------------------------------------------------- small helpers

    @staticmethod
    def overall_acc(s: _Seg) -> float:
        scale = 1.0 - max(s.kink_reduce, s.kink_reduce_prev)
        if s.blend_prev or s.term == _PARABOLIC:
            scale *= 0.5
        return s.maxaccel * scale

    def tan_acc(self, s: _Seg) -> float:
        a = self.overall_acc(s)
        if s.kind == _ARC:
            a *= s.acc_ratio_tan
        return a

    @staticmethod
    def seg_max_target(s: _Seg, scale: float) -> float:
        return min(s.reqvel * scale, s.maxvel)

    def max_target(self, s: _Seg) -> float:
        scale = min(self.max_scale, 1.0) if s.is_blending else self.max_scale
        v = min(s.reqvel * scale, s.maxvel)
        if not s.pure_rotary:
            v = min(v, self.v_limit)
        return v

    def real_target(self, s: _Seg | None) -> float:
        if s is None:
            return 0.0
        return min(s.reqvel, self.max_target(s))  # feed override 100 %

    def real_final(self, s: _Seg, nxt: _Seg | None) -> float:
        if s.term != _TANGENT:
            return 0.0
        v = min(self.real_target(s), self.real_target(nxt))
        return min(s.finalvel, v)

    def triangle_vel(self, s: _Seg) -> float:
        length = s.target if s.finalized else s.target / 2.0
        return math.sqrt(self.tan_acc(s) * length)

    # ------------------------------------------------------------------ adding lines

    def add_line(self, end9: list[float], vel: float, ini_maxvel: float, acc: float,
                 line: int, tolerance: float) -> None:
        s = _Seg()
        s.kind, s.line = _LINE, line
        s.term, s.tolerance = _PARABOLIC, tolerance
        s.reqvel, s.maxvel, s.maxaccel = vel, ini_maxvel, acc
        s.cycle_time = self.dt
        start = list(self.goal)
        delta = [e - b for e, b in zip(end9, start)]
        xyz = math.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
        xyz_zero = max(abs(delta[0]), abs(delta[1]), abs(delta[2])) < _CART_FUZZ
        abc_zero = max(abs(d) for d in delta[3:6]) < _CART_FUZZ
        uvw_zero = max(abs(d) for d in delta[6:9]) < _CART_FUZZ
        if not xyz_zero:
            target = xyz
        elif not uvw_zero:
            target = math.sqrt(sum(d * d for d in delta[6:9]))
        elif not abc_zero:
            target = math.sqrt(sum(d * d for d in delta[3:6]))
        else:
            target = 0.0
        if target < _TP_POS_EPSILON:
            return
        s.start, s.end, s.delta = start, list(end9), delta
        s.target = s.nominal_length = target
        s.ux, s.uy, s.uz = (delta[0] / xyz, delta[1] / xyz, delta[2] / xyz) if not xyz_zero \
            else (1.0, 0.0, 0.0)
        s.rotary = not (abc_zero and uvw_zero)
        s.pure_rotary = xyz_zero and uvw_zero
        s.maxvel = min(s.maxvel, s.target / s.cycle_time)  # tcClampVelocityByLength
        prev = self.queue[-1] if self.queue else None
        if self.lim.arc_blend_enable and prev is not None:
            self.handle_blend_arc(prev, s)
        if prev is not None and not prev.finalized:
            prev.maxvel = min(prev.maxvel, prev.target / prev.cycle_time)
            prev.finalized = True
        s.index = len(self.segments)
        self.segments.append(s)
        self.queue.append(s)
        self.goal = list(end9)
        self.run_optimization()

    def setup_tangent(self, prev: _Seg, s: _Seg) -> int:
        """tpSetupTangent: 0 tangent, -1 fail, 1 no action (kink too large)."""
        if s.rotary or prev.rotary or prev.kind != _LINE:
            return -1
        if self.lim.optimization_depth < 2 or prev.term == _STOP:
            return -1
        px, py, pz = prev.ux, prev.uy, prev.uz
        if (px + s.ux) ** 2 + (py + s.uy) ** 2 + (pz + s.uz) ** 2 < _SHARP_CORNER_EPSILON:
            prev.term, s.blend_prev = _STOP, False
            return -1
        v_max = min(self.seg_max_target(prev, self.max_scale),
                    self.seg_max_target(s, self.max_scale))
        a_inst = v_max / self.dt + s.maxaccel
        diff = ((s.ux * a_inst - px * a_inst), (s.uy * a_inst - py * a_inst),
                (s.uz * a_inst - pz * a_inst))
        scale = max(abs(diff[i] / self.acc_bound[i]) if self.acc_bound[i] != 0 else 0.0
                    for i in range(3))
        if scale < self.kink_ratio:
            prev.term, s.blend_prev = _TANGENT, False
            self.set_kink(prev, s, v_max, scale)
            return 0
        self.set_kink(prev, s, v_max * self.kink_ratio / scale, self.kink_ratio)
        return 1

    @staticmethod
    def set_kink(prev: _Seg, s: _Seg, kink_vel: float, reduce: float) -> None:
        prev.kink_vel = kink_vel
        prev.kink_reduce = max(reduce, prev.kink_reduce)
        s.kink_reduce_prev = max(reduce, s.kink_reduce_prev)

    @staticmethod
    def remove_kink(prev: _Seg, s: _Seg) -> None:
        prev.kink_vel, prev.kink_reduce, s.kink_reduce_prev = -1.0, 0.0, 0.0

    def handle_blend_arc(self, prev: _Seg, s: _Seg) -> None:
        """tpHandleBlendArc."""
        if prev.progress > prev.target / 2.0:
            return
        res = self.setup_tangent(prev, s)
        if res <= 0:
            return
        arc = None
        if prev.term == _PARABOLIC and not s.finalized and not prev.finalized \
                and prev.kind == _LINE:
            self.attempted_arc_lines.append(s.line)
            arc = self.line_line_blend(prev, s)
        if arc is None:
            self.choose_best_blend(prev, s, None)

    def parabolic_performance(self, prev: _Seg, s: _Seg) -> float:
        v_this, v_next, v_net = self.blend_velocity(prev, s, self.max_target(prev),
                                                    self.max_target(s), net=True)
        return v_net

    def choose_best_blend(self, prev: _Seg, s: _Seg, blend: _Seg | None) -> int:
        """tpChooseBestBlend: 0 parabolic, 1 tangent, 2 arc, 3 none."""
        if prev.term in (_EXACT, _STOP):
            return 3
        perf = (self.parabolic_performance(prev, s) / 2.0, prev.kink_vel,
                blend.maxvel if blend is not None else 0.0)
        best = 0
        for i in range(3):
            if perf[i] > perf[best]:
                best = i
        if best == 0:
            self.remove_kink(prev, s)
            prev.term, s.blend_prev = _PARABOLIC, True
        elif best == 1:
            prev.term, s.blend_prev = _TANGENT, False
        else:
            self.remove_kink(prev, s)
        return best

    def line_line_blend(self, prev: _Seg, s: _Seg) -> _Seg | None:
        """tpCreateLineLineBlend: the blend arc between two XYZ lines, queued between
        them (the previous line shortened or consumed, the new one shortened), or None
        where LinuxCNC falls back to a parabolic or tangent blend."""
        u1, u2 = (prev.ux, prev.uy, prev.uz), (s.ux, s.uy, s.uz)
        dot = max(-1.0, min(1.0, u1[0] * u2[0] + u1[1] * u2[1] + u1[2] * u2[2]))
        theta = math.acos(-dot) / 2.0
        if math.pi / 2.0 - theta < _TP_ANGLE_EPSILON or theta < _TP_ANGLE_EPSILON:
            return None
        cross = (u1[1] * u2[2] - u1[2] * u2[1], u1[2] * u2[0] - u1[0] * u2[2],
                 u1[0] * u2[1] - u1[1] * u2[0])
        binormal, _ = _unit(cross)
        normal, _ = _unit((u2[0] - u1[0], u2[1] - u1[1], u2[2] - u1[2]))
        P = s.start[:3]
        phi = math.pi - theta * 2.0
        L1 = min(prev.target, prev.nominal_length * _BLEND_DIST_FRACTION)
        L2 = s.target * _BLEND_DIST_FRACTION
        # tcFindBlendTolerance
        T1 = prev.tolerance or prev.nominal_length * 0.25
        T2 = s.tolerance or s.nominal_length * 0.25
        tolerance = min(min(T1, T2), prev.nominal_length * 0.25, s.nominal_length * 0.25)
        a_max = _inscribed_diameter(binormal, self.acc_bound)
        v_planar_max = _inscribed_diameter(binormal, self.vel_bound)
        if a_max is None or v_planar_max is None:
            return None
        a_n_max = a_max * _BLEND_ACC_RATIO_NORMAL
        v_req = max(self.seg_max_target(prev, 1.0), self.seg_max_target(s, 1.0))
        v_goal = max(self.seg_max_target(prev, self.max_scale),
                     self.seg_max_target(s, self.max_scale))
        phi_eff = min(phi, math.pi * 0.49)
        v_max1 = min(prev.maxvel, s.maxvel / math.cos(phi_eff))
        v_max2 = min(s.maxvel, prev.maxvel / math.cos(phi_eff))
        v_area = v_max1 * v_max2 / 2.0 * math.sin(phi)
        base = math.sqrt(sum((u2[i] * v_max2 - u1[i] * v_max1) ** 2 for i in range(3)))
        v_max_alt = 2.0 * v_area / base
        v_goal = min(v_goal, max(v_max_alt, v_planar_max))
        # blendComputeParameters
        h_tol = tolerance / (1.0 - math.sin(theta))
        d_tol = math.cos(theta) * h_tol
        d_geom = min(min(L1, L2), d_tol)
        R_geom = math.tan(theta) * d_geom
        v_plan = min(math.sqrt(a_n_max * R_geom), v_goal)
        a_parabolic = a_max * 0.5
        v_triangle = math.sqrt(2.0 * a_parabolic * d_geom)
        t_blend = min(v_triangle, v_plan) / a_parabolic
        s_blend = t_blend * v_plan
        R_blend = min(s_blend / phi, R_geom)
        R_plan = max(v_plan ** 2 / a_n_max, R_blend)
        d_plan = R_plan / math.tan(theta)
        if R_plan < _TP_POS_EPSILON or R_plan * phi < _TP_MIN_ARC_LENGTH:
            return None
        # blendFindPoints3
        center_dist = R_plan / math.sin(theta)
        center = [P[i] + normal[i] * center_dist for i in range(3)]
        arc_start = [P[i] - u1[i] * d_plan for i in range(3)]
        arc_end = [P[i] + u2[i] * d_plan for i in range(3)]
        # blendCheckConsume
        L_prev = prev.target - d_plan
        can_consume = not prev.blend_prev
        consume = L_prev / v_plan < self.lim.gap_cycles * prev.cycle_time and can_consume
        arc = _Arc()
        arc.u_tan, arc.line_length = u1, (L_prev if consume else 0.0)
        arc.start, arc.end, arc.center = arc_start, arc_end, center
        arc.r_start = [arc_start[i] - center[i] for i in range(3)]
        arc.r_end = [arc_end[i] - center[i] for i in range(3)]
        r0 = math.sqrt(sum(c * c for c in arc.r_start))
        r1 = math.sqrt(sum(c * c for c in arc.r_end))
        if r0 < _ARC_MIN_RADIUS or r1 < _ARC_MIN_RADIUS:
            return None
        arc.radius = r0
        cos_angle = sum(arc.r_start[i] / r0 * arc.r_end[i] / r1 for i in range(3))
        arc.angle = math.acos(max(-1.0, min(1.0, cos_angle)))
        if arc.angle < _ARC_MIN_ANGLE:
            return None
        arc.s_angle = math.sin(arc.angle)
        # tpInitBlendArcFromPrev
        b = _Seg()
        b.kind, b.arc, b.line = _ARC, arc, s.line
        b.cycle_time = self.dt
        b.tolerance = prev.tolerance
        b.maxaccel, b.maxvel, b.reqvel = a_max, v_plan, v_req
        b.term = _TANGENT
        b.target = b.nominal_length = arc.radius * arc.angle + arc.line_length
        b.finalized = True
        b.start = list(prev.start) if consume else arc_start + prev.end[3:]
        b.end = arc_end + prev.end[3:]
        b.delta = [e - a for e, a in zip(b.end, b.start)]
        b.ux, b.uy, b.uz = u1
        if self.choose_best_blend(prev, s, b) != 2:
            return None
        if consume:
            self.queue.pop()
        else:
            # tcConnectBlendArc: the previous line now ends where the arc starts
            prev.end = arc_start + prev.end[3:]
            prev.delta = [e - a for e, a in zip(prev.end, prev.start)]
            prev.target = math.sqrt(sum(d * d for d in prev.delta[:3]))
            prev.term = _TANGENT
        s.blend_prev = False
        s.start = arc_end + s.start[3:]
        s.delta = [e - a for e, a in zip(s.end, s.start)]
        s.target = math.sqrt(sum(d * d for d in s.delta[:3]))
        b.index = len(self.segments)
        self.segments.append(b)
        self.queue.append(b)
        self.blend_arc_lines.append(s.line)
        return b

    def run_optimization(self) -> None:
        """tpRunOptimization (lazy: stops after a few segments at their peak)."""
        q = self.queue
        n = len(q)
        hit_peaks = 0
        hit_non_tangent = False
        for x in range(1, self.lim.optimization_depth + 2):
            ind = n - x
            if ind - 1 < 0:
                return
            tc, prev = q[ind], q[ind - 1]
            if prev.term != _TANGENT:
                if hit_non_tangent:
                    return
                hit_non_tangent = True
                continue
            if prev.progress / prev.target >= _BLEND_DIST_FRACTION / 2.0:
                return
            if prev.splitting or prev.blending_next:
                return
            if not tc.finalized:
                v0 = min(math.sqrt(self.tan_acc(tc) * tc.target), self.max_target(tc))
                prev.finalvel = min(prev.maxvel, v0)
                if prev.kink_vel >= 0 and prev.term == _TANGENT:
                    prev.finalvel = min(prev.finalvel, prev.kink_vel)
                tc.finalvel = 0.0
            else:
                vs_back = math.sqrt(tc.finalvel ** 2 + 2.0 * self.tan_acc(tc) * tc.target)
                vf_prev = prev.maxvel
                if prev.kink_vel >= 0 and prev.term == _TANGENT:
                    vf_prev = min(vf_prev, prev.kink_vel)
                vf_limit = min(tc.maxvel, vf_prev)
                if vs_back >= vf_limit:
                    vs_back = vf_limit
                    prev.at_max = True
                prev.finalvel = vs_back
                tc.maxvel = min(tc.maxvel, tc.target / (self.dt * _TP_MIN_SEGMENT_CYCLES))
            if tc.at_max:
                hit_peaks += 1
            if hit_peaks > _TP_OPTIMIZATION_CUTOFF:
                return

    # -------------------------------------------------------------------- running

    def blend_velocity(self, tc: _Seg, nxt: _Seg, vt_this: float, vt_next: float,
                       net: bool = False) -> tuple[float, float, float]:
        """tpComputeBlendVelocity: (v_blend_this, v_blend_next, v_blend_net)."""
        acc_this, acc_next = self.tan_acc(tc), self.tan_acc(nxt)
        v_this = min(self.triangle_vel(tc), vt_this)
        v_next = min(self.triangle_vel(nxt), vt_next)
        t_reach = min(tc.target / v_this, nxt.target / v_next)
        t_blend = min(t_reach, max(v_this / acc_this, v_next / acc_next))
        b_this = min(v_this, t_blend * acc_this)
        b_next = min(v_next, t_blend * acc_next)
        if tc.kind == _LINE and nxt.kind == _LINE:
            dot = tc.ux * nxt.ux + tc.uy * nxt.uy + tc.uz * nxt.uz
            theta = math.acos(-max(-1.0, min(1.0, dot))) / 2.0
        else:
            theta = 0.0  # LinuxCNC reads no direction for a blend arc
        cos_theta = math.cos(theta)
        if tc.tolerance > 0 and cos_theta > _MIN_COS_THETA:
            tblend = 2.0 * math.sqrt(acc_this * tc.tolerance / cos_theta)
            b_this, b_next = min(b_this, tblend), min(b_next, tblend)
        v_net = math.sin(theta) * (b_this + b_next) / 2.0 if net else 0.0
        return b_this, b_next, v_net

    def update_cycle(self, tc: _Seg, nxt: _Seg | None) -> None:
        """tpUpdateCycle: one period's acceleration, velocity and progress of ``tc``."""
        if not tc.blending_next:
            tc.vel_at_blend_start = tc.currentvel
        dt = tc.cycle_time
        acc = vel_desired = None
        if tc.ramp and tc.term == _TANGENT:
            vel_final = self.real_final(tc, nxt)
            if vel_final >= _TP_VEL_EPSILON:
                dx = tc.target - tc.progress
                vel_avg = (tc.currentvel + vel_final) / 2.0
                t = max(dx / vel_avg, 1e-16) if vel_avg > _TP_VEL_EPSILON else 1e-16
                a_max = self.tan_acc(tc)
                acc = max(-a_max, min(a_max, (vel_final - tc.currentvel) / t))
                vel_desired = vel_final
        if acc is None:
            v_target = self.real_target(tc)
            v_final = self.real_final(tc, nxt)
            dx = tc.target - tc.progress
            a_max = self.tan_acc(tc)
            half = a_max * dt * 0.5
            t3 = half * half
            discr = v_final * v_final + a_max * (2.0 * dx - tc.currentvel * dt) + t3
            maxnewvel = -half
            if discr > t3:
                maxnewvel += math.sqrt(discr)
            newvel = max(-v_target, min(v_target, maxnewvel))
            acc = (newvel - tc.currentvel) / max(dt, _TP_TIME_EPSILON)
            acc = max(-a_max, min(a_max, acc))
            vel_desired = maxnewvel
        # tcUpdateDistFromAccel
        v_next = tc.currentvel + acc * dt
        if v_next < 0.0:
            v_next = 0.0
            if tc.target - tc.progress < tc.currentvel * dt:
                tc.progress = tc.target
        else:
            tc.progress += (v_next + tc.currentvel) * 0.5 * dt
            if tc.progress > tc.target:
                tc.progress = tc.target
            elif tc.progress < 0.0:
                tc.progress = 0.0
        tc.currentvel = v_next
        tc.on_final_decel = abs(vel_desired - v_next) < _TP_VEL_EPSILON and acc < 0.0
        self.check_end(tc, nxt)

    @staticmethod
    def set_split(tc: _Seg, split_time: float, v_f: float) -> None:
        if tc.splitting and split_time > 0.0:
            return
        tc.splitting, tc.cycle_time, tc.term_vel = True, split_time, v_f

    def check_end(self, tc: _Seg, nxt: _Seg | None) -> None:
        """tpCheckEndCondition: flag a split cycle when the segment ends within one."""
        tc.cycle_time = self.dt
        dx = tc.target - tc.progress
        if dx <= _TP_POS_EPSILON:
            tc.progress = tc.target
            self.set_split(tc, 0.0, tc.currentvel)
            if tc.term in (_STOP, _EXACT):
                tc.remove = True
            return
        if tc.term in (_STOP, _EXACT):
            return
        v_f = self.real_final(tc, nxt)
        v_avg = (tc.currentvel + v_f) / 2.0
        t = _TP_TIME_EPSILON / 2.0
        if v_avg > _TP_VEL_EPSILON:
            t = max(t, dx / v_avg)
        elif dx > v_avg * self.dt and dx > _TP_POS_EPSILON:
            return
        a = (v_f - tc.currentvel) / t
        a_max = self.tan_acc(tc)
        if a > a_max or a < -a_max:
            a = a_max if a > a_max else -a_max
            disc = (tc.currentvel / a) ** 2 + 2.0 / a * dx
            if disc < 0:
                return
            if disc < _TP_TIME_EPSILON * _TP_TIME_EPSILON:
                t = -tc.currentvel / a
            elif a > 0:
                t = -tc.currentvel / a + math.sqrt(disc)
            else:
                t = -tc.currentvel / a - math.sqrt(disc)
            v_f = tc.currentvel + t * a
        if t < _TP_TIME_EPSILON:
            tc.progress = tc.target
            self.set_split(tc, 0.0, v_f)
        elif t < self.dt:
            self.set_split(tc, t, v_f)

    def activate(self, tc: _Seg) -> None:
        """tpActivateSegment: decide on ramped acceleration for short segments."""
        if tc.active:
            return
        cutoff = 1.0 / max(self.lim.ramp_frequency_hz, _TP_TIME_EPSILON)
        length = tc.target - tc.progress
        denom = tc.currentvel + min(tc.finalvel, self.real_target(tc))
        seg_time = 2.0 * length / denom if denom > 0 else math.inf
        if seg_time < cutoff and tc.term == _TANGENT and length != 0:
            tc.ramp = True
        tc.active = True
        tc.blending_next = False
        tc.on_final_decel = False

    def run_cycle(self) -> bool:
        """tpRunCycle; False when the queue is empty."""
        q = self.queue
        if not q:
            self.exec_line = 0
            return False
        tc = q[0]
        nxt = q[1] if len(q) > 1 else None
        self.activate(tc)
        tc.is_blending = False
        if nxt is not None:
            nxt.is_blending = False
        if tc.splitting:
            if not tc.remove:
                tc.progress = tc.target
                tc.remove = True
                if nxt is not None:
                    if tc.term == _TANGENT:
                        nxt.cycle_time = self.dt - tc.cycle_time
                        nxt.currentvel = tc.term_vel
                    self.update_cycle(nxt, q[2] if len(q) > 2 else None)
                    if tc.cycle_time > nxt.cycle_time and tc.term == _TANGENT:
                        self.exec_line = tc.line
                    else:
                        self.exec_line = nxt.line
        elif not tc.remove:
            tc.cycle_time = self.dt
            self.update_cycle(tc, nxt)
            if tc.term == _PARABOLIC and nxt is not None:
                # only a parabolic segment reads its blend velocity (tcIsBlending)
                b_this, b_next, _ = self.blend_velocity(tc, nxt, self.real_target(tc),
                                                        self.real_target(nxt))
                tc.blend_vel, nxt.blend_vel = b_this, b_next
                if tc.on_final_decel and tc.currentvel < tc.blend_vel:
                    tc.blending_next = True
            elif nxt is None:
                tc.blend_vel = 0.0
            if nxt is not None and tc.blending_next:
                nxt.is_blending = True
                self.update_cycle(nxt, None)
                self.exec_line = tc.line if tc.currentvel > nxt.currentvel else nxt.line
            else:
                self.exec_line = tc.line
        if tc.remove:
            tc.active = tc.remove = tc.is_blending = tc.splitting = False
            tc.cycle_time = self.dt
            tc.currentvel = tc.term_vel = 0.0
            q.pop(0)
            self.last_done = tc
        return True


# ------------------------------------------------------------------------- simulation

@dataclass(frozen=True, slots=True)
class SimulatedStretch:
    """The control's motion along a stretch, one row per servo period from the period
    the first segment reaches the motion to the one its last ends in.

    ``position : (n, m) float`` the commanded position after each period (program
    units, the stretch's axes; ``start : (m,) float`` the pose before the first),
    ``line : (n,) int`` the program line HAL shows in that
    period (the line of the period before; 0 before the first); ``blend_arc_lines``
    the program lines whose move starts with a blend arc LinuxCNC inserts (modelled as
    ported, less exactly checked than the rest), ``segments`` the number of segments
    the planner queued.  Unpacks as ``position, line``."""

    position: np.ndarray
    line: np.ndarray
    start: np.ndarray
    blend_arc_lines: tuple[int, ...]
    segments: int
    servo_period_s: float

    def __post_init__(self):
        for name in ("position", "line", "start"):
            arr = np.array(getattr(self, name))
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __iter__(self):
        return iter((self.position, self.line))

    @property
    def moving(self) -> np.ndarray:
        """``(n,) bool``: the periods in which the commanded position changes."""
        before = np.vstack([self.start[None, :], self.position[:-1]])
        return np.any(self.position != before, axis=1)

    @property
    def duration_s(self) -> float:
        """From the first period that moves to the last that moves, both counted."""
        moving = np.flatnonzero(self.moving)
        if not len(moving):
            return 0.0
        return (moving[-1] - moving[0] + 1) * self.servo_period_s


def simulate(stretch: Stretch, limits: ControlLimits) -> SimulatedStretch:
    """The control's commanded positions along ``stretch``, every servo period, with
    the limits ``limits``: canon, the planner's queue filled one segment per period
    while it runs, and the motion until it stands still at the stretch's end."""
    moves = canon_moves(stretch, limits)
    cols = [POSE_AXES.index(a) for a in stretch.axes]
    start9 = [0.0] * 9
    for c, v in zip(cols, stretch.start):
        start9[c] = float(v)
    tp = _Planner(limits, start9)
    ends9 = []
    for row in moves.end:
        e = [0.0] * 9
        for c, v in zip(cols, row):
            e[c] = float(v)
        ends9.append(e)
    tolerance = dict(zip(stretch.line.tolist(), stretch.tolerance_mm.tolist()))
    capacity = _TC_QUEUE_SIZE - _TC_QUEUE_MARGIN
    interval = limits.segment_interval_cycles
    n_moves = len(ends9)
    rec_i0: list[int] = []
    rec_p0: list[float] = []
    rec_i1: list[int] = []
    rec_p1: list[float] = []
    rec_line: list[int] = []
    shown = 0
    k = cycle = 0
    queue = tp.queue
    while True:
        if k < n_moves and cycle % interval == 0 and len(queue) < capacity:
            tp.add_line(ends9[k], float(moves.vel[k]), float(moves.ini_maxvel[k]),
                        float(moves.acc[k]), int(moves.line[k]), tolerance[int(moves.line[k])])
            k += 1
        if not queue and k >= n_moves:
            break
        tp.run_cycle()
        rec_line.append(shown)
        shown = tp.exec_line
        if queue:
            s0 = queue[0]
            rec_i0.append(s0.index)
            rec_p0.append(s0.progress)
            if len(queue) > 1 and queue[1].progress != 0.0:
                rec_i1.append(queue[1].index)
                rec_p1.append(queue[1].progress)
            else:
                rec_i1.append(-1)
                rec_p1.append(0.0)
        else:  # at rest where the last segment ended
            rec_i0.append(tp.last_done.index)
            rec_p0.append(tp.last_done.target)
            rec_i1.append(-1)
            rec_p1.append(0.0)
        cycle += 1
    position9 = _positions(tp, np.array(rec_i0, dtype=int), np.array(rec_p0),
                           np.array(rec_i1, dtype=int), np.array(rec_p1))
    return SimulatedStretch(position9[:, cols], np.array(rec_line, dtype=int),
                            np.array(stretch.start, dtype=float),
                            tuple(tp.blend_arc_lines), len(tp.segments),
                            limits.servo_period_s)


def _segment_points(seg: _Seg, progress: np.ndarray) -> np.ndarray:
    """``(n, 9)`` points of ``seg`` at ``progress : (n,)`` (tcGetPosReal)."""
    if seg.kind == _LINE:
        rate = np.array(seg.delta) / seg.target
        return np.array(seg.start)[None, :] + progress[:, None] * rate[None, :]
    arc = seg.arc
    out = np.tile(np.array(seg.start, dtype=float), (len(progress), 1))
    net = progress - arc.line_length
    on_line = (net <= 0.0) & (arc.line_length > 0)
    ang = net / arc.radius
    s0 = np.sin(arc.angle - ang) / arc.s_angle
    s1 = np.sin(ang) / arc.s_angle
    xyz = (np.array(arc.center)[None, :] + s0[:, None] * np.array(arc.r_start)[None, :]
           + s1[:, None] * np.array(arc.r_end)[None, :])
    line_pts = np.array(arc.start)[None, :] + net[:, None] * np.array(arc.u_tan)[None, :]
    out[:, :3] = np.where(on_line[:, None], line_pts, xyz)
    return out


def _positions(tp: _Planner, i0: np.ndarray, p0: np.ndarray, i1: np.ndarray,
               p1: np.ndarray) -> np.ndarray:
    """The planner's position after every period: the front segment's point plus how
    far the next one has moved from its start (a parabolic blend moves both)."""
    pos = np.tile(np.array(tp.goal, dtype=float), (len(i0), 1))
    for index in np.unique(i0[i0 >= 0]):
        seg = tp.segments[index]
        rows = np.flatnonzero(i0 == index)
        pos[rows] = _segment_points(seg, p0[rows])
    for index in np.unique(i1[i1 >= 0]):
        seg = tp.segments[index]
        rows = np.flatnonzero(i1 == index)
        pos[rows] += _segment_points(seg, p1[rows]) - _segment_points(seg, np.zeros(1))
    return pos
