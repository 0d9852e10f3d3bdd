"""End-to-end time of ``sdit-path analyse`` on the five layers of the default sample at
1 kHz (issue 16: target at most 60 s): recordings made by ``perturb`` with Table 2's
geometry, a servo mismatch, a set-up offset, and unknown starts and clocks; the
programs not named (recognised).  Prints the time per stage from the progress lines and
the ratio of recorded time to analysis time.

    python bench/bench_analyse.py [--work DIR] [--config vmc_3axis]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from memory import peak_memory_line


def cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                          text=True, **kw)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work")
    ap.add_argument("--config", default="vmc_3axis")
    a = ap.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="bench-analyse-"))
    plan = work / "plan"
    if not plan.is_dir():
        r = cli("plan", a.config, "--out", str(plan), "-q")
        if r.returncode:
            sys.exit(r.stderr)
    names = [p.name.removesuffix(".ngc") for p in sorted((plan / "linuxcnc").glob("*.ngc"))]
    files, recorded = [], 0.0
    for k, prog in enumerate(names):
        f = work / f"{prog}.csv"
        if not f.is_file():
            r = cli("perturb", "--plan", str(plan), "--program", prog, "--model", "paper_table2",
                    "--effect", "servo_mismatch:axis=X,extra_lag_ms=0.8",
                    "--effect", "setup_offset:dx_um=12,dy_um=-7,dz_um=20",
                    "--lead-s", str(3.0 + 2.5 * k), "--clock-ppm", str(-120.0 + 60.0 * k),
                    "--noise-um", "0.2", "--out", str(f), "-q")
            if r.returncode:
                sys.exit(r.stderr)
        files.append(f)
        with f.open() as fh:
            last = fh.readlines()[-1]
        recorded += float(last.split(",")[0])
    args = ["analyse", "--plan", str(plan), "--out", str(work / "out"), "--force"]
    for f in files:
        args += ["--measured", str(f)]
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "sdit_path", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    stamps = []
    for line in proc.stderr:
        stamps.append((time.perf_counter() - t0, line.strip()))
    proc.wait()
    total = time.perf_counter() - t0
    if proc.returncode:
        sys.exit("\n".join(s for _, s in stamps[-3:]))
    ends = [t for t, _ in stamps[1:]] + [total]
    for (t, line), end in zip(stamps, ends):
        print(f"{end - t:7.1f} s  {line}")
    import json

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from sdit_path.errormodel.errorset import load_error_set

    truth = load_error_set("paper_table2").as_dict()
    rep = json.loads((work / "out" / "analysis.json").read_text())
    print("\nTable 2's errors against the determined combinations (z = error / stated std):")
    for c in rep["geometry"]["combinations"]:
        value = sum(t["coefficient"] * truth.get(t["parameter"], 0.0) for t in c["terms"])
        print(f"  z {abs(c['estimate'] - value) / c['std']:5.2f}  truth {value:9.3f}  {c['text']}")
    for x in rep["recordings"]:
        print(f"  {x['file']}: {x['program']}, findings "
              + ", ".join(f["effect"] for f in x["diagnosis"]["findings"]))
    print(f"\n{len(files)} recordings, {recorded:.0f} s recorded at 1 kHz; analysis {total:.1f} s "
          f"end to end (target 60 s); recorded time / analysis time = {recorded / total:.2f}")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
