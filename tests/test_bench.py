"""The benchmarks keep running (they print measured ratios; nothing here asserts a
time)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "bench"


def test_plan_benchmark_runs_and_prints_its_ratio():
    r = subprocess.run([sys.executable, str(BENCH / "bench_plan.py")], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "ratio BSPLINE / G1" in r.stdout and "max radial deviation sinumerik840d" in r.stdout


def test_timing_benchmark_runs_and_prints_its_ratios():
    r = subprocess.run([sys.executable, str(BENCH / "bench_timing.py"), "--feeds", "5000",
                        "--layers", "E"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "layer E: ruckig" in r.stdout and "ruckig/LB" in r.stdout
    assert "F5000: worst layer ratio" in r.stdout


def test_jerk_estimate_runs_and_prints_its_ratios():
    r = subprocess.run([sys.executable, str(BENCH / "jerk_estimate.py"), "--layers", "E",
                        "--runs", "1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "layer E        all runs" in r.stdout and "ruckig/estimate" in r.stdout


def test_interference_benchmark_runs_and_prints_its_ratio():
    r = subprocess.run([sys.executable, str(BENCH / "bench_interference.py")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "poses/s" in r.stdout and "ratio" in r.stdout


def test_identification_benchmark_runs_and_prints_its_ratio():
    r = subprocess.run([sys.executable, str(BENCH / "bench_identify.py"), "--quick"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    assert "samples/s" in r.stdout and "Cramer-Rao bound" in r.stdout


def test_diagnosis_benchmark_runs_and_prints_its_ratio():
    """On the small golden config (a two-minute trace, planned in seconds) so that the
    test stays short; the benchmark itself is the hour of the sample at F37."""
    r = subprocess.run([sys.executable, str(BENCH / "bench_diagnose.py"), "--config",
                        str(BENCH.parent / "tests" / "data" / "golden_small.toml"),
                        "--program", "GOLD_A", "--feed", "1000"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    assert "ratio trace duration / diagnosis time" in r.stdout


def test_perturb_selfcheck_runs_and_prints_its_scores(plan_f1500):
    """On the plan the diagnosis tests read (the self-check's own: the sample at F1500);
    two cases at a time, on the machine's two cores."""
    r = subprocess.run([sys.executable, str(BENCH / "perturb_selfcheck.py"), "--cases", "4",
                        "--jobs", "2", "--plan", str(plan_f1500)], capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    for key in ("top-1 effect", "false findings, clean traces", "honest outside the library",
                "held-out shrink"):
        assert key in r.stdout


def test_fuzz_campaign_runs_a_bounded_sample():
    """A bounded sample of the outside fuzzing campaign: mutated configs planned end to
    end in their own processes, none ending in a traceback, a signal or a hang."""
    r = subprocess.run([sys.executable, str(BENCH / "fuzz_campaign.py"), "--cases", "6",
                        "--seed", "3", "--timeout", "300"], capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "6 mutated configs planned end to end" in r.stdout and "failures: 0" in r.stdout
