"""Peak memory of whole commands, all their processes together, beside their time.

The tools run on a shop PC beside the machine (8 GB, other work open): the target is
1 GB for the whole command, its worker processes included.  Each command runs as a
subprocess; every 50 ms the proportional set size of it and all its descendants is
summed from /proc (``Pss`` of ``smaps_rollup``: a page shared by forked workers counts
once, split between them, where resident sizes would count it in every worker), and the
largest sum is its peak.  Printed per command: wall time, the peak of the whole tree,
the largest resident size of a single process, and the whole tree's peak against the
target.

Commands (``--only`` picks some):

* ``analyse``: the README's walkthrough, five 1 kHz layers of the default sample
  recorded by ``perturb``, analysed with the default workers;
* ``replan``: ``replan --analysis`` of that analysis (on the default sample no segment
  is bad, so nothing is searched), and ``replan --segment D3-2``, whose sector is
  searched for a new curve (candidates in worker processes);
* ``diagnose``: one recording an hour long (layer A of the default sample planned at
  F40, 56 min, recorded by ``perturb`` at 1 kHz).

    python bench/bench_memory.py [--work DIR] [--only analyse,replan,diagnose]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from memory import peak_memory_line

TARGET_MB = 1024.0
CLI = [sys.executable, "-m", "sdit_path"]


def _kb(pid: int, path: str, key: str) -> int:
    try:
        with open(f"/proc/{pid}/{path}") as fh:
            for line in fh:
                if line.startswith(key):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def _children(pid: int) -> list[int]:
    out = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as fh:
                out += [int(x) for x in fh.read().split()]
    except OSError:
        pass
    return out


def _tree(pid: int) -> list[int]:
    todo, seen = [pid], []
    while todo:
        p = todo.pop()
        seen.append(p)
        todo += _children(p)
    return seen


def measured(args: list[str], cwd: Path) -> tuple[float, float, float, subprocess.CompletedProcess]:
    """(wall s, peak MB of the whole process tree, peak MB of one process, result)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    peak = {"tree": 0, "one": 0}

    def watch():
        while proc.poll() is None:
            tree = _tree(proc.pid)
            peak["tree"] = max(peak["tree"], sum(_kb(p, "smaps_rollup", "Pss:") for p in tree))
            peak["one"] = max(peak["one"], max((_kb(p, "status", "VmRSS:") for p in tree),
                                               default=0))
            time.sleep(0.05)

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    out, err = proc.communicate()
    th.join()
    wall = time.perf_counter() - t0
    return wall, peak["tree"] / 1024.0, peak["one"] / 1024.0, subprocess.CompletedProcess(
        args, proc.returncode, out, err)


def _run(args: list[str], cwd: Path) -> None:
    r = subprocess.run(CLI + args, cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"bench_memory: {' '.join(args[:2])} failed: {r.stderr.strip()[-400:]}")


def _walkthrough(work: Path) -> list[str]:
    """The README's five recordings of a fresh plan P (made once per work folder)."""
    if not (work / "P" / "plan.json").is_file():
        _run(["plan", "--out", "P", "--force", "-q"], work)
    recs = []
    for k, layer in enumerate("ABCDE", start=1):
        rec = work / f"rec_{layer}.csv"
        if not rec.is_file():
            _run(["perturb", "--plan", "P", "--program", f"SDIT_{layer}", "--model",
                  "paper_table2", "--seed", str(k), "--effect",
                  "servo_mismatch:axis=X,extra_lag_ms=0.8", "--effect", "setup_offset",
                  "--out", rec.name, "-q"], work)
        recs += ["--measured", rec.name]
    return recs


def _hour(work: Path) -> Path:
    """Layer A of the default sample at F40 (56 min) and a 1 kHz recording of it."""
    from sdit_path.config import sample_path

    cfg = work / "hour.toml"
    text = sample_path("vmc_3axis.toml").read_text()
    text = text.replace("track_elevations_deg = [0.0, 18.0, 36.0, 54.0, 72.0]",
                        "track_elevations_deg = [0.0, 18.0]")
    text = text.replace("feed_mm_per_min = 600.0", "feed_mm_per_min = 40.0")
    cfg.write_text(text)
    if not (work / "H" / "plan.json").is_file():
        _run(["plan", str(cfg), "--out", "H", "--force", "-q"], work)
    rec = work / "hour.csv"
    if not rec.is_file():
        _run(["perturb", "--plan", "H", "--program", "SDIT_A", "--model", "paper_table2",
              "--seed", "4", "--effect", "servo_mismatch:axis=X,extra_lag_ms=0.8", "--out",
              rec.name, "-q"], work)
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default=None, help="folder for the plans and recordings "
                                                 "(kept between runs; default: a new one)")
    ap.add_argument("--only", default="analyse,replan,diagnose")
    a = ap.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="bench-memory-"))
    work.mkdir(parents=True, exist_ok=True)
    only = set(a.only.split(","))
    rows = []
    if only & {"analyse", "replan"}:
        recs = _walkthrough(work)
        if "analyse" in only or not (work / "analysis" / "analysis.json").is_file():
            wall, tree, one, r = measured(CLI + ["analyse", "--plan", "P", *recs, "--out",
                                                 "analysis", "--force", "-q"], work)
            if r.returncode != 0:
                sys.exit(f"bench_memory: analyse failed: {r.stderr.strip()[-400:]}")
            rows.append(("analyse, five 1 kHz layers", wall, tree, one))
        if "replan" in only:
            wall, tree, one, r = measured(CLI + ["replan", "--plan", "P", "--analysis",
                                                 "analysis/analysis.json", "--out", "R",
                                                 "--force", "-q"], work)
            if r.returncode != 0:
                sys.exit(f"bench_memory: replan failed: {r.stderr.strip()[-400:]}")
            rows.append(("replan --analysis", wall, tree, one))
            wall, tree, one, r = measured(CLI + ["replan", "--plan", "P", "--segment", "D3-2",
                                                 "--out", "R2", "--force", "-q"], work)
            if r.returncode != 0:
                sys.exit(f"bench_memory: replan --segment failed: {r.stderr.strip()[-400:]}")
            rows.append(("replan --segment D3-2", wall, tree, one))
    if "diagnose" in only:
        rec = _hour(work)
        wall, tree, one, r = measured(CLI + ["diagnose", "--plan", "H", "--program", "SDIT_A",
                                             "--measured", rec.name, "--model", "paper_table2",
                                             "-q"], work)
        if r.returncode != 0:
            sys.exit(f"bench_memory: diagnose failed: {r.stderr.strip()[-400:]}")
        rows.append(("diagnose, one hour at 1 kHz", wall, tree, one))
    print(f"work folder: {work}")
    print(f"{'command':32} {'wall s':>8} {'peak MB, all processes (PSS)':>29} "
          f"{'largest RSS':>12} {'/ 1 GB':>7}")
    for name, wall, tree, one in rows:
        print(f"{name:32} {wall:8.1f} {tree:29.0f} {one:12.0f} {tree / TARGET_MB:7.2f}")
    print(peak_memory_line())


if __name__ == "__main__":
    main()
