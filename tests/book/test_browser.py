"""Open the built book in Debian's headless chromium and check what a reader sees.

For every HTML page of book/_build/html: it loads, MathJax (served from the book itself) has typeset every math
element, every <img> has loaded, and no request left 127.0.0.1.  Skipped, with a message, only where chromium is
absent; a missing book is a failure (``make test`` builds it first).
"""

import functools
import re
import http.server
import shutil
import threading
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HTML = ROOT / "book" / "_build" / "html"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

pytestmark = [pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (apt-get install chromium); "
                                 "the browser test of the book is skipped")]

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture(scope="module")
def server():
    assert (HTML / "index.html").exists(), f"no built book at {HTML}: run `make book` first"
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(HTML)))
    t = threading.Thread(target=httpd.serve_forever, daemon=True)
    t.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        yield b
        b.close()


class Loaded:
    """A page opened once at 1400 x 1000 px, and what happened while it loaded: every request, failed request,
    response of status 400 or more (the browser's own /favicon.ico excepted: the book has no icon, and chromium asks
    for one at a time of its choosing) and script error (a missing resource is told by its response)."""

    def __init__(self, browser, url):
        self.requests, self.console_errors, self.missing, self.failed = [], [], [], []
        self.page = page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.on("request", lambda r: self.requests.append(r.url))
        page.on("console", lambda m: self.console_errors.append(m.text)
                if m.type == "error" and not m.text.startswith("Failed to load resource") else None)
        page.on("pageerror", lambda exc: self.console_errors.append(str(exc)))
        page.on("response", lambda r: self.missing.append(f"{r.status} {r.url}")
                if r.status >= 400 and not r.url.endswith("/favicon.ico") else None)
        page.on("requestfailed", lambda r: self.failed.append(r.url))
        self.response = page.goto(url, wait_until="load")


@pytest.fixture(scope="module")
def loaded(server, browser):
    """``loaded(page_path)``: the page, loaded once per test process for the tests that only read it."""
    held = {}

    def get(page_path):
        if page_path not in held:
            held[page_path] = Loaded(browser, f"{server}/{page_path}")
        return held[page_path]

    yield get
    for v in held.values():
        v.page.close()


def pages():
    skip = {"genindex.html", "search.html"}
    return sorted(str(p.relative_to(HTML)) for p in HTML.rglob("*.html")
                  if p.name not in skip and "_static" not in p.parts and "_sources" not in p.parts
                  and not _is_redirect(p))


def _is_redirect(p: Path) -> bool:
    return 'http-equiv="Refresh"' in p.read_text(errors="replace")[:2000]


def test_index_leads_to_landing_page(server, browser):
    page = browser.new_page()
    page.goto(f"{server}/index.html")
    page.wait_for_url("**/book/intro.html", timeout=10000)
    assert "What the paper claims" in page.content()
    page.close()


@pytest.mark.parametrize("page_path", pages() or ["index.html"])
def test_page_renders_offline(server, loaded, page_path):
    got = loaded(page_path)
    page, resp = got.page, got.response
    assert resp is not None and resp.ok, f"{page_path}: HTTP {resp.status if resp else 'no response'}"
    n_math = page.evaluate("document.querySelectorAll('div.math, span.math').length")
    if n_math:
        page.wait_for_function("() => window.MathJax && MathJax.startup && MathJax.startup.promise", timeout=30000)
        page.evaluate("() => MathJax.startup.promise")
        untypeset = page.evaluate(
            "Array.from(document.querySelectorAll('div.math, span.math'))"
            ".filter(e => !e.querySelector('mjx-container')).map(e => e.textContent.slice(0, 60))")
        assert not untypeset, f"{page_path}: raw TeX left untypeset: {untypeset[:3]}"
        assert page.evaluate("document.querySelectorAll('mjx-merror').length") == 0, f"{page_path}: MathJax errors"
    broken = page.evaluate(
        "Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src)")
    assert not broken, f"{page_path}: images not loaded: {broken}"
    # computed tables (Markdown outputs) render as tables, never as raw pipe text
    prose = page.evaluate("""() => {
        const root = document.querySelector('main') || document.body, out = [];
        const w = document.createTreeWalker(root, NodeFilter.SHOW_TEXT);
        for (let n = w.nextNode(); n; n = w.nextNode())
            if (!n.parentElement.closest('pre, code, .highlight, script, style')) out.push(n.textContent);
        return out.join(''); }""")  # rendered text outside code blocks
    assert "|---" not in prose and "---|" not in prose, f"{page_path}: a table left as raw pipe text"
    outside = [u for u in got.requests if not u.startswith(server) and not u.startswith("data:")]
    assert not outside, f"{page_path}: requests left localhost: {outside[:5]}"
    assert not got.failed, f"{page_path}: failed requests: {got.failed[:5]}"
    # no script error (Thebe's inline config, included twice, redeclared THEBE_JS_URL on every page) and no Thebe:
    # the book is offline and has no live code
    assert not got.console_errors, f"{page_path}: console errors: {got.console_errors[:3]}"
    assert not got.missing, f"{page_path}: resources not found: {got.missing[:3]}"
    html = (HTML / page_path).read_text()
    assert "thebe" not in html.lower(), f"{page_path}: still loads Thebe"
    # no emoji: the Debian fonts the book is read with have none (a box is drawn in its place)
    emoji = sorted({c for c in html if ord(c) >= 0x1F000 or c in "\u2705\u274c\u2b50"})
    assert not emoji, f"{page_path}: glyphs the fonts lack: {emoji}"


def test_chapters_have_figures_and_math(server, browser):
    page = browser.new_page()
    page.goto(f"{server}/chapters/01_tdl_channel.html", wait_until="load")
    page.wait_for_function("() => window.MathJax && MathJax.startup && MathJax.startup.promise", timeout=30000)
    page.evaluate("() => MathJax.startup.promise")
    assert page.evaluate("document.querySelectorAll('mjx-container').length") >= 2
    assert page.evaluate("Array.from(document.images).filter(i => i.naturalWidth > 0).length") >= 5
    page.close()


#: pages whose computed tables a reader must see as HTML tables, and how many at least
TABLES = {"chapters/01_tdl_channel.html": 1, "chapters/03_dpe.html": 2, "chapters/05_rmse_vs_snr.html": 5,
          "chapters/06_otdoa.html": 2, "chapters/07_reproduction.html": 3, "chapters/08_bounds.html": 3}


@pytest.mark.parametrize("page_path", list(TABLES))
def test_computed_tables_render_as_tables(loaded, page_path):
    n = loaded(page_path).page.evaluate("document.querySelectorAll('main table, article table').length")
    assert n >= TABLES[page_path], f"{page_path}: {n} HTML tables, expected at least {TABLES[page_path]}"


def test_meshcat_scene_draws_in_webgl(server, browser):
    """Chapter 4 embeds the meshcat scene; its WebGL canvas must draw (many distinct colours, not a blank fill)."""
    import io

    import numpy as np
    from PIL import Image

    page = browser.new_page(viewport={"width": 1000, "height": 900})
    page.goto(f"{server}/chapters/04_urban_scenario.html", wait_until="load")
    frame_el = page.wait_for_selector("iframe.dpe5g-scene3d", timeout=30000)
    frame = frame_el.content_frame()
    frame.wait_for_selector("canvas", timeout=30000)
    assert frame.evaluate("!!document.querySelector('canvas').getContext('webgl2') || "
                          "!!document.querySelector('canvas').getContext('webgl')")
    frame_el.scroll_into_view_if_needed()
    page.wait_for_timeout(3000)  # the scene commands are replayed asynchronously
    img = np.asarray(Image.open(io.BytesIO(frame_el.screenshot())).convert("RGB")).reshape(-1, 3)
    n_colours = len(np.unique(img, axis=0))
    assert img.std() > 10 and n_colours > 500, f"WebGL canvas looks blank: std {img.std():.1f}, {n_colours} colours"
    # the buildings (grey boxes) are drawn, not only the viewer's blue background gradient
    r, g, b = (img[:, i].astype(int) for i in range(3))
    grey = (np.abs(r - g) < 12) & (np.abs(g - b) < 16) & (r > 90) & (r < 235)
    assert grey.mean() > 0.02, f"no buildings on the WebGL canvas: grey share {grey.mean():.3f}"
    page.close()


@pytest.mark.parametrize("page_path", [p for p in pages() if p.startswith("chapters/")] or ["index.html"])
def test_every_figure_is_numbered_and_captioned(loaded, page_path):
    """Every image and embedded scene of a chapter sits in a numbered <figure> with a caption; a figure that
    reproduces one of the paper's says which ("Reproduces the paper's Fig. N"), every other says it is ours."""
    found = loaded(page_path).page.evaluate("""() => Array.from(document.querySelectorAll('main img, main iframe')).map(e => {
        const f = e.closest('figure'), c = f && f.querySelector('figcaption');
        return {src: (e.src || '').slice(-40), caption: c ? c.textContent.trim().replace(/\u2019/g, "'") : null,
                number: c && c.querySelector('.caption-number') ? c.querySelector('.caption-number').textContent : null,
                alt: e.getAttribute('alt')}; })""")
    for f in found:
        assert f["caption"], f"{page_path}: figure without a caption: {f['src']}"
        assert f["number"] and f["number"].startswith("Figure "), f"{page_path}: figure not numbered: {f['caption'][:60]}"
        assert "Reproduces the paper's Fig. " in f["caption"] or "not in the paper" in f["caption"], f["caption"][:80]
        assert f["alt"] is None or not re.fullmatch(r"[0-9a-f]{32,}(\.png)?", f["alt"]), f"{page_path}: hash alt text"


WIDE_JS = """() => {
    const art = document.querySelector('article'), right = art.getBoundingClientRect().right + 1;
    const out = [];
    for (const t of art.querySelectorAll('table')) {
        const box = t.closest('.pst-scrollable-table-container') || t.parentElement;
        if (t.getBoundingClientRect().width > box.clientWidth + 1 || t.getBoundingClientRect().right > right)
            out.push('table: ' + t.textContent.trim().slice(0, 50));
    }
    for (const m of art.querySelectorAll('mjx-container[display="true"]'))
        if (m.scrollWidth > m.clientWidth + 1 || m.getBoundingClientRect().right > right)
            out.push('equation: ' + (m.closest('.math') || m).textContent.slice(0, 50));
    for (const i of art.querySelectorAll('img'))
        if (i.getBoundingClientRect().right > right) out.push('image: ' + i.src.slice(-40));
    return out; }"""
#: two animation frames: the resize handlers of the theme and of MathJax have run and the page is laid out again
AFTER_RESIZE_JS = "() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))"


@pytest.mark.parametrize("page_path", pages() or ["index.html"])
def test_nothing_is_wider_than_its_column(loaded, page_path):
    """At a 1280-px and a 768-px window: no table, display equation or image of the page is wider than the
    article's column (a wider one is clipped or scrolls sideways, and its last column or its equation number is
    hidden).  The page loaded at 1400 px is resized to each width, then back."""
    page = loaded(page_path).page
    if page.evaluate("document.querySelectorAll('div.math').length"):
        page.wait_for_function("() => window.MathJax && MathJax.startup && MathJax.startup.promise", timeout=30000)
        page.evaluate("() => MathJax.startup.promise")
    wide = []
    try:
        for width in (1280, 768):
            page.set_viewport_size({"width": width, "height": 1000})
            page.evaluate(AFTER_RESIZE_JS)
            wide += [f"{width} px: {w}" for w in page.evaluate(WIDE_JS)]
    finally:
        page.set_viewport_size({"width": 1400, "height": 1000})
        page.evaluate(AFTER_RESIZE_JS)
    assert not wide, f"{page_path}: {len(wide)} element(s) wider than the column: {wide[:6]}"


@pytest.mark.parametrize("page_path", pages() or ["index.html"])
def test_no_code_block_runs_off_the_page(loaded, page_path):
    """Every page: every code or text block wraps inside its box (its content is no wider than the box), so no
    command, code line or docstring is cut off at the right."""
    wide = loaded(page_path).page.evaluate("""() => [...document.querySelectorAll('article pre')]
        .filter(p => p.scrollWidth > p.clientWidth + 1).map(p => p.textContent.slice(0, 80))""")
    assert not wide, f"{page_path}: {len(wide)} block(s) scroll sideways, e.g. {wide[0]!r}"


@pytest.mark.parametrize("page_path", pages() or ["index.html"])
def test_figures_are_shown_at_their_own_size(loaded, page_path):
    """Every page: every figure image is shown at least as wide as its pixels (the book never shrinks one).  With
    ``tests/figures/test_legibility.py`` (every figure at most 7.68 in at 100 dpi, every text at least 9 pt) this keeps every
    figure's text at 9 pt or more on the page."""
    shrunk = loaded(page_path).page.evaluate("""() => [...document.querySelectorAll('article img')]
        .filter(i => i.naturalWidth > i.clientWidth + 1)
        .map(i => `${i.src.slice(-24)}: ${i.naturalWidth} px shown at ${i.clientWidth} px`)""")
    assert not shrunk, f"{page_path}: {len(shrunk)} figure(s) shrunk, their text below 9 pt: {shrunk}"
