"""``mitsuba-whitted preview``: the server through plain HTTP requests (its
status, its token, paths and Host header refused, Ctrl-C), and its page in
a real browser: Chromium driven by Playwright.

Oracles: the status endpoint's JSON, the HTTP status codes, and
screenshots of the page, whose pixels must change when the scene file's
colour changes or the camera moves, and stay when an edit breaks the file.
"""

import io
import os
import shutil
import signal
import socket
import time
import urllib.error

import numpy as np
import pytest

import mitsuba_whitted
from conftest import ROOT, cli, limit_whitted, one_line
from mitsuba_whitted.preview.measure import preview
from mitsuba_whitted.preview.session import Superseded, _rows

CHROMIUM = shutil.which("chromium")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="Chromium is not installed (the Debian package 'chromium' "
    "gives /usr/bin/chromium)")
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "plugins"), str(ROOT)])}
#: A sphere over a floor, lit by a point light; $colour is the sphere's.
SCENE = """<scene version="3.0.0">
    <default name="colour" value="0.8, 0.1, 0.1"/>
    <integrator type="whitted">
        <string name="aa" value="grid"/>
        <integer name="aa_samples" value="2"/>
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="0, 1, 5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="48"/>
            <integer name="height" value="48"/>
        </film>
    </sensor>
    <emitter type="point">
        <point name="position" x="2" y="4" z="3"/>
        <rgb name="intensity" value="40"/>
    </emitter>
    <shape type="sphere">
        <bsdf type="diffuse"><rgb name="reflectance" value="$colour"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
            <translate y="-1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
    </shape>
</scene>
"""
BLUE = "0.1, 0.1, 0.8"


def write_scene(path, colour="0.8, 0.1, 0.1", broken=False):
    text = SCENE.replace('value="0.8, 0.1, 0.1"', f'value="{colour}"')
    path.write_text(text.replace("</scene>", "<shape" if broken else "</scene>"))


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "scene.xml"
    write_scene(path)
    return path


@pytest.fixture
def server(scene, tmp_path):
    """A running preview of ``scene``, its working folder ``tmp_path``."""
    with preview(scene, cwd=tmp_path, env=ENV) as running:
        running.wait(lambda status: status["state"] == "ready", 60)
        yield running


def http_status(server, path, **options) -> int:
    try:
        return server.request(path, **options).status
    except urllib.error.HTTPError as error:
        return error.code


# ------------------------------------------------------------------ plain HTTP

def test_status_reports_the_render(server):
    status = server.status()
    assert {"generation", "state", "error", "seconds", "width", "height"} <= status.keys()
    assert status["state"] == "ready" and status["error"] is None
    assert (status["width"], status["height"]) == (48, 48)
    assert status["generation"] >= 2  # aa none, then the scene's grid
    assert status["aa"] == "grid" and status["seconds"] > 0
    image = server.request("/image.png").read()
    assert image.startswith(b"\x89PNG")


def test_token_is_required(server):
    assert http_status(server, "/status", token=False) == 403
    assert http_status(server, "/", token=False) == 403
    assert http_status(server, "/status?token=wrong", token=False) == 403
    assert http_status(server, "/") == 200


@pytest.mark.parametrize("path", ["/../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd",
                                  "/page.js/../../pyproject.toml", "//etc/passwd",
                                  "/scene.xml", "/preview/page.js"])
def test_no_path_reaches_the_file_system(server, path):
    assert http_status(server, path) == 404


def test_other_host_names_are_refused(server):
    port = server.base.rsplit(":", 1)[1]
    assert http_status(server, "/status", headers={"Host": f"attacker.example:{port}"}) == 403
    assert http_status(server, "/status", headers={"Host": "127.0.0.1:1"}) == 403
    assert http_status(server, "/status", headers={"Host": f"localhost:{port}"}) == 200


def test_a_broken_edit_is_one_sentence_and_keeps_the_image(server, scene):
    shown = server.status()["generation"]
    write_scene(scene, broken=True)
    status = server.wait(lambda status: status["state"] == "error")
    assert status["generation"] == shown
    assert "scene.xml" in status["error"] and "\n" not in status["error"]
    write_scene(scene, BLUE)
    server.wait(lambda status: status["state"] == "ready" and status["generation"] > shown)


def test_a_refused_setting_is_shown_and_a_good_one_renders(server):
    server.request("/settings", {"max_depth": -5})
    status = server.wait(lambda status: status["state"] == "error")
    assert "max_depth" in status["error"]
    server.request("/settings", {"max_depth": 3, "aa": "none"})
    status = server.wait(lambda status: status["state"] == "ready")
    assert status["settings"]["max_depth"] == 3 and status["aa"] == "none"


def test_a_bad_request_is_answered_in_one_sentence(server):
    with pytest.raises(urllib.error.HTTPError) as refused:
        server.request("/camera", {"move": "fly"})
    assert refused.value.code == 400
    assert "'fly' is not a camera move" in refused.value.read().decode()


def test_save_names_the_file_in_one_line(server, tmp_path):
    saved = tmp_path / "scene-preview.png"
    answer = server.request("/save", {}).read().decode()
    assert str(saved) in answer and saved.read_bytes().startswith(b"\x89PNG")


def test_ctrl_c_ends_in_one_line_with_130(server, tmp_path):
    before = set(tmp_path.iterdir())
    server.process.send_signal(signal.SIGINT)
    out, err = server.process.communicate(timeout=10)
    assert server.process.returncode == 130
    assert one_line(err) == "mitsuba-whitted: interrupted."
    assert out == ""  # the URL was read already
    assert set(tmp_path.iterdir()) == before


# ------------------------------------------------------------------ bad input

def test_a_missing_scene_is_one_sentence(tmp_path):
    result = cli("preview", str(tmp_path / "missing.xml"), "--no-browser", env=ENV)
    assert result.returncode == 2 and "does not exist" in one_line(result.stderr)


def test_a_bad_define_is_one_sentence(scene):
    result = cli("preview", str(scene), "-D", "colour", "--no-browser", env=ENV)
    assert result.returncode == 2 and "-D expects name=value" in one_line(result.stderr)


def test_a_busy_port_is_one_sentence(scene):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = cli("preview", str(scene), "--port", str(port), "--no-browser", env=ENV)
    assert result.returncode == 2 and "the port is in use" in one_line(result.stderr)


def test_a_scene_that_cannot_load_is_one_sentence(scene):
    write_scene(scene, broken=True)
    result = cli("preview", str(scene), "--no-browser", env=ENV)
    assert result.returncode == 2 and "scene.xml" in one_line(result.stderr)


# ------------------------------------------------------------------- browser

@pytest.fixture(scope="module")
def browser():
    if CHROMIUM is None:
        pytest.skip("Chromium is not installed (the Debian package 'chromium' gives "
                    "/usr/bin/chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=CHROMIUM, headless=True,
                                              args=["--no-sandbox"])
        yield launched
        launched.close()


@pytest.fixture
def page(browser, server):
    """The preview's page, its first image shown."""
    # The page forbids evaluated scripts; Playwright's waits evaluate theirs.
    opened = browser.new_page(viewport={"width": 800, "height": 500}, bypass_csp=True)
    opened.goto(server.url)
    opened.wait_for_function("document.getElementById('view').naturalWidth > 0")
    yield opened
    opened.close()


def pixels(page) -> np.ndarray:
    from PIL import Image

    shot = page.locator("#view").screenshot()
    return np.asarray(Image.open(io.BytesIO(shot)).convert("RGB")).astype(int)


def changed_within(page, before: np.ndarray, seconds: float) -> np.ndarray | None:
    """The image once it differs from ``before``, if it does within ``seconds``."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        now = pixels(page)
        if now.shape != before.shape or np.abs(now - before).max() > 8:
            return now
        time.sleep(0.05)
    return None


@needs_chromium
def test_the_first_image_appears(page):
    image = pixels(page)
    assert image.shape[:2] == (48, 48) and image.max() > 50


@needs_chromium
def test_an_edited_colour_shows_within_2_s(page, scene):
    red = pixels(page)
    write_scene(scene, BLUE)
    blue = changed_within(page, red, 2.0)
    assert blue is not None, "the page did not change within 2 s"
    centre = (slice(20, 28), slice(20, 28))
    assert red[centre][..., 0].mean() > red[centre][..., 2].mean()
    page.wait_for_function("document.getElementById('state').textContent === 'ready'")
    blue = pixels(page)
    assert blue[centre][..., 2].mean() > blue[centre][..., 0].mean()


@needs_chromium
def test_a_broken_edit_shows_the_sentence_over_the_image(page, scene):
    page.wait_for_function("document.getElementById('state').textContent === 'ready'")
    before = pixels(page)
    write_scene(scene, broken=True)
    page.wait_for_selector("#error", state="visible", timeout=5000)
    assert "scene.xml" in page.inner_text("#error")
    assert page.evaluate("document.getElementById('view').naturalWidth") == 48
    page.evaluate("document.getElementById('error').hidden = true")  # to see the image under it
    assert np.abs(pixels(page) - before).max() <= 8
    write_scene(scene, BLUE)
    page.wait_for_selector("#error", state="hidden", timeout=5000)
    assert changed_within(page, before, 2.0) is not None


@needs_chromium
def test_a_drag_moves_the_camera(page, server):
    page.wait_for_function("document.getElementById('state').textContent === 'ready'")
    before, lookat = pixels(page), server.status()["lookat"]
    box = page.locator("#view").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 15, y + 5, steps=5)
    page.mouse.up()
    assert changed_within(page, before, 3.0) is not None
    assert server.status()["lookat"] != lookat
    page.click("#reset")
    server.wait(lambda status: status["lookat"] == lookat)


def test_every_interface_is_warned_about(scene, tmp_path):
    with preview(scene, "--host", "0.0.0.0", cwd=tmp_path, env=ENV) as running:
        warning = running.process.stderr.readline()
        assert warning.startswith("warning: --host 0.0.0.0 serves the preview on every "
                                  "network interface")
        assert running.status()["state"] in ("rendering", "ready")


def test_a_render_overtaken_by_a_newer_request_stops_after_its_band(monkeypatch):
    """A render in flight when a newer request comes finishes the band it
    is in and goes no further; one that stays the newest gives the whole
    image."""
    limit_whitted(monkeypatch, band_samples=4 * 16, typical_samples=1)  # bands of 4 rows
    loaded = mitsuba_whitted.load_file(str(ROOT / "scenes" / "cases" / "mirror_chain.xml"),
                                       res="16")
    integrator = loaded.integrator()

    class Requests:
        """The render's request stays the newest for ``answers`` questions."""

        def __init__(self, answers):
            self.answers, self.asked = answers, 0

        def is_newest(self, request):
            self.asked += 1
            return self.asked <= self.answers

    whole = _rows(integrator, loaded, Requests(answers=10**6), 1)
    assert whole.shape[:2] == (16, 16) and integrator.last_stats["bands"] == 4
    overtaken = Requests(answers=2)  # asked before the render and after its first band
    with pytest.raises(Superseded):
        _rows(integrator, loaded, overtaken, 1)
    assert overtaken.asked == 3  # stopped after the second band, of four
