"""The report in real headless Chromium: loads from disk alone (index.html copied away from its folder), no
console errors, every image loaded, the navigation works when clicked.

Driven by Playwright for Python with the system's Chromium (``executable_path``: no browser download).
The screenshot is saved to ``$SBCAL_ARTIFACTS`` (default ``artifacts/``) as ``report.png``. Under CI
(``CI`` set) a missing Chromium is a failure: ``.ci/run`` installs Debian's package.
"""

import os
import shutil
from pathlib import Path

import pytest

from sbcal.cli import main

playwright = pytest.importorskip("playwright.sync_api", reason="pip install -e '.[test]' installs Playwright")

EXE = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)


@pytest.fixture(scope="module")
def page():
    if EXE is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is not installed: .ci/run should have installed Debian's chromium")
        pytest.skip("no chromium here (CI installs it)")
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=EXE, args=["--no-sandbox", "--disable-gpu"])
        page = browser.new_page(viewport={"width": 1200, "height": 900})
        try:
            yield page
        finally:
            browser.close()


@pytest.mark.slow
def test_report_in_headless_chromium(run_store, tmp_path, page):
    out = tmp_path / "rep"
    assert main(["report", "--runs", str(run_store), "-o", str(out)]) == 0
    alone = tmp_path / "mailed" / "report.html"  # the page without its folder: it carries its figures
    alone.parent.mkdir()
    shutil.copy(out / "index.html", alone)
    errors = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("requestfailed", lambda r: errors.append(f"{r.url}: {r.failure}"))
    page.goto(alone.as_uri(), wait_until="load")
    images = page.eval_on_selector_all("img", "els => els.map(i => [i.getAttribute('data-src'), i.complete, i.naturalWidth])")
    art = Path(os.environ.get("SBCAL_ARTIFACTS", "artifacts"))
    art.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(art / "report.png"))
    assert not errors, errors
    assert len(images) >= 14
    broken = [src for src, complete, width in images if not (complete and width > 0)]
    assert not broken, broken

    # the navigation: every link points at a section of the page, and clicking one goes there
    targets = page.eval_on_selector_all("nav a", "els => els.map(a => a.getAttribute('href'))")
    assert "#provenance" in targets and "#map" in targets
    for href in targets:
        assert page.locator(f"[id='{href[1:]}']").count() == 1, href
    for href in ("#provenance", "#map"):
        page.click(f"nav a[href='{href}']")
        page.wait_for_function(f"location.hash === '{href}'")
        top = page.eval_on_selector(href, "e => e.getBoundingClientRect().top")
        assert -1 < top < 900, (href, top)  # scrolled into view (to the subpixel)

