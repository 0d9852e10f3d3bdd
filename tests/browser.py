"""The report in a real browser, for the tests: Debian's headless Chromium driven by
Playwright (which launches /usr/bin/chromium; no browser of its own is downloaded)
opens a file, takes a screenshot at desktop width and prints it to A4, recording the
console, page errors and every request; the checks every report must pass."""

from __future__ import annotations

import io
import subprocess
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]

#: skip a browser test where Debian's chromium is missing (scripts/test.sh installs it)
needs_chromium = pytest.mark.skipif(not Path(CHROMIUM).exists(),
                                    reason="Debian's chromium is not installed (scripts/test.sh "
                                           "installs it)")


def open_in_chromium(html: Path, out: Path) -> dict:
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


def check_page(seen: dict, min_images: int) -> None:
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


def pdf_pages(pdf: Path) -> list[str]:
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True).stdout
    return text.split("\f")
