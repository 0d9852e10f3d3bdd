"""Simulated end to end check of ``sdit-path replan`` (issue 17): a plan with a sector
made bad on purpose (``golden_small`` at F1000 with, ``--case curvature``, eight waves in
sector A2, where the curvature caps the speed, or, ``--case feed``, sector A2 run at
2500 mm/min, where a lag reads 2.7 times the plan's median) and its re-planned version
are recorded by ``perturb`` with the same hidden geometry (linear order 1 + squareness,
random per trial), the same servo mismatch and set-up, and identified (``identify
--linear-order 1``, the hidden geometry's model, geometry only: what a user without a
dynamics model gets).  Printed per plan over the seeded trials: how far the determined
combinations are from the truth in their own standard uncertainties and in their units,
how large those uncertainties are, and the bias the mismatch alone brings (the same
recordings - same noise seed, set-up and instrument - made without it and identified:
the difference isolates the dynamics from the noise).

    python validation/replan_check.py [--case curvature|feed] [--trials 6] [--seed 1] [--work DIR]
                                [--mismatch-ms 1.0]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from analyse_blind import geometry, hidden_model  # noqa: E402

BAD = {"curvature": '\n[[test.curve.override]]\nsector = "A2"\nwaves_per_sector = 8\n',
       "feed": '\n[[test.curve.override]]\nsector = "A2"\nfeed_mm_per_min = 2500.0\n'}


def cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True, text=True)


def must(r: subprocess.CompletedProcess) -> None:
    if r.returncode:
        sys.exit(r.stderr.strip()[-500:])


def _identify(plan: Path, d: Path, name: str, inst: dict, hidden: Path, setup: str,
              mismatch_ms: float, seed: int) -> dict:
    # the model of the hidden geometry (linear order 1 + squareness), as analyse's default
    args = ["identify", "--plan", str(plan), "--linear-order", "1", "--json",
            str(d / f"{name}.json")]
    for prog, (lead, ppm, noise) in inst.items():
        f = d / f"{name}_{prog}.csv"
        must(cli("perturb", "--plan", str(plan), "--program", prog, "--model", str(hidden),
                 "--effect", setup, "--effect", f"servo_mismatch:axis=X,extra_lag_ms={mismatch_ms}",
                 "--lead-s", f"{lead:.3f}", "--clock-ppm", f"{ppm:.2f}",
                 "--noise-um", f"{noise:.3f}", "--seed", str(seed), "--out", str(f), "-q"))
        args += ["--trace", str(f), "--program", prog]
    must(cli(*args))
    return json.loads((d / f"{name}.json").read_text())


def _same_direction(a: list, b: list) -> bool:
    """Two combinations along the same direction of the parameters (the plan decides it;
    the order of the terms may differ)."""
    ca = {t["parameter"]: t["coefficient"] for t in a}
    cb = {t["parameter"]: t["coefficient"] for t in b}
    keys = sorted(set(ca) | set(cb))
    u = np.array([ca.get(k, 0.0) for k in keys])
    v = np.array([cb.get(k, 0.0) for k in keys])
    return float(u @ v) > 0.9999 * float(np.linalg.norm(u) * np.linalg.norm(v))


def trial(k: int, seed: int, plans: dict, work: Path, mismatch_ms: float) -> dict:
    """One seeded trial: per plan, the recordings with the servo mismatch and the same
    recordings (same noise, set-up, instrument) without it; the difference of the two
    identifications is the bias the mismatch alone brings."""
    rng = np.random.default_rng([seed, k, 17])
    d = work / f"trial{k}"
    d.mkdir(parents=True, exist_ok=True)
    truth = geometry(rng)
    (d / "hidden.toml").write_text(hidden_model(truth))
    setup = (f"setup_offset:dx_um={rng.normal(0, 8):.3f},dy_um={rng.normal(0, 8):.3f},"
             f"dz_um={rng.normal(0, 8):.3f}")
    inst = {p: (rng.uniform(1, 15), rng.uniform(-120, 120), rng.uniform(0.1, 0.3))
            for p in ("GOLD_A", "GOLD_B")}
    noise_seed = int(rng.integers(1, 2**31))
    out = {}
    for which, plan in plans.items():
        tag = which.replace(" ", "_").replace("-", "")
        rep = _identify(plan, d, tag, inst, d / "hidden.toml", setup, mismatch_ms, noise_seed)
        ref = _identify(plan, d, tag + "_nodyn", inst, d / "hidden.toml", setup, 0.0, noise_seed)
        errs, zs, stds, bias, bz = [], [], [], [], []
        paired = len(rep["combinations"]) == len(ref["combinations"]) and all(
            _same_direction(a["terms"], b["terms"])
            for a, b in zip(rep["combinations"], ref["combinations"]))
        for i, c in enumerate(rep["combinations"]):
            value = sum(t["coefficient"] * truth.get(t["parameter"], 0.0) for t in c["terms"])
            errs.append(abs(c["estimate"] - value))
            zs.append(errs[-1] / c["std"])
            stds.append(c["std"])
            if paired:
                # the same direction in both (the plan decides it); what the mismatch moved
                c0 = ref["combinations"][i]
                b = abs(c["estimate"] - c0["estimate"])
                bias.append(b)
                bz.append(b / c["std"])
        out[which] = {"combinations": len(zs), "z": zs, "err": errs, "std": stds,
                      "bias": bias, "bias_z": bz, "noise_um": rep["noise_std_um"]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--work")
    ap.add_argument("--mismatch-ms", type=float, default=1.0)
    ap.add_argument("--case", choices=sorted(BAD), default="curvature")
    a = ap.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="replan-check-"))
    work.mkdir(parents=True, exist_ok=True)
    cfg = work / "bad.toml"
    cfg.write_text((HERE.parent / "tests/data/golden_small.toml").read_text() + BAD[a.case])
    plans = {"as planned": work / "plan", "re-planned": work / "replanned"}
    if not (work / "plan" / "plan.json").is_file():
        must(cli("plan", str(cfg), "--out", str(work / "plan"), "-q"))
    if not (work / "replanned" / "plan.json").is_file():
        must(cli("replan", "--plan", str(work / "plan"), "--segment", "A2-1", "--out",
                 str(work / "replanned"), "-q"))
    rep = json.loads((work / "replanned" / "replan.json").read_text())
    print(f"sector A2: {rep['sectors'][0]['chosen']}; information "
          f"{rep['information_nats']['before']:.3f} -> {rep['information_nats']['after']:.3f} nats; "
          f"cycle {rep['cycle_s']['before']:.1f} -> {rep['cycle_s']['after']:.1f} s")
    rows = {w: {"z": [], "err": [], "std": [], "rank": [], "bias": [], "bias_z": []} for w in plans}
    for k in range(a.trials):
        res = trial(k, a.seed, plans, work, a.mismatch_ms)
        line = []
        for w, r in res.items():
            for key in ("z", "err", "std", "bias", "bias_z"):
                rows[w][key] += r[key]
            rows[w]["rank"].append(r["combinations"])
            line.append(f"{w}: {r['combinations']} combos, max z {max(r['z'], default=0):.2f}, "
                        f"RMS error {np.sqrt(np.mean(np.square(r['err']))):.4f}, "
                        f"noise {r['noise_um']:.3f} um")
        print(f"trial {k}: " + " | ".join(line), flush=True)
    print(f"\n{a.trials} trials, servo mismatch of X {a.mismatch_ms} ms in every recording:")
    for w, r in rows.items():
        z = np.array(r["z"])
        print(f"  {w:11}: combinations per trial {sorted(set(r['rank']))}; error / std: median "
              f"{np.median(z):.2f}, max {z.max():.2f}, within 3 std {int((z <= 3).sum())}/{len(z)}; "
              f"median error {np.median(r['err']):.4f}; median std {np.median(r['std']):.4f}")
        if r["bias"]:
            b, bz = np.array(r["bias"]), np.array(r["bias_z"])
            print(f"  {'':11}  bias from the mismatch alone (same recordings without it): "
                  f"median {np.median(b):.4f}, RMS {np.sqrt(np.mean(b ** 2)):.4f}, "
                  f"in std median {np.median(bz):.2f} max {bz.max():.2f} ({len(b)} combinations)")
        else:
            print(f"  {'':11}  bias from the mismatch alone: not paired (the combinations differ)")


if __name__ == "__main__":
    main()
