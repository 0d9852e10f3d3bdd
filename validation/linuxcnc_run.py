"""Our LinuxCNC programs run on LinuxCNC itself: its interpreter, its trajectory planner
and its motion controller (Debian's ``linuxcnc-uspace``, headless, a simulated machine
with the plan's axes and limits), the commanded position of every axis sampled every
1 ms servo period, and compared with the plan's timed trajectory.

    python validation/linuxcnc_run.py --plan DIR --program SDIT_E [--program ...]
        [--json OUT] [--motion-dir DIR [--reuse]]
    python validation/linuxcnc_run.py --plan DIR --all [--json OUT]
    python validation/linuxcnc_run.py --plan DIR --plan DIR2 --all --motion-dir RUNS
    python validation/linuxcnc_run.py --config samples/vmc_3axis.toml
        --config samples/bc_table_5axis.toml --json validation/results/linuxcnc.json
    python validation/linuxcnc_run.py --rescore validation/results/linuxcnc.json

A second ``--plan`` (the same programs timed otherwise, ``timing.control``) is compared
with the same motion; ``--config`` plans a config both ways itself (as it is, and
LinuxCNC alone with ``timing.control = "linuxcnc"``) and runs every LinuxCNC program;
``--reuse`` reads the runs kept in ``--motion-dir`` again instead of running the
control; ``--rescore`` prints the campaign's table from its JSON.

Per run (the motion between two dwells at static nodes) it prints the control's
duration and ours, the lowest speed while cruising over the feed, and how far the
control's commanded path leaves the sphere and our planned curve; per program the
cycle (the dwells follow the wall clock, 2 ms or so long each: the runs do not).

How the control runs (facts of LinuxCNC 2.9 in POSIX non-realtime mode, checked here):
``rtapi_app`` refuses to run as root without ``RTAPI_UID`` (a non-root uid it runs the
real-time part as) and needs ``RTAPI_FIFO_PATH``, the path of its socket (not a
folder), where that uid may create it; the servo thread is an ordinary 1 ms thread
but motion advances exactly one servo period per tick, so the sampled motion is exact
in control time; ``G4`` dwells follow the wall clock.  Only one LinuxCNC may run on a
machine (its lock file ``/tmp/linuxcnc.lock``): the runner refuses to start while
another holds it.  The display is a script of ours that resets the estop, switches the
machine on, homes every joint where it stands, moves to the program's first pose by
MDI, runs the program and waits until it has ended and the machine is in position.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from sdit_path.machine.kinematics import Kinematics  # noqa: E402
from sdit_path.plan.files import PlanFiles, load_plan  # noqa: E402
from sdit_path.program_marks import TEST_ENDS  # noqa: E402

LOCK = Path("/tmp/linuxcnc.lock")
SERVO_S = 0.001
#: the uid the real-time part runs as when we are root (Debian's ``nobody``)
FALLBACK_UID = 65534

DRIVER = r'''#!/usr/bin/python3
"""The display of one run: estop reset, machine on, home in place, MDI to the first
pose, run the program, wait until it has ended in position (exit 3 on any error the
control reports)."""
import os, subprocess, sys, time
import linuxcnc

# the sampler's FIFO holds every servo period since the HAL was loaded: read from now on
sampler = subprocess.Popen(["halsampler", "-c", "0", "-t"],
                           stdout=open(os.environ["SDIT_SAMPLES"], "w"))
s, c, e = linuxcnc.stat(), linuxcnc.command(), linuxcnc.error_channel()


def fail(msg):
    print("SDIT-ERROR " + str(msg), flush=True)
    sys.exit(3)


def check():
    err = e.poll()
    if err:
        fail(err[1])


def settle(timeout):
    end = time.time() + timeout
    time.sleep(0.05)
    while time.time() < end:
        s.poll()
        check()
        if s.interp_state == linuxcnc.INTERP_IDLE and s.queue == 0 and s.inpos:
            return
        if s.interp_state == linuxcnc.INTERP_PAUSED or s.paused:
            # a program stop (M0: mount the bar, take it off): the operator's cycle start
            c.auto(linuxcnc.AUTO_RESUME)
        time.sleep(0.01)
    fail("the control did not finish within %.0f s" % timeout)


c.state(linuxcnc.STATE_ESTOP_RESET); c.wait_complete(10)
c.state(linuxcnc.STATE_ON); c.wait_complete(10)
c.mode(linuxcnc.MODE_MANUAL); c.wait_complete(10)
c.teleop_enable(0); c.wait_complete(10)
c.home(-1); c.wait_complete(10)
end = time.time() + 20
while True:
    s.poll()
    check()
    if all(s.joint[j]["homed"] for j in range(s.joints)):
        break
    if time.time() > end:
        fail("the joints did not home")
    time.sleep(0.02)
c.teleop_enable(1); c.wait_complete(10)
c.mode(linuxcnc.MODE_MDI); c.wait_complete(10)
c.mdi(os.environ["SDIT_FIRST_POSE"]); c.wait_complete(10)
settle(120)
c.mode(linuxcnc.MODE_AUTO); c.wait_complete(10)
c.program_open(os.environ["SDIT_PROGRAM"]); c.wait_complete(10)
c.auto(linuxcnc.AUTO_RUN, 0)
settle(float(os.environ["SDIT_TIMEOUT_S"]))
time.sleep(0.3)
sampler.terminate()
sampler.wait()
print("SDIT-DONE", flush=True)
'''


@dataclass(frozen=True)
class ControlRun:
    """The control's motion from the program's first dwell on: ``t_s : (n,)`` control
    time (0 at the first dwell's start), ``position : (n, m)`` the commanded axis values
    in program coordinates (mm, deg), ``line : (n,)`` the program line executing."""

    program: str
    axes: tuple[str, ...]
    t_s: np.ndarray
    position: np.ndarray
    line: np.ndarray


def _ini(plan: PlanFiles, work: Path, axes: tuple[str, ...]) -> str:
    m = plan.config.machine
    lines = ["[EMC]", "VERSION = 1.1", "MACHINE = sdit-path-run", "DEBUG = 0",
             "[DISPLAY]", f"DISPLAY = {work / 'drive.py'}", "CYCLE_TIME = 0.05",
             "[TASK]", "TASK = milltask", "CYCLE_TIME = 0.001",
             "[RS274NGC]", f"PARAMETER_FILE = {work / 'run.var'}",
             "[EMCMOT]", "EMCMOT = motmod", "COMM_TIMEOUT = 1.0",
             f"SERVO_PERIOD = {int(SERVO_S * 1e9)}",
             "[EMCIO]", "EMCIO = io", "CYCLE_TIME = 0.100", f"TOOL_TABLE = {work / 'run.tbl'}",
             "[HAL]", f"HALFILE = {work / 'run.hal'}",
             "[TRAJ]", f"COORDINATES = {''.join(axes)}", "LINEAR_UNITS = mm",
             "ANGULAR_UNITS = degree", "DEFAULT_LINEAR_VELOCITY = 10"]
    lin = [m.axis(a) for a in axes if not m.axis(a).is_rotary]
    lines += [f"MAX_LINEAR_VELOCITY = {max(a.max_velocity for a in lin):g}",
              f"MAX_LINEAR_ACCELERATION = {max(a.max_acceleration for a in lin):g}"]
    lines += ["[KINS]", f"JOINTS = {len(axes)}",
              f"KINEMATICS = trivkins coordinates={''.join(axes)}"]
    for j, name in enumerate(axes):
        ax = m.axis(name)
        lo, hi = (ax.to_display(v) for v in ax.travel)
        # the sampled limits as the config gives them, in mm or deg
        vel, acc = ax.to_display(ax.max_velocity), ax.to_display(ax.max_acceleration)
        block = [f"MIN_LIMIT = {lo - 1:g}", f"MAX_LIMIT = {hi + 1:g}",
                 f"MAX_VELOCITY = {vel:g}", f"MAX_ACCELERATION = {acc:g}"]
        lines += [f"[AXIS_{name}]", *block,
                  f"[JOINT_{j}]", f"TYPE = {'ANGULAR' if ax.is_rotary else 'LINEAR'}", *block,
                  "HOME_SEQUENCE = 0", "HOME_SEARCH_VEL = 0", "HOME_LATCH_VEL = 0", "HOME = 0"]
    return "\n".join(lines) + "\n"


def _hal(axes: tuple[str, ...]) -> str:
    n = len(axes)
    lines = ["loadrt [KINS]KINEMATICS",
             "loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD "
             "num_joints=[KINS]JOINTS",
             f"loadrt sampler depth=262144 cfg={'f' * n}s",
             "addf motion-command-handler servo-thread",
             "addf motion-controller servo-thread",
             "addf sampler.0 servo-thread"]
    lines += [f"net j{j} joint.{j}.motor-pos-cmd => joint.{j}.motor-pos-fb" for j in range(n)]
    lines += [f"net s{j} axis.{a.lower()}.pos-cmd => sampler.0.pin.{j}"
              for j, a in enumerate(axes)]
    lines += [f"net line motion.program-line => sampler.0.pin.{n}",
              "net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in",
              "net tool-prep-loop iocontrol.0.tool-prepare => iocontrol.0.tool-prepared",
              "net tool-change-loop iocontrol.0.tool-change => iocontrol.0.tool-changed"]
    return "\n".join(lines) + "\n"


def _first_pose(text: str) -> str:
    """The MDI move to the program's first programmed pose (its first G1)."""
    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith("G1 ") and " X" in f" {line}":
            words = re.findall(r"([XYZABC])(-?\d+\.?\d*)", line)
            return "G21 G90 G0 " + " ".join(f"{a}{v}" for a, v in words)
    raise ValueError("no G1 move in the program")


def _remove_orphaned_segments() -> None:
    """Shared memory a killed LinuxCNC left behind (HAL's and the sampler's keys, no
    process attached): a sampler segment of another size makes the next run's sampler
    fail to load."""
    try:
        table = subprocess.run(["ipcs", "-m"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return
    for row in table.splitlines():
        cols = row.split()
        if len(cols) >= 6 and cols[0].lower().startswith(("0x4853", "0x4841")) and cols[5] == "0":
            subprocess.run(["ipcrm", "-m", cols[1]], capture_output=True, check=False)


def run_text(plan: PlanFiles, text: str, axes: tuple[str, ...], work: Path,
             timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Any program ``text`` run on the control as the machine of ``plan`` with the
    coordinates ``axes``: every servo period's commanded position ``(n, m)`` (mm, deg)
    and executing program line ``(n,)``, from the HAL's start."""
    if LOCK.exists():
        raise RuntimeError(f"another LinuxCNC runs here ({LOCK} exists); refusing to start")
    if shutil.which("linuxcnc") is None:
        raise RuntimeError("LinuxCNC is not installed (Debian's linuxcnc-uspace)")
    _remove_orphaned_segments()
    work.mkdir(parents=True, exist_ok=True)
    os.chmod(work, 0o777)  # the real-time part (RTAPI_UID) creates its socket here
    (work / "program.ngc").write_text(text, encoding="utf-8")
    for f in ("run.var", "run.tbl"):
        (work / f).write_text("", encoding="utf-8")
        os.chmod(work / f, 0o666)
    (work / "run.ini").write_text(_ini(plan, work, axes), encoding="utf-8")
    (work / "run.hal").write_text(_hal(axes), encoding="utf-8")
    driver = work / "drive.py"
    driver.write_text(DRIVER, encoding="utf-8")
    driver.chmod(0o755)
    samples = work / "samples.txt"
    # the socket's folder: one the real-time part's uid can reach (``work`` may sit
    # under a folder only we may enter, as pytest's do)
    sockets = Path(tempfile.mkdtemp(prefix="sdit-rtapi-"))
    os.chmod(sockets, 0o777)
    env = {**os.environ, "SDIT_PROGRAM": str(work / "program.ngc"),
           "SDIT_FIRST_POSE": _first_pose(text), "SDIT_TIMEOUT_S": f"{timeout_s:.0f}",
           "RTAPI_FIFO_PATH": str(sockets / "rtapi.fifo"), "SDIT_SAMPLES": str(samples)}
    if os.geteuid() == 0:
        env["RTAPI_UID"] = str(FALLBACK_UID)
    try:
        proc = subprocess.Popen(["linuxcnc", "-r", str(work / "run.ini")], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                cwd=work)
        try:
            log, _ = proc.communicate(timeout=timeout_s + 120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    finally:
        shutil.rmtree(sockets, ignore_errors=True)
    (work / "linuxcnc.log").write_text(log, encoding="utf-8")
    if "SDIT-DONE" not in log:
        why = re.search(r"SDIT-ERROR (.*)", log)
        raise RuntimeError(f"the control did not run it: {why.group(1) if why else log[-800:]}")
    data = np.loadtxt(samples)
    if data.ndim != 2 or not len(data):
        raise RuntimeError("no samples")
    if np.any(np.diff(data[:, 0].astype(np.int64)) != 1):
        raise RuntimeError("the sampler lost samples")
    return data[:, 1:1 + len(axes)], data[:, 1 + len(axes)].astype(int)


def program_axes(plan: PlanFiles, program: str) -> tuple[str, ...]:
    """The coordinates ``program``'s LinuxCNC text moves: XYZ in the table frame, the
    machine's axes otherwise."""
    entry = next(p for p in plan.manifest["programs"]
                 if p["name"] == program and p["controller"] == "linuxcnc")
    if entry["frame"]["name"] == "table":
        return ("X", "Y", "Z")
    return tuple(plan.trajectory(program).axis_names)


def program_text(plan: PlanFiles, program: str) -> str:
    entry = next(p for p in plan.manifest["programs"]
                 if p["name"] == program and p["controller"] == "linuxcnc")
    return (plan.directory / entry["file"]).read_text(encoding="utf-8")


def kept(plan: PlanFiles, program: str, work: Path) -> tuple[np.ndarray, np.ndarray]:
    """The samples of a run kept in ``work`` (``--motion-dir``); it must have run the
    plan's text of ``program``."""
    if (work / "program.ngc").read_text(encoding="utf-8") != program_text(plan, program):
        raise RuntimeError(f"{work}: the control ran another text than the plan's {program}")
    axes = program_axes(plan, program)
    data = np.loadtxt(work / "samples.txt")
    return data[:, 1:1 + len(axes)], data[:, 1 + len(axes)].astype(int)


def control_run(plan: PlanFiles, program: str, position: np.ndarray, line: np.ndarray
                ) -> ControlRun:
    """The control's samples of ``program`` on the plan's clock."""
    axes = program_axes(plan, program)
    # a dwell is the task's, not the motion's: the motion's program line is 0 until the
    # first run after the first dwell moves; that sample is our first run's start
    # (the operator's way to the bar before the first dwell, and back after the comment
    # that ends the test, are left out)
    text = program_text(plan, program).splitlines()
    first_dwell = next(n for n, raw in enumerate(text, start=1) if raw.startswith("G4 "))
    end_line = next((n for n, raw in enumerate(text, start=1) if TEST_ENDS in raw.lower()),
                    len(text) + 1)
    moved = np.flatnonzero(line > first_dwell)
    if not len(moved):
        raise RuntimeError(f"{program}: the control never moved along the program")
    traj = plan.trajectory(program)
    first_run = float(traj.t_s[np.flatnonzero(traj.phase != "dwell")[0]])
    k = max(0, moved[0] - int(round(first_run / SERVO_S)))
    after = np.flatnonzero((line > end_line) & (np.arange(len(line)) > moved[0]))
    stop = after[0] if len(after) else len(line)
    t = (np.arange(k, stop) - moved[0]) * SERVO_S + first_run
    return ControlRun(program, axes, t, position[k:stop], line[k:stop])


def write_motion(run_: ControlRun, path: Path) -> None:
    """The control's motion as CSV: control time (s, 0 where our plan starts), every
    axis' commanded value (mm, deg) per 1 ms servo period, the program line executing."""
    cols = ["t_s", *(f"axis_{a}" for a in run_.axes), "line"]
    rows = [",".join(cols)]
    for t, p, ln in zip(run_.t_s, run_.position, run_.line):
        rows.append(f"{t:.3f}," + ",".join(f"{v:.6f}" for v in p) + f",{int(ln)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


# ------------------------------------------------------------------------- comparing

def _ball(plan: PlanFiles, run_: ControlRun, table_frame: bool) -> np.ndarray:
    """The ball centre in the table frame at every sample."""
    if table_frame:
        return run_.position[:, :3]
    kin = Kinematics(plan.config.machine)
    q = np.zeros((len(run_.t_s), len(kin.names)))
    for col, name in enumerate(run_.axes):
        ax = kin.axes[kin.index[name]]
        q[:, kin.index[name]] = np.radians(run_.position[:, col]) if ax.is_rotary else \
            run_.position[:, col]
    return kin.forward(q)


def _stills(t: np.ndarray, p: np.ndarray, min_s: float) -> list[tuple[int, int]]:
    """[start, end) index ranges where the commanded position does not change for at
    least ``min_s``."""
    moving = np.r_[True, np.any(np.abs(np.diff(p, axis=0)) > 1e-9, axis=1)]
    out, k, n = [], 0, len(t)
    while k < n:
        if moving[k]:
            k += 1
            continue
        j = k
        while j < n and not moving[j]:
            j += 1
        if t[min(j, n - 1)] - t[k] >= min_s:
            out.append((k - 1 if k else 0, j))
        k = j
    return out


def _to_polyline(points: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Distance (mm) of every point ``q`` to the polyline ``points``."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    _, i = tree.query(q)
    best = np.full(len(q), np.inf)
    for a, b in ((i - 1, i), (i, i + 1)):
        a, b = np.clip(a, 0, len(points) - 1), np.clip(b, 0, len(points) - 1)
        pa, pb = points[a], points[b]
        d = pb - pa
        L2 = np.maximum((d * d).sum(1), 1e-300)
        u = np.clip(((q - pa) * d).sum(1) / L2, 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(pa + u[:, None] * d - q, axis=1))
    return best


def compare(plan: PlanFiles, run_: ControlRun) -> dict:
    """Run by run, the control's motion against the plan's timed trajectory."""
    entry = next(p for p in plan.manifest["programs"]
                 if p["name"] == run_.program and p["controller"] == "linuxcnc")
    traj = plan.trajectory(run_.program)
    cfg = plan.config
    pivot, radius = np.array(cfg.ballbar.pivot_mm), cfg.ballbar.bar_length_mm
    ball = _ball(plan, run_, entry["frame"]["name"] == "table")
    dt = SERVO_S
    speed = np.r_[0.0, np.linalg.norm(np.diff(ball, axis=0), axis=1) / dt]
    # our runs: between dwells; the control's: between the standstills of the dwells
    dwell = traj.phase == "dwell"
    ours = []
    edges = np.flatnonzero(np.diff(dwell.astype(int)))
    starts, ends = edges[dwell[edges]] + 1, edges[~dwell[edges]] + 1  # run start, run end
    for a in starts:
        b = ends[ends > a]
        if len(b):
            ours.append((a, b[0]))
    stills = _stills(run_.t_s, ball, min_s=0.5 * cfg.test.dwell_s)
    theirs = [(s0[1], s1[0]) for s0, s1 in zip(stills, stills[1:])]
    feed = cfg.test.feed_mm_per_min / 60.0
    runs = []
    for (a, b), (c, d) in zip(ours, theirs):
        seg = str(traj.segment[(a + b) // 2])
        ours_s, theirs_s = float(traj.t_s[b] - traj.t_s[a]), float(run_.t_s[d] - run_.t_s[c])
        p = ball[c:d]
        r = np.linalg.norm(p - pivot, axis=1) - radius
        curve = _to_polyline(traj.ball_mm[a:b + 1], p)
        v = speed[c:d]
        own = float(np.max(traj.speed_mm_per_s[a:b])) if b > a else feed
        # cruising: away from the stops by the distance the slowest ramp takes
        cruise = v[(np.arange(len(v)) > 200) & (np.arange(len(v)) < len(v) - 200)]
        runs.append({"segment": seg, "ours_s": ours_s, "control_s": theirs_s,
                     "ratio": theirs_s / ours_s if ours_s > 0 else math.nan,
                     "planned_speed_mm_s": own,
                     "min_cruise_speed_mm_s": float(cruise.min()) if len(cruise) else math.nan,
                     "max_from_sphere_um": float(np.max(np.abs(r)) * 1e3),
                     "max_from_curve_um": float(np.max(curve) * 1e3)})
    ours_cycle, theirs_cycle = float(traj.t_s[-1]), float(run_.t_s[stills[-1][1] - 1]) \
        if stills else float(run_.t_s[-1])
    motion_ours = sum(r["ours_s"] for r in runs)
    motion_theirs = sum(r["control_s"] for r in runs)
    return {"program": run_.program, "runs": runs,
            "dwells_control": len(stills), "dwells_planned": len(ours) + 1,
            "cycle_planned_s": ours_cycle, "cycle_control_s": theirs_cycle,
            "motion_planned_s": motion_ours, "motion_control_s": motion_theirs,
            "motion_ratio": motion_theirs / motion_ours if motion_ours else math.nan,
            "max_from_sphere_um": max((r["max_from_sphere_um"] for r in runs), default=0.0),
            "max_from_curve_um": max((r["max_from_curve_um"] for r in runs), default=0.0)}


def print_comparison(c: dict) -> None:
    print(f"{c['program']}: cycle control {c['cycle_control_s']:.2f} s, planned "
          f"{c['cycle_planned_s']:.2f} s; motion control {c['motion_control_s']:.2f} s, planned "
          f"{c['motion_planned_s']:.2f} s (ratio {c['motion_ratio']:.3f}); dwells "
          f"{c['dwells_control']} of {c['dwells_planned']}; from the sphere at most "
          f"{c['max_from_sphere_um']:.3f} um, from the planned curve "
          f"{c['max_from_curve_um']:.3f} um")
    print(f"  {'run':<10}{'planned s':>10}{'control s':>10}{'ratio':>8}{'feed mm/s':>10}"
          f"{'min cruise':>11}{'sphere um':>10}{'curve um':>9}")
    for r in c["runs"]:
        print(f"  {r['segment']:<10}{r['ours_s']:>10.3f}{r['control_s']:>10.3f}"
              f"{r['ratio']:>8.4f}{r['planned_speed_mm_s']:>10.2f}"
              f"{r['min_cruise_speed_mm_s']:>11.2f}{r['max_from_sphere_um']:>10.3f}"
              f"{r['max_from_curve_um']:>9.3f}")


def print_summary(results: list[dict]) -> None:
    """The worst run and the cycles of the programs compared with one plan."""
    if not results:
        return
    worst = max((r for c in results for r in c["runs"]), key=lambda r: abs(r["ratio"] - 1.0))
    cycles = [c["cycle_control_s"] / c["cycle_planned_s"] for c in results]
    motions = [c["motion_ratio"] for c in results]
    ratios = [r["ratio"] for c in results for r in c["runs"]]
    print(f"  {len(results)} program(s): control / planned per run {min(ratios):.4f}.."
          f"{max(ratios):.4f} (worst {worst['segment']}), motion {min(motions):.4f}.."
          f"{max(motions):.4f}, cycle {min(cycles):.4f}..{max(cycles):.4f}")


def table(results: dict[str, dict[str, list[dict]]]) -> None:
    """The campaign's figures: per sample and timing, each program's cycle and motion on
    the control against the plan, the runs' spread, the slowest cruise and the path's
    distance from the sphere and the planned curve."""
    print(f"{'program':<10}{'timing':<14}{'cycle ctl s':>12}{'planned s':>11}{'ratio':>8}"
          f"{'motion':>8}{'runs min..max':>16}{'cruise':>8}{'sphere':>8}{'curve':>7}")
    print(f"{'':<10}{'':<14}{'':>12}{'':>11}{'':>8}{'ratio':>8}{'':>16}{'mm/s':>8}"
          f"{'um':>8}{'um':>7}")
    for sample, timings in results.items():
        print(f"{sample}:")
        plans = {k: v for k, v in timings.items() if k != "model"}
        programs = [c["program"] for c in next(iter(plans.values()))]
        for name in programs:
            for timing, rows in plans.items():
                c = next(c for c in rows if c["program"] == name)
                ratios = [r["ratio"] for r in c["runs"]]
                cruise = min((r["min_cruise_speed_mm_s"] for r in c["runs"]
                              if not math.isnan(r["min_cruise_speed_mm_s"])), default=math.nan)
                print(f"{name:<10}{timing:<14}{c['cycle_control_s']:>12.2f}"
                      f"{c['cycle_planned_s']:>11.2f}"
                      f"{c['cycle_control_s'] / c['cycle_planned_s']:>8.4f}"
                      f"{c['motion_ratio']:>8.4f}{min(ratios):>8.4f}..{max(ratios):<6.4f}"
                      f"{cruise:>8.2f}{c['max_from_sphere_um']:>8.3f}"
                      f"{c['max_from_curve_um']:>7.3f}")


def _model_check(plan: PlanFiles, name: str, text: str, position: np.ndarray,
                 line: np.ndarray) -> dict | None:
    """Our model of LinuxCNC's planner (``timing.control = "linuxcnc"``) against the
    control's samples of ``name``, stretch by stretch and period by period
    (``linuxcnc_tp_check.check``), in brief."""
    import linuxcnc_tp_check

    from sdit_path.timing.linuxcnc_tp import ControlLimits

    axes = program_axes(plan, name)
    c = linuxcnc_tp_check.check(name, text, axes,
                                ControlLimits.from_machine(plan.config.machine, axes),
                                position, line)
    rows = c["stretches"]
    return {"program": name, "stretches": len(rows),
            "motion_control_s": c["motion_control_s"], "motion_model_s": c["motion_model_s"],
            "max_abs_diff_ms": max(abs(r["diff_ms"]) for r in rows),
            "max_linear_um": max(r["max_linear_um"] for r in rows),
            "max_rotary_mdeg": max(r["max_rotary_mdeg"] for r in rows)}


def model_table(results: dict[str, dict[str, list[dict]]]) -> None:
    """Per program: the model of LinuxCNC's planner against the control."""
    print(f"{'program':<10}{'stretches':>10}{'motion ctl s':>14}{'model s':>10}"
          f"{'|dt| ms':>9}{'position um':>13}{'rotary mdeg':>13}")
    for sample, timings in results.items():
        for m in timings.get("model", []):
            print(f"{m['program']:<10}{m['stretches']:>10}{m['motion_control_s']:>14.3f}"
                  f"{m['motion_model_s']:>10.3f}{m['max_abs_diff_ms']:>9.0f}"
                  f"{m['max_linear_um']:>13.3f}{m['max_rotary_mdeg']:>13.3f}")


def _variant(config: Path, folder: Path) -> Path:
    """``config`` timed as LinuxCNC runs it: the same file name (the programs' headers
    name it), LinuxCNC alone, ``timing.control = "linuxcnc"``."""
    import tomllib

    text = config.read_text(encoding="utf-8")
    data = tomllib.loads(text)
    if "timing" in data:
        raise SystemExit(f"{config}: has a [timing] table; give a config without one")
    listed = re.search(r'(?m)^controllers\s*=.*$', text)
    if not listed:
        raise SystemExit(f"{config}: no post.controllers line to replace")
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / config.name
    out.write_text(text[:listed.start()] + 'controllers = ["linuxcnc"]' + text[listed.end():]
                   + '\n[timing]\ncontrol = "linuxcnc"\n', encoding="utf-8")
    return out


def _plan(config: Path, out: Path) -> Path:
    subprocess.run([sys.executable, "-m", "sdit_path", "plan", str(config), "--out", str(out),
                    "--force", "-q"], check=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--plan", type=Path, action="append",
                     help="the plan whose programs run; again: further plans of the same "
                          "program texts (another timing) compared with the same motion")
    src.add_argument("--config", type=Path, action="append",
                     help="a sample or config: planned twice (as it is, and timed as "
                          "LinuxCNC runs it), every LinuxCNC program run once and compared "
                          "with both")
    src.add_argument("--rescore", type=Path, help="print the table of a --json file again")
    ap.add_argument("--program", action="append", default=[])
    ap.add_argument("--all", action="store_true", help="every LinuxCNC program of the plan")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--motion-dir", type=Path, default=None,
                    help="keep each run's folder (the control's samples, its log) here")
    ap.add_argument("--reuse", action="store_true",
                    help="read the runs kept in --motion-dir instead of running the control")
    a = ap.parse_args()
    if a.rescore:
        results = json.loads(a.rescore.read_text(encoding="utf-8"))
        table(results)
        print()
        model_table(results)
        return
    if a.reuse and not a.motion_dir:
        ap.error("--reuse reads the runs kept in --motion-dir: name it")
    results: dict[str, dict[str, list[dict]]] = {}
    with tempfile.TemporaryDirectory(prefix="sdit-campaign-") as scratch:
        if a.config:
            groups = []
            for k, config in enumerate(a.config):
                base = Path(scratch) / f"{k}"
                modelled = _plan(_variant(config, base / "variant"), base / "linuxcnc")
                groups.append((config.stem, [modelled, _plan(config, base / "jerk")]))
            everything = True
        else:
            groups = [(a.plan[0].name, a.plan)]
            everything = a.all
        for sample, paths in groups:
            plans = [load_plan(p) for p in paths]
            results[sample] = _compare_all(plans, everything, a, sample)
            if a.json:
                a.json.write_text(json.dumps(results, indent=1) + "\n")
    for sample, timings in results.items():
        for timing, rows in timings.items():
            if timing != "model":
                print(f"summary {sample}, timing.control = {timing}")
                print_summary(rows)


def _compare_all(plans: list[PlanFiles], everything: bool, a, sample: str
                 ) -> dict[str, list[dict]]:
    plan = plans[0]
    names = [p["name"] for p in plan.manifest["programs"] if p["controller"] == "linuxcnc"] \
        if everything else a.program
    if not names:
        raise SystemExit("name a --program or give --all")
    out: dict[str, list[dict]] = {p.config.timing.control: [] for p in plans}
    if len(out) != len(plans):
        raise SystemExit("the plans compared must differ in timing.control")
    for name in names:
        text = program_text(plan, name)
        for other in plans[1:]:
            if program_text(other, name) != text:
                raise SystemExit(f"{other.directory}: its {name} is another text")
        with tempfile.TemporaryDirectory(prefix="sdit-lcnc-") as tmp:
            folder = (a.motion_dir / sample) if a.motion_dir and a.config else a.motion_dir
            work = (folder / name) if folder else Path(tmp)
            if a.reuse:
                position, line = kept(plan, name, work)
            else:
                entry = next(p for p in plan.manifest["programs"]
                             if p["name"] == name and p["controller"] == "linuxcnc")
                limit = 3.0 * float(entry.get("cycle_time_s") or 600.0) + 60.0
                position, line = run_text(plan, text, program_axes(plan, name), work, limit)
        model = _model_check(plan, name, text, position, line)
        if model is not None:
            print(f"[{sample}, the planner's model against the control, period by period] "
                  f"motion {model['motion_model_s']:.3f} s against {model['motion_control_s']:.3f} s, "
                  f"stretches within {model['max_abs_diff_ms']:.0f} ms, positions within "
                  f"{model['max_linear_um']:.3f} um, {model['max_rotary_mdeg']:.3f} mdeg")
            out.setdefault("model", []).append(model)
        for k, other in enumerate(plans):
            motion = control_run(other, name, position, line)
            if k == 0 and folder and not a.reuse:
                write_motion(motion, folder / f"{name}.motion.csv")
            print(f"[{sample}, timing.control = {other.config.timing.control}]")
            c = compare(other, motion)
            print_comparison(c)
            out[other.config.timing.control].append(c)
    return out


if __name__ == "__main__":
    main()
