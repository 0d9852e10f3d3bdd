"""Blind check of ``analyse`` on recordings of a real control's motion (issue 47).

Our LinuxCNC programs run on LinuxCNC itself (``validation/linuxcnc_run.py --motion-dir
DIR``: Debian's ``linuxcnc-uspace`` 2.9, headless, its commanded axes every 1 ms servo
period, its ramps, blends, corner slow-downs and wall-clock dwells); the independent
generator (``physics_gen.py``, nothing from sdit_path) turns that motion into
recordings: its own kinematics, one effect acting on the machine axes (or none), a
set-up residual, its own instrument (start 1-20 s early, clock +-150 ppm, noise).  Each
recording is given to ``sdit-path analyse`` unnamed, with the plan and nothing else
(``--controller`` only when asked).  Then it is scored against the truth:

- the program recognised;
- every run's measured duration within 3 of its stated standard uncertainties of the
  control's (the generator's clock applied), where the analysis timed the recording
  run by run; where it kept the plan's timing, how far the plan's run durations are
  from the control's;
- the start within 3 of its stated standard uncertainties;
- a clean recording with no finding besides the set-up; a single effect named first
  where it shows above the noise.

    python validation/linuxcnc_run.py --plan P3 --program SDIT_E --motion-dir RUNS
    python validation/control_blind.py --case P3:SDIT_E --motion-dir RUNS [--case ...
        --motion-dir ...] [--cases 13]
        [--seed 1] [--magnitudes bad|typical] [--jobs 2] [--controller linuxcnc] [--json OUT]
    python validation/control_blind.py --rescore OUT.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import physics_gen as gen  # noqa: E402

SETUP = ("setup_offset", "bar_length")
#: what each case holds in turn: clean twice, then every effect of the generator
KINDS = (None, None) + gen.EFFECTS


def control_runs(pd_: gen.PlanData) -> list[float]:
    """The control's run durations (s, control time): its stretches of motion."""
    moving = pd_.phase != "dwell"
    e = np.flatnonzero(np.diff(np.r_[0, moving.astype(int), 0]))
    dt = float(np.median(np.diff(pd_.t)))
    # a run spans from the last still sample before it to the first still one after
    return [float((b - a + 1) * dt) for a, b in zip(e[::2], e[1::2])]


def run_case(job) -> dict:
    plan_dir, program, motion_dir, k, seed, magnitudes, controller = job
    pd_ = gen.load_motion(plan_dir, program, Path(motion_dir) / f"{program}.motion.csv")
    effect = KINDS[k % len(KINDS)]
    rng = np.random.default_rng([seed, k, len(program), 47])
    case = gen.draw(effect, rng, pd_, magnitudes) if effect else None
    text, truth = gen.record(pd_, case, seed * 100_000 + k)
    runs_true = [d * (1 + truth["clock_ppm"] * 1e-6) for d in control_runs(pd_)]
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / f"recording_{k}.csv"
        rec.write_text(text)
        out = Path(tmp) / "out"
        args = [sys.executable, "-m", "sdit_path", "analyse", "--plan", str(plan_dir),
                "--measured", str(rec), "--out", str(out), "--no-pictures", "--jobs", "1", "-q"]
        if controller:
            args += ["--controller", controller]
        t0 = time.perf_counter()
        # ---- the blind part: the plan and the recording's file
        r = subprocess.run(args, capture_output=True, text=True)
        seconds = time.perf_counter() - t0
        base = {"program": program, "case": k, "effect": effect or "clean",
                "excited": bool(truth["excited"]), "noise_um": truth["noise_um"],
                "excited_beyond_setup": bool(truth["excited_beyond_setup"]),
                "visible_beyond_setup_rms_um": truth["visible_beyond_setup_rms_um"],
                "seconds": round(seconds, 1)}
        if r.returncode:
            return {**base, "refused": r.stderr.strip().splitlines()[-1][:400] if r.stderr.strip()
                    else f"exit {r.returncode}"}
        rep = json.loads((out / "analysis.json").read_text())
    x = rep["recordings"][0]
    fs = [f for f in x["diagnosis"]["findings"] if f["effect"] not in SETUP]
    al = x["diagnosis"]["alignment"]
    timing = x.get("timing") or {"model": "plan"}
    res = {**base, "recognised": x["program"] == program, "matched": x["matched"][:300],
           "timing": timing["model"], "found": [(f["effect"], f["confidence"]) for f in fs],
           "offset_error_ms": (al["offset_s"] - truth["offset_s"]) * 1e3,
           "offset_std_ms": al["offset_std_s"] * 1e3}
    res["offset_ok"] = abs(res["offset_error_ms"]) <= 3 * max(res["offset_std_ms"], 1e-3) \
        + truth["following_delay_s"] * 1e3
    if timing["model"] == "recording" and len(timing["runs"]) == len(runs_true):
        z = [(row["measured_s"] - t) / max(row["std_s"], 1e-9)
             for row, t in zip(timing["runs"], runs_true)]
        res["run_z"] = [round(v, 2) for v in z]
        res["run_error_ms"] = [round((row["measured_s"] - t) * 1e3, 1)
                               for row, t in zip(timing["runs"], runs_true)]
        res["runs_ok"] = all(abs(v) <= 3 for v in z)
    elif timing["model"] == "plan":
        plan_runs = control_runs(gen.load(plan_dir, program))
        res["plan_run_error_ms"] = [round((p * (1 + al["clock_ppm"] * 1e-6) - t) * 1e3, 1)
                                    for p, t in zip(plan_runs, runs_true)]
    if effect is None:
        res["no_finding"] = not fs
    else:
        res["top1"] = bool(fs) and effect in [fs[0]["effect"], *fs[0].get("ambiguous_with", [])]
    return res


def table(results: list[dict]) -> None:
    def frac(rows, key):
        g = sum(bool(r.get(key)) for r in rows)
        return f"{g} of {len(rows)}"

    done = [r for r in results if "refused" not in r]
    print(f"cases {len(results)}: analysed {len(done)}, refused {len(results) - len(done)}")
    for r in results:
        if "refused" in r:
            print(f"  REFUSED {r['program']} case {r['case']} ({r['effect']}): {r['refused'][:200]}")
    print(f"recognised as its program:        {frac(done, 'recognised')}")
    timed = [r for r in done if "run_z" in r]
    z = np.array([v for r in timed for v in r["run_z"]])
    print(f"timed run by run:                 {len(timed)} of {len(done)}; every run within 3 std "
          f"in {frac(timed, 'runs_ok')} recordings; runs within 1/2/3 std: "
          + (f"{np.mean(np.abs(z) <= 1):.0%}/{np.mean(np.abs(z) <= 2):.0%}/"
             f"{np.mean(np.abs(z) <= 3):.0%} of {len(z)}, |z| max {np.abs(z).max():.2f}"
             if len(z) else "none"))
    kept = [r for r in done if "plan_run_error_ms" in r]
    if kept:
        e = np.array([v for r in kept for v in r["plan_run_error_ms"]])
        print(f"plan's timing kept:               {len(kept)}; its run durations off the "
              f"control's by {np.median(np.abs(e)):.1f} ms median, {np.abs(e).max():.1f} ms at most")
    print(f"start within 3 std:               {frac(done, 'offset_ok')}")
    clean = [r for r in done if r["effect"] == "clean"]
    print(f"clean with no finding:            {frac(clean, 'no_finding')}")
    single = [r for r in done if r["effect"] != "clean" and r["excited"]]
    print(f"effect named first (shown above the noise): {frac(single, 'top1')}")
    beyond = [r for r in single if r.get("excited_beyond_setup")]
    if any("excited_beyond_setup" in r for r in single):
        print(f"  of which above the noise beyond what a set-up change reproduces: "
              f"{frac(beyond, 'top1')}")
    for r in single:
        if not r.get("top1"):
            why = "" if "excited_beyond_setup" not in r else (
                f" (beyond a set-up change: {r['visible_beyond_setup_rms_um']:.3f} um, "
                f"noise {r['noise_um']:.3f} um)")
            print(f"  {r['program']} case {r['case']} {r['effect']}: found {r['found'][:3]}{why}")
    for r in clean:
        if not r.get("no_finding"):
            print(f"  {r['program']} case {r['case']} clean: found {r['found'][:3]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", action="append", default=[], help="PLAN_DIR:PROGRAM (repeat)")
    ap.add_argument("--motion-dir", action="append", type=Path, default=[],
                    help="linuxcnc_run.py --motion-dir's folder (one for every --case, or "
                         "one for all)")
    ap.add_argument("--cases", type=int, default=len(KINDS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--magnitudes", choices=["bad", "typical"], default="typical")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--controller", default=None)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--rescore", type=Path)
    a = ap.parse_args()
    if a.rescore:
        table(json.loads(a.rescore.read_text()))
        return
    if not a.case or len(a.motion_dir) not in (1, len(a.case)):
        ap.error("--case and --motion-dir (one, or one per --case) are needed (or --rescore)")
    dirs = a.motion_dir * len(a.case) if len(a.motion_dir) == 1 else a.motion_dir
    jobs = []
    for spec, motion_dir in zip(a.case, dirs):
        plan_dir, program = spec.rsplit(":", 1)
        for k in range(a.cases):
            jobs.append((plan_dir, program, str(motion_dir), k, a.seed, a.magnitudes,
                         a.controller))
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        results = list(ex.map(run_case, jobs))
    if a.json:
        a.json.write_text(json.dumps(results, indent=1) + "\n")
    table(results)


if __name__ == "__main__":
    main()
