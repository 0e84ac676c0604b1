"""What the preview shows: the scene as last loaded, rendered in one
worker thread, and the status the page and scripts read.

Every request (a changed file, a camera move, a control) counts one up;
the worker renders for the newest. A render first goes without
anti-aliasing, then with the scene's own (or the page's choice), and each
pass's image is shown as soon as it is done. A render whose request is no
longer the newest finishes the band it is in and is discarded
(:class:`Superseded`).

Where the scene's ``whitted`` has photons, both of those leave them out,
and the photon passes follow, each added to the second image: it is shown
after pass 1, 2, 4, 8, ..., after the scene's last (``photon_passes``),
and after any pass that ends :data:`SHOW_EVERY` seconds or more after the
last image shown. While nothing changes the passes go on past the scene's,
along the same shrinking radius (pass k is the same however it is reached,
so the image converges), until :data:`REFINE_FACTOR` times the scene's
passes or :data:`REFINE_SECONDS` past them; a newer request stops them
after the pass in progress.

The old scene is dropped before a reload: Dr.Jit compiles object ids into
the kernels, and a scene loaded while the old one lives gets new ids and
compiles new kernels (0.9 s on the report's scene, against 0.15 s for one
whose ids are reused). A load that fails leaves no scene: the page keeps
the last image under the error until the file is fixed.
"""

from __future__ import annotations

import gc
import threading
import time
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..errors import Error, one_sentence
from ..imageio import png_bytes, stored_pixels, write_image
from ..integrators.film import developed, developed_format
from ..integrators.settings import AA_MODES, MAX_PHOTON_PASSES, is_whitted
from ..scene_files import files_read, first_sensor
from .orbit import Orbit

#: The integrator settings the page's controls change (``aa`` apart).
SETTINGS = ("max_depth", "indirect_samples")
#: The page's ``aa`` choice that keeps the scene's own.
SCENE_AA = "scene"
#: Pixels as the page shows them: the colour alone, over black, 8-bit sRGB
#: (as a JPEG stores them, see :func:`.imageio.stored_pixels`).
_SHOWN_AS = Path("shown.jpg")
#: Photon passes go on, while the camera and files stay, up to this many
#: times the scene's ``photon_passes``: the error of the mean falls as
#: passes^(-1/3), so the last image's is 16^(-1/3), 0.4 times the scene's.
REFINE_FACTOR = 16
#: ... and for no longer than this past the scene's passes, so that a page
#: left open does not keep the machine busy.
REFINE_SECONDS = 60.0
#: Seconds after which a pass's image is shown even between powers of two,
#: so that slow passes still show progress.
SHOW_EVERY = 1.0


class Superseded(Error):
    """A newer request came while a render ran: the render stops after its
    band, and nobody sees this sentence."""

    def __init__(self, message: str = "a newer request came while the render ran."):
        super().__init__(message, "mitsuba-whitted preview")


class _Enough(Error):
    """The photon passes reached the preview's bound: they stop there, and
    nobody sees this sentence."""

    def __init__(self, message: str = "the photon passes reached the preview's bound."):
        super().__init__(message, "mitsuba-whitted preview")


class Session:
    """The scene at ``path`` with ``defines``, rendered for the page.
    ``watch(files)`` hears the files the scene reads after each load."""

    def __init__(self, path: Path, defines: dict, watch):
        self.path, self.defines, self.watch = path, defines, watch
        self._changed = threading.Condition()
        self._request = 1  # the first load
        self._reload = True
        self._overrides: dict = {}
        self._exposure = 0.0
        self._moved: Orbit | None = None
        self._scene_camera: Orbit | None = None
        self._scene = self._scene_matrix = self._scene_aa = None
        self._image: np.ndarray | None = None
        self._version = 0
        self.png = b""
        self._status = {"generation": 0, "state": "rendering", "error": None, "seconds": None,
                        "width": None, "height": None, "aa": None, "rays_per_second": None,
                        "settings": {}, "exposure": 0.0, "lookat": None, "passes": None,
                        "photon_passes": None}
        self._first_load = threading.Event()
        self._first_error: BaseException | None = None

    # ---------------------------------------------------------- the page's side

    def start(self) -> None:
        """Start the worker and wait for the first load; its error, if any,
        is raised here (a command that cannot show the scene at all)."""
        threading.Thread(target=self._work, name="preview renderer", daemon=True).start()
        self._first_load.wait()
        if self._first_error is not None:
            raise self._first_error

    def status(self) -> dict:
        with self._changed:
            return dict(self._status)

    def shown(self) -> tuple[bytes, int]:
        """The PNG shown and its generation, read together."""
        with self._changed:
            return self.png, self._status["generation"]

    def next_status(self, seen: int, timeout: float) -> tuple[dict | None, int]:
        """The status once it differs from version ``seen`` (``None`` after
        ``timeout`` seconds without a change), and its version."""
        with self._changed:
            self._changed.wait_for(lambda: self._version != seen, timeout)
            changed = self._version != seen
            return (dict(self._status) if changed else None), self._version

    def files_changed(self) -> None:
        self._ask(reload=True)

    def move_camera(self, move: str, x: float, y: float) -> None:
        """``orbit`` (radians), ``dolly`` (e-fold steps), ``pan`` (fractions
        of the distance) or ``reset`` to the scene's camera."""
        if move not in ("orbit", "dolly", "pan", "reset"):
            raise ValueError(f"'{move}' is not a camera move (orbit, dolly, pan, reset).")
        with self._changed:
            if move == "reset":
                self._moved = None
            elif self._scene_camera is not None:
                self._moved = self._moved or self._scene_camera.copy()
                {"orbit": self._moved.orbit, "dolly": lambda x, y: self._moved.dolly(x),
                 "pan": self._moved.pan}[move](x, y)
            self._status["lookat"] = self._camera().lookat_xml() if self._camera() else None
        self._ask()

    def change_settings(self, values: dict) -> None:
        """The page's controls: ``aa`` (a mode or ``"scene"``), the
        :data:`SETTINGS` as whole numbers, ``exposure`` in stops."""
        values = _checked_settings(values)
        with self._changed:
            if "exposure" in values:
                self._exposure = values.pop("exposure")
                self._status["exposure"] = self._exposure
            if values.get("aa") == SCENE_AA:
                self._overrides.pop("aa", None)
                values.pop("aa")
            self._overrides.update(values)
        if values:
            self._ask()
        else:
            self._show_again()

    def save(self, folder: Path) -> Path:
        """Write the image shown (its exposure applied) as a new PNG in
        ``folder``, through the package's atomic writer."""
        with self._changed:
            image, exposure = self._image, self._exposure
        if image is None:
            raise ValueError("there is no image to save yet.")
        stem = self.path.stem
        path = folder / f"{stem}-preview.png"
        number = 1
        while path.exists():
            number += 1
            path = folder / f"{stem}-preview-{number}.png"
        write_image(path, image * 2.0 ** exposure)
        return path

    def _ask(self, reload: bool = False) -> None:
        with self._changed:
            self._request += 1
            self._reload |= reload
            self._changed.notify_all()

    def _camera(self) -> Orbit | None:
        return self._moved or self._scene_camera

    # -------------------------------------------------------- the worker's side

    def _work(self) -> None:
        done = 0
        while True:
            with self._changed:
                self._changed.wait_for(lambda: self._request != done)
                done, reload = self._request, self._reload
                self._reload = False
                overrides = dict(self._overrides)
                moved = self._moved.copy() if self._moved else None
                self._publish(state="rendering")
            try:
                if reload:
                    self._load()
                if self._scene is not None:
                    self._render(done, overrides, moved)
            except Superseded:
                continue
            except Exception as error:  # shown on the page; the server goes on
                if not self._first_load.is_set():
                    self._first_error = error
                self._publish(state="error", error=one_sentence(error))
            finally:
                self._first_load.set()

    def _load(self) -> None:
        import mitsuba_whitted

        self._scene = None
        gc.collect()
        try:
            self.watch([self.path, *files_read(self.path, self.defines)])
        except Exception:
            self.watch([self.path])  # what is broken, the load below says
        scene = mitsuba_whitted.load_file(self.path, **self.defines)
        sensor = first_sensor(scene, self.path)
        matrix = np.array(mi.traverse(sensor)["to_world"].matrix, np.float64)[..., 0]
        integrator = scene.integrator()
        with self._changed:
            self._scene, self._scene_matrix = scene, matrix
            self._scene_aa = integrator.aa if is_whitted(integrator) else None
            self._scene_camera = Orbit.of_matrix(matrix, _target_distance(scene, sensor))
            self._status["lookat"] = self._camera().lookat_xml()

    def _render(self, request: int, overrides: dict, moved: Orbit | None) -> None:
        scene = self._scene
        sensor, integrator = scene.sensors()[0], scene.integrator()
        camera = mi.traverse(sensor)
        camera["to_world"] = (mi.ScalarTransform4f().look_at(moved.origin, moved.target, moved.up)
                              if moved else mi.ScalarTransform4f(self._scene_matrix))
        camera.update()
        if not is_whitted(integrator):
            self._show(*_timed(lambda: np.array(mi.render(scene, sensor=sensor))), aa=None,
                       rays=None)
            return
        self._apply(integrator, overrides)
        final = overrides.get("aa", self._scene_aa)
        photons = integrator.photons > 0
        planned = integrator.photon_passes if photons else None
        for aa in dict.fromkeys(("none", final)):
            integrator.aa = aa
            started = time.perf_counter()
            image, seconds = _timed(lambda: _rows(integrator, scene, self, request))
            self._show(image, seconds, aa, integrator.last_stats.get("total"),
                       state="ready" if aa == final and not photons else "rendering",
                       passes=0 if photons else None, photon_passes=planned)
        if photons:
            self._photon_passes(integrator, scene, request, image, final, started)

    def _photon_passes(self, integrator, scene, request: int, rest: np.ndarray, aa,
                       started: float) -> None:
        """The photons' passes, each added to ``rest`` (the image without
        them, at ``aa``, begun at ``started``) and shown as the module's
        docstring says."""
        planned = integrator.photon_passes
        bound = min(REFINE_FACTOR * planned, MAX_PHOTON_PASSES)
        pixel_format = developed_format(scene.sensors()[0].film())
        shown_at, refining_since = time.perf_counter(), None

        def heard(k: int, light) -> None:
            nonlocal shown_at, refining_since
            if not self.is_newest(request):
                raise Superseded
            now = time.perf_counter()
            if k == planned:
                refining_since = now
            last = k == bound or (refining_since is not None
                                  and now - refining_since >= REFINE_SECONDS)
            if last or k == planned or k & (k - 1) == 0 or now - shown_at >= SHOW_EVERY:
                self._show(rest + _added(np.array(light), pixel_format), now - started, aa,
                           None, state="ready" if last else
                           "rendering" if k < planned else "refining", passes=k,
                           photon_passes=planned)
                shown_at = now
            if last:
                raise _Enough

        try:
            integrator.photon_light(scene, passes=bound, on_pass=heard)
        except _Enough:
            return
        # No pass was heard: no light of the photons' kinds in the scene.
        self._show(rest, time.perf_counter() - started, aa, None, passes=0,
                   photon_passes=planned)

    def _apply(self, integrator, overrides: dict) -> None:
        """The page's settings on the integrator (``aa`` is chosen per pass)."""
        params = mi.traverse(integrator)
        for name in SETTINGS:
            if name in overrides:
                params[name] = int(overrides[name])
        params.update()
        self._publish(settings={"aa": overrides.get("aa", SCENE_AA), "scene_aa": self._scene_aa,
                                **{name: getattr(integrator, name) for name in SETTINGS}})

    def _show(self, image: np.ndarray, seconds: float, aa, rays, state: str = "ready",
              passes: int | None = None, photon_passes: int | None = None) -> None:
        """Show ``image``; ``passes``: the photon passes in it, of the
        scene's ``photon_passes`` (``None`` without photons)."""
        height, width = image.shape[:2]
        with self._changed:
            self._image = image
        self._first_load.set()  # the URL may go out once there is an image to show
        self._show_again(state=state, seconds=seconds, aa=aa, width=width, height=height,
                         error=None, rays_per_second=rays / seconds if rays else None,
                         passes=passes, photon_passes=photon_passes)

    def _show_again(self, **status) -> None:
        """Encode the image with the exposure now set and show it."""
        with self._changed:
            image, exposure = self._image, self._exposure
        if image is None:
            return
        png = png_bytes(stored_pixels(_SHOWN_AS, image * 2.0 ** exposure))
        with self._changed:
            self.png = png
            self._publish(generation=self._status["generation"] + 1, **status)

    def _publish(self, **status) -> None:
        """Change the status and wake whoever waits for it."""
        with self._changed:
            self._status.update(status)
            self._version += 1
            self._changed.notify_all()

    def is_newest(self, request: int) -> bool:
        return self._request == request


def _checked_settings(values: dict) -> dict:
    """The page's settings as numbers and names, or a ``ValueError``."""
    checked = {}
    for name, value in values.items():
        if name == "exposure":
            checked[name] = float(value)
            if not np.isfinite(checked[name]):
                raise ValueError(f"exposure must be a finite number (got {value!r}).")
        elif name == "aa":
            if value not in (SCENE_AA, *AA_MODES):
                raise ValueError(f"aa must be one of {', '.join((SCENE_AA, *AA_MODES))}.")
            checked[name] = value
        elif name in SETTINGS:
            checked[name] = int(value)
        else:
            raise ValueError(f"'{name}' is not a setting of the preview.")
    return checked


def _rows(integrator, scene, session: Session, request: int) -> np.ndarray:
    """The image without the photons' light, band by band;
    :class:`Superseded` after the band in which a newer request came."""
    bands = []

    def take(first_row: int, rows: np.ndarray) -> None:
        bands.append(rows)
        if not session.is_newest(request):
            raise Superseded

    if not session.is_newest(request):
        raise Superseded
    integrator.render_rows(scene, take, photons=False)
    return np.concatenate(bands)


def _added(light: np.ndarray, pixel_format) -> np.ndarray:
    """The photons' RGB ``light`` in the film's ``pixel_format``, to add to
    the rest of the image (alpha, where there is one, is the rest's)."""
    if pixel_format.name.endswith("A"):
        light = np.concatenate([light, np.zeros_like(light[..., :1])], axis=-1)
    return developed(light, pixel_format)


def _timed(make):
    started = time.perf_counter()
    result = make()
    return result, time.perf_counter() - started


def _target_distance(scene, sensor) -> float:
    """How far ahead the camera looks: to what its central ray hits, or
    else to the centre of the scene's bounds."""
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(0.5), mi.Point2f(0.5))
    hit = float(scene.ray_intersect(ray).t.numpy()[0])
    if np.isfinite(hit) and hit > 0:
        return hit
    bounds = scene.bbox()
    origin = np.array(ray.o.numpy()).reshape(-1)[:3]
    centre = (np.array(bounds.min) + np.array(bounds.max)) / 2
    return max(float(np.linalg.norm(centre - origin)), 1e-3)
