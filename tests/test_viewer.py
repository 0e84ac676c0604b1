"""compare's page (``index.html``) in a real browser: Chromium, driven by
Playwright, opening the page from ``file://`` as a reader would.

Oracles: the browser's own account of the page (images decoded, console
errors), and screenshots: pixels that must change when the wipe slider
moves, and blocks of identical pixels where one image pixel is enlarged.
"""

import io
import os
import shutil

import numpy as np
import pytest
from PIL import Image

from conftest import ROOT, cli

CHROMIUM = shutil.which("chromium")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed "
                                "(the Debian package 'chromium' gives /usr/bin/chromium)")
SCENE = ROOT / "scenes" / "cases" / "mirror_chain.xml"
RESOLUTION = 32


def compare(out, env=None):
    """``out``, the folder of a quick comparison of a small scene."""
    result = cli("compare", str(SCENE), "-D", f"res={RESOLUTION}", "--quick", "--out", str(out),
                 env=env, timeout=300)
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    return compare(tmp_path_factory.mktemp("compare"))


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=CHROMIUM)
        yield launched
        launched.close()


@pytest.fixture
def page(browser, report):
    opened = open_page(browser, report)
    yield opened
    opened.close()


def open_page(browser, folder):
    """The page of ``folder``, loaded with its images; ``page.errors``
    collects what the console reports as errors and the exceptions the page
    raises."""
    opened = browser.new_page(viewport={"width": 1200, "height": 900})
    opened.errors = []
    opened.on("console", lambda message: message.type == "error"
              and opened.errors.append(message.text))
    opened.on("pageerror", lambda error: opened.errors.append(str(error)))
    opened.goto((folder / "index.html").as_uri())
    opened.wait_for_function("[...document.images].every(image => image.complete)")
    return opened


def choose(page, selector: str, value) -> None:
    page.select_option(selector, str(value))


def slide(page, selector: str, value: float) -> None:
    """Move a range input as a reader's drag does: its value, then 'input'."""
    page.eval_on_selector(selector, "(input, value) => { input.value = value; "
                          "input.dispatchEvent(new Event('input')); }", value)


def image_index(page, key: str) -> int:
    return page.evaluate("key => data.images.findIndex(item => item.key === key)", key)


def pixels(page, selector: str = ".pane", clip=None) -> np.ndarray:
    shot = page.screenshot(clip=clip) if clip else page.locator(selector).first.screenshot()
    return np.asarray(Image.open(io.BytesIO(shot)).convert("RGB")).astype(int)


def loaded_widths(page) -> list[int]:
    page.wait_for_function("[...document.images].every(image => image.complete)")
    return page.evaluate("[...document.images].map(image => image.naturalWidth)")


def test_every_image_and_map_loads_without_errors(page):
    layers = page.eval_on_selector_all("#layer option", "options => options.map(o => o.value)")
    assert layers[:2] == ["image", "relmse"]
    for layer in layers:
        choose(page, "#layer", layer)
        for mode in ("side", "wipe", "flip"):
            choose(page, "#mode", mode)
            assert all(width == RESOLUTION for width in loaded_widths(page)), (layer, mode)
    page.hover("#plot circle.point >> nth=-1")  # drawn last, on top
    assert page.is_visible("#tip img")
    assert all(width > 0 for width in loaded_widths(page))
    # Every table of the report, and every setting in the plot's legend.
    assert page.locator("#tables table").count() >= 2
    assert page.locator("#plot circle.point").count() > 10
    assert page.errors == []


def test_the_wipe_slider_changes_the_pixels_under_it(page):
    choose(page, "#mode", "wipe")
    choose(page, "#first", image_index(page, "path_independent_1_spp"))
    choose(page, "#second", image_index(page, "reference"))
    shots = {}
    for at in (100, 0, 50):
        slide(page, "#wipe", at)
        shots[at] = pixels(page)
    width = shots[50].shape[1]
    left, right = slice(0, width // 2 - 4), slice(width // 2 + 4, width)
    # At 100 the left image fills the pane, at 0 the right one; at 50
    # each fills its own half.
    assert np.any(shots[100] != shots[0])
    assert np.array_equal(shots[50][:, left], shots[100][:, left])
    assert np.array_equal(shots[50][:, right], shots[0][:, right])
    assert page.errors == []


def test_zoomed_in_one_image_pixel_is_a_block_of_equal_pixels(page, report):
    """Where two neighbouring pixels of the reference differ most, zoomed
    in about them: each row of the screen shows runs of one colour as long
    as the zoom, where smoothing would show a ramp."""
    choose(page, "#mode", "flip")
    page.keyboard.press("1")  # the reference
    reference = np.asarray(Image.open(report / "images" / "reference.png").convert("RGB"))
    steps = np.abs(np.diff(reference.astype(int), axis=1)).sum(axis=2)
    row, column = np.unravel_index(np.argmax(steps), steps.shape)
    box = page.locator(".layer img").first.bounding_box()
    per_pixel = box["width"] / RESOLUTION
    x, y = box["x"] + (column + 1) * per_pixel, box["y"] + (row + 0.5) * per_pixel
    page.mouse.move(x, y)
    for _ in range(3):
        page.mouse.wheel(0, -300)
    page.wait_for_function(f"state.view.scale > {per_pixel * 2}")
    scale = page.evaluate("state.view.scale")
    assert page.inner_text("#zoom") == f"zoom {float(f'{scale:.3g}'):g}x"
    strip = pixels(page, clip={"x": x - 2 * scale, "y": y - scale / 4, "width": 4 * scale,
                               "height": scale / 2})
    for line in strip:
        edges = np.flatnonzero(np.any(line[1:] != line[:-1], axis=1)) + 1
        assert len(edges) >= 1, "the two pixels look alike"
        runs = np.diff(edges)
        assert np.all(runs >= scale - 2), runs
    assert page.errors == []


def test_exposure_brightens_the_image_only(page):
    choose(page, "#mode", "flip")
    before = pixels(page)
    slide(page, "#exposure", 2)
    after = pixels(page)
    # Black stays black, and so does the pane around the image.
    assert np.all(after >= before - 1) and np.any(after > before + 16)
    page.hover("#plot circle.point >> nth=-1")  # the plot's preview takes it too
    tip = pixels(page, "#tip img")
    slide(page, "#exposure", 0)
    page.mouse.move(0, 0)
    page.hover("#plot circle.point >> nth=-1")
    unexposed = pixels(page, "#tip img")
    assert np.all(tip >= unexposed - 1) and np.any(tip > unexposed + 16)
    choose(page, "#layer", "relmse")
    slide(page, "#exposure", 2)
    assert page.evaluate("getComputedStyle(document.querySelector('.layer')).filter") == "none"
    assert page.is_visible("#colour-bar")
    assert page.errors == []


def test_without_flip_the_page_shows_relmse_and_says_why(browser, tmp_path):
    """Where the flip-evaluator package cannot be imported, as on a plain
    install: relMSE maps only, a note that says so, and no error."""
    stub = tmp_path / "no_flip" / "flip_evaluator"
    stub.mkdir(parents=True)
    (stub / "__init__.py").write_text("raise ImportError('No module named flip_evaluator')\n")
    path = os.pathsep.join(filter(None, [str(stub.parent), os.environ.get("PYTHONPATH")]))
    folder = compare(tmp_path / "report", env=dict(os.environ, PYTHONPATH=path))
    page = open_page(browser, folder)
    try:
        layers = page.eval_on_selector_all("#layer option", "options => options.map(o => o.value)")
        assert layers == ["image", "relmse"]
        assert "FLIP is not available here" in page.inner_text("#note")
        assert min(loaded_widths(page)) > 0 and page.errors == []
    finally:
        page.close()
