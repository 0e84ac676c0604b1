"""``mitsuba-whitted preview``: the server through plain HTTP requests (its
status, its token, paths and Host header refused, Ctrl-C), and its page in
a real browser: Chromium driven by Playwright.

Oracles: the status endpoint's JSON, the HTTP status codes, and
screenshots of the page, whose pixels must change when the scene file's
colour changes or the camera moves, and stay when an edit breaks the file.
"""

import io
import json
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
from mitsuba_whitted.preview.session import REFINE_FACTOR, Superseded, _rows

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
#: A glass ball focusing a point light onto the floor beside it, with
#: photons: $photons per pass, $passes passes.
CAUSTIC = """<scene version="3.0.0">
    <default name="photons" value="20000"/>
    <default name="passes" value="2"/>
    <integrator type="whitted">
        <integer name="max_depth" value="8"/>
        <string name="aa" value="grid"/>
        <integer name="aa_samples" value="2"/>
        <integer name="photons" value="$photons"/>
        <integer name="photon_passes" value="$passes"/>
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="0.6, 2.4, 3.6" target="0.6, 0.2, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="32"/>
            <integer name="height" value="32"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="6"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" x="0" y="0.5" z="0"/>
        <float name="radius" value="0.5"/>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>
    </shape>
    <emitter type="point">
        <point name="position" x="-2.5" y="2.2" z="0"/>
        <rgb name="intensity" value="20"/>
    </emitter>
</scene>
"""


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


# --------------------------------------------------------------------- photons

@pytest.fixture
def caustic(tmp_path):
    path = tmp_path / "caustic.xml"
    path.write_text(CAUSTIC)
    return path


def shown_images(server, until, timeout: float = 60.0):
    """The statuses of the image events, and the image of each (PNG
    decoded to 8-bit RGB) where it was still shown when fetched, until
    ``until(status)`` holds."""
    from PIL import Image

    stream = server.request("/events")
    events, images, seen = [], {}, None
    end = time.perf_counter() + timeout
    for line in stream:
        assert time.perf_counter() < end, f"no such status within {timeout} s: {events[-1:]}"
        if not line.startswith(b"data:"):
            continue
        status = json.loads(line[5:])
        if status["generation"] == seen:
            continue
        seen = status["generation"]
        events.append(status)
        answer = server.request("/image.png")
        if int(answer.headers["X-Generation"]) == seen:
            images[seen] = np.asarray(Image.open(io.BytesIO(answer.read())).convert("RGB"),
                                      int)
        if until(status):
            return events, images
    raise AssertionError("the event stream ended")


def caustic_pixels(path) -> np.ndarray:
    """Where the photons' light is brightest: the caustic (a mask)."""
    scene = mitsuba_whitted.load_file(str(path))
    light = np.array(scene.integrator().photon_light(scene)).mean(axis=-1)
    return light > 0.5 * light.max()


def test_photon_passes_go_on_while_the_camera_is_still(caustic, tmp_path):
    """The image without photons comes first, then one after passes 1, 2,
    4, ..., past the scene's 2 passes up to the bound, each more converged:
    the caustic brightens from the first image on."""
    with preview(caustic, cwd=tmp_path, env=ENV) as running:
        events, images = shown_images(running, lambda status: status["state"] == "ready")
    bound = REFINE_FACTOR * 2
    passes = [status["passes"] for status in events]
    assert passes[-1] == bound and passes == sorted(passes)
    assert {1, 2, 4, 8, 16} <= set(passes)
    assert all(status["photon_passes"] == 2 and status["error"] is None for status in events)
    states = [status["state"] for status in events]
    assert states == sorted(states, key=["rendering", "refining", "ready"].index)
    assert states.count("ready") == 1 and "refining" in states
    passes_of = {status["generation"]: status["passes"] for status in events}
    lit = [generation for generation in images if passes_of[generation] > 0]
    dark = [generation for generation in images if generation not in lit]
    assert len(lit) >= 2, "the passes' images did not arrive more than once"
    mask = caustic_pixels(caustic)
    brightness = {generation: images[generation][mask].mean() for generation in images}
    assert all(brightness[later] > brightness[first] + 20 for first in dark for later in lit)
    assert not np.array_equal(images[lit[0]], images[lit[-1]])


def test_a_camera_move_stops_the_photon_passes(caustic, tmp_path):
    """A move while the passes go on: the image of the next pass of the old
    camera is not shown, the new camera's passes start again from its
    image without photons, and Ctrl-C ends the server mid-pass."""
    with preview(caustic, "-D", "passes=64", cwd=tmp_path, env=ENV) as running:
        events, _ = shown_images(running, lambda status: status["passes"] >= 4)
        lookat = events[-1]["lookat"]
        moved = time.perf_counter()
        running.request("/camera", {"move": "orbit", "x": 0.2, "y": 0})
        after, _ = shown_images(running, lambda status: status["passes"] == 2)
        assert all(status["lookat"] != lookat for status in after)
        assert time.perf_counter() - moved < 10
        # The stream's first status is the last image before the move; a
        # pass that ended as the move came may have been shown after it.
        new = after[1:]
        if new[0]["passes"] > 0:
            new = new[1:]
        assert [status["passes"] for status in new][:3] == [0, 0, 1]  # aa none, grid, pass 1
        assert [status["aa"] for status in new][:2] == ["none", "grid"]
        interrupted = time.perf_counter()
        running.process.send_signal(signal.SIGINT)
        running.process.communicate(timeout=10)
        assert running.process.returncode == 130 and time.perf_counter() - interrupted < 5


def test_photon_passes_continue_deterministically_and_stop_when_told(caustic):
    """Pass k's mean is the same reached by a longer run; an exception from
    on_pass ends the passes after the pass it heard of, and the next call
    starts cleanly."""
    scene = mitsuba_whitted.load_file(str(caustic), photons="5000")
    integrator = scene.integrator()
    heard = {}

    def on_pass(k, light):
        heard[k] = np.array(light)
        if k == 3:
            raise Superseded

    with pytest.raises(Superseded):
        integrator.photon_light(scene, passes=8, on_pass=on_pass)
    assert sorted(heard) == [1, 2, 3]
    for k in (1, 3):
        assert np.array_equal(np.array(integrator.photon_light(scene, passes=k)), heard[k])


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


@needs_chromium
def test_the_page_shows_the_photon_passes(browser, caustic, tmp_path):
    with preview(caustic, cwd=tmp_path, env=ENV) as running:
        opened = browser.new_page(viewport={"width": 800, "height": 500}, bypass_csp=True)
        opened.goto(running.url)
        opened.wait_for_function("document.getElementById('view').naturalWidth > 0")
        first, early = pixels(opened), opened.inner_text("#state") != "ready"
        opened.wait_for_function("document.getElementById('state').textContent === 'ready'",
                                 timeout=60000)
        assert f"photon passes {REFINE_FACTOR * 2} (the scene's 2)" in opened.inner_text("#stats")
        assert not early or np.abs(pixels(opened) - first).max() > 8
        opened.close()


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
