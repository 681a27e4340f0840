"""The PIL report in a real headless Chromium (Debian package `chromium`, driven over the DevTools
protocol by rvd_pil/bench/browser.py): at 1400 px the verdict table is visible whole without horizontal
scrolling, no script error occurs, and a click on a heading sorts the table by that column.
A 1400 px screenshot is kept beside the report (report-1400px.png)."""
from __future__ import annotations

import struct

import pytest

import report_campaign
from rvd_pil.bench import browser, report

pytestmark = pytest.mark.skipif(browser.find_chromium() is None,
                                reason="chromium missing: tools/install-deps test installs it")


@pytest.fixture(scope="module")
def page_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("pil-browser")
    report_campaign.make(out)
    return report.write(out)


def test_verdict_table_fits_1400px_without_script_errors(page_file):
    with browser.Page(width=1400, height=900) as page:
        page.open(page_file)
        assert page.eval("document.body.getAttribute('data-script')") == "ready"  # the page's script ran to its end
        box = page.eval("(() => { const r = document.getElementById('verdict').getBoundingClientRect();"
                        " return [r.left, r.right, r.top, window.innerWidth]; })()")
        left, right, top, inner = box
        assert inner == 1400
        assert 0 <= left and right <= inner, f"verdict table spans {left:.0f}-{right:.0f} px of {inner}"
        assert top < 900, "the verdict table starts below the first screen"
        # the page as a whole does not scroll sideways, and neither does the verdict table's own box
        assert page.eval("document.documentElement.scrollWidth") <= inner
        assert page.eval("(() => { const d = document.getElementById('verdict').parentElement;"
                         " return d.scrollWidth - d.clientWidth; })()") == 0
        # every column heading of the verdict table is within the window
        heads = page.eval("Array.from(document.querySelectorAll('#verdict th')).map(th => th.getBoundingClientRect().right)")
        assert heads and max(heads) <= inner
        # every figure decoded (they are embedded in the page: nothing to fetch)
        assert page.eval("Array.from(document.images).every(i => i.complete && i.naturalWidth > 0)")
        assert page.eval("document.images.length") >= 3
        shot = page.screenshot(page_file.parent / "report-1400px.png")
        assert page.errors == [], page.errors
    width, height = struct.unpack(">II", shot.read_bytes()[16:24])  # PNG IHDR
    assert (width, height) == (1400, 900)


def test_headings_sort_the_table(page_file):
    with browser.Page(width=1400, height=900) as page:
        page.open(page_file)
        col = page.eval("Array.from(document.querySelectorAll('#verdict th')).findIndex(th => th.textContent === 'margin (worst)')")
        assert col >= 0

        def column():
            return page.eval(f"Array.from(document.querySelectorAll('#verdict tbody tr')).map("
                             f"tr => +tr.cells[{col}].getAttribute('data-v'))")

        before = column()
        page.eval(f"document.querySelectorAll('#verdict th')[{col}].click()")
        up = column()
        # ascending: the smallest margin first, the q7s docking case, whose worst solve misses the deadline
        first = page.eval("document.querySelector('#verdict tbody tr').textContent")
        assert "docking" in first and "FAIL" in first
        page.eval(f"document.querySelectorAll('#verdict th')[{col}].click()")
        down = column()
        assert sorted(before) == up and up == down[::-1] and up != before
        assert page.errors == [], page.errors


def test_a_script_error_is_caught(tmp_path):
    """The check itself can fail: a page with a broken script reports the error."""
    bad = tmp_path / "bad.html"
    bad.write_text("<!doctype html><p>x</p><script>document.body.dataset.x = undefinedName.y;</script>")
    with browser.Page(width=800, height=600) as page:
        page.open(bad)
        assert any("undefinedName" in e for e in page.errors)
