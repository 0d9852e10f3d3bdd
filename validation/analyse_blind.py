"""Seeded blind check of ``sdit-path analyse`` (issue 16): recordings of every program of
a plan made by ``perturb`` with hidden random geometry (linear order 1 + squareness: a
few um and tens of urad), one hidden effect of the machine (the same in every program,
or none), a set-up offset, and an unknown start, clock and noise per recording.  The
analysis sees the plan and the recordings' files, nothing else; then it is scored:

- every determined combination against the truth (within 3 standard uncertainties);
- the hidden effect named first in each recording (set-up and geometry are not effects);
- a clean machine with no effect named;
- the start (within 50 ms: a lag of the servo is part of it) and the clock (within
  max(5 ppm, 4 of its stated uncertainties));
- refusals: per case, a recording of the same machine made with the plan at 0.6 times
  the feed, and one made with another plan of the same program names (upper tracks
  5 degrees higher, one node more per track), each given unnamed and named; and one of
  the case's own recordings named as another program.  Each must be refused with one
  line (no traceback) and no output folder.

With ``--control linuxcnc`` the recordings are made from the motion of LinuxCNC 2.9's
planner running the programs as written (``perturb --control linuxcnc``: chords,
blends, ramps, slow-downs) and analysed with ``--controller linuxcnc`` (issue 47).

    python validation/analyse_blind.py [--plan-config tests/data/golden_small.toml] [--cases 10]
                                  [--seed 1] [--json OUT] [--work DIR] [--no-refusals]
                                  [--refusals feed,plan,name] [--control linuxcnc]

``--refusals`` picks the kinds of stranger tried (another feed, another plan, a
recording named as another program; all by default).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from sdit_path.reading.context import build_context  # noqa: E402
from sdit_path.plan.files import load_plan  # noqa: E402
from sdit_path.sim.perturb import Recording, draw_effect, perturb  # noqa: E402

EFFECTS = ("servo_lag", "servo_mismatch", "backlash", "reversal_spike", "thermal_drift",
           "lateral_play", "contour_smoothing", None)
NOT_EFFECTS = ("setup_offset", "bar_length", "squareness", "scale_mismatch",
               "geometry_beyond_library")


def cli(*args):
    return subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                          text=True)


def geometry(rng) -> dict:
    values = {}
    for axis in "XYZ":
        for comp in "XYZ":
            values[f"E{comp}{axis}"] = rng.normal(0, 3.0)
            values[f"E{comp}{axis}.P1"] = rng.normal(0, 3.0)
        for comp in "ABC":
            values[f"E{comp}{axis}"] = rng.normal(0, 20.0)
    for sq in ("EC0Y", "EB0Z", "EA0Z"):
        values[sq] = rng.normal(0, 30.0)
    return values


def hidden_model(truth: dict) -> str:
    """The error-set TOML of a hidden geometry (linear order 1 + squareness)."""
    return ('name = "hidden"\n\n[model]\nlinear_order = 1\nsquareness = true\n\n[values]\n'
            + "\n".join(f'"{n}" = {v:.5f}' for n, v in truth.items()) + "\n")


def effect_text(h) -> str:
    return h.name + ":" + ",".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}"
                                   for k, v in h.params.items())


def refusals(k: int, rng, d: Path, plan_dir: Path, others: dict[str, Path], files: list[Path],
             setup, hidden, named_wrong: bool = True) -> list[dict]:
    """The case's machine recorded with the wrong plans, and (``named_wrong``) a recording
    named as another program: each given to ``analyse`` against the case's plan must be
    refused."""
    plan = load_plan(plan_dir)
    tries = []
    for what, other in others.items():
        prog = plan.program_names[int(rng.integers(len(plan.program_names)))]
        f = d / f"{what}_{prog.lower()}.csv"
        args = ["perturb", "--plan", str(other), "--program", prog, "--model", str(d / "hidden.toml"),
                "--effect", effect_text(setup), "--lead-s", f"{rng.uniform(1, 20):.3f}",
                "--clock-ppm", f"{rng.uniform(-150, 150):.2f}",
                "--noise-um", f"{rng.uniform(0.1, 0.3):.3f}", "--out", str(f), "-q"]
        for h in hidden:
            args += ["--effect", effect_text(h)]
        r = cli(*args)
        if r.returncode:
            tries.append({"what": what, "error": r.stderr.strip()[-300:]})
            continue
        tries += [(what + " unnamed", str(f)), (what + f" named {prog}", f"{prog}={f}")]
    own = files[0]
    wrong = plan.program_names[1] if len(plan.program_names) > 1 and named_wrong else None
    if wrong:
        tries.append(("own recording named " + wrong, f"{wrong}={own}"))
    out = []
    for i, t in enumerate(tries):
        if isinstance(t, dict):
            out.append(t)
            continue
        what, given = t
        o = d / f"refused{i}"  # must not come to exist
        r = cli("analyse", "--plan", str(plan_dir), "--measured", given, "--out", str(o),
                "--no-pictures", "-q")
        last = (r.stderr.strip().splitlines() or [""])[-1]
        out.append({"what": what, "refused": r.returncode != 0 and "Traceback" not in r.stderr
                    and len(last) < 800 and not o.exists(), "line": last[:300]})
    return out


def visible_rms(plan, program: str, hidden) -> float:
    """What the hidden effect alone puts into the program's reading: its RMS where it
    acts (above a tenth of its peak), its median taken out, as the independent blind
    check scores it (an effect counts where the program excites it above the noise)."""
    if not hidden:
        return 0.0
    quiet = Recording(lead_s=0.0, tail_s=0.0, clock_ppm=0.0, noise_um=0.0, quantisation_um=0.0,
                      dropout_fraction=0.0)
    _, truth = perturb(plan, program, None, hidden, quiet, 0, build_context(plan, program))
    v = sum(np.asarray(truth.contributions[h.name], float) for h in hidden)
    v = v - np.median(v)
    acts = np.abs(v) > 0.1 * np.max(np.abs(v)) if np.any(v) else np.zeros(len(v), bool)
    return float(np.sqrt(np.mean(v[acts] ** 2))) if acts.any() else 0.0


def run_case(k: int, seed: int, plan_dir: Path, work: Path,
             others: dict[str, Path] | None = None, control: str | None = None,
             named_wrong: bool = True) -> dict:
    rng = np.random.default_rng([seed, k, 16])
    plan = load_plan(plan_dir)
    d = work / f"case{k}"
    d.mkdir(parents=True, exist_ok=True)
    truth = geometry(rng)
    (d / "hidden.toml").write_text(hidden_model(truth))
    name = EFFECTS[k % len(EFFECTS)]
    ctx = build_context(plan, plan.program_names[0])
    hidden = [draw_effect(name, rng, ctx)] if name else []
    setup = draw_effect("setup_offset", rng, ctx)
    files, recs, visible = [], [], {}
    for prog in plan.program_names:
        lead, ppm, noise = rng.uniform(1, 20), rng.uniform(-150, 150), rng.uniform(0.1, 0.3)
        f = d / f"{prog.lower()}.csv"
        args = ["perturb", "--plan", str(plan_dir), "--program", prog, "--model",
                str(d / "hidden.toml"), "--effect", effect_text(setup),
                "--lead-s", f"{lead:.3f}", "--clock-ppm", f"{ppm:.2f}", "--noise-um",
                f"{noise:.3f}", "--out", str(f), "--truth", str(d / f"{prog}.truth.json"), "-q"]
        for h in hidden:
            args += ["--effect", effect_text(h)]
        if control:
            args += ["--control", control]
        r = cli(*args)
        if r.returncode:
            return {"case": k, "error": r.stderr.strip()[-300:]}
        files.append(f)
        recs.append((prog, json.loads((d / f"{prog}.truth.json").read_text())["recording"]))
        visible[prog] = visible_rms(plan, prog, hidden)
    t0 = time.time()
    args = ["analyse", "--plan", str(plan_dir), "--out", str(d / "out"), "--force",
            "--no-pictures", "-q"]
    for f in files:
        args += ["--measured", str(f)]
    if control:
        args += ["--controller", control]
    r = cli(*args)
    seconds = time.time() - t0
    if r.returncode:
        return {"case": k, "effect": name, "error": r.stderr.strip()[-300:]}
    rep = json.loads((d / "out" / "analysis.json").read_text())
    combos = rep["geometry"]["combinations"]
    z = [abs(c["estimate"] - sum(t["coefficient"] * truth.get(t["parameter"], 0.0)
                                 for t in c["terms"])) / c["std"] for c in combos]
    out = {"case": k, "effect": name, "control": control, "seconds": seconds,
           "combinations": len(combos),
           "within_3": int(sum(v <= 3.0 for v in z)), "z_max": max(z, default=0.0),
           "recordings": []}
    truth_rec = dict(recs)
    for x in rep["recordings"]:
        lead = next((f for f in x["diagnosis"]["findings"] if f["effect"] not in NOT_EFFECTS), None)
        first = lead["effect"] if lead else None
        # an ambiguous finding names its pair together (lag or smoothing at one feed)
        pair = [first] + list(lead.get("ambiguous_with") or []) if lead else [None]
        al = x["diagnosis"]["alignment"]
        t = truth_rec[x["program"]]
        out["recordings"].append({
            "program": x["program"], "named_first": first,
            "visible_rms_um": visible[x["program"]], "noise_um": t["noise_um"],
            "excited": visible[x["program"]] >= t["noise_um"],
            "right": first == name,
            "in_ambiguous": name in pair and first != name,
            "offset_ms": (al["offset_s"] - t["offset_s"]) * 1e3,
            "clock_err_ppm": al["clock_ppm"] - t["clock_ppm"],
            "clock_ok": abs(al["clock_ppm"] - t["clock_ppm"]) <= max(5.0, 4 * (al["clock_std_ppm"] or 0)),
            "offset_ok": abs(al["offset_s"] - t["offset_s"]) <= 0.05})
    if others or named_wrong:
        out["refusals"] = refusals(k, rng, d, plan_dir, others or {}, files, setup, hidden,
                                   named_wrong)
    return out


def _tilted(m) -> str:
    """Every track but the equator raised by 5 degrees (at most to 80)."""
    els = [float(v) for v in m.group(1).split(",")]
    return "track_elevations_deg = [" + ", ".join(
        f"{v if v == 0 else min(v + 5.0, 80.0):.1f}" for v in els) + "]"


def other_plans(config: Path, work: Path, kinds: tuple[str, ...] = ("feed", "plan")
                ) -> dict[str, Path]:
    """The plan's configuration at 0.6 times its feed, and with its upper tracks raised
    by 5 degrees and one node more per track (the same program names), planned once."""
    import re
    text = config.read_text()
    feed = float(re.search(r"feed_mm_per_min\s*=\s*([0-9.]+)", text).group(1))
    variants = {
        "other feed": re.sub(r"feed_mm_per_min\s*=\s*[0-9.]+", f"feed_mm_per_min = {0.6 * feed:.1f}",
                             text),
        "other plan": re.sub(r"nodes_per_track\s*=\s*\d+", lambda m: f"nodes_per_track = "
                             f"{int(m.group(0).split('=')[1]) + 1}",
                             re.sub(r"track_elevations_deg\s*=\s*\[([^\]]*)\]", _tilted, text))}
    out = {}
    for what, cfg_text in variants.items():
        if what.split()[-1] not in kinds:
            continue
        if cfg_text == text:
            sys.exit(f"{config}: cannot make the {what} (no such setting in the file)")
        stem = what.replace(" ", "_")
        d = work / stem
        if not d.is_dir():
            cfg = work / f"{stem}.toml"
            cfg.write_text(cfg_text)
            r = cli("plan", str(cfg), "--out", str(d), "-q")
            if r.returncode:
                sys.exit(r.stderr)
        out[what] = d
    return out


def summary(results: list[dict]) -> None:
    """The campaign's figures from its cases (a run's, or an earlier ``--json`` file's)."""
    ok = [r for r in results if "error" not in r]
    combos = sum(r["combinations"] for r in ok)
    within = sum(r["within_3"] for r in ok)
    recs = [x for r in ok for x in r["recordings"]]
    eff = [x for r in ok for x in r["recordings"] if r["effect"]]
    clean = [x for r in ok for x in r["recordings"] if not r["effect"]]
    print(f"\ncases {len(ok)} of {len(results)} analysed; determined combinations within 3 std: "
          f"{within}/{combos} ({within / max(combos, 1):.1%})")
    print(f"effect named first: {sum(x['right'] for x in eff)}/{len(eff)} recordings (and "
          f"{sum(x.get('in_ambiguous', False) for x in eff)} more named with it as one ambiguous "
          f"finding); clean recordings with no effect named: "
          f"{sum(x['right'] for x in clean)}/{len(clean)}")
    seen = [x for x in eff if x.get("excited")]
    print(f"  where the program excites the effect above the recording's noise (as the "
          f"independent blind check counts): {sum(x['right'] for x in seen)}/{len(seen)} named "
          f"first, {sum(x.get('in_ambiguous', False) for x in seen)} more as one ambiguous finding")
    print(f"alignment: start within 50 ms {sum(x['offset_ok'] for x in recs)}/{len(recs)}, clock "
          f"within max(5 ppm, 4 std) {sum(x['clock_ok'] for x in recs)}/{len(recs)}")
    tried = [x for r in ok for x in r.get("refusals", [])]
    if tried:
        print(f"refused (other feed, other plan, named as another program): "
              f"{sum(bool(x.get('refused')) for x in tried)}/{len(tried)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan-config", default=str(HERE.parent / "tests/data/golden_small.toml"))
    ap.add_argument("--cases", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json")
    ap.add_argument("--work")
    ap.add_argument("--no-refusals", action="store_true",
                    help="skip the recordings of other plans and wrongly named programs")
    ap.add_argument("--refusals", default="feed,plan,name",
                    help="the strangers tried: another feed, another plan, a recording named "
                         "as another program (comma-separated; default all)")
    ap.add_argument("--control", choices=["linuxcnc"], default=None,
                    help="record the control's own motion and analyse with --controller")
    ap.add_argument("--rescore", type=Path, default=None,
                    help="Print the figures of an earlier --json file.")
    a = ap.parse_args()
    if a.rescore:
        summary(json.loads(a.rescore.read_text()))
        return
    work = Path(a.work or tempfile.mkdtemp(prefix="analyse-blind-"))
    plan_dir = work / "plan"
    if not plan_dir.is_dir():
        r = cli("plan", a.plan_config, "--out", str(plan_dir), "-q")
        if r.returncode:
            sys.exit(r.stderr)
    config = Path(a.plan_config)
    if not config.is_file():  # a bundled sample's name
        from sdit_path.config import sample_path
        config = sample_path(a.plan_config if a.plan_config.endswith(".toml") else a.plan_config + ".toml")
    kinds = () if a.no_refusals else tuple(x.strip() for x in a.refusals.split(",") if x.strip())
    if set(kinds) - {"feed", "plan", "name"}:
        sys.exit(f"--refusals: expected feed, plan or name, got {a.refusals!r}")
    others = other_plans(config, work, kinds) if {"feed", "plan"} & set(kinds) else {}
    results = []
    for k in range(a.cases):
        res = run_case(k, a.seed, plan_dir, work, others, a.control, "name" in kinds)
        results.append(res)
        if "error" in res:
            print(f"case {k:3d} {res.get('effect')}: ERROR {res['error']}", flush=True)
            continue
        recs = " ".join(f"{x['program']}:{x['named_first'] or '-'}"
                        f"{'' if x['right'] else '(x)'} off {x['offset_ms']:+.1f} ms "
                        f"clk {x['clock_err_ppm']:+.1f}" for x in res["recordings"])
        print(f"case {k:3d} {str(res['effect']):18s} combos {res['within_3']}/{res['combinations']}"
              f" (max z {res['z_max']:.1f}) {recs} {res['seconds']:.0f} s", flush=True)
        for x in res.get("refusals", []):
            if not x.get("refused"):
                print(f"         NOT REFUSED: {x['what']}: {x.get('error') or x['line']}", flush=True)
    summary(results)
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
