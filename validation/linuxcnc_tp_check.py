"""Our model of LinuxCNC's motion (:mod:`sdit_path.timing.linuxcnc_tp`) against the
real control, stretch by stretch (the motion between two dwells).

    python validation/linuxcnc_tp_check.py --plan DIR --program SDIT_E [--program ...]
        [--all] [--runs K] [--json OUT] [--keep DIR] [--reuse DIR]

Each program's LinuxCNC text (or its first ``--runs K`` stretches, the program cut
after the K-th and ended by M2) runs on the control (``linuxcnc_run.run_text``: every
axis' commanded position every 1 ms servo period) and through the model.  Both are cut
into stretches where the position stands still longer than half the shortest dwell;
each pair is aligned at its first moving sample.  Per stretch it prints the control's
duration and the model's (first to last moving sample, both counted), their
difference in ms and %, and the largest position difference over the aligned samples
(linear axes in um, rotary ones in mdeg; the shorter side held at its end); per
program the motion time both ways.  ``--keep DIR`` keeps each control run's folder
(``DIR/<program>/samples.txt``, ``program.ngc``), ``--reuse DIR`` checks the model
against such kept runs again without the control.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from linuxcnc_run import program_axes, run_text  # noqa: E402

from sdit_path.plan.files import load_plan  # noqa: E402
from sdit_path.timing.linuxcnc_tp import ControlLimits, simulate, stretches  # noqa: E402


def cut_program(text: str, runs: int, axes: tuple[str, ...]) -> str:
    """``text`` up to the end of its ``runs``-th stretch (its dwell included), then M2."""
    found = stretches(text, axes)
    if runs >= len(found):
        return text
    lines = text.splitlines()
    stop = found[runs - 1].last_line
    # keep the dwell that ends the stretch (a G94 may come between)
    for k in range(stop, min(len(lines), stop + 4)):
        if lines[k].strip().upper().startswith("G4"):
            stop = k + 1
            break
    body = lines[:stop] + ["M2"]
    if lines and lines[0].strip() == "%":
        body.append("%")
    return "\n".join(body) + "\n"


def control_stretches(position: np.ndarray, line: np.ndarray, min_gap: int
                      ) -> list[tuple[int, int]]:
    """[first, last] moving sample of every stretch of the control's run: moving samples
    (the position differs from the sample before) with stills shorter than ``min_gap``
    samples inside; the MDI move before the program (program line 0 throughout) is
    left out."""
    moving = np.flatnonzero(np.any(np.diff(position, axis=0) != 0.0, axis=1)) + 1
    if not len(moving):
        return []
    breaks = np.flatnonzero(np.diff(moving) > min_gap)
    firsts = np.r_[moving[0], moving[breaks + 1]]
    lasts = np.r_[moving[breaks], moving[-1]]
    return [(int(a), int(b)) for a, b in zip(firsts, lasts)
            if np.any(line[a:min(b + 2, len(line))] > 0)]


def compare_stretch(control: np.ndarray, model: np.ndarray, rotary: np.ndarray
                    ) -> tuple[float, float]:
    """Largest |difference| of two aligned runs ``(n, m)``, the shorter held at its end:
    (linear um, rotary mdeg)."""
    n = max(len(control), len(model))
    c = np.vstack([control, np.repeat(control[-1:], n - len(control), axis=0)])
    m = np.vstack([model, np.repeat(model[-1:], n - len(model), axis=0)])
    d = np.abs(c - m)
    lin = float(d[:, ~rotary].max()) * 1e3 if (~rotary).any() else 0.0
    rot = float(d[:, rotary].max()) * 1e3 if rotary.any() else 0.0
    return lin, rot


def check(name: str, text: str, axes: tuple[str, ...], limits: ControlLimits,
          position: np.ndarray, line: np.ndarray) -> dict:
    """The model against the control's ``position : (n, m)`` and ``line : (n,)``."""
    found = stretches(text, axes)
    dwells = [s.dwell_after_s for s in found[:-1] if s.dwell_after_s > 0]
    gap = max(50, int(0.5 * min(dwells, default=0.1) / limits.servo_period_s))
    ctrl = control_stretches(position, line, gap)
    if len(ctrl) != len(found):
        raise RuntimeError(f"{name}: the control made {len(ctrl)} stretches, the program "
                           f"has {len(found)}")
    rotary = np.array([a in "ABC" for a in axes])
    rows = []
    model_time = 0.0
    for k, (st, (a, b)) in enumerate(zip(found, ctrl)):
        shown = set(np.unique(line[a:b + 2]).tolist()) - {0}
        if shown and not shown <= set(st.line.tolist()):
            raise RuntimeError(f"{name}: control stretch {k} ran lines outside "
                               f"{st.first_line}-{st.last_line}")
        t0 = time.perf_counter()
        sim = simulate(st, limits)
        model_time += time.perf_counter() - t0
        moving = np.flatnonzero(sim.moving)
        ma, mb = int(moving[0]), int(moving[-1])
        ctrl_s = (b - a + 1) * limits.servo_period_s
        model_s = (mb - ma + 1) * limits.servo_period_s
        lin, rot = compare_stretch(position[a:b + 1], sim.position[ma:mb + 1], rotary)
        moves_rotary = bool(rotary.any() and np.any(np.ptp(
            np.vstack([st.start[None, :], st.end])[:, rotary], axis=0) > 0))
        kind = "rotary" if moves_rotary else ("xyz+arcs" if sim.blend_arc_lines else "xyz")
        rows.append({"stretch": k, "lines": [st.first_line, st.last_line], "kind": kind,
                     "blocks": len(st.end), "blend_arcs": len(sim.blend_arc_lines),
                     "control_s": ctrl_s, "model_s": model_s,
                     "diff_ms": (model_s - ctrl_s) * 1e3,
                     "diff_pct": (model_s - ctrl_s) / ctrl_s * 100.0,
                     "max_linear_um": lin, "max_rotary_mdeg": rot})
    c_tot = sum(r["control_s"] for r in rows)
    m_tot = sum(r["model_s"] for r in rows)
    kinds = {}
    for r in rows:
        g = kinds.setdefault(r["kind"], {"stretches": 0, "max_abs_diff_ms": 0.0,
                                         "max_abs_diff_pct": 0.0, "max_linear_um": 0.0,
                                         "max_rotary_mdeg": 0.0})
        g["stretches"] += 1
        g["max_abs_diff_ms"] = max(g["max_abs_diff_ms"], abs(r["diff_ms"]))
        g["max_abs_diff_pct"] = max(g["max_abs_diff_pct"], abs(r["diff_pct"]))
        g["max_linear_um"] = max(g["max_linear_um"], r["max_linear_um"])
        g["max_rotary_mdeg"] = max(g["max_rotary_mdeg"], r["max_rotary_mdeg"])
    return {"program": name, "axes": list(axes), "stretches": rows, "by_kind": kinds,
            "motion_control_s": c_tot, "motion_model_s": m_tot,
            "motion_diff_pct": (m_tot - c_tot) / c_tot * 100.0 if c_tot else math.nan,
            "model_run_s": model_time}


def print_check(c: dict) -> None:
    print(f"{c['program']} ({''.join(c['axes'])}): motion control {c['motion_control_s']:.3f} s, "
          f"model {c['motion_model_s']:.3f} s ({c['motion_diff_pct']:+.3f} %); model ran "
          f"{c['model_run_s']:.2f} s")
    print(f"  {'#':>3} {'lines':<11} {'kind':<9}{'blocks':>7}{'arcs':>5}{'control s':>11}"
          f"{'model s':>10}{'diff ms':>9}{'diff %':>9}{'lin um':>9}{'rot mdeg':>10}")
    for r in c["stretches"]:
        lines = f"{r['lines'][0]}-{r['lines'][1]}"
        print(f"  {r['stretch']:>3} {lines:<11} {r['kind']:<9}{r['blocks']:>7}"
              f"{r['blend_arcs']:>5}{r['control_s']:>11.3f}{r['model_s']:>10.3f}"
              f"{r['diff_ms']:>+9.0f}{r['diff_pct']:>+9.3f}{r['max_linear_um']:>9.3f}"
              f"{r['max_rotary_mdeg']:>10.3f}")
    for kind, g in c["by_kind"].items():
        print(f"  {kind}: {g['stretches']} stretches, |diff| <= {g['max_abs_diff_ms']:.0f} ms "
              f"({g['max_abs_diff_pct']:.3f} %), position <= {g['max_linear_um']:.3f} um, "
              f"{g['max_rotary_mdeg']:.3f} mdeg")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plan", required=True, type=Path)
    ap.add_argument("--program", action="append", default=[])
    ap.add_argument("--all", action="store_true", help="every LinuxCNC program of the plan")
    ap.add_argument("--runs", type=int, default=0, help="only the first K stretches")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep each control run's folder here (DIR/<program>/)")
    ap.add_argument("--reuse", type=Path, default=None,
                    help="read the control runs kept by --keep instead of running it")
    a = ap.parse_args()
    plan = load_plan(a.plan)
    entries = [p for p in plan.manifest["programs"] if p["controller"] == "linuxcnc"]
    names = [p["name"] for p in entries] if a.all else a.program
    if not names:
        ap.error("name a --program or give --all")
    results = []
    for name in names:
        entry = next(p for p in entries if p["name"] == name)
        axes = program_axes(plan, name)
        limits = ControlLimits.from_machine(plan.config.machine, axes)
        if a.reuse:
            folder = a.reuse / name
            text = (folder / "program.ngc").read_text(encoding="utf-8")
            data = np.loadtxt(folder / "samples.txt")
            position, line = data[:, 1:1 + len(axes)], data[:, 1 + len(axes)].astype(int)
        else:
            text = (plan.directory / entry["file"]).read_text(encoding="utf-8")
            if a.runs:
                text = cut_program(text, a.runs, axes)
            budget = sum(simulate(s, limits).duration_s + s.dwell_after_s
                         for s in stretches(text, axes))
            with tempfile.TemporaryDirectory(prefix="sdit-tp-") as tmp:
                work = (a.keep / name) if a.keep else Path(tmp)
                position, line = run_text(plan, text, axes, work, 1.5 * budget + 60.0)
        c = check(name, text, axes, limits, position, line)
        print_check(c)
        results.append(c)
        if a.json:
            a.json.write_text(json.dumps(results, indent=1) + "\n")
    if len(results) > 1:
        c_tot = sum(r["motion_control_s"] for r in results)
        m_tot = sum(r["motion_model_s"] for r in results)
        print(f"all: motion control {c_tot:.3f} s, model {m_tot:.3f} s "
              f"({(m_tot - c_tot) / c_tot * 100:+.3f} %)")


if __name__ == "__main__":
    main()
