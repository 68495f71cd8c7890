"""A report seen as an operator sees it: Debian's Chromium, headless, driven by Playwright.

`.ci/run` installs the browser. Elsewhere, without it, the tests that need it skip, unless
FOLDCELL_REQUIRE_BROWSER=1 (set by CI) makes a missing browser a failure."""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest

VIEWPORT = {"width": 1400, "height": 1000}
# what a figure left unformatted would show in a cell
UNFORMATTED = {"None", "none", "nan", "NaN", "null", "undefined", "inf", "-inf"}

# Per section of the page, what a reader can see in it: rows of its tables (cell texts), drawn lines
# with an area, images that loaded, and the text of an empty-section notice.
_READ_PAGE = """() => {
  const visible = e => { const r = e.getBoundingClientRect(); return r.width > 0 && r.height > 0; };
  const out = {};
  for (const s of document.querySelectorAll('section')) {
    out[s.id] = {
      rows: [...s.querySelectorAll('tr')].filter(visible)
        .map(tr => [...tr.querySelectorAll('td')].map(td => td.innerText.trim()))
        .filter(cells => cells.length > 0),
      lines: [...s.querySelectorAll('polyline')].filter(p => { const b = p.getBBox();
        return b.width > 0 && b.height > 0 && visible(p); }).map(p => p.dataset.joint),
      images: [...s.querySelectorAll('img')].filter(i => i.complete && i.naturalWidth > 0 && visible(i))
        .length,
      captions: [...s.querySelectorAll('figcaption')].map(c => c.innerText.trim()),
      empty: [...s.querySelectorAll('.empty')].map(e => e.innerText.trim()),
    };
  }
  return out;
}"""


@dataclass(frozen=True)
class Section:
    rows: list[list[str]]
    lines: list[str]      # the joint named by each polyline drawn
    images: int
    captions: list[str]
    empty: list[str]      # an empty section's notice


@dataclass(frozen=True)
class RenderedReport:
    headline: str
    verdicts: list[str]
    sections: dict[str, Section]
    screenshot: np.ndarray = field(repr=False)        # the whole page, BGR
    headline_pixels: np.ndarray = field(repr=False)   # the headline's box cut out of the screenshot

    def cells(self) -> list[str]:
        return [c for s in self.sections.values() for row in s.rows for c in row]


def chromium() -> str:
    """The browser's path, or the test skips (fails under FOLDCELL_REQUIRE_BROWSER=1)."""
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        reason = "no Chromium on this machine (apt-get install chromium)"
        if os.environ.get("FOLDCELL_REQUIRE_BROWSER") == "1":
            pytest.fail(reason)
        pytest.skip(reason)
    return path


def render(page: Path, screenshot: Path) -> RenderedReport:
    """Open `page` in headless Chromium, read what each section shows and take a full-page screenshot."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium(), args=[
            "--disable-gpu", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--no-first-run"])
        try:
            view = browser.new_page(viewport=VIEWPORT)
            view.goto(page.as_uri(), wait_until="load")
            head = view.locator(".headline")
            headline = head.inner_text().strip()
            box = head.bounding_box()
            verdicts = [t.strip() for t in view.locator(".headline + ul > li").all_inner_texts()]
            sections = {k: Section(**v) for k, v in view.evaluate(_READ_PAGE).items()}
            view.screenshot(path=str(screenshot), full_page=True)
        finally:
            browser.close()
    image = cv2.imread(str(screenshot))
    assert image is not None and box is not None, "the browser wrote no screenshot or showed no headline"
    x, y, w, h = (round(v) for v in (box["x"], box["y"], box["width"], box["height"]))
    return RenderedReport(headline, verdicts, sections, image, image[y:y + h, x:x + w])


def text_drawn(pixels: np.ndarray) -> bool:
    """Whether dark glyphs are drawn on a light ground (the screenshot shows the text, not a blank)."""
    gray = cv2.cvtColor(pixels, cv2.COLOR_BGR2GRAY)
    return gray.size > 0 and float((gray < 100).mean()) > 0.01 and float((gray > 200).mean()) > 0.3
