"""Configuration: one TOML file describes the machine, the ballbar, the test and the post.

Loading validates everything that the file alone decides.  Every problem raises
:class:`~sdit_path.errors.ConfigError` whose message names the file, the line (when it
can be found) and the dotted key, says what was expected and what arrived.  Unknown
keys are errors too, so a misspelt or wrongly-unitised key (``feed_mm_per_s``) is
caught instead of silently ignored.  What only a later stage can judge (a controller
name, the pivot within reach) is checked by that stage
(:func:`sdit_path.plan.configure.check_config`).
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

from ..errors import ConfigError
from .model import (AXIS_NAMES, CREST_RANGE, FIVE_AXIS_MODES, TIMING_CONTROLS, PASSES, PROJECTIONS, SCHEDULES,
                    SHAPES, TILT_OFFSET_MAX_DEG, TRANSITS, Axis, BallbarConfig, CheckConfig, Config,
                    CurveConfig, DEFAULT_DIRECTION, MachineConfig, PostConfig, RotaryConfig,
                    SceneConfig, ScenePart, SectorCurve, TestConfig, TimingConfig)
from .reader import Reader, describe, short
from .samples import DEFAULT_SAMPLE, bundled_samples, sample_path


_LINEAR_KEYS = ("type", "direction", "travel_mm", "max_velocity_mm_per_s",
                "max_acceleration_mm_per_s2", "max_jerk_mm_per_s3")
_ROTARY_KEYS = ("type", "direction", "point_mm", "travel_deg", "max_velocity_deg_per_s",
                "max_acceleration_deg_per_s2", "max_jerk_deg_per_s3")


def _unit_vector(r: Reader, data: dict, key: str, default) -> tuple[float, float, float]:
    x, y, z = r.xyz(data, key, default=default)
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-12:
        raise r.fail(key, "expected a non-zero direction vector")
    return (x / n, y / n, z / n)


def _axis(r: Reader, a: dict, key: str, name: str, on_workpiece: bool) -> Axis:
    kind = r.string(a, f"{key}.type", "rotary" if name in "ABC" else "linear", ("linear", "rotary"))
    r.no_unknown(a, key, _ROTARY_KEYS if kind == "rotary" else _LINEAR_KEYS)
    default: tuple[float, float, float] = DEFAULT_DIRECTION[name]
    if kind == "linear" and on_workpiece:
        # the table moves against the program axis
        default = (-default[0], -default[1], -default[2])
    direction = _unit_vector(r, a, f"{key}.direction", default)
    if kind == "linear":
        lo, hi = r.vector(a, f"{key}.travel_mm", 2, unit="mm", bound=1e5)
        scale, unit, point = 1.0, "mm", (0.0, 0.0, 0.0)
    else:
        lo, hi = r.vector(a, f"{key}.travel_deg", 2, unit="deg", bound=1e5)
        scale, unit = math.pi / 180.0, "deg"
        point = r.xyz(a, f"{key}.point_mm", default=(0.0, 0.0, 0.0), unit="mm")
    if not lo < hi:
        raise r.fail(f"{key}.travel_{unit}", f"expected [min, max] with min < max, got [{lo:g}, {hi:g}]")
    # plausibility bounds: the slowest and the fastest machine tools, with room to spare
    # (linear motors reach about 3 m/s, 5 g and 1e6 mm/s^3; direct-drive tables 3000 deg/s)
    vel, acc, jerk = _LIMIT_BOUNDS[kind]
    return Axis(
        name=name, kind=kind, direction=direction, point_mm=point,
        travel=(lo * scale, hi * scale),
        max_velocity=r.number(a, f"{key}.max_velocity_{unit}_per_s", ge=vel[0], le=vel[1],
                              unit=f"{unit}/s") * scale,
        max_acceleration=r.number(a, f"{key}.max_acceleration_{unit}_per_s2", ge=acc[0],
                                  le=acc[1], unit=f"{unit}/s^2") * scale,
        max_jerk=r.number(a, f"{key}.max_jerk_{unit}_per_s3", ge=jerk[0], le=jerk[1],
                          unit=f"{unit}/s^3") * scale,
    )


#: (min, max) of velocity, acceleration and jerk limits, per axis kind (mm or deg)
_LIMIT_BOUNDS = {"linear": ((0.1, 2e4), (1.0, 2e5), (10.0, 1e9)),
                 "rotary": ((0.1, 1e5), (1.0, 1e6), (10.0, 1e10))}


def _machine(r: Reader, root: dict) -> MachineConfig:
    m = r.table(root, "machine", ("name", "axes", "workpiece_chain", "tool_chain", "tool_length_mm",
                                  "spindle_direction"))
    name = r.string(m, "machine.name")
    workpiece = r.strings(m, "machine.workpiece_chain", ("X", "Y"))
    tool = r.strings(m, "machine.tool_chain", ("Z",))
    chain = workpiece + tool
    for ax in chain:
        if ax not in AXIS_NAMES:
            raise r.fail("machine.workpiece_chain" if ax in workpiece else "machine.tool_chain",
                         f"unknown axis {short(ax)}; expected axis names among {', '.join(AXIS_NAMES)}")
    if len(set(chain)) != len(chain):
        raise r.fail("machine.workpiece_chain", f"an axis appears twice in the chains: {list(chain)}")
    axes_table = r.table(m, "machine.axes", chain)
    axes = []
    for ax in chain:
        key = f"machine.axes.{ax}"
        a = axes_table.get(ax)
        if not isinstance(a, dict):
            raise r.fail(key, f"missing table; the chains name axis {ax}, expected a [{key}] section")
        axes.append(_axis(r, a, key, ax, ax in workpiece))
    linear = [a for a in axes if not a.is_rotary]
    if len(linear) != 3:
        raise r.fail("machine.workpiece_chain",
                     f"expected exactly 3 linear axes in the chains, got {len(linear)}")
    det = _det3([a.direction for a in linear])
    if abs(det) < 1e-6:
        raise r.fail("machine.axes", "the 3 linear axis directions must be independent")
    if any(a.is_rotary for a in axes if a.name in tool):
        raise r.fail("machine.tool_chain", "rotary axes in the tool branch (swivel heads) are not "
                                           "supported yet; put rotary axes in machine.workpiece_chain")
    return MachineConfig(
        name=name, axes=tuple(axes), workpiece_chain=workpiece, tool_chain=tool,
        tool_length_mm=r.number(m, "machine.tool_length_mm", 0.0, ge=0, le=2000, unit="mm"),
        spindle_direction=_unit_vector(r, m, "machine.spindle_direction", (0.0, 0.0, 1.0)))


def _det3(rows) -> float:
    (a, b, c), (d, e, f), (g, h, i) = rows
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _ballbar(r: Reader, root: dict, machine: MachineConfig) -> BallbarConfig:
    b = r.table(root, "ballbar", ("bar_length_mm", "pivot_mm", "ball_diameter_mm",
                                  "bar_diameter_mm", "sensor_range_mm", "length_range_mm"))
    length_range = r.span(b, "ballbar.length_range_mm", default=(50.0, 600.0), unit="mm",
                          bound=3000)
    if not 0 < length_range[0] <= length_range[1]:
        raise r.fail("ballbar.length_range_mm",
                     f"expected [min, max] with 0 < min <= max, got {list(length_range)}")
    length = r.number(b, "ballbar.bar_length_mm", gt=0, unit="mm")
    if not length_range[0] <= length <= length_range[1]:
        raise r.fail("ballbar.bar_length_mm",
                     f"expected a bar length within the instrument's reach "
                     f"{length_range[0]:g}..{length_range[1]:g} mm (ballbar.length_range_mm), "
                     f"got {length:g} mm")
    ball = r.number(b, "ballbar.ball_diameter_mm", default=12.7, ge=1, le=100, unit="mm")
    if not ball < length:
        raise r.fail("ballbar.ball_diameter_mm",
                     f"expected a ball diameter smaller than the bar length {length:g} mm, got {ball:g}")
    sensor = r.number(b, "ballbar.sensor_range_mm", default=1.0, gt=0, le=10.0, unit="mm")
    bar = r.number(b, "ballbar.bar_diameter_mm", default=min(12.0, ball), ge=0.5, unit="mm")
    if bar > ball:
        raise r.fail("ballbar.bar_diameter_mm",
                     f"expected a bar no thicker than the balls ({ball:g} mm), got {bar:g}")
    pivot = r.xyz(b, "ballbar.pivot_mm", unit="mm")
    return BallbarConfig(bar_length_mm=length, pivot_mm=pivot, ball_diameter_mm=ball,
                         bar_diameter_mm=bar, sensor_range_mm=sensor, length_range_mm=length_range)


def _test(r: Reader, root: dict, machine: MachineConfig) -> TestConfig:
    t = r.table(root, "test", ("track_elevations_deg", "nodes_per_track", "subsegments_per_sector",
                               "dwell_s", "feed_mm_per_min", "passes", "transit", "projection",
                               "curve", "rotary", "remeasure"))
    elev = r.numbers(t, "test.track_elevations_deg", (0.0, 18.0, 36.0, 54.0, 72.0), unit="deg")
    if len(elev) > 25:
        raise r.fail("test.track_elevations_deg", f"expected at most 25 tracks, got {len(elev)}")
    if elev[0] < 0:
        raise r.fail("test.track_elevations_deg",
                     f"expected elevations >= 0 deg (a hemisphere above the pivot), got {elev[0]:g}")
    for a, b in zip(elev, elev[1:]):
        if not b > a:
            raise r.fail("test.track_elevations_deg",
                         f"expected strictly increasing elevations, got {a:g} then {b:g}")
        if b - a < 1.0:
            raise r.fail("test.track_elevations_deg",
                         f"expected tracks at least 1 deg apart (a layer needs room for its "
                         f"curves), got {a:g} then {b:g}")
    if elev[-1] >= 90:
        raise r.fail("test.track_elevations_deg",
                     f"expected elevations < 90 deg (the pole is the node TOP), got {elev[-1]:g}")
    nodes = r.integer(t, "test.nodes_per_track", 6, ge=1, le=72)
    subs = r.integer(t, "test.subsegments_per_sector", 3, ge=1, le=20)
    # a dwell shorter than 0.1 s gives no still reading to anchor the timing (and no
    # control programs less than a millisecond)
    dwell = r.number(t, "test.dwell_s", 2.0, ge=0.1, le=3600, unit="s")
    feed = _feed(r, t, "test.feed_mm_per_min", machine)
    passes = r.strings(t, "test.passes", PASSES)
    for p in passes:
        if p not in PASSES:
            raise r.fail("test.passes", f"expected passes among {', '.join(PASSES)}, got {short(p)}")
    if len(set(passes)) != len(passes):
        raise r.fail("test.passes", f"expected each pass at most once, got {list(passes)}")
    transit = r.string(t, "test.transit", "meridian", TRANSITS)
    projection = r.string(t, "test.projection", "stereographic", PROJECTIONS)
    c = r.table(t, "test.curve", ("amplitude", "waves_per_sector", "cap_elevation_deg",
                                  "override"), required=False)
    amplitude = r.number(c, "test.curve.amplitude", 1.0, gt=0, le=1)
    waves = r.integer(c, "test.curve.waves_per_sector", 1, ge=1, le=10)
    cap = r.number(c, "test.curve.cap_elevation_deg", (elev[-1] + 90.0) / 2.0, le=90, unit="deg")
    if not elev[-1] < cap < 90:
        raise r.fail("test.curve.cap_elevation_deg",
                     f"expected a value between the top track ({elev[-1]:g} deg) and 90 deg, got {cap:g}")
    rotary = _rotary(r, t, machine)
    overrides = _overrides(r, c, len(elev), nodes, machine, rotary.schedule)
    return TestConfig(track_elevations_deg=elev, nodes_per_track=nodes, subsegments_per_sector=subs,
                      dwell_s=dwell, feed_mm_per_min=feed, passes=passes, transit=transit,
                      projection=projection,
                      curve=CurveConfig(amplitude=amplitude, waves_per_sector=waves,
                                        cap_elevation_deg=cap,
                                        overrides=overrides),
                      rotary=rotary,
                      remeasure=_remeasure(r, t, len(elev), nodes))


def _sector_name(r: Reader, key: str, sector, tracks: int, nodes: int) -> str:
    letters = "ABCDEFGHIJKLMNOPQRSTUVWXY"[:tracks]
    ok = (isinstance(sector, str) and len(sector) >= 2 and sector[0] in letters
          and sector[1:].isdigit() and 1 <= int(sector[1:]) <= nodes
          and str(int(sector[1:])) == sector[1:])
    if not ok:
        raise r.fail(key, f"expected a layer letter ({letters[0]}-{letters[-1]}) and a sector "
                          f"number 1-{nodes}, such as {letters[-1]}{min(3, nodes)}, got "
                          f"{short(sector) if isinstance(sector, str) else describe(sector)}")
    return sector


def _remeasure(r: Reader, t: dict, tracks: int, nodes: int) -> tuple[str, ...]:
    m = r.table(t, "test.remeasure", ("sectors",), required=False)
    raw = m.get("sectors", [])
    if not isinstance(raw, list):
        raise r.fail("test.remeasure.sectors", f"expected a list of sectors such as [\"D3\"], "
                                               f"got {describe(raw)}")
    out = [_sector_name(r, "test.remeasure.sectors", s, tracks, nodes) for s in raw]
    if len(set(out)) != len(out):
        raise r.fail("test.remeasure.sectors", f"expected each sector at most once, got {out}")
    return tuple(sorted(out, key=lambda x: (x[0], int(x[1:]))))


def _feed(r: Reader, t: dict, key: str, machine: MachineConfig, default=None) -> float:
    """A feed in mm/min the programs can write and the machine can reach."""
    feed = r.number(t, key, default, gt=0, unit="mm/min")
    if feed < 1.0:
        raise r.fail(key, f"expected a feed of at least 1 mm/min (programs write F with 3 "
                          f"decimals, and a slower test would last days), got {feed:g}")
    slowest = min(ax.max_velocity for ax in machine.linear_axes) * 60.0
    fastest_path = math.sqrt(sum((ax.max_velocity * 60.0) ** 2 for ax in machine.linear_axes))
    if feed > fastest_path:
        raise r.fail(key, f"expected a feed the machine can reach (<= {fastest_path:.0f} mm/min "
                          f"from the axis velocity limits; slowest axis {slowest:.0f} mm/min), "
                          f"got {feed:g}")
    return feed


def _overrides(r: Reader, c: dict, tracks: int, nodes: int, machine: MachineConfig,
               schedule: str) -> tuple[SectorCurve, ...]:
    """``[[test.curve.override]]``: one table per re-planned sector."""
    raw = c.get("override", [])
    key = "test.curve.override"
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list) or not all(isinstance(o, dict) for o in raw):
        raise r.fail(key, f"expected [[{key}]] tables, got {describe(raw)}")
    if len(raw) > 25 * 72:
        raise r.fail(key, f"expected at most one override per sector, got {len(raw)}")
    out, seen = [], set()
    base = key
    for i, o in enumerate(raw, start=1):
        key = f"{base}[{i}]" if len(raw) > 1 else base
        r.no_unknown(o, key, ("sector", "amplitude", "waves_per_sector", "projection",
                              "feed_mm_per_min", "tilt_offset_deg", "crest_at"))
        sector = _sector_name(r, f"{key}.sector", r.string(o, f"{key}.sector"), tracks, nodes)
        if sector in seen:
            raise r.fail(f"{key}.sector", f"expected each sector at most once, got {sector} twice")
        seen.add(sector)
        if "tilt_offset_deg" in o and schedule != "moving":
            raise r.fail(f"{key}.tilt_offset_deg",
                         f"expected test.rotary.schedule = \"moving\" for a tilt offset (the "
                         f"'{schedule}' schedule holds the tilt axis still), got it on {sector}")
        out.append(SectorCurve(
            sector,
            r.number(o, f"{key}.amplitude", gt=0, le=1) if "amplitude" in o else None,
            r.integer(o, f"{key}.waves_per_sector", ge=1, le=10) if "waves_per_sector" in o else None,
            r.string(o, f"{key}.projection", choices=PROJECTIONS) if "projection" in o else None,
            _feed(r, o, f"{key}.feed_mm_per_min", machine) if "feed_mm_per_min" in o else None,
            r.number(o, f"{key}.tilt_offset_deg", ge=-TILT_OFFSET_MAX_DEG, le=TILT_OFFSET_MAX_DEG,
                     unit="deg") if "tilt_offset_deg" in o else None,
            r.number(o, f"{key}.crest_at", ge=CREST_RANGE[0], le=CREST_RANGE[1])
            if "crest_at" in o else None))
    return tuple(sorted(out, key=lambda x: (x.sector[0], int(x.sector[1:]))))


def _rotary(r: Reader, t: dict, machine: MachineConfig) -> RotaryConfig:
    rot = r.table(t, "test.rotary", ("schedule", "locked_deg", "tilt_axis", "turn_axis",
                                     "hold_azimuth_deg", "tilt_at_equator_deg", "tilt_at_pole_deg"),
                  required=False)
    names = [a.name for a in machine.rotary_axes]
    schedule = r.string(rot, "test.rotary.schedule", "locked", SCHEDULES)
    locked_table = rot.get("locked_deg", {})
    if not isinstance(locked_table, dict):
        raise r.fail("test.rotary.locked_deg", "expected a table of axis = angle in deg, e.g. {B = 0, C = 0}")
    r.no_unknown(locked_table, "test.rotary.locked_deg", tuple(names))
    locked = tuple((n, math.radians(r.number(locked_table, f"test.rotary.locked_deg.{n}", 0.0,
                                               ge=-1e5, le=1e5, unit="deg"))) for n in names)
    tilt = r.string(rot, "test.rotary.tilt_axis", names[0] if len(names) == 2 else "")
    turn = r.string(rot, "test.rotary.turn_axis", names[-1] if names else "")
    if schedule == "moving":
        if len(names) != 2:
            raise r.fail("test.rotary.schedule",
                         f"'moving' needs two rotary axes (tilt and turn), the machine has {len(names)}")
        for key, value in (("tilt_axis", tilt), ("turn_axis", turn)):
            if value not in names:
                raise r.fail(f"test.rotary.{key}",
                             f"expected one of the rotary axes {', '.join(names)}, got {short(value)}")
        if tilt == turn:
            raise r.fail("test.rotary.turn_axis", "tilt and turn axes must differ")
        dz = machine.axis(turn).direction[2]
        if abs(dz) < 0.5:
            raise r.fail(f"machine.axes.{turn}.direction",
                         f"the 'moving' schedule turns the table about a near-vertical axis; "
                         f"expected {turn}'s direction within 60 deg of Z, got "
                         f"{[round(x, 4) for x in machine.axis(turn).direction]} (normalised)")
    return RotaryConfig(
        schedule=schedule, locked_rad=locked, tilt_axis=tilt, turn_axis=turn,
        hold_azimuth_rad=math.radians(r.number(rot, "test.rotary.hold_azimuth_deg", 0.0,
                                               ge=-360, le=360, unit="deg")),
        tilt_at_equator_rad=math.radians(r.number(rot, "test.rotary.tilt_at_equator_deg", 0.0,
                                                  ge=-360, le=360, unit="deg")),
        tilt_at_pole_rad=math.radians(r.number(rot, "test.rotary.tilt_at_pole_deg", 0.0,
                                               ge=-360, le=360, unit="deg")))


def _check(r: Reader, root: dict) -> CheckConfig:
    c = r.table(root, "check", ("travel_margin_mm", "angle_margin_deg", "safety_clearance_mm",
                                "pose_spacing_mm"), required=False)
    return CheckConfig(
        travel_margin_mm=r.number(c, "check.travel_margin_mm", 0.0, ge=0, le=1000, unit="mm"),
        angle_margin_rad=math.radians(r.number(c, "check.angle_margin_deg", 0.0, ge=0, le=90,
                                               unit="deg")),
        safety_clearance_mm=r.number(c, "check.safety_clearance_mm", 1.0, ge=0, le=200, unit="mm"),
        # below 0.05 mm the pose count (and memory) grows past millions per layer while
        # the clearance it finds changes by nanometres
        pose_spacing_mm=r.number(c, "check.pose_spacing_mm", 0.5, ge=0.05, le=0.5, unit="mm"))


_PART_KEYS = ("name", "body", "shape", "size_mm", "position_mm", "axis", "mesh_file")
_SIZES = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1, "mesh": 0}
#: Parts sdit-path adds itself: the two balls and the bar between them.
BALLBAR_PARTS = ("pivot_ball", "tool_ball", "bar")


def _scene(r: Reader, root: dict, machine: MachineConfig) -> SceneConfig:
    sc = r.table(root, "scene", ("parts", "allowed_contacts"), required=False)
    raw_parts = sc.get("parts", [])
    if not isinstance(raw_parts, list) or not all(isinstance(p, dict) for p in raw_parts):
        raise r.fail("scene.parts", "expected an array of tables [[scene.parts]]")
    bodies = ("bed",) + machine.workpiece_chain + machine.tool_chain
    parts, names = [], set(BALLBAR_PARTS)
    for k, p in enumerate(raw_parts):
        key = f"scene.parts[{k}]"
        r.no_unknown(p, key, _PART_KEYS)
        name = r.string(p, f"{key}.name")
        if name in names:
            raise r.fail(f"{key}.name", f"part name {name!r} is used twice (or is reserved)")
        names.add(name)
        body = r.string(p, f"{key}.body", choices=bodies)
        shape = r.string(p, f"{key}.shape", choices=SHAPES)
        n = _SIZES[shape]
        size = r.vector(p, f"{key}.size_mm", n, unit="mm", bound=1e4) if n else ()
        if any(v < 0.01 for v in size):
            raise r.fail(f"{key}.size_mm", f"expected sizes of at least 0.01 mm, got {list(size)}")
        mesh = r.string(p, f"{key}.mesh_file", "") if shape == "mesh" else ""
        if shape == "mesh" and not mesh:
            raise r.fail(f"{key}.mesh_file", "a mesh part needs mesh_file (an STL path)")
        parts.append(ScenePart(name=name, body=body, shape=shape, size_mm=size,
                               position_mm=r.xyz(p, f"{key}.position_mm", default=(0, 0, 0),
                                                 unit="mm"),
                               axis=_unit_vector(r, p, f"{key}.axis", (0.0, 0.0, 1.0)),
                               mesh_file=mesh))
    allowed = []
    raw_allowed = sc.get("allowed_contacts", [])
    if not isinstance(raw_allowed, list) or not all(
            isinstance(x, list) and len(x) == 2 and all(isinstance(y, str) for y in x)
            for x in raw_allowed):
        raise r.fail("scene.allowed_contacts", "expected a list of [part, part] name pairs")
    for a, b in raw_allowed:
        for n in (a, b):
            if n not in names:
                raise r.fail("scene.allowed_contacts", f"unknown part {short(n)}; parts: {', '.join(sorted(names))}")
        allowed.append((a, b))
    return SceneConfig(parts=tuple(parts), allowed_contacts=tuple(allowed))


def _post(r: Reader, root: dict) -> PostConfig:
    p = r.table(root, "post", ("controllers", "program_prefix", "decimals", "spline_degree",
                               "spline_tolerance_um", "chord_tolerance_um",
                               "chord_curve_tolerance_um", "work_offset", "comment",
                               "five_axis_mode", "operator_sequence", "safe_position_mm",
                               "approach_feed_mm_per_min"))
    controllers = r.strings(p, "post.controllers", ("sinumerik840d", "linuxcnc"))
    # the names are judged by the post-processor registry (sdit_path.nc.registry)
    if len(set(controllers)) != len(controllers):
        raise r.fail("post.controllers", f"expected each controller once, got {list(controllers)}")
    offset = r.string(p, "post.work_offset", "G54")
    if not re.fullmatch(r"G5(00|[4-9]|0[5-9]|[1-9][0-9])|G54\.1 P([1-9][0-9]{0,2})", offset) or (
            offset.startswith("G54.1") and int(offset.split("P")[1]) > 300):
        raise r.fail("post.work_offset",
                     f"expected a work offset such as G54..G59, G54.1 P1..P300 or G500 (machine "
                     f"frame), got {offset[:40]!r}")
    return PostConfig(
        controllers=controllers,
        program_prefix=r.string(p, "post.program_prefix", "SDIT"),
        decimals=r.integer(p, "post.decimals", 6, ge=3, le=9),
        spline_degree=r.integer(p, "post.spline_degree", 3, ge=2, le=3),
        spline_tolerance_um=r.number(p, "post.spline_tolerance_um", 0.01, ge=0.001, le=100,
                                     unit="um"),
        chord_tolerance_um=r.number(p, "post.chord_tolerance_um", 0.1, ge=0.001, le=100, unit="um"),
        chord_curve_tolerance_um=r.number(p, "post.chord_curve_tolerance_um", 1.0, ge=0.01,
                                          le=1000, unit="um"),
        work_offset=offset,
        comment=r.string(p, "post.comment", ""),
        five_axis_mode=r.string(p, "post.five_axis_mode", "traori", FIVE_AXIS_MODES),
        operator_sequence=r.boolean(p, "post.operator_sequence", True),
        safe_position_mm=(r.xyz(p, "post.safe_position_mm", unit="mm")
                          if "safe_position_mm" in p else None),
        approach_feed_mm_per_min=r.number(p, "post.approach_feed_mm_per_min", 2000.0, gt=0,
                                          le=60000, unit="mm/min"),
    )


def parse_config(text: str, source: str = "<config>") -> Config:
    """Parse and validate TOML ``text``; ``source`` names it in error messages."""
    try:
        root = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        where = f"{source}:{m.group(1)}" if m else source
        raise ConfigError(where, f"cannot parse TOML: {msg}") from None
    r = Reader(source, text)
    r.no_unknown(root, "", ("machine", "ballbar", "test", "post", "check", "scene", "timing"))
    machine = _machine(r, root)
    ballbar = _ballbar(r, root, machine)
    test = _test(r, root, machine)
    post = _post(r, root)
    check = _check(r, root)
    scene = _scene(r, root, machine)
    tm = r.table(root, "timing", ("sample_rate_hz", "export_trajectories", "control"),
                 required=False)
    timing = TimingConfig(
        sample_rate_hz=r.number(tm, "timing.sample_rate_hz", 1000.0, ge=10, le=5000, unit="Hz"),
        export_trajectories=r.boolean(tm, "timing.export_trajectories", True),
        control=r.string(tm, "timing.control", "jerk_limited", TIMING_CONTROLS))
    if timing.control == "linuxcnc" and tuple(post.controllers) != ("linuxcnc",):
        raise r.fail("timing.control", "\"linuxcnc\" times the plan as LinuxCNC runs its "
                                       "program: post.controllers must be [\"linuxcnc\"] "
                                       f"alone, got {list(post.controllers)} (another control "
                                       "runs another timing: plan it with its own config)")
    return Config(source=source, machine=machine, ballbar=ballbar, test=test, post=post,
                  check=check, scene=scene, timing=timing, text=text)


def load_config(path: str | Path | None = None) -> Config:
    """Load a config file, or the bundled default sample when ``path`` is None."""
    if path is None:
        text = sample_path(DEFAULT_SAMPLE).read_text(encoding="utf-8")
        return parse_config(text, source=f"samples/{DEFAULT_SAMPLE}")
    p = Path(path)
    raw_name = str(path)
    looks_like_a_path = ("/" in raw_name or "\\" in raw_name or raw_name.endswith(".toml")
                         or raw_name.startswith("."))
    if not looks_like_a_path and not p.exists():
        name = f"{raw_name}.toml"
        if name in bundled_samples():
            text = sample_path(name).read_text(encoding="utf-8")
            return parse_config(text, source=f"samples/{name}")
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        names = ", ".join(n.removesuffix(".toml") for n in bundled_samples())
        raise ConfigError(str(p), f"no such file; expected a TOML configuration file, or the "
                                  f"bare name of a bundled sample ({names})") from None
    except IsADirectoryError:
        raise ConfigError(str(p), "is a directory; expected a TOML configuration file") from None
    except OSError as exc:
        raise ConfigError(str(p), f"cannot read: {exc.strerror}") from None
    try:
        # a byte-order mark (what Notepad writes) is accepted, as in a recording
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(f"{p}:{line}", "not UTF-8 text; expected a TOML configuration") from None
    return parse_config(text, source=str(p))

