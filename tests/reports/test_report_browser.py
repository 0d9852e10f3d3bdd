"""The plan's report in a real browser (tests/browser.py): the page is not blank, every
image decodes, nothing is fetched from anywhere but the file itself, the console shows
no error, what a user types stays text, equal input gives an equal file, and an existing
file is replaced only when it is an earlier report.  The test report of an analysis is
opened the same way in tests/identify/test_analyse.py, on the analysis made there."""

from __future__ import annotations

import pytest

from browser import check_page, needs_chromium, open_in_chromium
from conftest import run  # noqa: E402


@pytest.mark.slow
@needs_chromium
def test_the_plan_report_opens_and_prints(golden_plans, tmp_path):
    out = tmp_path / "plan_report.html"
    r = run("report", "--plan", str(golden_plans["fast"]), "--out", str(out), "--operator",
            "<script>alert(1)</script>", "--date", "2026-11-28", "-q")
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert "<script" not in text and "&lt;script&gt;" in text  # what a user types is text
    seen = open_in_chromium(out, tmp_path)
    check_page(seen, min_images=1)
    assert "The plan" in seen["text"] and "GOLD_A" in seen["text"]
    # equal input, equal file; an existing file is kept unless --force, a foreign one always
    again = tmp_path / "again.html"
    assert run("report", "--plan", str(golden_plans["fast"]), "--out", str(again), "--operator",
               "<script>alert(1)</script>", "--date", "2026-11-28", "-q").returncode == 0
    assert again.read_bytes() == out.read_bytes()
    r = run("report", "--plan", str(golden_plans["fast"]), "--out", str(out), "-q")
    assert r.returncode == 5 and "--force" in r.stderr and "Traceback" not in r.stderr
    mine = tmp_path / "notes.html"
    mine.write_text("<p>my notes</p>")
    r = run("report", "--plan", str(golden_plans["fast"]), "--out", str(mine), "--force", "-q")
    assert r.returncode == 5 and "not a report" in r.stderr
    assert mine.read_text() == "<p>my notes</p>"
