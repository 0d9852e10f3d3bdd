"""The test report in a real browser: Debian's headless Chromium opens it (driven by
Playwright, which launches /usr/bin/chromium; no browser of its own is downloaded),
takes a screenshot at desktop width and prints it to A4.  The page is not blank, every
image decodes, nothing is fetched from anywhere but the file itself, the console shows
no error, and the first printed page carries the results with their k=2 uncertainties.
The screenshot and the PDF are written beside the test's files for a person to look at."""

from __future__ import annotations

import io
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import run  # noqa: E402

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]

pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists(),
                                reason="Debian's chromium is not installed (scripts/test.sh "
                                       "installs it)")


def _open(html: Path, out: Path) -> dict:
    from playwright.sync_api import sync_playwright

    seen = {"console": [], "errors": [], "requests": []}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.on("console", lambda m: seen["console"].append((m.type, m.text)))
        page.on("pageerror", lambda e: seen["errors"].append(str(e)))
        page.on("request", lambda r: seen["requests"].append(r.url))
        page.goto(html.as_uri(), wait_until="load")
        seen["images"] = page.evaluate(
            "Array.from(document.images).map(i => [i.complete, i.naturalWidth, i.naturalHeight])")
        seen["text"] = page.inner_text("body")
        seen["screenshot"] = page.screenshot(full_page=True)
        seen["pdf"] = page.pdf(format="A4", print_background=True, prefer_css_page_size=True)
        browser.close()
    (out / f"{html.stem}.png").write_bytes(seen["screenshot"])
    (out / f"{html.stem}.pdf").write_bytes(seen["pdf"])
    return seen


def _check(seen: dict, min_images: int) -> None:
    from PIL import Image

    assert not seen["errors"], seen["errors"]
    assert not [c for c in seen["console"] if c[0] in ("error", "warning")], seen["console"]
    assert all(u.startswith(("file:", "data:")) for u in seen["requests"]), seen["requests"]
    images = seen["images"]
    assert len(images) >= min_images, images
    assert all(ok and w > 50 and h > 50 for ok, w, h in images), images
    shot = np.asarray(Image.open(io.BytesIO(seen["screenshot"])).convert("L"), dtype=float)
    assert shot.shape[1] == 1280 and shot.shape[0] > 900, shot.shape
    # not blank: dark text and drawings on a light page
    assert (shot < 128).mean() > 0.005 and shot.std() > 10, (shot.mean(), shot.std())
    assert seen["pdf"][:5] == b"%PDF-"


def _pdf_pages(pdf: Path) -> list[str]:
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True).stdout
    return text.split("\f")


@pytest.mark.slow
def test_the_plan_report_opens_and_prints(golden_plans, tmp_path):
    out = tmp_path / "plan_report.html"
    r = run("report", "--plan", str(golden_plans["fast"]), "--out", str(out), "--operator",
            "<script>alert(1)</script>", "--date", "2026-11-28", "-q")
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert "<script" not in text and "&lt;script&gt;" in text  # what a user types is text
    seen = _open(out, tmp_path)
    _check(seen, min_images=1)
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


@pytest.mark.slow
@pytest.mark.xdist_group("recorded")  # on the worker that made the analysis
def test_the_test_report_opens_prints_and_leads_with_the_results(recorded, tmp_path):
    assert recorded["run"].returncode == 0, recorded["run"].stderr
    html = recorded["out"] / "report.html"
    seen = _open(html, tmp_path)
    # the plan map, a polar plot per layer, a picture per finding
    _check(seen, min_images=1 + 2 + 1)
    pages = _pdf_pages(tmp_path / "report.pdf")
    assert len(pages) >= 3
    first = pages[0]
    for words in ("squareness X-Y", "scale mismatch X-Y", "servo mismatch", "backlash",
                  "k=2"):
        assert words in first, (words, first[:2000])
    # the same report from the command line, from the analysis folder
    again = tmp_path / "again.html"
    r = run("report", "--plan", str(recorded["plan"]), "--analysis",
            str(recorded["out"] / "analysis.json"), "--out", str(again), "-q")
    assert r.returncode == 0, r.stderr
    assert again.read_bytes() == html.read_bytes()
