"""The validation pages, generated from the campaigns' JSON: every figure on
``docs/validation/index.md`` is printed here from a results file under
``validation/results/``, by the same scoring code the campaign prints with, beside the
command that made the file and the one that prints its figures.

    python validation/tables.py > docs/validation/index.md

``tests/test_validation_pages.py`` checks that the page is this script's output.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
RESULTS = HERE / "results"


@dataclass(frozen=True)
class Campaign:
    title: str
    results: str  # file name under validation/results/
    made_by: str  # the command that wrote it
    printed_by: str  # the command that prints its figures
    what: str  # what it scores, in a few lines


def _blind(rows: list) -> None:
    import blind_check

    blind_check.table(rows)


def _analyse(rows: list) -> None:
    import analyse_blind

    analyse_blind.summary(rows)


def _selfcheck(rows: list) -> None:
    import perturb_selfcheck

    perturb_selfcheck.summary(rows, 1500.0)


SCORERS = {"blind": _blind, "analyse": _analyse, "selfcheck": _selfcheck}

CAMPAIGNS = (
    (Campaign(
        "Blind check of the diagnosis, the domain brief's bad magnitudes",
        "blind_bad.json",
        "python validation/blind_check.py --plans PLANS --per-program 17 --seed 1 --jobs 2 "
        "--json validation/results/blind_bad.json",
        "python validation/blind_check.py --rescore validation/results/blind_bad.json",
        "Recordings of the independent generator (`physics_gen.py`: its own kinematics, "
        "effects acting on the machine axes, its own instrument and a set-up residual in "
        "every trace; nothing of sdit-path) of three programs: SDIT_C of the default sample "
        "at F600, SDIT_B of it at F2000 and SDIT5_C of the 5-axis sample. Per program the "
        "cases take in turn two clean recordings, each effect of the generator and each "
        "effect outside the library. The diagnosis reads the recording's file and the plan, "
        "nothing else; only then is it scored against the truth the generator kept."),
     "blind"),
    (Campaign(
        "Blind check of the diagnosis, typical magnitudes",
        "blind_typical.json",
        "python validation/blind_check.py --plans PLANS --per-program 17 --seed 1 --jobs 2 "
        "--magnitudes typical --json validation/results/blind_typical.json",
        "python validation/blind_check.py --rescore validation/results/blind_typical.json",
        "As above, with the effects drawn at the magnitudes of a healthy machine (the "
        "domain brief's typical column): smaller, closer to the noise."),
     "blind"),
    (Campaign(
        "Blind check of `analyse`",
        "analyse_blind.json",
        "python validation/analyse_blind.py --cases 3 --seed 1 --json "
        "validation/results/analyse_blind.json",
        "python validation/analyse_blind.py --rescore validation/results/analyse_blind.json",
        "Recordings of both programs of `tests/data/golden_small.toml` made by `perturb` "
        "with hidden random geometry, one hidden effect of the machine (the same in both), "
        "a set-up offset and an unknown start, clock and noise; `analyse` sees the plan and "
        "the files. Scored: every determined combination within three standard "
        "uncertainties, the effect named, the start and clock, and the refusal of "
        "recordings of another feed, another plan, or named as another program."),
     "analyse"),
    (Campaign(
        "Self-check of the diagnosis on `perturb`'s recordings (not blind)",
        "selfcheck.json",
        "python validation/perturb_selfcheck.py --cases 8 --jobs 2 --json "
        "validation/results/selfcheck.json",
        "python validation/perturb_selfcheck.py --rescore validation/results/selfcheck.json",
        "`perturb` builds its recordings with the diagnosis' own context, so this is a "
        "self-consistency check, not a blind one: the default sample at F1500, Table 2's "
        "geometry, clean traces, one or several hidden effects of the library and effects "
        "outside it."),
     "selfcheck"),
)


def page() -> str:
    out = io.StringIO()
    w = out.write
    w("# Validation\n\n"
      "Current figures of the validation campaigns. Each table is printed from a results "
      "file under `validation/results/` by the campaign's own scoring code; the file was "
      "made by the command given, and the second command prints the table again. This "
      "page is generated:\n\n"
      "```sh\npython validation/tables.py > docs/validation/index.md\n```\n\n"
      "History (earlier figures, with the commit they were measured at) is in the "
      "[CHANGELOG](../../CHANGELOG.md). The recordings that motivated a rule of the "
      "diagnosis are named in `validation/hard_cases.toml`; the speed benchmarks are in "
      "`bench/` ([testing](../development/testing.md)).\n")
    for campaign, kind in CAMPAIGNS:
        w(f"\n## {campaign.title}\n\n{campaign.what}\n\n")
        path = RESULTS / campaign.results
        w(f"Made by `{campaign.made_by}`; printed by `{campaign.printed_by}`.\n\n")
        if not path.exists():
            w("(No results file yet.)\n")
            continue
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            SCORERS[kind](json.loads(path.read_text(encoding="utf-8")))
        w("```\n" + buf.getvalue().strip("\n") + "\n```\n")
    return out.getvalue()


if __name__ == "__main__":
    sys.stdout.write(page())
