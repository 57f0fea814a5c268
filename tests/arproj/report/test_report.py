"""The demo's report rendered in a real browser (issue 23 item 3): report.html and report.pdf from headless
Chromium; every image loads, no text crosses the page's edge, every page is numbered and no page ends on a
heading; every object class of the wall is scored, a wrong class named as such.

The report is written from a context whose map stage is replaced by hand-made mapped objects on the shipped
small_test_wall: what the report shows is checked, not how well the map is made (tests/arproj/test_demo.py runs
the whole demo). Skips, saying why, where Chromium is not installed (`./run test` installs it as root).
"""

from __future__ import annotations

import html
import json
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from arproj import demo
from arproj.report import write_report
from arproj.report.pdf import chromium, run_headless
from mapping.map_object import MapObject
from scanner.wall import load_wall, shipped_walls

BROWSER = chromium()
pytestmark = pytest.mark.skipif(BROWSER is None, reason="headless Chromium is not installed (Debian: apt-get "
                                "install chromium; ./run test installs it when run as root)")
PRINT_WIDTH_PX = 688  # A4 less the report's 14 mm side margins, at 96 px per inch: the page the text must fit
MARGIN_PT = 14 / 25.4 * 72

# After the page has loaded: every image decoded, and every text fragment's boxes inside the page's width.
CHECK_SCRIPT = """<script>
window.addEventListener('load', () => {
  const width = document.documentElement.clientWidth;
  const images = [...document.images].map(i => ({src: i.getAttribute('src'), ok: i.complete && i.naturalWidth > 0}));
  const overflow = [];
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  for (let node = walker.nextNode(); node; node = walker.nextNode()) {
    if (!node.textContent.trim()) continue;
    const range = document.createRange();
    range.selectNodeContents(node);
    for (const r of range.getClientRects()) {
      if (r.width > 0 && (r.left < -0.5 || r.right > width + 0.5)) {
        overflow.push(node.textContent.trim().slice(0, 60)); break;
      }
    }
  }
  const out = document.createElement('pre');
  out.id = 'arproj-check';
  out.textContent = JSON.stringify({width, images, overflow});
  document.body.appendChild(out);
});
</script>"""


def browser_check(page: Path) -> dict[str, Any]:
    """Load `page` (a copy with CHECK_SCRIPT beside it) at the printed page's width in headless Chromium."""
    assert BROWSER is not None
    probe = page.with_name("_check_" + page.name)
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", CHECK_SCRIPT + "</body>"), encoding="utf-8")
    done = run_headless(BROWSER, ["--allow-file-access-from-files", f"--window-size={PRINT_WIDTH_PX},900",
                                  "--virtual-time-budget=5000", "--dump-dom", probe.resolve().as_uri()])
    found = re.search(r'<pre id="arproj-check">(.*?)</pre>', done.stdout, re.S)
    assert found, done.stdout[-500:]
    return dict(json.loads(html.unescape(found.group(1))))


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """small_test_wall (a live cable, a copper pipe, a screw) with a map that found the cable and the pipe and
    drew a power line over the screw: the report's scores must call that a wrong class."""
    out = tmp_path_factory.mktemp("report")
    path = shipped_walls()["small_test_wall"]
    ctx = demo.DemoContext(demo.DemoOptions(out=out, wall=path, quick=True), load_wall(path), path)
    for name, _, _ in demo.STAGES:
        ctx.stages[name] = demo.StageRecord(name, status="not run", reason="not run in this test")
    ctx.stages["map"] = demo.StageRecord("map", 1.0, "done")
    objects = [MapObject("line", np.array([[0.12, 0.0], [0.12, 0.30]]), 0.01, cls="power_line"),
               MapObject("line", np.array([[0.0, 0.18], [0.35, 0.18]]), 0.015, cls="metal_pipe"),
               MapObject("line", np.array([[0.25, 0.07], [0.29, 0.07]]), 0.01, cls="power_line")]
    ctx.figures["map"] = {"recall": 1.0, "fasteners found": "0 of 1"}
    demo.map_against_truth(ctx, objects)
    ctx.picture("missing.png", "A picture whose file is not there.", "map")
    write_report(ctx)
    return out


def test_every_object_class_is_scored_and_a_wrong_class_is_named(report: Path) -> None:
    page = (report / "report.html").read_text(encoding="utf-8")
    for row in (r"<td>cable-v</td>.*?found", r"<td>pipe-h</td>.*?found",
                r"<td>screw-1</td><td>screw</td><td>fastener</td>.*?wrong class</td>\s*<td>power line</td>"):
        assert re.search(row, page, re.S), row
    assert re.search(r"<td>fastener</td><td class=\"num\">1</td><td class=\"num\">0</td>\s*"
                     r"<td class=\"num bad\">1</td>", page)
    for heading in ("Limitations", "What the scanner cannot see", "Depth", "Unknown areas", "Inferred stretches"):
        assert f">{heading}</h" in page
    assert "arproj</th><td>0." in page and "robot position</th>" in page and "small_test_wall.yaml" in page
    assert 'src="map_vs_truth.png"' in page and "missing picture missing.png" in page


def test_the_map_against_truth_draws_what_its_caption_says(report: Path) -> None:
    """The truth wide in light grey; the screw mapped as a power line labelled in red."""
    import cv2

    from arproj.report.figures import MAP_VS_TRUTH_TEXT, TRUTH_GREY

    image = cv2.cvtColor(cv2.imread(str(report / "map_vs_truth.png")), cv2.COLOR_BGR2RGB).astype(int)
    grey = np.array([int(TRUTH_GREY[i:i + 2], 16) for i in (1, 3, 5)])
    assert (np.abs(image - grey).sum(axis=2) <= 6).sum() > 500
    red = (image[..., 0] > 170) & (image[..., 1] < 40) & (image[..., 2] < 40)
    assert red.sum() > 20
    assert "light grey" in MAP_VS_TRUTH_TEXT and "red label" in MAP_VS_TRUTH_TEXT


def test_the_page_in_the_browser_loads_every_image_and_fits_the_page_width(report: Path) -> None:
    result = browser_check(report / "report.html")
    assert result["width"] <= PRINT_WIDTH_PX
    assert [i["src"] for i in result["images"]] == ["map_vs_truth.png"]
    assert all(i["ok"] for i in result["images"]), result["images"]
    assert result["overflow"] == [], result["overflow"]


def test_the_browser_check_sees_a_broken_image_and_text_past_the_edge(tmp_path: Path, report: Path) -> None:
    """The check above can fail: a missing image and an unbreakable line wider than the page are reported."""
    shutil.copy(report / "map_vs_truth.png", tmp_path)
    bad = tmp_path / "bad.html"
    bad.write_text('<!doctype html><html><body><img src="map_vs_truth.png"><img src="gone.png">'
                   f'<p style="white-space:nowrap">{"wide " * 200}</p></body></html>', encoding="utf-8")
    result = browser_check(bad)
    assert [i["ok"] for i in result["images"]] == [True, False]
    assert result["overflow"] and result["overflow"][0].startswith("wide wide")


def test_the_pdf_is_numbered_fits_its_pages_and_keeps_headings_with_their_text(report: Path) -> None:
    from pdfminer.high_level import extract_pages
    from pdfminer.layout import LTChar, LTImage, LTTextLineHorizontal

    pages = list(extract_pages(report / "report.pdf"))
    assert len(pages) >= 2
    headings = set(re.findall(r"<h[23]>([^<]+)</h[23]>", (report / "report.html").read_text(encoding="utf-8")))
    images = 0

    def walk(item: Any) -> Any:  # a page, its text boxes, lines and characters, its figures and images
        yield item
        if hasattr(item, "__iter__"):
            for child in item:
                yield from walk(child)

    for number, page in enumerate(pages, start=1):
        _, _, width, height = page.bbox
        lines = []
        for item in walk(page):
            if isinstance(item, LTChar) and item.get_text().strip():
                assert item.x0 >= MARGIN_PT - 1 and item.x1 <= width - MARGIN_PT + 1, (number, item.get_text())
                assert item.y0 >= 0 and item.y1 <= height, (number, item.get_text())
            elif isinstance(item, LTImage):
                images += 1
            elif isinstance(item, LTTextLineHorizontal) and item.get_text().strip():
                lines.append((item.y0, item.get_text().strip()))
        text = [t for _, t in sorted(lines, reverse=True)]
        assert f"arproj demo report — page {number} of {len(pages)}" in text, text[-3:]
        body = [t for t in text if not t.startswith("arproj demo report — page")]
        assert body and body[-1] not in headings, f"page {number} ends on the heading {body[-1]!r}"
    assert images == 1  # map_vs_truth.png; the missing picture is a line of text, not a broken image
