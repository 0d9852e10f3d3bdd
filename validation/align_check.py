"""Blind check of the alignment (and the top finding) on recordings of the independent
generator (``physics_gen.py``, which shares no code with sdit_path).

For each case a recording is written to a file, ``sdit-path diagnose --json`` runs on
that file alone, and only then is its alignment compared with the truth the generator
kept: offset error against the following delay + 2 ms, clock error against 5 ppm.

    python validation/align_check.py --plan P --program SDIT_C [--cases 24] [--seed 1] [--jobs 2]
    python validation/align_check.py --plan P --program SDIT_C --probe 0   # timing information
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import physics_gen as gen  # noqa: E402


def one(plan: str, program: str, pd_, k: int, seed: int) -> dict:
    rng = np.random.default_rng([seed, k])
    kinds = (None,) + gen.EFFECTS
    effect = kinds[k % len(kinds)]
    case = gen.draw(effect, rng, pd_) if effect else None
    text, truth = gen.record(pd_, case, seed * 1000 + k)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "measured.csv"
        path.write_text(text)
        out = Path(tmp) / "d.json"
        r = subprocess.run([sys.executable, "-m", "sdit_path", "diagnose", "--plan", plan,
                            "--program", program, "--measured", str(path), "--json", str(out),
                            "-q"], capture_output=True, text=True, timeout=1800)
        if r.returncode != 0:
            return {"k": k, "truth": truth, "error": r.stderr.strip()[-300:]}
        rep = json.loads(out.read_text())
    al = rep["alignment"]
    return {"k": k, "truth": truth, "alignment": al,
            "findings": [(f["effect"], f["confidence"]) for f in rep["findings"]]}


def probe(plan: str, program: str, pd_, k: int, seed: int) -> None:
    """How much timing information case ``k`` holds: the residual RMS of the
    diagnoser's generic alignment model at the true alignment and shifted from it."""
    from sdit_path.diagnose.align import _fit_rms, generic_columns  # a probe of the internals
    from sdit_path.reading.context import build_context
    from sdit_path.plan.files import load_plan

    rng = np.random.default_rng([seed, k])
    kinds = (None,) + gen.EFFECTS
    effect = kinds[k % len(kinds)]
    case = gen.draw(effect, rng, pd_) if effect else None
    text, truth = gen.record(pd_, case, seed * 1000 + k)
    data = np.genfromtxt(text.splitlines()[2:], delimiter=",")
    t_m, y = data[:, 0], data[:, 1]
    ctx = build_context(load_plan(plan), program)
    X = generic_columns(ctx, np.zeros(ctx.n))
    sel = np.flatnonzero(np.isfinite(y))[::5]
    off, kk = truth["offset_s"], truth["clock_ppm"] * 1e-6
    print(f"case {k} ({effect or 'clean'}): noise {truth['noise_um']:.3f} um, centring "
          f"{[round(c, 1) for c in truth['centring_um']]} um")
    for d_ms, d_ppm in ((0, 0), (-20, 0), (-2, 0), (2, 0), (20, 0), (0, -20), (0, 20)):
        rms = _fit_rms(X, ctx.t_s, t_m[sel], y[sel], off + d_ms * 1e-3, kk + d_ppm * 1e-6)[0]
        print(f"  offset {d_ms:+4d} ms, clock {d_ppm:+4d} ppm from the truth: residual RMS "
              f"{rms:.6f} um")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plan", required=True)
    ap.add_argument("--program", required=True)
    ap.add_argument("--cases", type=int, default=24)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", default=None)
    ap.add_argument("--probe", type=int, default=None,
                    help="Only print how much timing information case K holds.")
    args = ap.parse_args()
    pd_ = gen.load(args.plan, args.program)
    if args.probe is not None:
        probe(args.plan, args.program, pd_, args.probe, args.seed)
        return
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda k: one(args.plan, args.program, pd_, k, args.seed),
                                range(args.cases)))
    ok_off = ok_clk = done = 0
    print(f"{'case':>4} {'effect':18s} {'off err ms':>10} {'allowed':>8} {'clk err ppm':>11} "
          f"{'std ms':>7} {'std ppm':>7} {'CRB ms':>6} {'ppm':>6}  top finding")
    for res in results:
        tr = res["truth"]
        name = tr["effect"] or "clean"
        if "error" in res:
            print(f"{res['k']:4d} {name:18s} ERROR {res['error']}")
            continue
        done += 1
        al = res["alignment"]
        off_err = (al["offset_s"] - tr["offset_s"]) * 1e3
        allowed = tr["following_delay_s"] * 1e3 + 2.0
        clk_err = al["clock_ppm"] - tr["clock_ppm"]
        # the target, or three times the physical bound where the trace holds less
        # timing information than the target needs (the generator's own Cramer-Rao bound)
        b_off, b_clk = tr["offset_bound_s"] * 1e3, tr["clock_bound_ppm"]
        beyond = off_err - min(max(off_err, 0.0), allowed - 2.0)
        good_off = abs(beyond) <= max(2.0, 3 * b_off)
        good_clk = abs(clk_err) <= max(5.0, 3 * b_clk)
        ok_off += good_off
        ok_clk += good_clk
        std_ms = (al.get("offset_std_s") or float("nan")) * 1e3
        top = res["findings"][0] if res["findings"] else ("-", "")
        print(f"{res['k']:4d} {name:18s} {off_err:10.2f} {allowed:8.2f} {clk_err:11.2f} "
              f"{std_ms:7.2f} {al.get('clock_std_ppm') or float('nan'):7.2f} "
              f"{b_off:6.2f} {b_clk:6.1f}  "
              f"{top[0]} ({top[1]}){'' if good_off and good_clk else '   <-- MISS'}")
    print(f"{args.program}: offset within following delay + max(2 ms, 3 CRB) in {ok_off} of "
          f"{done}; clock within max(5 ppm, 3 CRB) in {ok_clk} of {done}; "
          f"{len(results) - done} refused")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))


if __name__ == "__main__":
    main()
