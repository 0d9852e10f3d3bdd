"""A fuzzing campaign from the outside: seeded mutations of the configs (the mutator of
``mutate.py``, which ``tests/test_hostile.py`` draws from too), each planned end to end
by ``sdit-path plan`` in its own process with a time limit, counting what happened.  Nothing may end in a traceback, a
signal (segmentation fault, abort), a hang or more than one error line.

    python validation/fuzz_campaign.py [--cases 100] [--seed 1] [--timeout 120] [--jobs 2]

Half the cases scale numbers (mostly plausible configs that reach the planner's
corners), half are the structural mutations of the tests.  Mutations are applied to the small golden config (two tracks, three nodes), so a plan
takes seconds; the accepted ones are planned for real (reach, interference, timing,
posts, lint, files).
"""

from __future__ import annotations

import argparse
import collections
import random
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from mutate import mutate_config  # noqa: E402

SMALL = HERE.parent / "tests" / "data" / "golden_small.toml"


_NUMBER = r"(?<![\w.])-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"


def _mutate_numbers(text: str, rng: random.Random) -> str:
    """Scale one to three numbers of the config by 10^U(-3, 3), sometimes flipping the
    sign: mostly plausible configs that reach the planner's corners."""
    import re

    lines = text.splitlines()
    for _ in range(rng.randint(1, 3)):
        cand = [i for i, ln in enumerate(lines)
                if "=" in ln and not ln.lstrip().startswith("#") and re.search(_NUMBER, ln)]
        i = rng.choice(cand)
        key, value = lines[i].split("=", 1)
        value = value.split("#", 1)[0]
        matches = list(re.finditer(_NUMBER, value))
        m = rng.choice(matches)
        x = float(m.group(0)) * 10 ** rng.uniform(-3, 3) * (-1 if rng.random() < 0.15 else 1)
        new = f"{x:.6g}" if "." in m.group(0) or "e" in m.group(0) else str(int(round(x)))
        if "." not in new and "e" not in new and "." in m.group(0):
            new += ".0"
        lines[i] = key + "=" + value[:m.start()] + new + value[m.end():]
    return "\n".join(lines) + "\n"


def one(k: int, text: str, timeout: float) -> tuple[str, str]:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / f"fuzz{k}.toml"
        cfg.write_text(text, encoding="utf-8")
        try:
            r = subprocess.run([sys.executable, "-m", "sdit_path", "plan", str(cfg), "--out",
                                str(Path(tmp) / "out"), "-q"], capture_output=True, text=True,
                               timeout=timeout)
        except subprocess.TimeoutExpired:
            return "hang", text
    if r.returncode < 0:
        return f"signal {-r.returncode}", text
    if "Traceback" in r.stderr:
        return "traceback", r.stderr[-2000:]
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("sdit-path: error:")]
    if r.returncode != 0 and len(errors) != 1:
        return "not one error line", r.stderr[-2000:]
    return f"exit {r.returncode}", ""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    base = SMALL.read_text(encoding="utf-8")
    texts = [(_mutate_numbers if k % 2 == 0 else mutate_config)(base, rng)
             for k in range(args.cases)]
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda kt: one(kt[0], kt[1], args.timeout), enumerate(texts)))
    counts = collections.Counter(kind for kind, _ in results)
    print(f"{args.cases} mutated configs planned end to end (seed {args.seed}):")
    for kind, n in sorted(counts.items()):
        print(f"  {kind:20s} {n}")
    bad = [(k, kind, detail) for k, (kind, detail) in enumerate(results)
           if not kind.startswith("exit")]
    for k, kind, detail in bad[:5]:
        print(f"--- case {k}: {kind}\n{detail}")
    print(f"failures: {len(bad)}")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
