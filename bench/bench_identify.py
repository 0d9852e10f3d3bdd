"""Identification benchmark.

1. Time to identify a full-hemisphere trace set (every layer program of the default
   sample, simulated at 1 kHz with realistic errors and noise), and samples per second.
2. Estimator variance against the Cramer-Rao bound: the same errors, many noise seeds;
   for every determined combination the empirical variance of its estimate over the
   trials divided by the bound sigma^2 / lambda (sigma^2 = noise variance plus the
   quantisation's q^2/12).  Target ratio <= 1.2.

    python bench/bench_identify.py [--trials 20] [--quick]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from sdit_path.config import load_config
from sdit_path.errormodel.errorset import ErrorSet
from sdit_path.errormodel.model import ModelOptions, build_model, prior_scale
from sdit_path.identify.identify import _schur, experiment_gram, identify
from sdit_path.output import write_tree
from sdit_path.plan.pipeline import plan
from sdit_path.plan.files import load_plan
from sdit_path.plan.manifest import plan_directory_files
from sdit_path.sim.simulate import simulate_trace
from memory import peak_memory_line

NOISE_UM = 0.2
QUANT_UM = 0.1


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="two layers, few trials (smoke test)")
    args = ap.parse_args()
    cfg = load_config()
    result = plan(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        write_tree(Path(tmp) / "plan", plan_directory_files(result))
        pf = load_plan(Path(tmp) / "plan")
        options = ModelOptions(linear_order=1, squareness=True, location=False)
        model = build_model(cfg.machine, pf.tested_travel(), options)
        rng = np.random.default_rng(2026)
        truth = ErrorSet("bench", options, tuple((p.name, float(rng.normal(0, prior_scale(p))))
                                                 for p in model.parameters))
        programs = pf.program_names[:2] if args.quick else pf.program_names
        traces = [(pf, prog, simulate_trace(pf, prog, truth, noise_um=NOISE_UM,
                                            quantisation_um=QUANT_UM, seed=1)) for prog in programs]
        n = sum(len(t.t_s) for _, _, t in traces)
        t0 = time.perf_counter()
        report = identify(traces, options).to_json()
        dt = time.perf_counter() - t0
        print(f"identification, {len(programs)} layer traces at 1 kHz ({n:,} samples), "
              f"{len(model.parameters)} parameters: {dt:.2f} s ({n / dt:,.0f} samples/s); "
              f"rank {report['rank']}, determined {report['determined']}, "
              f"noise estimate {report['noise_std_um']:.4f} um")

        # Cramer-Rao: one layer, many noise seeds
        prog = programs[-1]
        g = experiment_gram(pf, prog, None, model)
        S, _, _, _ = _schur([g])
        lam, V = np.linalg.eigh(S)
        order = np.argsort(lam)[::-1]
        lam, V = lam[order], V[:, order]
        sigma2 = NOISE_UM ** 2 + QUANT_UM ** 2 / 12.0
        positive = lam > lam[0] * 1e-12
        crb = np.where(positive, sigma2 / np.where(positive, lam, 1.0), np.inf)
        keep = np.sqrt(crb) < 0.5  # the determined combinations (scaled units)
        trials = 4 if args.quick else args.trials
        estimates = []
        for seed in range(trials):
            tr = simulate_trace(pf, prog, truth, noise_um=NOISE_UM, quantisation_um=QUANT_UM,
                                seed=100 + seed)
            gt = experiment_gram(pf, prog, tr, model)
            _, r, _, _ = _schur([gt])
            estimates.append((V.T @ r) / np.where(positive, lam, 1.0))
        est = np.array(estimates)[:, keep]
        ratio = est.var(axis=0, ddof=1) / crb[keep]
        print(f"estimator variance / Cramer-Rao bound over {trials} seeded trials, "
              f"{int(keep.sum())} determined combinations of layer {prog}: mean "
              f"{ratio.mean():.3f}, median {np.median(ratio):.3f}, max {ratio.max():.3f} "
              f"(target mean <= 1.2; the max of {int(keep.sum())} ratios from {trials} trials "
              f"scatters by about +-{math.sqrt(2 / (trials - 1)) * 100:.0f} %)")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
