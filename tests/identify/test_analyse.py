"""``sdit-path analyse`` on recordings made by ``perturb`` with hidden geometry (linear
order 1 + squareness), a hidden servo mismatch, unknown start and clock: the programs
are recognised, the geometry is recovered within its stated uncertainty, the effect is
named, and a recording of another feed is refused with one line and nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from browser import CHROMIUM, check_page, open_in_chromium, pdf_pages
from conftest import run  # noqa: E402

# one worker takes the module: its recordings and their analysis (a minute and a half)
# are made once, not once per worker (scripts/test.sh runs pytest --dist loadgroup)
pytestmark = pytest.mark.xdist_group("analyse")


@pytest.mark.slow
def test_recognised_aligned_and_geometry_within_its_uncertainty(recorded, tmp_path):
    r = recorded["run"]
    assert r.returncode == 0, r.stderr
    rep = json.loads((recorded["out"] / "analysis.json").read_text())
    progs = {x["file"]: x["program"] for x in rep["recordings"]}
    assert progs == {str(recorded["files"][0]): "GOLD_A", str(recorded["files"][1]): "GOLD_B"}
    for x, k in ((rep["recordings"][0], 1), (rep["recordings"][1], 0)):
        t = json.loads((recorded["root"] / f"truth{k}.json").read_text())["recording"]
        al = x["diagnosis"]["alignment"]
        assert abs(al["clock_ppm"] - t["clock_ppm"]) <= max(5.0, 4 * al["clock_std_ppm"]), (al, t)
        # the lag of the common servo is part of the offset: within 50 ms of the start
        assert abs(al["offset_s"] - t["offset_s"]) < 0.05, (al, t)
        assert x["diagnosis"]["findings"], x
        named = [f["effect"] for f in x["diagnosis"]["findings"] if f["effect"] not in
                 ("setup_offset", "bar_length", "squareness", "scale_mismatch")]
        assert named and named[0] == "servo_mismatch", named
    geo = rep["geometry"]
    assert geo["combinations"]
    truth = recorded["truth"]
    misses = []
    for c in geo["combinations"]:
        value = sum(term["coefficient"] * truth.get(term["parameter"], 0.0) for term in c["terms"])
        if abs(c["estimate"] - value) > 3 * c["std"] + 1e-3:
            misses.append((c["text"], value))
    # 3 standard uncertainties: at most one miss in twenty
    assert len(misses) <= len(geo["combinations"]) // 20, misses
    text = (recorded["out"] / "analysis.txt").read_text()
    assert "GEOMETRY" in text and "servo mismatch" in text
    # the set-up once, with its recording, not again as a finding
    assert text.count("set-up: ball centring") == 2 and "Set-up (estimated" not in text
    assert "setup_offset" not in text
    _the_report_opens_prints_and_leads_with_the_results(recorded, tmp_path)
    aligned = sorted(p.name for p in (recorded["out"] / "aligned").iterdir())
    assert aligned == ["GOLD_A_rec0.csv", "GOLD_B_rec1.csv"]


def _the_report_opens_prints_and_leads_with_the_results(recorded, tmp_path):
    """analyse's report.html in Debian's headless Chromium (tests/browser.py): the plan
    map, a polar plot per layer, a picture per finding; the first printed page carries
    the results with their k=2 uncertainties; ``report`` from the analysis folder writes
    the same bytes."""
    html = recorded["out"] / "report.html"
    assert html.is_file()
    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed (scripts/test.sh installs it)")
    seen = open_in_chromium(html, tmp_path)
    check_page(seen, min_images=1 + 2 + 1)
    pages = pdf_pages(tmp_path / "report.pdf")
    assert len(pages) >= 3
    for words in ("squareness X-Y", "scale mismatch X-Y", "servo mismatch", "backlash",
                  "k=2"):
        assert words in pages[0], (words, pages[0][:2000])
    again = tmp_path / "again.html"
    r = run("report", "--plan", str(recorded["plan"]), "--analysis",
            str(recorded["out"] / "analysis.json"), "--out", str(again), "-q")
    assert r.returncode == 0, r.stderr
    assert again.read_bytes() == html.read_bytes()


@pytest.mark.slow
def test_a_recording_of_another_feed_or_misnamed_is_refused_and_nothing_is_written(
        perturbed, golden_plans, tmp_path):
    rec = tmp_path / "slow.csv"
    r = run("perturb", "--plan", str(golden_plans["slow"]), "--program", "GOLD_A", "--lead-s", "4",
            "--noise-um", "0.2", "--out", str(rec), "-q")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    # and GOLD_A's own recording named as GOLD_B
    own = perturbed["files"][0]
    for given, prog in ((str(rec), "GOLD_A"), (f"GOLD_A={rec}", "GOLD_A"),
                        (f"GOLD_B={own}", "GOLD_B")):
        r = run("analyse", "--plan", str(perturbed["plan"]), "--measured", given, "--out", str(out))
        assert r.returncode != 0
        lines = r.stderr.strip().splitlines()
        assert len(lines[-1]) < 700 and "Traceback" not in r.stderr, r.stderr
        path = given.partition("=")[2] or given
        assert path in lines[-1] and (prog in lines[-1] or "no program" in lines[-1]), lines
        assert not out.exists()


@pytest.mark.slow
def test_bad_requests_get_one_line_and_touch_nothing(perturbed, tmp_path):
    recorded = perturbed
    plan, rec = str(recorded["plan"]), str(recorded["files"][0])
    before = sorted(p.name for p in recorded["plan"].iterdir())
    cases = ((["--measured", f"FOO={rec}", "--out", str(tmp_path / "o")], "'FOO' is not a program"),
             (["--measured", rec, "--out", plan], "which this run reads"),
             (["--measured", rec, "--measured", f"GOLD_A={rec}", "--out", str(tmp_path / "o")],
              "given twice"),
             (["--measured", f"GOLD_A={rec}", "--measured", f"GOLD_A={recorded['files'][1]}",
               "--out", str(tmp_path / "o")], "a second recording of GOLD_A"))
    for args, expected in cases:
        r = run("analyse", "--plan", plan, *args, "-q")
        assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
        assert expected in r.stderr.strip().splitlines()[-1], r.stderr
    assert not (tmp_path / "o").exists()
    assert sorted(p.name for p in recorded["plan"].iterdir()) == before
