"""Five-axis programs of the paper's B-C swivel-table machine, read back and checked
through the machine's forward kinematics (and LinuxCNC's own interpreter)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.interpolate import BSpline

from sdit_path.config import load_config, parse_config, sample_path
from sdit_path.machine.kinematics import Kinematics
from sdit_path.nc.readback import read_sinumerik
from sdit_path.plan.pipeline import plan
from sdit_path.plan.manifest import manifest
from sdit_path.timing.trajectory import Timer, sample

from conftest import edit
from nc.test_linuxcnc import _require_interpreter


@pytest.fixture(scope="module")
def five_plan():
    return plan(load_config(sample_path("bc_table_5axis.toml")))


def _q_spline(curve, rot, kin, axes=("B", "C")):
    """Machine values of a read-back spline (X Y Z + rotary words) as one BSpline."""
    n = len(curve.control_points_mm)
    q = np.zeros((n, len(kin.names)))
    for col, name in enumerate("XYZ"):
        q[:, kin.index[name]] = curve.control_points_mm[:, col]
    for name in axes:
        q[:, kin.index[name]] = np.radians(rot[name])
    return BSpline(curve.knots, q, curve.degree, extrapolate=False)


def _interpreted(rec, kin, h) -> tuple[np.ndarray, float]:
    """Machine values (rad, mm) of the interpreter's feed moves, and the largest distance
    of the ball from the sphere along them (every block moves every axis linearly; the
    first move goes from an unknown position to the start and is not checked)."""
    raw = np.array([x[1:] for x in rec.test_feeds])        # x y z a b c
    q = np.zeros((len(raw), len(kin.names)))
    for col, axis in enumerate("XYZABC"):
        if axis in kin.index:
            q[:, kin.index[axis]] = np.radians(raw[:, col]) if axis in "ABC" else raw[:, col]
    t = np.linspace(0, 1, 9)[:, None, None]
    path = (q[:-1][None] * (1 - t) + q[1:][None] * t)[:, 1:].reshape(-1, len(kin.names))
    r = np.linalg.norm(kin.forward(path) - h.centre_mm, axis=1) - h.radius_mm
    return q, float(np.abs(r).max())


def _spline_radius_error(read, kin, h) -> float:
    """Largest distance of the ball from the sphere along a machine-frame 840D program's
    read-back splines, through the forward kinematics (mm)."""
    worst = 0.0
    for curve, rot in zip(read.splines, read.spline_rotary):
        spline = _q_spline(curve, rot, kin)
        lo, hi = curve.domain
        q = spline(np.linspace(lo, hi, 40 * len(curve.control_points_mm)))
        r = np.linalg.norm(kin.forward(q) - h.centre_mm, axis=1) - h.radius_mm
        worst = max(worst, float(np.abs(r).max()))
    return worst


@pytest.mark.slow
def test_traori_programs_keep_the_table_frame_path_on_the_sphere(five_plan):
    h = five_plan.hemisphere
    progs = [p for p in five_plan.programs if p.controller == "sinumerik840d"]
    assert [p.layer for p in progs] == list("ABCDE")
    for prog in progs:
        lines = prog.text.splitlines()
        assert "TRAORI" in lines and lines.index("TRAORI") < lines.index("TRAFOOF")
        assert lines[-1] == "M30"
        read = read_sinumerik(prog.text)
        assert read.traori
        for curve, rot in zip(read.splines, read.spline_rotary):
            assert set(rot) == {"B", "C"} and len(rot["C"]) == len(curve.control_points_mm)
            u = np.linspace(*curve.domain, 30 * len(curve.control_points_mm))
            r = np.linalg.norm(curve.evaluate(u) - h.centre_mm, axis=1) - h.radius_mm
            assert np.abs(r).max() <= 1e-5
        c = np.concatenate([rot["C"] for rot in read.spline_rotary])
        assert np.abs(np.diff(c)).max() < 5.0           # rotary words never jump
        assert 355 < c.max() - c.min() < 365            # C turns once with the bar


@pytest.mark.slow
def test_machine_mode_840d_spline_stays_on_the_sphere_through_fk():
    text = sample_path("bc_table_5axis.toml").read_text()
    text = edit(text, "five_axis_mode", '"machine"')
    text = edit(text, "track_elevations_deg", "[36.0, 72.0]")
    cfg = parse_config(text, "machine_mode.toml")
    result = plan(cfg)
    kin = Kinematics(cfg.machine)
    h = result.hemisphere
    prog = next(p for p in result.programs if p.controller == "sinumerik840d")
    assert "TRAORI" not in prog.text and prog.built.program.frame == "machine"
    read = read_sinumerik(prog.text)
    assert _spline_radius_error(read, kin, h) <= 1e-5
    m = manifest(result)
    assert {p["frame"]["name"] for p in m["programs"]} == {"machine"}


@pytest.mark.oracle
def test_linuxcnc_five_axis_programs_pass_the_interpreter_on_the_sphere(five_plan, tmp_path):
    _require_interpreter()
    from linuxcnc_oracle import interpret, ok

    cfg = five_plan.config
    kin = Kinematics(cfg.machine)
    h = five_plan.hemisphere
    tol = cfg.post.chord_tolerance_um * 1e-3
    for prog in (p for p in five_plan.programs if p.controller == "linuxcnc"):
        assert prog.built.program.frame == "machine"
        f = tmp_path / prog.file.replace("/", "_")
        f.write_text(prog.text)
        result, message, rec = interpret(str(f))
        assert ok(result), f"{prog.file}: {message}"
        _, worst = _interpreted(rec, kin, h)
        assert worst <= tol, (prog.file, worst)
        assert [s for _, s in rec.dwells] == [2.0] * len(
            next(x for x in five_plan.paths if x.layer == prog.layer).dwells)


def test_plan_json_says_which_frame(five_plan):
    m = manifest(five_plan)
    frames = {p["file"]: p["frame"]["name"] for p in m["programs"]}
    assert frames["sinumerik840d/SDIT5_A.MPF"] == "traori"
    assert frames["linuxcnc/SDIT5_A.ngc"] == "machine"
    json.dumps(m)


@pytest.mark.slow
def test_locked_schedule_on_the_five_axis_machine_sets_rotary_axes_once():
    text = edit(sample_path("bc_table_5axis.toml").read_text(), "schedule", '"locked"')
    text = edit(text, "track_elevations_deg", "[0.0, 45.0]")
    result = plan(parse_config(text, "locked.toml"))
    for prog in result.programs:
        assert prog.built.program.frame == "table"
        moves = [l for l in prog.text.splitlines() if l.startswith("G1 X")]
        assert " B0.000000 C0.000000 " in moves[0] + " "
        assert "TRAORI" not in prog.text and "G93" not in prog.text
    # machine Z = table z + tool length: the table frame is the bed frame at B = C = 0
    kin = Kinematics(result.config.machine)
    q = kin.inverse(np.array([[0.0, 0.0, 0.0]]), {"B": [0.0], "C": [0.0]})
    assert q[0, kin.index["Z"]] == pytest.approx(100.0)


TILTED = '\n[[test.curve.override]]\nsector = "A2"\ntilt_offset_deg = 12.0\n'


@pytest.mark.slow
@pytest.mark.oracle
def test_a_sectors_tilt_offset_tilts_only_its_patch_and_keeps_every_program_on_the_sphere(tmp_path):
    """``tilt_offset_deg`` (issue 17): over its sector's patch the table tilts away from
    the schedule, smoothly to zero at the patch's boundary (the nodes, the tracks); the
    ball's path, the timing and every other sector stay as they were; the 840D program in
    machine coordinates (through the forward kinematics) and the LinuxCNC program (through
    its interpreter) keep the ball on the sphere."""
    text = edit(sample_path("bc_table_5axis.toml").read_text(), "five_axis_mode", '"machine"')
    text = edit(text, "track_elevations_deg", "[36.0, 72.0]")
    base = plan(parse_config(text, "base.toml"))
    tilted = plan(parse_config(text + TILTED, "tilted.toml"))
    a, b = (sample(r.layers[0].timed, Timer(r.config), 1000.0) for r in (base, tilted))
    assert np.array_equal(a.t_s, b.t_s) and np.array_equal(a.ball_mm, b.ball_mm)
    kin = Kinematics(tilted.config.machine)
    tilt = a.axis_names.index("B")
    d = b.axes[:, tilt] - a.axes[:, tilt]
    inside = np.char.startswith(b.segment.astype(str), "A2-")
    assert np.abs(d[~inside]).max() < 1e-9
    assert 5.0 < d[inside].max() <= 12.0 and d[inside].min() >= 0.0
    # zero with zero slope where the sector meets its nodes
    edges = np.flatnonzero(np.diff(inside.astype(int)))
    for i in edges:
        assert abs(d[i]) < 1e-3 and abs(d[i + 1]) < 1e-3
    # the ball stays put: the tilt is taken up by the linear axes
    q = np.array([[np.radians(v) if u == "deg" else v for v, u in zip(row, b.axis_units)]
                  for row in b.axes[::50]])
    assert np.abs(kin.forward(q[:, [b.axis_names.index(n) for n in kin.names]])
                  - b.ball_mm[::50]).max() < 1e-6
    h = tilted.hemisphere
    prog = next(p for p in tilted.programs if p.controller == "sinumerik840d" and p.layer == "A")
    read = read_sinumerik(prog.text)
    assert _spline_radius_error(read, kin, h) <= 1e-5
    b_words = [np.asarray(rot["B"]) for rot in read.spline_rotary]
    plain = read_sinumerik(next(p for p in base.programs if p.controller == "sinumerik840d"
                                and p.layer == "A").text)
    moved = [np.abs(x - np.asarray(y["B"])).max() if len(x) == len(y["B"]) else np.inf
             for x, y in zip(b_words, plain.spline_rotary)]
    assert sum(m > 1.0 for m in moved) >= 2 and sum(m < 1e-9 for m in moved) >= 4
    _require_interpreter()
    from linuxcnc_oracle import interpret, ok

    tilts = []
    for result in (base, tilted):
        prog = next(p for p in result.programs if p.controller == "linuxcnc" and p.layer == "A")
        f = tmp_path / f"{len(tilts)}.ngc"
        f.write_text(prog.text)
        ran, message, rec = interpret(str(f))
        assert ok(ran), message
        q, worst = _interpreted(rec, kin, h)
        assert worst <= result.config.post.chord_tolerance_um * 1e-3
        tilts.append(np.degrees(q[:, kin.index["B"]]))
    # the interpreter's B leaves the base program's by most of the offset
    assert len(tilts[0]) == len(tilts[1]) and np.abs(tilts[1] - tilts[0]).max() > 5.0


def test_a_tilt_offset_on_a_locked_schedule_is_refused_in_one_line():
    from sdit_path.errors import ConfigError

    text = edit(sample_path("bc_table_5axis.toml").read_text(), "schedule", '"locked"')
    with pytest.raises(ConfigError) as e:
        parse_config(text + TILTED, "locked.toml")
    msg = str(e.value)
    assert "test.curve.override.tilt_offset_deg" in msg and "moving" in msg and "\n" not in msg
    with pytest.raises(ConfigError) as e:
        parse_config(text.replace('"locked"', '"moving"', 1) + TILTED.replace("12.0", "45.0"),
                     "steep.toml")
    assert "tilt_offset_deg" in str(e.value) and "30" in str(e.value)
