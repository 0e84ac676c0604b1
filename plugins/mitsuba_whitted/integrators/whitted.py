"""The ``whitted`` integrator plugin: Whitted ray tracing for any Mitsuba scene.

The plugin reads and checks its settings (:mod:`.settings`), plans the
render's memory and bands (:mod:`.render_plan`), places camera samples
(:mod:`.antialias`, :mod:`.lens`), traces their ray trees
(:mod:`.tracers`, through :mod:`.camera_shader`), and hands the bands to
the film (:mod:`.film`) or to a file; :mod:`.gradients` differentiates it.
"""

from __future__ import annotations

from functools import partial

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import ParameterError, check, check_choice
from ..jit import to_int
from ..parameters import LastValid
from ..render_lock import one_at_a_time
from . import antialias, gradients, render_plan
from .camera_shader import CameraShader, has_aperture, sensor_of, settle_sampler
from .film import (adjoint_pixels, developed, developed_format, film_channels, film_entries,
                   image_block)
from .kept_launches import KeepingShader, KeptLaunches, LaunchesDiffer, fingerprint
from .lighting import LightingSettings
from .photons.progressive import PATH_COMPLEMENT, PhotonLookup, ProgressivePhotons, kinds_for
from .render_plan import Demand, RenderPlan, plan_render
from .render_progress import RenderProgress
from .scene_checks import check_emitters, check_placements
from .scene_needs import SceneNeeds, analyse
from .scene_ref import identity, plain_values
from .settings import (AA_MODES, MAX_PHOTON_PASSES, PLUGIN_NAME, SETTINGS, SHADOW_MODES,
                       UNBOUNDED_DEPTH, Exposed, read_settings, require_supported_variant,
                       seed_value, validate)
from .shading import MAX_TREE_RAYS, TreeSettings
from .tracers import RayBatch, build_tracer
from .tracers.tree_replay import ReplayRefused


class WhittedIntegrator(mi.SamplingIntegrator):
    r"""
    .. _integrator-whitted:

    Whitted ray tracer (:monosp:`whitted`)
    --------------------------------------

    .. pluginparameters::

     * - max_depth
       - |int|
       - Longest path, as in Mitsuba: -1 is unbounded (until pruned, at most
         256 generations), 1 shows emitters only, 2 direct light only, 3 one
         mirror or refraction bounce... A camera sample's tree stops at 1024
         rays, with a warning. (Default: 10)
       - |exposed|
     * - ambient
       - |rgb|
       - Ambient light, times each hit's diffuse albedo. (Default: 0)
       - |exposed|, |differentiable|
     * - shadows
       - |string|
       - ``"physical"``: shadow rays pass only surfaces that transmit
         without bending light (index-matched or thin dielectrics, null,
         mask), tinted by their transmittance. ``"tinted"``: refracting
         surfaces pass light too, the COSC363 ray tracer's lightened shadows
         behind glass (each crossing lets through 1 - Fresnel reflectance
         times the transmittance). (Default: physical)
       - |exposed| (read-only)
     * - emitter_samples
       - |int|
       - Shadow rays per hit for each area or environment emitter. (Default: 16)
       - |exposed|
     * - indirect_samples
       - |int|
       - Paths of indirect light per pixel: 0 is classic Whitted. Above 0,
         each diffuse or glossy hit of the tree also gathers the light
         Whitted leaves out, by path tracing; with ``ambient`` 0 and
         ``shadows="physical"`` the image converges to ``path``'s at the
         same ``max_depth``. Not differentiated. (Default: 0)
       - |exposed|
     * - min_throughput
       - |float|
       - A reflected or refracted ray whose throughput is below this in
         every channel is not traced (Hall & Greenberg 1983). (Default: 1e-4)
       - |exposed|
     * - hide_emitters
       - |bool|
       - Hide directly visible emitters. (Default: false)
       - |exposed|
     * - aa
       - |string|
       - Anti-aliasing: ``"none"`` (pixel centres), ``"grid"``
         (``aa_samples``\ :sup:`2` stratified samples), ``"adaptive"`` (the
         report's recursive four-way split) or ``"contrast"`` (centres, then
         ``aa_samples``\ :sup:`2` points where the neighbourhood contrast
         passes ``aa_threshold``, after Mitchell 1987). (Default: none)
       - |exposed| (read-only)
     * - aa_samples
       - |int|
       - Grid: samples per pixel side. Contrast: a refined pixel takes its
         square. (Default: 2)
       - |exposed|
     * - aa_threshold
       - |float|
       - Adaptive: a quadrant whose colour differs from its siblings' mean
         by more than this is split. Contrast: the contrast above which a
         pixel is refined. (Default: 0.1)
       - |exposed|
     * - aa_max_depth
       - |int|
       - Adaptive: levels of splitting below the first four samples, 0 to
         16. (Default: 3)
       - |exposed|
     * - aa_budget
       - |float|
       - Most camera samples per pixel, on average, that refinement takes
         before it stops with a warning. (Default: 64)
       - |exposed|
     * - wavefront_size
       - |int|
       - Most rays of one launch; bounds the memory of a render. (Default: 262144)
       - |exposed|
     * - photons
       - |int|
       - Photons per pass of progressive photon mapping: 0 is none. Above
         0, the photons carry the light the rest of the render leaves out
         (with ``indirect_samples`` 0, caustics and indirect light; above
         0, only the light of point, spot and directional lights through
         mirrors and glass onto smooth surfaces, which no path finds),
         gathered at the ray tree's smooth hits. Not differentiated.
         (Default: 0)
       - |exposed|
     * - photon_passes
       - |int|
       - Passes of photons, each with a smaller gather radius: the photons'
         light converges as they grow. (Default: 16)
       - |exposed|
     * - photon_radius
       - |float|
       - Gather radius of the first pass, in scene units; 0: half the width
         of a pixel at the median distance of the camera's first hits.
         (Default: 0)
       - |exposed|

    Whitted (1980) ray tracing for any Mitsuba scene: at each hit, the
    emission, the ambient term, every light through the BSDF with a hard
    shadow, and a child ray for each delta lobe of the BSDF (mirror,
    Fresnel reflection and refraction) times its exact weight. Nothing is
    random: the image is a deterministic function of the scene. The camera
    samples are placed by ``aa`` (an ``spp`` passed to ``mi.render`` is
    not used, with a warning); a thin-lens camera gives depth of field.
    A render checks its memory before it allocates, and one that cannot
    fit is refused in one sentence naming what to lower.

    Gradients (``mi.render(scene, params)``, then ``dr.backward`` or
    ``dr.forward``) are exact and bit for bit repeatable, through the whole
    ray tree, for the parameters of BSDFs, textures, emitters and
    ``ambient``; changes of visibility (silhouettes, shadow edges) are not
    differentiated, and parameters that move geometry or the sensor are
    refused. :mod:`.gradients` says how.

    .. tabs::

        .. code-tab:: xml

            <integrator type="whitted">
                <integer name="max_depth" value="8"/>
                <string name="aa" value="adaptive"/>
                <float name="aa_threshold" value="0.25"/>
            </integrator>
    """

    plugin_name = PLUGIN_NAME
    #: What bounds a render's memory (:class:`.render_plan.Limits`).
    limits = render_plan.Limits()
    #: How a derivative traces the samples again (:mod:`.gradients`):
    #: ``"tree"``, frozen kernels that differentiate a hit at a time where the
    #: depth-first tracer serves; ``"graph"``, the whole trace differentiated
    #: unfrozen, which the tests keep as the oracle of the first.
    gradient_replay = "tree"

    def __init__(self, props: mi.Properties):
        # Refused before Mitsuba's base class warns about scalar variants.
        require_supported_variant()
        # Read before the base class, which reads ``hide_emitters`` too and
        # refuses a wrong type with a message of its own.
        settings = read_settings(props)
        super().__init__(props)
        self.shadows = check_choice(props.get("shadows", "physical"), SHADOW_MODES,
                                    PLUGIN_NAME, "shadows")
        self.aa = check_choice(props.get("aa", "none"), AA_MODES, PLUGIN_NAME, "aa")
        self._exposed = Exposed(settings)
        self._state_valid = LastValid(PLUGIN_NAME, nested=False)
        self.parameters_changed()
        #: Called as ``progress(done, total, message)`` while rendering, one
        #: count for the whole render (:mod:`.render_progress`).
        self.progress = None
        #: Set to keep every ray the next render casts in ``last_rays``.
        self.capture_rays = False
        self._state = _RenderState()

    # The render state is kept in a plain object, which Dr.Jit does not
    # look into when a frozen kernel traverses the scene (and with it this
    # integrator). Values that change from render to render would otherwise
    # make it record its kernels again, and the tracer (which holds the
    # scene) would lead it round a cycle.

    @property
    def last_stats(self) -> dict:
        """Statistics of the last render (ray counts by kind, AA samples)."""
        return self._state.stats

    @property
    def last_replay(self) -> str | None:
        """How the last derivative traced the camera samples again:
        ``"tree"`` or ``"graph"`` (:mod:`.gradients`); ``None`` before any."""
        replay = self._state.replay
        return None if replay is None else replay.kind

    @property
    def last_replay_rays(self) -> dict:
        """Rays the last derivative's tree replay walked, and walked again
        (each node with children, once they were done); empty for the
        graph replay."""
        replay = self._state.replay
        return {} if replay is None else dict(replay.rays)

    @property
    def last_sample_map(self):
        """Camera samples per pixel of the last adaptive or contrast render
        (mi.UInt32)."""
        return self._state.sample_map

    @property
    def last_rays(self):
        """A :class:`~.tracers.base.CapturedBatch` of every batch the last render
        traced (its rays and its shadow rays), if ``capture_rays`` was set."""
        return self._state.rays

    @last_rays.setter
    def last_rays(self, value):
        self._state.rays = value

    # ------------------------------------------------------------------ setup

    def make_tracer(self, scene: mi.Scene, seed: int = 0, wavefront: bool = False,
                    needs: SceneNeeds = None, differentiable: str = None, photons=None):
        """A tracer of ``scene`` with this integrator's settings
        (:func:`.tracers.build_tracer`; ``wavefront`` asks for the wavefront
        tracer, e.g. to capture each generation's rays, ``differentiable``
        for one whose traces Dr.Jit can differentiate, ambient term
        included: ``"graph"`` or ``"tree"``; ``photons``, a
        :class:`.photons.progressive.PhotonLookup`, for the tracer of photon
        passes, whose hits add the photons' light alone). ``needs`` replaces
        ``analyse(scene)``, e.g. to trace with another absolute offset length
        (its ``scale``)."""
        check_placements(scene)
        depth = UNBOUNDED_DEPTH if self.max_depth == -1 else self.max_depth
        ambient = self._exposed.arrays["ambient"] if differentiable else self.ambient
        return build_tracer(scene, needs or analyse(scene), self.shadows,
                            LightingSettings(ambient, self.emitter_samples, seed,
                                             self.indirect_samples),
                            TreeSettings(depth, self.min_throughput, self.hide_emitters),
                            self.wavefront_size, wavefront, differentiable, photons)

    def _tracer_for(self, scene: mi.Scene, seed: int):
        """The last render's tracer if nothing it was built from changed
        (the scene's objects, what the scene needs, the seed, this
        integrator's parameters, the scene's plain-number parameters), so
        that its frozen kernels replay rather than being recorded again;
        else a new one. Scene arrays the kernels read (parameters updated
        through ``mi.traverse``) reach them as arguments either way; plain
        numbers (a dielectric's ``eta``) are constants of the kernels
        (:func:`.scene_ref.plain_values`). The tracer reads ``scene`` only while
        ``render`` holds it in the tracer's ``scene_ref``."""
        needs = analyse(scene)
        built_from = self._built_from(scene, needs, seed, self.capture_rays)
        if self._state.built_from == built_from:
            self._state.tracer.reload()
            return self._state.tracer
        tracer = self.make_tracer(scene, seed, wavefront=self.capture_rays, needs=needs)
        self._state.built_from, self._state.tracer = built_from, tracer
        return tracer

    def _photon_tracer_for(self, scene: mi.Scene, with_paths: bool):
        """The tracer of the photon passes (``with_paths``: see
        :class:`.photons.progressive.PhotonLookup`), kept as
        ``_tracer_for`` keeps the render's. It is the same for every seed:
        it casts no shadow rays, and the passes take the seed as a kernel
        input."""
        needs = analyse(scene)
        built_from = self._built_from(scene, needs, 0, "photons", with_paths)
        state = self._state
        if state.photon_built_from == built_from:
            state.photon_tracer.reload()
            return state.photon_tracer
        tracer = self.make_tracer(scene, needs=needs, photons=PhotonLookup(with_paths))
        state.photon_built_from, state.photon_tracer = built_from, tracer
        return tracer

    @one_at_a_time
    def photon_light(self, scene: mi.Scene, sensor=0, seed=0, complement: str = "whitted",
                     passes: int = None, on_pass=None):
        """The photons' light alone, per pixel of the sensor's crop window
        (a ``mi.TensorXf`` of height x width x 3), with this integrator's
        ``photons``, ``photon_passes`` and ``photon_radius``.
        ``complement``: ``"whitted"``, the light this integrator's render
        adds with them; ``"path"``, the light a path tracer misses (point,
        spot and directional lights through any delta or null surface onto
        a smooth one), which completes a ``path`` reference.
        ``passes``: how many passes (``photon_passes`` if not given); more
        passes go on along the same shrinking radius, so that the mean of
        the first k is the same however many follow. ``on_pass(k, light)``,
        if given, hears after each pass k of the mean of the first k (a
        tensor like the one returned); what it raises ends the passes
        there and leaves this call (a live view stops them so)."""
        check_choice(complement, ("whitted", "path"), PLUGIN_NAME, "complement")
        check(self.photons > 0, PLUGIN_NAME, "photons", "must be > 0 for the photons' light")
        count = self.photon_passes if passes is None else passes
        check(isinstance(count, int) and 1 <= count <= MAX_PHOTON_PASSES, PLUGIN_NAME,
              "passes", f"must be a whole number between 1 and {MAX_PHOTON_PASSES} (got "
              f"{count!r})")
        sensor = sensor_of(scene, sensor)
        settle_sampler(sensor)
        check_emitters(scene)
        width, height = sensor.film().crop_size()
        shape = (height, width, 3)
        heard = None if on_pass is None else (
            lambda k, mean: on_pass(k, mi.TensorXf(dr.ravel(mean), shape)))
        light, self._state.stats = self._photon_light(scene, sensor, seed_value(seed), heard,
                                                      complement=complement, passes=count)
        return mi.TensorXf(dr.ravel(light), shape)

    def _photon_light(self, scene: mi.Scene, sensor: mi.Sensor, seed: int, on_pass=None,
                      complement: str = "whitted", passes: int = None):
        """The photons' light of every pixel of the crop window
        (:mod:`.photons.progressive`), and what the passes did."""
        kinds, delta_only = ((PATH_COMPLEMENT, True) if complement == "path"
                             else kinds_for(self.indirect_samples))
        tracer = self._photon_tracer_for(scene, with_paths=not kinds.smooth_bounces)
        depth = UNBOUNDED_DEPTH if self.max_depth == -1 else self.max_depth
        passes = ProgressivePhotons(self.photons, passes or self.photon_passes,
                                    self.photon_radius,
                                    kinds, delta_only, depth)
        shader = CameraShader(tracer, sensor)
        jitter = self.aa != "none"
        with tracer.scene_ref.holding(scene):
            light = passes.render(scene, sensor, seed, tracer, shader.trace, jitter,
                                  jitter and has_aperture(sensor), on_pass)
        return light, passes.stats

    def _replay_for(self, scene: mi.Scene, seed: int, sensor: mi.Sensor):
        """The :class:`.gradients.Replay` of the last derivative, of
        ``sensor``'s samples, if nothing its tracer was built from changed
        (as ``_tracer_for``; also whether the ambient term is
        differentiated, which a tracer leaves out where it is 0), else a
        new one, of the ``gradient_replay`` kind."""
        needs = analyse(scene)
        state = self._state
        kind = self.gradient_replay
        built_from = self._built_from(scene, needs, seed, kind,
                                      dr.grad_enabled(self._exposed.arrays["ambient"]))
        if built_from == state.replay_refused:
            kind = "graph"
            built_from = built_from + (kind,)
        if state.replay_built_from != built_from:
            tracer = self.make_tracer(scene, seed, needs=needs, differentiable=kind)
            state.replay_built_from, state.replay = built_from, gradients.replay_of(tracer, sensor)
        state.replay.sensor = sensor
        state.replay.start()
        return state.replay

    def _built_from(self, scene: mi.Scene, needs: SceneNeeds, seed: int, *kind) -> tuple:
        """What a tracer of ``scene`` is built from, ``kind`` included."""
        return (identity(scene), needs, seed, *kind, self._parameter_values(),
                plain_values(scene))

    def _parameter_values(self) -> tuple:
        return (self.max_depth, self.shadows, self.emitter_samples, self.min_throughput,
                self.hide_emitters, self.wavefront_size, tuple(self.ambient),
                self.indirect_samples)

    # ---------------------------------------------------------------- render

    @one_at_a_time
    def render(self, scene: mi.Scene, sensor=0, seed=0, spp=0,
               develop: bool = True, evaluate: bool = True):
        sensor = sensor_of(scene, sensor)
        seed = seed_value(seed)
        self._state.seed = seed
        self._note_sample_count(spp)
        film = sensor.film()
        channels = film_channels(film)

        def take(band, radiance, alpha):
            film.put_block(image_block(film, band, radiance, alpha, channels))

        kept = self._keeping(scene, sensor, seed)
        self.render_bands(scene, sensor, seed, take, film_entries(film, channels, develop),
                          prepare=lambda: film.prepare([]),
                          shader=None if kept is None else partial(KeepingShader, kept=kept))
        self._state.kept = kept if kept is not None and kept.complete else None
        return film.develop() if develop else mi.TensorXf()

    def _keeping(self, scene: mi.Scene, sensor: mi.Sensor, seed: int):
        """The :class:`.kept_launches.KeptLaunches` a render fills for its
        derivative, in a variant with derivatives and without indirect
        light (which is not differentiated); else ``None``. The last
        render's go first, before this one allocates."""
        self._state.kept = None
        if not dr.is_diff_v(mi.Float) or self.indirect_samples or self.photons:
            return None
        return KeptLaunches(fingerprint(scene, sensor, seed), self.limits.memory())

    # ------------------------------------------------------------- gradients

    @one_at_a_time
    def render_forward(self, scene: mi.Scene, params, sensor=0, seed=0, spp=0):
        """The derivative of ``render``'s image along the tangents of the
        parameters of ``params`` (:mod:`.gradients`), as a film's image."""
        return self._started_again_if_refused(self._render_forward, scene, params, sensor, seed,
                                              spp)

    def _render_forward(self, scene: mi.Scene, params, sensor, seed, spp):
        sensor, seed, replay, keys, read = self._gradient_setup(scene, params, sensor, seed, spp)
        film = sensor.film()
        channels = film_channels(film)

        def take(band, radiance, alpha):
            tangent = gradients.band_tangent(radiance)
            film.put_block(image_block(film, band, tangent, dr.zeros(mi.Float, band.pixels),
                                       channels))

        with gradients.StandIns(params, keys, tangents=True) as stand_ins, \
                replay.tracer.scene_ref.holding(scene):
            tangents = stand_ins.tangents_of()

            def tangent(positions, sample_keys, lens):
                return replay.tangent(positions, sample_keys, lens, tangents)

            self.render_bands(scene, sensor, seed, take, film_entries(film, channels),
                              prepare=lambda: film.prepare([]),
                              shader=partial(gradients.RecordingShader, tangent=tangent,
                                             read=read), derivative=True)
        return film.develop()

    @one_at_a_time
    def render_backward(self, scene: mi.Scene, params, grad_in, sensor=0, seed=0,
                        spp=0) -> None:
        """Add to the gradients of the parameters of ``params`` the
        derivative of ``render``'s image weighed by ``grad_in``, an image
        of adjoints (:mod:`.gradients`)."""
        self._started_again_if_refused(self._render_backward, scene, params, grad_in, sensor,
                                       seed, spp)

    def _render_backward(self, scene: mi.Scene, params, grad_in, sensor, seed, spp) -> None:
        sensor, seed, replay, keys, read = self._gradient_setup(scene, params, sensor, seed, spp)
        adjoint = adjoint_pixels(grad_in, sensor.film())
        shaders = []

        def shader(*args):
            shaders.append(gradients.RecordingShader(*args, read=read))
            return shaders[-1]

        with gradients.StandIns(params, keys, tangents=False) as stand_ins, \
                replay.tracer.scene_ref.holding(scene):

            def take(band, radiance, alpha):
                launches = shaders[-1].launches
                samples = gradients.sample_adjoints(launches, radiance, adjoint(band))
                launches.clear()
                replay.backward(*samples, stand_ins.leaves())

            self.render_bands(scene, sensor, seed, take, film_entries=0, shader=shader,
                              derivative=True)

    def _started_again_if_refused(self, derivative, *args):
        """``derivative(*args)``, started again without what was refused:
        the tree replay, whose kernels Dr.Jit refused to record (the graph
        replay takes over), or the render's kept launches, which the
        derivative's sampler did not ask for (it traces). Either is
        refused before the parameters' gradients change: the stand-ins'
        gradients are dropped."""
        for _ in range(2):
            try:
                return derivative(*args)
            except ReplayRefused:
                self._state.replay_refused = self._state.replay_built_from
            except LaunchesDiffer:
                self._state.kept = None
        return derivative(*args)

    def _gradient_setup(self, scene: mi.Scene, params, sensor, seed, spp):
        """The sensor, the seed of the image to differentiate, a
        :class:`.gradients.Replay` of its samples, the keys of the
        differentiated parameters and the reader of the render's kept
        launches (``None`` unless they are this image's), once the variant,
        the settings and ``params`` are found differentiable and the tile
        traced again is found to fit beside the render."""
        gradients.require_differentiable(self.indirect_samples, self.photons)
        keys = gradients.differentiated(params)
        sensor = sensor_of(scene, sensor)
        self._note_sample_count(spp)
        seed = gradients.primal_seed(seed_value(seed), self._state.seed)
        replay = self._replay_for(scene, seed, sensor)
        demand = self._demand(sensor.film(), self._tracer_for(scene, seed), 0, 0)
        plan_render(gradients.tile_demand(demand, replay), self.limits)
        kept = self._state.kept
        read = None
        if kept is not None and kept.key == fingerprint(scene, sensor, seed):
            read = kept.reader()
        return sensor, seed, replay, keys, read

    @one_at_a_time
    def render_rows(self, scene: mi.Scene, take, sensor=0, seed=0, held_bytes: int = 0,
                    photons: bool = True) -> None:
        """Render without a film of the whole image: ``take(first_row,
        rows)`` receives the image band by band, top to bottom, as float32
        NumPy arrays (rows, width, channels) holding what the film's
        ``develop`` would (in its pixel format: RGB, luminance or XYZ, with
        or without alpha), so that images
        larger than memory reach a file one band at a time. ``held_bytes``:
        what ``take`` keeps meanwhile, for the memory check. ``photons``
        False leaves the photons' light out (:meth:`photon_light` gives it
        apart, pass by pass: a live view shows the rest first)."""
        sensor = sensor_of(scene, sensor)
        seed = seed_value(seed)
        channels = film_channels(sensor.film())
        pixel_format = developed_format(sensor.film())

        def take_band(band, radiance, alpha):
            values = [radiance.x, radiance.y, radiance.z] + ([alpha] if channels == 5 else [])
            rows = np.stack([value.numpy() for value in values], axis=-1)
            take(band.first_row, developed(rows.reshape(band.rows, band.width, channels - 1),
                                           pixel_format))

        self.render_bands(scene, sensor, seed, take_band, film_entries=0, held_bytes=held_bytes,
                          photons=photons)

    def render_bands(self, scene: mi.Scene, sensor: mi.Sensor, seed, take,
                     film_entries: int, prepare=None, held_bytes: int = 0,
                     shader=None, derivative: bool = False, photons: bool = True) -> None:
        """Trace the crop window band by band (:mod:`.render_plan`) and hand
        each band's radiance and alpha to ``take(band, radiance, alpha)``.
        ``film_entries``: the floats the caller's film holds; ``prepare()``
        runs once the render is known to fit, before anything large is
        allocated; ``shader(tracer, sensor, progress)`` makes what traces the
        camera samples (a :class:`CameraShader` if not given); a
        ``derivative``'s pass leaves ``last_stats`` as the render left it;
        ``photons`` False leaves the photons' light out."""
        check_emitters(scene)
        aperture = has_aperture(sensor)
        if self.aa == "none" and aperture:
            self._note_once("pinhole", "whitted: aa='none' traces each pixel from the centre "
                            "of the thin lens's aperture, so the image has no depth of field; "
                            "use 'grid', 'adaptive' or 'contrast'.")
        self._note_indirect_model()
        self._note_long_grid()
        settle_sampler(sensor)
        tracer = self._tracer_for(scene, seed)
        plan = plan_render(self._demand(sensor.film(), tracer, film_entries, held_bytes),
                           self.limits)
        photon_light, photon_stats = None, {}
        if self.photons and photons and not derivative:
            photon_light, photon_stats = self._photon_light(scene, sensor, seed)
        if prepare is not None:
            prepare()
        tracer.captured = [] if self.capture_rays else None
        total = antialias.SampleCount()
        sampler = self._sampler(lens=self.aa != "none" and aperture)
        bands = list(plan.bands())
        with tracer.scene_ref.holding(scene):
            progress = RenderProgress(self.progress, sampler, bands)
            shade = (shader or CameraShader)(tracer, sensor, progress.traced,
                                             self.indirect_samples)
            for band in bands:
                progress.start_band(band)
                radiance, alpha, count = sampler.render(band, shade, total.refined)
                if photon_light is not None:
                    radiance = radiance + band_of(photon_light, band)
                _require_finite(radiance, alpha)
                take(band, radiance, alpha)
                total.add(count)
                progress.end_band()
        if not derivative:
            self._record(tracer, total, plan, photon_stats)

    def _demand(self, film: mi.Film, tracer, film_entries: int, held_bytes: int) -> Demand:
        """What a render of ``film`` asks of memory (:mod:`.render_plan`)."""
        width, height = film.crop_size()
        kept = self.aa_budget if self.aa in ("adaptive", "contrast") else 1
        launch, parameter = tracer.launch_rays, "wavefront_size"
        if self.aa == "grid" and self.aa_samples ** 2 > launch:
            launch, parameter = self.aa_samples ** 2, "aa_samples"
        return Demand(width, height, kept, launch, film_entries, launch_parameter=parameter,
                      held_bytes=held_bytes)

    def _record(self, tracer, count: antialias.SampleCount, plan: RenderPlan,
                photon_stats: dict) -> None:
        """Keep what the last render did for ``last_stats`` and friends."""
        stats = tracer.statistics()
        stats.update(photon_stats)
        stats["aa_samples"] = count.samples
        stats["aa_per_level"] = count.per_level
        stats["aa_levels"] = count.levels
        stats["aa_budget_hit_at"] = count.budget_hit_at
        stats["bands"] = plan.band_count
        self._state.stats = stats
        self._state.sample_map = count.per_pixel if plan.band_count == 1 else None
        self._state.rays = tracer.captured
        if stats["cut"]:
            _warn(f"whitted: {stats['cut']:,} rays were left untraced: the ray tree of a "
                  f"camera sample stops at {MAX_TREE_RAYS} rays; lower 'max_depth' or raise "
                  "'min_throughput'.")

    def _sampler(self, lens: bool):
        """What places and traces each band's camera samples, for ``aa``:
        ``render(band, shade, refined_before)`` gives the band's radiance,
        alpha and sample count, its refinement samples' keys following the
        ``refined_before`` of the bands above. ``lens``: whether the samples
        take points of the sensor's aperture."""
        budget = antialias.SampleBudget(self.aa_budget, self.limits.band_samples)
        if self.aa == "adaptive":
            return antialias.AdaptiveSampler(self.aa_threshold, self.aa_max_depth, budget,
                                             _warn, lens)
        if self.aa == "contrast":
            return antialias.ContrastSampler(self.aa_threshold, self.aa_samples, budget,
                                             _warn, lens)
        return antialias.GridSampler(self.aa_samples if self.aa == "grid" else 1, lens)

    def _note_indirect_model(self) -> None:
        """The ambient term and tinted shadows stand in for light that the
        indirect paths also gather: with both, some light counts twice."""
        doubled = [what for what, present in (
            ("the ambient term", any(c > 0 for c in self.ambient)),
            ("tinted shadows", self.shadows != "physical")) if present]
        gatherers = [name for name in ("indirect_samples", "photons") if getattr(self, name)]
        if gatherers and doubled:
            self._note_once("indirect model", (
                f"whitted: with {' and '.join(gatherers)} > 0, {' and '.join(doubled)} add "
                "light that the indirect paths or photons gather as well; set 'ambient' to 0 "
                "and 'shadows' to 'physical' for an image that converges to the true one."))

    def _note_long_grid(self) -> None:
        """A grid traces every sample it asks for, past ``aa_budget`` too
        (what does not fit in memory goes in bands, what Dr.Jit cannot hold
        is refused by the plan): say that the render takes longer."""
        samples = self.aa_samples ** 2
        if self.aa == "grid" and samples > self.aa_budget:
            self._note_once(f"grid of {samples}", (
                f"whitted: aa='grid' with aa_samples={self.aa_samples} traces {samples} camera "
                f"samples per pixel, {samples / self.aa_budget:.3g} times 'aa_budget' "
                f"({self.aa_budget:g}): the render takes about that much longer."))

    def _note_sample_count(self, spp: int) -> None:
        """``mi.render(..., spp=N)``: whitted places its own camera samples
        (``aa``, ``aa_samples``), so a count passed in is not used; say so
        rather than ignore it silently."""
        if spp:
            self._note_once("spp", f"whitted: spp={spp} is not used: whitted places its own "
                            f"camera samples, set by 'aa' (now '{self.aa}') and 'aa_samples'.")

    def _note_once(self, subject: str, message: str) -> None:
        """Warn about ``subject`` once in this integrator's life."""
        if subject not in self._state.noted:
            self._state.noted.add(subject)
            _warn(message)

    @one_at_a_time
    def trace_rays(self, scene: mi.Scene, ray: mi.Ray3f, seed: int = 0,
                   needs: SceneNeeds = None):
        """Whitted radiance and alpha along arbitrary rays, with the tracer of
        the last render where it still fits (``needs``: see
        ``make_tracer``; a tracer made for them is not kept). Each hit
        gathers with ``indirect_samples`` paths (times its throughput)."""
        if needs is None:
            tracer = self._tracer_for(scene, seed_value(seed))
        else:
            tracer = self.make_tracer(scene, seed, needs=needs)
        keys = dr.arange(mi.UInt32, dr.width(ray.o))
        with dr.suspend_grad(), tracer.scene_ref.holding(scene):
            radiance, alpha, *_ = tracer.trace(RayBatch(mi.Point3f(ray.o), mi.Vector3f(ray.d),
                                                        mi.Color3f(1), keys))
        return radiance, alpha

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """Whitted radiance along arbitrary rays (no anti-aliasing)."""
        radiance, alpha = self.trace_rays(scene, ray)
        return mi.Spectrum(radiance), alpha > 0, []

    # ------------------------------------------------------------ interfaces

    def aov_names(self):
        return []

    def traverse(self, callback):
        """The numeric settings, which an update may change (the integrator
        then traces with new kernels), and ``aa`` and ``shadows``, which it
        may not: they choose what kind of render this is. ``ambient`` is
        differentiable."""
        flags = mi.ParamFlags.NonDifferentiable
        for name, value in self._exposed.arrays.items():
            callback.put(name, value, mi.ParamFlags.Differentiable if name == "ambient" else flags)
        for name in ("aa", "shadows"):
            callback.put(name, getattr(self, name), flags | mi.ParamFlags.ReadOnly)

    def properties(self) -> dict:
        """The settings as the properties of a ``whitted`` that renders
        like this one (for ``mi.load_dict``, without its ``type``)."""
        properties = {name: getattr(self, name) for name in SETTINGS}
        properties["ambient"] = {"type": "rgb", "value": list(self.ambient)}
        properties.update(aa=self.aa, shadows=self.shadows)
        return properties

    def parameters_changed(self, keys=()):
        """Take the settings from the traversed arrays, or refuse them all
        and leave the arrays as they were."""
        with self._state_valid.updating(self):
            values = self._exposed.values()
            validate(values)
            for name, value in values.items():
                setattr(self, name, value)

    def to_string(self):
        return (f"WhittedIntegrator[max_depth={self.max_depth}, shadows={self.shadows}, "
                f"aa={self.aa}, ambient={list(self.ambient)}]")


class _RenderState:
    """What the integrator keeps from one render to the next: the tracer
    and what it was built from (reused while that is unchanged), what the
    last render left (see the integrator's ``last_*``), and the warnings
    already given."""

    __slots__ = ("built_from", "tracer", "photon_built_from", "photon_tracer",
                 "replay_built_from", "replay", "replay_refused", "kept", "stats", "sample_map",
                 "rays", "noted", "seed")

    def __init__(self):
        self.built_from = self.tracer = self.sample_map = self.rays = None
        #: The tracer of the photon passes, and what it was built from.
        self.photon_built_from = self.photon_tracer = None
        #: The last derivative's replay (``_replay_for``), and what the
        #: tree replay Dr.Jit refused was built from.
        self.replay_built_from = self.replay = self.replay_refused = None
        #: The last render's launches (:mod:`.kept_launches`), if kept.
        self.kept = None
        #: The seed of the last ``render`` (``gradients`` differentiate its image).
        self.seed = 0
        self.stats = {}
        #: Subjects of the warnings given once (``_note_once``).
        self.noted = set()


def band_of(pixels: mi.Color3f, band) -> mi.Color3f:
    """The values of ``band``'s pixels, of per-pixel values of the whole
    crop window (row-major)."""
    index = dr.arange(mi.UInt32, band.pixels) + dr.opaque(mi.UInt32, band.first_pixel)
    return dr.gather(mi.Color3f, pixels, index)


def _require_finite(radiance: mi.Color3f, alpha: mi.Float) -> None:
    """Stop before a NaN or infinite pixel reaches the image. The scene's
    emitters and placements are checked beforehand; what passes those and
    still overflows (a radiance beyond float32's range) is named here."""
    bad = to_int(dr.count(~(dr.isfinite(radiance.x) & dr.isfinite(radiance.y)
                            & dr.isfinite(radiance.z) & dr.isfinite(alpha))))
    if bad:
        raise ParameterError(
            PLUGIN_NAME, "scene",
            f"gives {bad} pixel(s) a NaN or infinite value: a radiance, intensity or "
            "reflectance in it is too large for float32")


def _warn(message: str) -> None:
    mi.Log(mi.LogLevel.Warn, message)


mi.register_integrator(PLUGIN_NAME, lambda props: WhittedIntegrator(props))