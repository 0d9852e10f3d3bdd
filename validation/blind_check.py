"""Blind check of ``diagnose`` on recordings of the independent generator
(``physics_gen.py``: its own kinematics, effects acting on the machine axes, its own
instrument and a set-up residual in every trace; nothing from sdit_path).

    python validation/blind_check.py [--per-program 51] [--plans DIR] [--seed 1] [--jobs 2]
                                [--magnitudes bad|typical] [--json OUT]
    python validation/blind_check.py --case PLAN:PROGRAM [--case ...] [--per-program 17] ...
    python validation/blind_check.py --rescore OUT.json [--programs SDIT_C,SDIT_B]

Without ``--case`` it plans the issue's three programs (SDIT_C of the default sample at
F600, SDIT_B of it at F2000, SDIT5_C of the 5-axis sample) into ``--plans DIR`` (kept
and reused when given, else a temporary directory) and runs each.

Per program, case k takes in turn: clean (twice), each effect of the generator, each
out-of-library gap.  Each recording is written to a file; the diagnosis reads that
file, the plan and the program name, nothing else (no geometric model: the generator
has none).  Only then is it scored against the truth the generator kept:

- single effect named first (set-up offset and bar length, present in every trace,
  are not effects), counted where the effect shows above the noise where it acts;
- clean traces with no finding besides the set-up;
- out-of-library gaps: no high-confidence finding, and the gap left unexplained or
  nothing named;
- held-out shrink of the gap above the noise when the effect is named first;
- alignment: offset error beyond the following delay within max(2 ms, 3 CRB), clock
  error within max(5 ppm, 3 CRB), where CRB is the generator's own Cramer-Rao bound
  of the trace's timing information.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per case
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import physics_gen as gen  # noqa: E402

#: the issue's programs: (sample, feed or None for the sample's own, program)
DEFAULT = (("vmc_3axis.toml", None, "SDIT_C"), ("vmc_3axis.toml", 2000.0, "SDIT_B"),
           ("bc_table_5axis.toml", None, "SDIT5_C"))


def default_cases(root: Path) -> list[str]:
    """Plan the default programs under ``root`` (a plan already there is reused)."""
    import subprocess

    from sdit_path.config import sample_path
    out = []
    for sample, feed, program in DEFAULT:
        name = f"{Path(sample).stem}_F{int(feed) if feed else 'sample'}"
        plan_dir = root / name
        if not (plan_dir / "plan.json").is_file():
            text = sample_path(sample).read_text()
            if feed:
                key = "feed_mm_per_min = "
                line = next(ln for ln in text.splitlines() if ln.startswith(key))
                text = text.replace(line, f"{key}{feed}")
            cfg = root / f"{name}.toml"
            cfg.write_text(text)
            r = subprocess.run([sys.executable, "-m", "sdit_path", "plan", str(cfg), "--out",
                                str(plan_dir)], capture_output=True, text=True)
            if r.returncode:
                sys.exit(f"planning {sample} failed: {r.stderr.strip()[-300:]}")
        out.append(f"{plan_dir}:{program}")
    return out

SETUP = ("setup_offset", "bar_length")
KINDS = (None, None) + gen.EFFECTS + gen.GAPS


def run_case(job):
    plan_dir, program, k, seed, magnitudes = job
    from sdit_path.diagnose import diagnose
    from sdit_path.plan.files import load_plan
    from sdit_path.reading.recording import read_trace

    pd_ = gen.load(plan_dir, program)
    effect = KINDS[k % len(KINDS)]
    rng = np.random.default_rng([seed, k, len(program)])
    case = gen.draw(effect, rng, pd_, magnitudes) if effect else None
    text, truth = gen.record(pd_, case, seed * 100_000 + k)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "measured.csv"
        path.write_text(text)
        t0 = time.perf_counter()
        # ---- the blind part: the plan, the program name and the file
        rep = diagnose(load_plan(plan_dir), program, read_trace(path)).to_json()
        seconds = time.perf_counter() - t0
    return score(program, k, effect, truth, rep, seconds)


#: effects that leave the pivot where the set-up put it.  A geometric error (scale,
#: squareness, cyclic error, a straightness gap) moves the pivot's image as well (a scale
#: error about the machine's zero reads the pivot itself off by the scale times its
#: position), and so does a drift or a mount slip: there the generator's split between
#: set-up and effect is its own, not something a recording can tell.
SETUP_SCORED = ("servo_lag", "servo_mismatch", "backlash", "reversal_spike", "stick_slip",
                "vibration", "contour_smoothing")


def setup_errors(truth, rep) -> dict:
    """The set-up's reported parameters against the generator's set-up residual:
    parameter -> (error, stated standard uncertainty).  The generator puts the pivot
    off by ``centring_um`` (the diagnoser's dx, dy, dz) and reads ``bar_offset_um`` less
    (the diagnoser's dL_um, a bar that long too much)."""
    want = {"dx_um": truth["centring_um"][0], "dy_um": truth["centring_um"][1],
            "dz_um": truth["centring_um"][2], "dL_um": -truth["bar_offset_um"]}
    out = {}
    for f in rep["findings"]:
        if f["effect"] not in SETUP:
            continue
        std = f.get("parameter_std", {})
        for key, true in want.items():
            if key in f["parameters"] and key in std:
                out[key] = (f["parameters"][key] - true, std[key])
    return out


def lag_errors(effect, params, rep) -> dict:
    """A named servo lag's or mismatch's reported lags against the generator's: parameter
    -> (error, stated standard uncertainty).  The generator lags every axis by
    ``tau_ms``, and ``axis`` by ``mismatch_ms`` more; the diagnoser reports an equal
    lag's ``tau_ms`` and a mismatch's ``lag_<axis>_minus_<reference>_ms``."""
    out = {}
    for f in rep["findings"]:
        if f["effect"] != effect:
            continue
        std = f.get("parameter_std", {})
        for key, value in f["parameters"].items():
            if key not in std:
                continue
            if effect == "servo_lag" and key == "tau_ms":
                out[key] = (value - params["tau_ms"], std[key])
            elif effect == "servo_mismatch" and key.startswith("lag_") and "_minus_" in key:
                axis, ref = key[len("lag_"):-len("_ms")].split("_minus_")
                lag = {a: params["mismatch_ms"] if a == params["axis"] else 0.0
                       for a in (axis, ref)}
                out[key] = (value - (lag[axis] - lag[ref]), std[key])
    return out


def score(program, k, effect, truth, rep, seconds) -> dict:
    fs = [f for f in rep["findings"] if f["effect"] not in SETUP]
    al = rep["alignment"]
    off_err = (al["offset_s"] - truth["offset_s"]) * 1e3
    delay = truth["following_delay_s"] * 1e3
    beyond = off_err - min(max(off_err, 0.0), delay)
    out = {"program": program, "case": k, "effect": effect or "clean",
           "params": truth["params"], "excited": truth["excited"],
           "visible_rms_um": truth["visible_rms_um"], "noise_um": truth["noise_um"],
           "excited_beyond_setup": truth["excited_beyond_setup"],
           "visible_beyond_setup_rms_um": truth["visible_beyond_setup_rms_um"],
           "found": [(f["effect"], f["confidence"]) for f in fs],
           "ambiguous_with": fs[0].get("ambiguous_with", []) if fs else [],
           "unexplained_significant": rep["unexplained"]["significant"],
           "offset_error_ms": off_err, "offset_beyond_delay_ms": beyond,
           "clock_error_ppm": al["clock_ppm"] - truth["clock_ppm"],
           "offset_std_ms": al["offset_std_s"] * 1e3, "clock_std_ppm": al["clock_std_ppm"],
           "offset_bound_ms": truth["offset_bound_s"] * 1e3,
           "clock_bound_ppm": truth["clock_bound_ppm"], "timing_weak": al["timing_weak"],
           "seconds": round(seconds, 1)}
    out["setup"] = setup_errors(truth, rep) if effect is None or effect in SETUP_SCORED else {}
    if effect in ("servo_lag", "servo_mismatch"):
        out["lags"] = lag_errors(effect, truth["params"], rep)
    out["offset_ok"] = abs(beyond) <= max(2.0, 3 * out["offset_bound_ms"])
    out["clock_ok"] = abs(out["clock_error_ppm"]) <= max(5.0, 3 * out["clock_bound_ppm"])
    if effect is None:
        out["kind"] = "clean"
        out["no_finding"] = not fs
    elif effect in gen.GAPS:
        out["kind"] = "gap"
        out["honest"] = (not any(c == "high" for _, c in out["found"])
                         and (rep["unexplained"]["significant"] or not fs))
    else:
        out["kind"] = "single"
        # a finding reported as ambiguous between two effects names both
        out["top1"] = bool(fs) and effect in [fs[0]["effect"], *fs[0].get("ambiguous_with", [])]
        if out["top1"]:
            sigma = truth["noise_um"]
            before = fs[0]["heldout_rms_before_um"]
            after = rep["findings"][-1]["heldout_rms_after_um"]
            ex_b = math.sqrt(max(before ** 2 - sigma ** 2, 0.0))
            ex_a = math.sqrt(max(after ** 2 - sigma ** 2, 0.0))
            out["shrink"] = 1 - ex_a / ex_b if ex_b > 0 else 1.0
    return out


def table(results: list[dict]) -> None:
    def frac(rows, key):
        n = len(rows)
        g = sum(bool(r[key]) for r in rows)
        return f"{g} of {n} ({100 * g / max(n, 1):.0f} %)"

    single = [r for r in results if r["kind"] == "single" and r["excited"]]
    clean = [r for r in results if r["kind"] == "clean"]
    gap = [r for r in results if r["kind"] == "gap" and r["excited"]]
    shrink = [r["shrink"] for r in single if "shrink" in r]
    print(f"cases {len(results)} ({len(single)} single effects shown above the noise, "
          f"{len(clean)} clean, {len(gap)} gaps)")
    print(f"single effect named first:        {frac(single, 'top1')}   target >= 90 %")
    beyond = [r for r in single if r.get("excited_beyond_setup")]
    if any("excited_beyond_setup" in r for r in single):
        print(f"  of which above the noise beyond what a set-up change reproduces: "
              f"{frac(beyond, 'top1')}")
    print(f"clean traces with no finding:     {frac(clean, 'no_finding')}   target >= 95 %")
    print(f"gap unexplained, none confident:  {frac(gap, 'honest')}   target >= 90 %")
    print(f"held-out shrink when named, median: "
          f"{100 * float(np.median(shrink)) if shrink else float('nan'):.0f} %   target >= 70 %")
    print(f"offset within delay + max(2 ms, 3 CRB): {frac(results, 'offset_ok')}")
    print(f"clock within max(5 ppm, 3 CRB):         {frac(results, 'clock_ok')}")
    # 3 bounds fail now and then even for an efficient estimator (0.27 % per number:
    # about one of 150 cases x 2 numbers); 4 bounds (6e-5 per number) hold on every case
    # of 150 with 98 % probability
    in4 = sum(abs(r["offset_beyond_delay_ms"]) <= max(2.0, 4 * r["offset_bound_ms"]) and
              abs(r["clock_error_ppm"]) <= max(5.0, 4 * r["clock_bound_ppm"]) for r in results)
    print(f"both within max(2 ms / 5 ppm, 4 CRB):   {in4} of {len(results)}")
    strict_o = sum(abs(r["offset_beyond_delay_ms"]) <= 2.0 for r in results)
    strict_c = sum(abs(r["clock_error_ppm"]) <= 5.0 for r in results)
    print(f"(the issue's literal targets: offset {strict_o}, clock {strict_c} of {len(results)})")
    cover = sum(abs(r["clock_error_ppm"]) <= 3 * r["clock_std_ppm"] and
                abs(r["offset_beyond_delay_ms"]) <= 3 * r["offset_std_ms"] for r in results)
    print(f"stated timing uncertainty covers the error (3 sigma): {cover} of {len(results)}")
    setup = [e for r in results for e in r.get("setup", {}).values()]
    if setup:
        held = sum(abs(err) <= 3 * std for err, std in setup)
        print(f"stated set-up uncertainty covers the generator's set-up (3 sigma): {held} of "
              f"{len(setup)} numbers (dx, dy, dz, dL; clean traces and dynamic effects)")
    lags = [e for r in results for e in r.get("lags", {}).values()]
    if any("lags" in r for r in results):
        held = sum(abs(err) <= 3 * std for err, std in lags)
        print(f"stated lag uncertainty covers the generator's lag (3 sigma): {held} of "
              f"{len(lags)} numbers (a servo lag's time constant, a mismatch's lag "
              f"differences, where named)")
    per: dict = {}
    for r in single:
        per.setdefault(r["effect"], []).append(r["top1"])
    print("named first per effect: " + ", ".join(f"{e} {sum(v)}/{len(v)}"
                                                 for e, v in sorted(per.items())))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", action="append", default=None,
                    help="PLAN:PROGRAM (default: the three programs of the issue, planned)")
    ap.add_argument("--plans", type=Path, default=None,
                    help="Where the default programs are planned (and reused).")
    ap.add_argument("--per-program", type=int, default=len(KINDS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--magnitudes", choices=sorted(gen.RANGES), default="bad",
                    help="The domain brief's bad (default) or typical magnitudes.")
    ap.add_argument("--only", default=None, help="Only these case numbers (comma-separated).")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--rescore", type=Path, default=None,
                    help="Print the table of an earlier --json file.")
    ap.add_argument("--programs", default=None,
                    help="With --rescore: only these programs (comma-separated).")
    args = ap.parse_args()
    if args.rescore:
        rows = json.loads(args.rescore.read_text())
        if args.programs:
            keep = set(args.programs.split(","))
            rows = [r for r in rows if r["program"] in keep]
        table(rows)
        return
    if args.case is None:
        if args.plans is None:
            keep = tempfile.TemporaryDirectory()
            args.plans = Path(keep.name)
        args.plans.mkdir(parents=True, exist_ok=True)
        args.case = default_cases(args.plans)
    jobs = []
    for spec in args.case:
        plan_dir, program = spec.rsplit(":", 1)
        ks = ([int(k) for k in args.only.split(",")] if args.only
              else range(args.per_program))
        jobs += [(plan_dir, program, k, args.seed, args.magnitudes) for k in ks]
    results = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for r in pool.map(run_case, jobs):
            results.append(r)
            top = r["found"][0] if r["found"] else ("-", "")
            print(f"{r['program']:8s} {r['case']:3d} {r['effect']:18s} "
                  f"{'excited' if r['excited'] else 'quiet  '} top {top[0]} ({top[1]}) "
                  f"off {r['offset_beyond_delay_ms']:+7.2f} ms clk {r['clock_error_ppm']:+7.1f} ppm "
                  f"{'' if r['offset_ok'] and r['clock_ok'] else 'TIMING '}{r['seconds']} s",
                  flush=True)
            if args.json:
                args.json.write_text(json.dumps(results, indent=1, default=float))
    table(results)


if __name__ == "__main__":
    main()
