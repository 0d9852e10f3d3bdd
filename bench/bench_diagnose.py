"""Diagnosis speed on a one-hour trace at 1 kHz (3.6 million samples).

    python bench/bench_diagnose.py [--plan DIR] [--feed F] [--config TOML --program NAME]

Plans layer A of the default 3-axis sample at F37 (about an hour with its dwells),
makes a measured trace with hidden effects (set-up offset, servo lag, backlash;
seeded), then times what ``sdit-path diagnose --json`` does: read the plan and the
trace file, align, localise, explain, report.  Prints the ratio of the trace's
duration to the diagnosis time (target >= 60: an hour in at most a minute).  With
``--config`` and ``--program``, another config's program at ``--feed`` (the suite's
smoke test: a small config, so that it stays short).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sdit_path.config import sample_path  # noqa: E402
from sdit_path.reading.context import build_context  # noqa: E402
from sdit_path.diagnose import diagnose  # noqa: E402
from sdit_path.reports.diagnosis import summary_text  # noqa: E402
from sdit_path.errormodel.errorset import load_error_set  # noqa: E402
from sdit_path.plan.files import load_plan  # noqa: E402
from sdit_path.reading.recording import measured_csv  # noqa: E402
from sdit_path.sim.perturb import draw_effect, draw_recording, perturb  # noqa: E402
from sdit_path.reading.recording import read_trace  # noqa: E402
from memory import peak_memory_line  # noqa: E402

PROGRAM = "SDIT_A"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plan", type=Path, default=None, help="Reuse a plan made at F37.")
    ap.add_argument("--feed", type=float, default=37.0)
    ap.add_argument("--config", type=Path, default=None,
                    help="Plan this config instead of the bundled 3-axis sample.")
    ap.add_argument("--program", default=PROGRAM)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        plan_dir = args.plan
        if plan_dir is None:
            cfg = tmp / "hour.toml"
            text = (args.config or sample_path("vmc_3axis.toml")).read_text()
            cfg.write_text(re.sub(r"(?m)^feed_mm_per_min\s*=\s*[0-9.eE+-]+",
                                  f"feed_mm_per_min = {args.feed}", text, count=1))
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", "from sdit_path.cli import main; main()", "plan",
                            str(cfg), "--out", str(tmp / "plan"), "--force", "-q"], check=True)
            print(f"plan at F{args.feed:g}: {time.perf_counter() - t0:.0f} s (not timed)")
            plan_dir = tmp / "plan"
        plan = load_plan(plan_dir)
        model = load_error_set("paper_table2")
        program = args.program
        ctx = build_context(plan, program)
        rng = np.random.default_rng([7, 11])
        hidden = [draw_effect(n, rng, ctx) for n in ("setup_offset", "servo_lag", "backlash")]
        trace, _truth = perturb(plan, program, model, hidden, draw_recording(7), 7, ctx)
        path = tmp / "hour.csv"
        path.write_text(measured_csv(trace))
        del ctx, trace, plan
        duration = None
        t0 = time.perf_counter()
        plan = load_plan(plan_dir)
        measured = read_trace(path)
        t_read = time.perf_counter() - t0
        result = diagnose(plan, program, measured, model)
        report = json.dumps(result.to_json())
        summary_text(result)
        seconds = time.perf_counter() - t0
        duration = float(measured.t_s[-1] - measured.t_s[0])
    n = len(measured.t_s)
    print(f"trace: {n} samples, {duration:.0f} s at 1 kHz; hidden: "
          f"{', '.join(h.name for h in hidden)}")
    found = ", ".join(" or ".join([f.effect, *f.ambiguous_with]) for f in result.findings)
    print(f"found: {found or '-'}; unexplained {result.unexplained['rms_um']:.3f} um; "
          f"report {len(report)} bytes")
    print(f"diagnosis {seconds:.1f} s (reading plan + trace {t_read:.1f} s)")
    print(f"ratio trace duration / diagnosis time: {duration / seconds:.1f} (target >= 60)")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
