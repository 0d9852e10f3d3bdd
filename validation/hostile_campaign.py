"""The hostile-input campaign: what a careless or hostile user hands sdit-path, each case
run by the command line in its own process with a time limit, counting what happened.
Nothing may end in a traceback, a signal (segmentation fault, abort), a hang, more than
one error line, or exit 0 where the input must be refused (a wrong success).

    python validation/hostile_campaign.py [--kinds config,recording,plan] [--cases 40]
                                          [--seed 1] [--timeout 300] [--jobs 2]

Kinds (``--cases`` mutations of each seeded kind):

* ``config``: seeded mutations of the small golden config (``mutate.py``: numbers scaled
  by 10^U(-3, 3) in half of them, the structural mutations in the other half), planned
  end to end (reach, interference, timing, posts, lint, files): exit 0 or one error line.
* ``recording``: a recording of GOLD_A (``simulate`` with Table 2's errors and noise,
  as an instrument exports it: time and reading) edited by ``mutate.py``'s trace mutations, given to ``identify`` and to ``diagnose``:
  exit 0 or one error line; then every case of ``hostile_cases.RECORDING_CASES`` (a
  reading of 1e308, one row, a tenth of the program, ...), which must end with its exit
  code and name what is wrong.
* ``plan``: every edit of ``hostile_cases.PLAN_EDITS`` (a manifest edited with or
  without its seal, trajectories swapped, cut, renamed, a NaN, ...) applied to a copy of
  the plan, then ``simulate``, ``identify`` and ``diagnose`` in turn: each must refuse
  it (exit 2 or 5) with one line; an exit 0 is a wrong success.  Without ``--all-edits``
  the edits are drawn (``--cases`` of them, seeded).

Atomicity under kills, a full disk, determinism and injection of user text into the
programs are checked by ``tests/test_hostile.py`` (they need no sampling).
"""

from __future__ import annotations

import argparse
import collections
import random
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from hostile_cases import PLAN_EDITS, RECORDING_CASES  # noqa: E402
from mutate import mutate_config, mutate_numbers, mutate_trace  # noqa: E402

SMALL = HERE.parent / "tests" / "data" / "golden_small.toml"
CLI = [sys.executable, "-m", "sdit_path"]
PROGRAM = "GOLD_A"


def _run(args: list[str], timeout: float) -> subprocess.CompletedProcess | None:
    try:
        return subprocess.run(CLI + args, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None


def outcome(r: subprocess.CompletedProcess | None, refuse: bool = False,
            code: int | None = None, expected: str | None = None) -> str:
    """What one run did: ``exit N`` when it behaved, else the failure's kind.  ``refuse``:
    the input must be refused (exit 0 is a wrong success); ``code``/``expected``: the
    exit code and a piece of the error line it must end with."""
    if r is None:
        return "hang"
    if r.returncode < 0:
        return f"signal {-r.returncode}"
    if "Traceback" in r.stderr:
        return "traceback"
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("sdit-path: error:")]
    if r.returncode != 0 and len(errors) != 1:
        return "not one error line"
    if r.returncode == 0 and (refuse or code not in (None, 0)):
        return "wrong exit 0"
    if code is not None and r.returncode != code:
        return f"exit {r.returncode}, not {code}"
    if expected is not None and r.returncode != 0 and expected not in errors[0]:
        return "error line without what is wrong"
    return f"exit {r.returncode}"


def _config_case(k: int, text: str, timeout: float) -> tuple[str, str]:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / f"fuzz{k}.toml"
        cfg.write_text(text, encoding="utf-8")
        r = _run(["plan", str(cfg), "--out", str(Path(tmp) / "out"), "-q"], timeout)
    return outcome(r), (r.stderr[-1500:] if r is not None else text[:1500])


def _reading_commands(plan: Path, rec: Path) -> list[list[str]]:
    return [["identify", "--plan", str(plan), "--trace", str(rec), "--program", PROGRAM],
            ["diagnose", "--plan", str(plan), "--program", PROGRAM, "--measured", str(rec), "-q"]]


def _recording_case(plan: Path, name: str, text: str, timeout: float,
                    code: int | None = None, expected: str | None = None) -> tuple[str, str]:
    """The recording read by each command in turn: the first that misbehaves, else the
    last one's exit."""
    got = "exit 0"
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / f"{name}.csv"
        rec.write_text(text, encoding="utf-8")
        for args in _reading_commands(plan, rec):
            r = _run(args, timeout)
            got = outcome(r, code=code, expected=expected)
            if not got.startswith("exit ") or "," in got:
                return got, f"{args[0]}: " + (r.stderr[-1500:] if r is not None else "")
    return got, ""


def _plan_case(plan: Path, name: str, rec: Path, timeout: float) -> tuple[str, str]:
    edit, expected = PLAN_EDITS[name]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "plan"
        shutil.copytree(plan, d)
        edit(d)
        commands = [["simulate", "--plan", str(d), "--program", PROGRAM, "--errors",
                     "paper_table2", "--out", str(Path(tmp) / "s.csv"), "-q"],
                    *_reading_commands(d, rec)]
        for args in commands:
            r = _run(args, timeout)
            got = outcome(r, refuse=True, expected=expected)
            if not got.startswith("exit ") or got == "exit 0":
                return got, f"{args[0]}: " + (r.stderr[-1500:] if r is not None else "")
            if got not in ("exit 2", "exit 5"):
                return f"{got}, not 2 or 5", f"{args[0]}: " + r.stderr[-1500:]
    return "refused", ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kinds", default="config,recording,plan")
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=300.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--all-edits", action="store_true", help="every plan edit, not a sample")
    a = ap.parse_args()
    kinds = a.kinds.split(",")
    unknown = set(kinds) - {"config", "recording", "plan"}
    if unknown:
        sys.exit(f"hostile_campaign: unknown kind(s) {', '.join(sorted(unknown))}")
    rng = random.Random(a.seed)
    jobs: list[tuple[str, str, object]] = []
    with tempfile.TemporaryDirectory() as tmp:
        plan, rec = Path(tmp) / "plan", Path(tmp) / "rec.csv"
        if {"recording", "plan"} & set(kinds):
            for args in (["plan", str(SMALL), "--out", str(plan), "-q"],
                         ["simulate", "--plan", str(plan), "--program", PROGRAM, "--errors",
                          "paper_table2", "--noise-um", "0.2", "--out", str(rec), "-q"]):
                r = _run(args, a.timeout)
                if r is None or r.returncode != 0:
                    sys.exit(f"hostile_campaign: {args[0]} failed: "
                             f"{r.stderr[-400:] if r is not None else 'timed out'}")
            # as a ballbar's software exports it: time and reading, no labels of ours
            rec.write_text("".join(ln if ln.startswith("#") else ",".join(ln.split(",")[:2]) + "\n"
                                   for ln in rec.read_text().splitlines(keepends=True)))
        if "config" in kinds:
            base = SMALL.read_text(encoding="utf-8")
            for k in range(a.cases):
                text = (mutate_numbers if k % 2 == 0 else mutate_config)(base, rng)
                jobs.append(("config", f"config {k}",
                             lambda k=k, text=text: _config_case(k, text, a.timeout)))
        if "recording" in kinds:
            text = rec.read_text(encoding="utf-8")
            for k in range(a.cases):
                mutated = mutate_trace(text, rng)
                jobs.append(("recording", f"recording {k}", lambda k=k, m=mutated:
                             _recording_case(plan, f"m{k}", m, a.timeout)))
            for name, (mutate, code, expected) in sorted(RECORDING_CASES.items()):
                jobs.append(("recording", name, lambda name=name, mutate=mutate, code=code,
                             expected=expected: _recording_case(plan, "case", mutate(text),
                                                                a.timeout, code, expected)))
        if "plan" in kinds:
            names = sorted(PLAN_EDITS)
            if not a.all_edits:
                names = sorted(rng.sample(names, min(a.cases, len(names))))
            for name in names:
                jobs.append(("plan", name, lambda name=name: _plan_case(plan, name, rec,
                                                                        a.timeout)))
        with ThreadPoolExecutor(max(1, a.jobs)) as pool:
            results = list(pool.map(lambda job: job[2](), jobs))
    print(f"hostile-input campaign (seed {a.seed}), each case in its own process:")
    failures = []
    for kind in kinds:
        mine = [(label, res) for (k, label, _), res in zip(jobs, results) if k == kind]
        counts = collections.Counter(res[0] for _, res in mine)
        print(f"  {kind}: {len(mine)} case(s): "
              + ", ".join(f"{what} {n}" for what, n in sorted(counts.items())))
        failures += [(kind, label, res) for label, res in mine
                     if not (res[0].startswith("exit ") and "," not in res[0]
                             or res[0] == "refused")]
    tally = collections.Counter(res[0].split(",")[0] for _, _, res in failures)
    print(f"tracebacks: {tally['traceback']}, wrong exits 0: {tally['wrong exit 0']}, "
          f"signals: {sum(n for k, n in tally.items() if k.startswith('signal'))}, "
          f"hangs: {tally['hang']}")
    for kind, label, (what, detail) in failures[:5]:
        print(f"--- {kind} {label}: {what}\n{detail}")
    print(f"failures: {len(failures)}")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
