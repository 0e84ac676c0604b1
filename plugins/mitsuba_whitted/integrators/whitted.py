from __future__ import annotations

import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit import in_launches, to_int
from ..errors import ParameterError, VariantError, check, check_choice
from ..film_format import developed_format
from ..parameters import LastValid, check_seed, checked_numbers, describe
from ..render_lock import one_at_a_time
from . import antialias, gradients, render_plan
from .render_plan import Demand, RenderPlan, plan_render
from .scene_checks import check_emitters, check_placements
from .lighting import LightingSettings
from .scene_needs import SceneNeeds, analyse
from .scene_ref import identity
from .shading import MAX_TREE_RAYS, TreeSettings
from .tracers import RayBatch
from .tracers import build_tracer

PLUGIN_NAME = "whitted"

AA_MODES = ("none", "grid", "adaptive", "contrast")
#: ``"seed"``, the mode's first name, still names ``"tinted"``.
SHADOW_MODES = ("physical", "tinted", "seed")
#: ``max_depth = -1`` means "until pruned"; this cap keeps two facing
#: perfect mirrors from looping forever.
UNBOUNDED_DEPTH = 256
#: Deeper adaptive levels would place samples closer than float32 resolves.
AA_DEPTH_LIMIT = 16
#: Most indirect paths per hit: the Sobol points' 32-bit indices, and far
#: beyond what converges any image.
MAX_INDIRECT_SAMPLES = 1 << 20


def _given(props: mi.Properties, name: str, default):
    """The property as given, of whatever type (``Properties.get`` with a
    default refuses another type than the default's with a message of its
    own), or ``default``."""
    return props.get(name) if name in props else default


#: The range of the 32-bit integers the settings are kept in (``mi.Int32``).
INT32_RANGE = (-(1 << 31), (1 << 31) - 1)


def _whole(default: int):
    def read(props: mi.Properties, name: str) -> int:
        given = _given(props, name, default)
        check(not isinstance(given, str), PLUGIN_NAME, name,
              f"must be a whole number (got {describe(given)})")
        value = checked_numbers(given, PLUGIN_NAME, name)[0]
        check(value == int(value), PLUGIN_NAME, name, f"must be a whole number (got {value:g})")
        low, high = INT32_RANGE
        check(low <= value <= high, PLUGIN_NAME, name,
              f"must be a whole number from {low} to {high} (got {int(value)})")
        return int(value)
    return read


def _real(default: float):
    def read(props: mi.Properties, name: str) -> float:
        return checked_numbers(_given(props, name, default), PLUGIN_NAME, name)[0]
    return read


def _flag(default: bool):
    def read(props: mi.Properties, name: str) -> bool:
        value = _given(props, name, default)
        check(isinstance(value, bool), PLUGIN_NAME, name,
              f"must be true or false (got {describe(value)})")
        return value
    return read


def _colour(props: mi.Properties, name: str) -> list:
    return checked_numbers(_given(props, name, 0.0), PLUGIN_NAME, name, size=3, broadcast=True)


#: The numeric settings: how each is read from the scene's properties (with
#: its default). ``mi.traverse`` exposes them as one-entry arrays.
SETTINGS = {
    "max_depth": _whole(10),
    "ambient": _colour,
    "emitter_samples": _whole(16),
    "indirect_samples": _whole(0),
    "min_throughput": _real(1e-4),
    "hide_emitters": _flag(False),
    "aa_samples": _whole(2),
    "aa_threshold": _real(0.1),
    "aa_max_depth": _whole(3),
    "aa_budget": _real(64.0),
    "wavefront_size": _whole(1 << 18),
}


class WhittedIntegrator(mi.SamplingIntegrator):
    r"""
    .. _integrator-whitted:

    Whitted ray tracer (:monosp:`whitted`)
    --------------------------------------

    .. pluginparameters::

     * - max_depth
       - |int|
       - Longest path, in Mitsuba's convention: -1 is unbounded (until pruned,
         at most 256 generations), 1 shows emitters only, 2 direct light
         only, 3 one mirror or refraction bounce, ... Whatever the depth, the
         ray tree of one camera sample stops at 1024 rays, with a warning
         that counts the rays left out. (Default: 10)
     * - ambient
       - |rgb|
       - Ambient light, multiplied by the diffuse albedo of each hit
         (``eval_diffuse_reflectance``; zero for BSDFs without a diffuse
         lobe). (Default: 0, no ambient term)
       - |exposed|, |differentiable|
     * - shadows
       - |string|
       - ``"physical"``: shadow rays pass only surfaces that transmit
         without bending light (index-matched or thin dielectrics, null,
         mask), tinted by their transmittance; refracting surfaces block
         them, as they block Mitsuba's (``volpath`` passes null, mask and
         thin surfaces too; ``path`` passes none). ``"tinted"`` (also
         ``"seed"``): refracting surfaces pass light too, the COSC363 ray
         tracer's lightened shadows behind glass. The shadow ray goes on straight;
         at each surface it crosses, it passes the part the surface
         transmits at the angle where the ray meets it, as if arriving from
         outside (1 - Fresnel reflectance, times the surface's
         transmittance), so both crossings of a closed object count and
         there is no total internal reflection on the way out.
         Under a glass sphere of index n and transmittance T, the centre of
         the shadow receives (1 - ((n - 1) / (n + 1))\ :sup:`2`)\ :sup:`2`
         T\ :sup:`2` of the light it would receive unshadowed.
         (Default: physical)
     * - emitter_samples
       - |int|
       - Shadow rays per hit for each area or environment emitter, placed
         by a rotated low-discrepancy sequence. (Default: 16)
     * - indirect_samples
       - |int|
       - Paths of indirect light per pixel, on average: 0 is classic
         Whitted. Above 0, each hit of the ray tree with a diffuse or glossy
         part also gathers the light Whitted leaves out (interreflection,
         caustics from area and environment lights) by path tracing from
         that hit, with light sampling and multiple importance sampling,
         along Owen-scrambled Sobol samples; the tree keeps everything it
         does exactly (delta chains, delta lights, the shadow rays to every
         light). A pixel's paths are shared among its camera samples, and a
         hit seen through a dim reflection or refraction takes fewer, in
         proportion to the light that reaches the camera from it (at least
         one per sample and smooth hit); pixels that see only delta chains
         spend nothing on them. With ``ambient`` 0 and
         ``shadows="physical"``, the image's expectation is that of
         Mitsuba's ``path`` at the same ``max_depth``. Not differentiated.
         (Default: 0)
     * - min_throughput
       - |float|
       - Ray-tree pruning (Hall & Greenberg 1983): a reflected or refracted
         ray whose throughput is below this in every channel is not traced.
         0 traces every ray up to ``max_depth`` and the 1024-ray cap of a
         tree. (Default: 1e-4)
     * - hide_emitters
       - |bool|
       - Hide directly visible emitters. (Default: false)
     * - aa
       - |string|
       - Anti-aliasing: ``"none"`` (pixel centres), ``"grid"``
         (``aa_samples`` x ``aa_samples`` stratified samples),
         ``"adaptive"`` (recursive four-way split of the pixels) or
         ``"contrast"`` (pixel centres, then ``aa_samples``\ :sup:`2`
         Hammersley points in each pixel whose neighbourhood contrast is
         high, after Mitchell 1987). (Default: none)
     * - aa_samples
       - |int|
       - Grid: samples per pixel side, all of them traced (past
         ``aa_budget``, with a warning that the render takes that much
         longer). Contrast: a refined pixel takes ``aa_samples``\ :sup:`2`
         points. (Default: 2)
     * - aa_threshold
       - |float|
       - Adaptive: a quadrant is split when its colour (clamped to [0, 1])
         differs from the mean of its siblings by more than this in some
         channel. Contrast: a pixel is refined when, in some channel
         (R, G, B, alpha), ``(max - min) / (max + min)`` over it and its
         8 neighbours is above this. (Default: 0.1)
     * - aa_max_depth
       - |int|
       - Adaptive: levels of splitting below the first four samples,
         0 to 16. (Default: 3)
     * - aa_budget
       - |float|
       - Most camera samples per pixel that the refinements choose to
         take, on average over the image (over a band of it, for films cut
         into bands): adaptive refinement stops with a warning where a level
         would pass it; contrast refinement takes fewer points per pixel,
         with a warning. A grid, whose count is asked for explicitly, takes
         it whole, with a warning past this. (Default: 64)
     * - wavefront_size
       - |int|
       - Most rays of one generation in the wavefront tracer; the stack
         tracer, which keeps far less per ray outside its kernel, launches
         up to 8 times as many camera samples at once; a gradient traces
         4 times as many again with AD, about a kilobyte each. Wider
         batches are split so memory stays bounded. (Default: 262144)

    Whitted (1980) ray tracing for any Mitsuba scene. At each hit the
    radiance is the emission, the ambient term, the light of every delta
    emitter (point, spot, directional) through the BSDF with a hard shadow,
    the light of every area and environment emitter from
    ``emitter_samples`` shadow rays, and, for each delta component of the
    BSDF (mirror reflection, Fresnel reflection and refraction,
    straight-through transmission), the radiance of a child ray times its
    exact weight. Nothing is chosen at random: the image is a deterministic
    function of the scene (and of ``seed`` for area lights).

    Each camera sample's ray tree is walked depth first inside one frozen
    kernel, with a small per-lane stack of pending rays; trees too deep for
    that stack (``max_depth`` -1 or very large with several delta
    components) are traced as wavefronts instead, one generation at a time.
    Both give the same image to float rounding. Pixels are box filtered over
    their own area; the film's reconstruction filter is not used.

    A camera with an aperture (``thinlens``) gives depth of field by
    distributed ray tracing (Cook 1984): every camera sample also takes a
    point of the aperture, deterministic, and stratified together with the
    film positions (``grid``: the film strata and the lens strata paired so
    that every two coordinates take all combinations; ``contrast``: the
    refinement's Hammersley points take the next two Halton coordinates;
    ``adaptive``: each cell's quadrants take the quarters of the cell's
    square of the lens, nested down the levels; the first, single sample of
    a ``contrast`` pixel takes a hashed point, so that blur shows as
    contrast). ``aa = "none"`` traces each pixel from the centre of the
    aperture, a pinhole, and says so in a warning.

    The camera samples are placed by ``aa``: a sample count that
    ``mi.render`` passes (``spp``) and the sensor's sampler are not used,
    and an ``spp`` passed draws a warning. Before it allocates, a render
    estimates the memory it needs (the film, the samples of the
    anti-aliasing, the tracer's launches) and compares it with what the
    machine has left; a film whose samples would not fit at once is
    rendered in bands of rows (a cut that depends only on the film's size
    and these parameters), and a render that cannot fit at all is refused
    with a sentence naming what to lower. Every emitter's values are checked
    before each render, and the placements of sensors and shapes when the
    scene is set up: NaN, infinite or negative amounts of light are refused,
    naming the object.

    Gradients: ``mi.render(scene, params)`` with parameters whose
    gradients are enabled, then ``dr.backward`` or ``dr.forward``, gives
    the exact derivative of the image (no samples, no noise; the same bits
    on every run), for every ``aa`` and ``shadows`` mode
    (:mod:`.gradients` says how). It flows through the whole ray tree,
    through the mirrors, glass and shadow rays that reach a parameter:

    - BSDFs: diffuse and specular reflectance, the Phong exponent,
      conductor reflectance, dielectric transmittance, a thin dielectric's
      index, a blend's weight, and any texture they use;
    - textures: bitmap data (a bitmap loaded with ``format`` ``variant``:
      8-bit pixels are stored as integers), ``tartan`` colour and
      placement, ``sphere_map`` centre and placement, ``planar_map``
      bounds;
    - emitters: point and spot intensity and position (the placement of a
      spot), environment and area radiance;
    - the ``ambient`` term.

    Not differentiated: changes of visibility, as in Mitsuba's ``prb``
    without reparameterisation. Silhouettes, shadow edges, the edge of
    total internal reflection, the edges of a tartan's squares (its
    ``frequency`` moves nothing else) stay where they are. Parameters that
    move geometry (a shape's vertices or placement, the sensor) are
    refused with one sentence. Mitsuba's ``dielectric`` keeps its index of
    refraction as a plain number, which no integrator can differentiate.
    Forward mode: the frozen kernels take the parameters' tangents as
    inputs, and record anew for each new literal tangent (about the time
    of a first render); opaque tangents (``dr.make_opaque``) avoid it.
    The seed ``mi.render`` gives the gradient (a hash of the primal one)
    is taken back to that of the image it returned, so that the
    derivative is that image's, area lights included. A gradient renders
    the image's camera samples again (with the frozen kernels, so the
    anti-aliasing refines where the image did) and traces their trees once
    more with AD, 4 x ``wavefront_size`` camera samples at a time: about a
    kilobyte per sample of that tile is kept for the backward pass.

    .. tabs::

        .. code-tab:: xml

            <integrator type="whitted">
                <integer name="max_depth" value="8"/>
                <string name="aa" value="adaptive"/>
                <float name="aa_threshold" value="0.25"/>
            </integrator>
    """

    def __init__(self, props: mi.Properties):
        # Refused before Mitsuba's base class warns about scalar variants.
        _require_supported_variant()
        # Read before the base class, which reads ``hide_emitters`` too and
        # refuses a wrong type with a message of its own.
        settings = {name: read(props, name) for name, read in SETTINGS.items()}
        super().__init__(props)
        self.shadows = check_choice(props.get("shadows", "physical"), SHADOW_MODES,
                                    PLUGIN_NAME, "shadows")
        self.aa = check_choice(props.get("aa", "none"), AA_MODES, PLUGIN_NAME, "aa")
        self._exposed = _Exposed(settings)
        self._last_valid = LastValid(PLUGIN_NAME, nested=False)
        self.parameters_changed()
        #: Called as ``progress(done, expected, message)`` while rendering.
        self.progress = None
        #: Set to keep every ray the next render casts in ``last_rays``.
        self.capture_rays = False
        self._last = _LastRender()

    # What the last render left: kept in a plain object, which Dr.Jit does
    # not look into when a frozen kernel traverses the scene (and with it
    # this integrator). Values that change from render to render would
    # otherwise make it record its kernels again, and the tracer (which
    # holds the scene) would lead it round a cycle.

    @property
    def last_stats(self) -> dict:
        """Statistics of the last render (ray counts by kind, AA samples)."""
        return self._last.stats

    @property
    def last_sample_map(self):
        """Camera samples per pixel of the last adaptive or contrast render
        (mi.UInt32)."""
        return self._last.sample_map

    @property
    def last_rays(self):
        """A :class:`~.tracers.base.CapturedBatch` of every batch the last render
        traced (its rays and its shadow rays), if ``capture_rays`` was set."""
        return self._last.rays

    @last_rays.setter
    def last_rays(self, value):
        self._last.rays = value

    def _validate(self, v: dict) -> None:
        """Refuse settings ``v`` (by name) that make no sense together."""
        check(v["max_depth"] >= -1, PLUGIN_NAME, "max_depth",
              f"must be -1 (unbounded) or >= 0 (got {v['max_depth']})")
        check(v["emitter_samples"] >= 1, PLUGIN_NAME, "emitter_samples",
              f"must be >= 1 (got {v['emitter_samples']})")
        check(0 <= v["indirect_samples"] <= MAX_INDIRECT_SAMPLES, PLUGIN_NAME,
              "indirect_samples", f"must be between 0 and {MAX_INDIRECT_SAMPLES} "
              f"(got {v['indirect_samples']})")
        check(v["min_throughput"] >= 0, PLUGIN_NAME, "min_throughput",
              f"must be >= 0 (got {v['min_throughput']:g})")
        check(v["aa_samples"] >= 1, PLUGIN_NAME, "aa_samples",
              f"must be >= 1 (got {v['aa_samples']})")
        check(v["aa_threshold"] >= 0, PLUGIN_NAME, "aa_threshold",
              f"must be >= 0 (got {v['aa_threshold']:g})")
        check(0 <= v["aa_max_depth"] <= AA_DEPTH_LIMIT, PLUGIN_NAME, "aa_max_depth",
              f"must be between 0 and {AA_DEPTH_LIMIT} (got {v['aa_max_depth']})")
        check(v["aa_budget"] >= 4, PLUGIN_NAME, "aa_budget",
              f"must be >= 4 samples per pixel (got {v['aa_budget']:g})")
        check(v["wavefront_size"] >= 1024, PLUGIN_NAME, "wavefront_size",
              f"must be >= 1024 (got {v['wavefront_size']})")
        check(all(c >= 0 for c in v["ambient"]), PLUGIN_NAME, "ambient",
              f"must not be negative (got {list(v['ambient'])})")

    # ------------------------------------------------------------------ setup

    def make_tracer(self, scene: mi.Scene, seed: int = 0, wavefront: bool = False,
                    needs: SceneNeeds = None, differentiable: bool = False):
        """A tracer of ``scene`` with this integrator's settings
        (:func:`.tracers.build_tracer`; ``wavefront`` asks for the wavefront
        tracer, e.g. to capture each generation's rays, ``differentiable``
        for one whose traces Dr.Jit can differentiate, ambient term
        included). ``needs`` replaces ``analyse(scene)``, e.g. to trace with
        another absolute offset length (its ``scale``)."""
        check_placements(scene)
        depth = UNBOUNDED_DEPTH if self.max_depth == -1 else self.max_depth
        ambient = self._exposed.arrays["ambient"] if differentiable else self.ambient
        return build_tracer(scene, needs or analyse(scene), self.shadows,
                            LightingSettings(ambient, self.emitter_samples, seed,
                                             self.indirect_samples),
                            TreeSettings(depth, self.min_throughput, self.hide_emitters),
                            self.wavefront_size, wavefront, differentiable)

    def _tracer_for(self, scene: mi.Scene, seed: int):
        """The last render's tracer if nothing it was built from changed
        (the scene's objects, what the scene needs, the seed, this
        integrator's parameters), so that its frozen kernels replay rather
        than being recorded again; else a new one. Scene data the kernels
        read (parameters updated through ``mi.traverse``) reach them as
        arguments either way. The tracer reads ``scene`` only while
        ``render`` holds it in the tracer's ``scene_ref``."""
        needs = analyse(scene)
        built_from = (identity(scene), needs, seed, self.capture_rays,
                      self._parameter_values())
        if self._last.built_from == built_from:
            self._last.tracer.reload()
            return self._last.tracer
        tracer = self.make_tracer(scene, seed, wavefront=self.capture_rays, needs=needs)
        self._last.built_from, self._last.tracer = built_from, tracer
        return tracer

    def _parameter_values(self) -> tuple:
        return (self.max_depth, self.shadows, self.emitter_samples, self.min_throughput,
                self.hide_emitters, self.wavefront_size, tuple(self.ambient),
                self.indirect_samples)

    # ---------------------------------------------------------------- render

    @one_at_a_time
    def render(self, scene: mi.Scene, sensor=0, seed=0, spp=0,
               develop: bool = True, evaluate: bool = True):
        sensor = _sensor(scene, sensor)
        seed = seed_value(seed)
        self._last.seed = seed
        self._note_sample_count(spp)
        film = sensor.film()
        channels = _film_channels(film)

        def take(band, radiance, alpha):
            film.put_block(_image_block(film, band, radiance, alpha, channels))

        self.render_bands(scene, sensor, seed, take, _film_entries(film, channels, develop),
                          prepare=lambda: film.prepare([]))
        return film.develop() if develop else mi.TensorXf()

    # ------------------------------------------------------------- gradients

    @one_at_a_time
    def render_forward(self, scene: mi.Scene, params, sensor=0, seed=0, spp=0):
        """The derivative of ``render``'s image along the tangents of the
        parameters of ``params`` (:mod:`.gradients`), as a film's image."""
        sensor, seed, replay, keys = self._gradient_setup(scene, params, sensor, seed, spp)
        film = sensor.film()
        channels = _film_channels(film)

        def take(band, radiance, alpha):
            tangent = gradients.band_tangent(radiance)
            film.put_block(_image_block(film, band, tangent, dr.zeros(mi.Float, band.pixels),
                                        channels))

        with gradients.StandIns(params, keys, tangents=True) as stand_ins, \
                replay.tracer.scene_ref.holding(scene):
            tangents = stand_ins.tangents_of()

            def tangent(positions, sample_keys, lens):
                return replay.tangent(positions, sample_keys, lens, tangents)

            self.render_bands(scene, sensor, seed, take, _film_entries(film, channels),
                              prepare=lambda: film.prepare([]),
                              shader=gradients.recording_shader(CameraShader, tangent))
        return film.develop()

    @one_at_a_time
    def render_backward(self, scene: mi.Scene, params, grad_in, sensor=0, seed=0,
                        spp=0) -> None:
        """Add to the gradients of the parameters of ``params`` the
        derivative of ``render``'s image weighed by ``grad_in``, an image
        of adjoints (:mod:`.gradients`)."""
        sensor, seed, replay, keys = self._gradient_setup(scene, params, sensor, seed, spp)
        adjoint = _adjoint_pixels(grad_in, sensor.film())
        shaders = []

        def shader(*args):
            shaders.append(gradients.recording_shader(CameraShader)(*args))
            return shaders[-1]

        with gradients.StandIns(params, keys, tangents=False) as stand_ins, \
                replay.tracer.scene_ref.holding(scene):

            def take(band, radiance, alpha):
                launches = shaders[-1].launches
                samples = gradients.sample_adjoints(launches, radiance, adjoint(band))
                launches.clear()
                replay.backward(*samples, stand_ins.leaves())

            self.render_bands(scene, sensor, seed, take, film_entries=0, shader=shader)

    def _gradient_setup(self, scene: mi.Scene, params, sensor, seed, spp):
        """The sensor, the seed of the image to differentiate, a
        :class:`.gradients.Replay` of its samples and the keys of the
        differentiated parameters, once the variant and ``params`` are found
        differentiable."""
        gradients.require_differentiable_variant()
        check(self.indirect_samples == 0, PLUGIN_NAME, "indirect_samples",
              f"is {self.indirect_samples}, and the indirect light is not differentiated: "
              "set it to 0 for gradients")
        keys = gradients.differentiated(params)
        sensor = _sensor(scene, sensor)
        self._note_sample_count(spp)
        seed = self._primal_seed(seed)
        replay = gradients.Replay(self.make_tracer(scene, seed, differentiable=True), sensor)
        # The tile traced again with AD must fit beside the render.
        demand = self._demand(sensor.film(), self._tracer_for(scene, seed), 0, 0)
        plan_render(dataclasses.replace(demand, launch_samples=replay.tile,
                                        launch_sample_bytes=gradients.TILE_SAMPLE_BYTES))
        return sensor, seed, replay, keys

    def _primal_seed(self, seed) -> int:
        """The seed whose image is differentiated. ``mi.render`` passes its
        differential phase a seed of its own, a hash of the primal one
        (``sample_tea_32(seed, 1)``): whitted maps that hash of the last
        render's seed back to it, so that the derivative is that of the
        image ``mi.render`` returned."""
        value = seed_value(seed)
        return self._last.seed if value == _differential_seed(self._last.seed) else value

    @one_at_a_time
    def render_rows(self, scene: mi.Scene, take, sensor=0, seed=0, held_bytes: int = 0) -> None:
        """Render without a film of the whole image: ``take(first_row,
        rows)`` receives the image band by band, top to bottom, as float32
        NumPy arrays (rows, width, channels) holding what the film's
        ``develop`` would (in its pixel format: RGB, luminance or XYZ, with
        or without alpha), so that images
        larger than memory reach a file one band at a time. ``held_bytes``:
        what ``take`` keeps meanwhile, for the memory check."""
        sensor = _sensor(scene, sensor)
        seed = seed_value(seed)
        channels = _film_channels(sensor.film())
        developed = developed_format(sensor.film())

        def take_band(band, radiance, alpha):
            values = [radiance.x, radiance.y, radiance.z] + ([alpha] if channels == 5 else [])
            rows = np.stack([value.numpy() for value in values], axis=-1)
            take(band.first_row, _developed(rows.reshape(band.rows, band.width, channels - 1),
                                            developed))

        self.render_bands(scene, sensor, seed, take_band, film_entries=0, held_bytes=held_bytes)

    def render_bands(self, scene: mi.Scene, sensor: mi.Sensor, seed, take,
                     film_entries: int, prepare=None, held_bytes: int = 0,
                     shader=None) -> None:
        """Trace the crop window band by band (:mod:`.render_plan`) and hand
        each band's radiance and alpha to ``take(band, radiance, alpha)``.
        ``film_entries``: the floats the caller's film holds; ``prepare()``
        runs once the render is known to fit, before anything large is
        allocated; ``shader(tracer, sensor, progress)`` makes what traces the
        camera samples (a :class:`CameraShader` if not given)."""
        check_emitters(scene)
        aperture = _has_aperture(sensor)
        if self.aa == "none" and aperture:
            self._note_once("pinhole", "whitted: aa='none' traces each pixel from the centre "
                            "of the thin lens's aperture, so the image has no depth of field; "
                            "use 'grid', 'adaptive' or 'contrast'.")
        self._note_indirect_model()
        self._note_long_grid()
        _settle_sampler(sensor)
        tracer = self._tracer_for(scene, seed)
        plan = plan_render(self._demand(sensor.film(), tracer, film_entries, held_bytes))
        if prepare is not None:
            prepare()
        tracer.captured = [] if self.capture_rays else None
        total = antialias.SampleCount()
        lens = self.aa != "none" and aperture
        with tracer.scene_ref.holding(scene):
            shade = (shader or CameraShader)(tracer, sensor, self.progress,
                                             self.indirect_samples)
            for index, band in enumerate(plan.bands()):
                shade.label = _band_label(index, plan.band_count)
                radiance, alpha, count = self._sample_pixels(band, shade, total.refined, lens)
                _require_finite(radiance, alpha)
                take(band, radiance, alpha)
                total.add(count)
        self._record(tracer, total, plan)

    def _demand(self, film: mi.Film, tracer, film_entries: int, held_bytes: int) -> Demand:
        """What a render of ``film`` asks of memory (:mod:`.render_plan`)."""
        width, height = film.crop_size()
        kept = self.aa_budget if self.aa in ("adaptive", "contrast") else 1
        launch, parameter = tracer.launch_rays, "wavefront_size"
        if self.aa == "grid" and self.aa_samples ** 2 > launch:
            launch, parameter = self.aa_samples ** 2, "aa_samples"
        return Demand(width, height, kept, launch, film_entries, launch_parameter=parameter,
                      held_bytes=held_bytes)

    def _record(self, tracer, count: antialias.SampleCount, plan: RenderPlan) -> None:
        """Keep what the last render did for ``last_stats`` and friends."""
        stats = tracer.statistics()
        stats["aa_samples"] = count.samples
        stats["aa_per_level"] = count.per_level
        stats["aa_levels"] = count.levels
        stats["aa_budget_hit_at"] = count.budget_hit_at
        stats["bands"] = plan.band_count
        self._last.stats = stats
        self._last.sample_map = count.per_pixel if plan.band_count == 1 else None
        self._last.rays = tracer.captured
        if stats["cut"]:
            _warn(f"whitted: {stats['cut']:,} rays were left untraced: the ray tree of a "
                  f"camera sample stops at {MAX_TREE_RAYS} rays; lower 'max_depth' or raise "
                  "'min_throughput'.")

    def _sample_pixels(self, band, shade, refined_before: int, lens: bool):
        """Radiance, alpha and sample count of ``band``; its refinement
        samples' keys follow the ``refined_before`` of the bands above.
        ``lens``: whether the samples take points of the sensor's aperture."""
        budget = antialias.SampleBudget(self.aa_budget, render_plan.BAND_SAMPLES)
        if self.aa == "adaptive":
            sampler = antialias.AdaptiveSampler(self.aa_threshold, self.aa_max_depth, budget,
                                                _warn, lens)
            return sampler.render(band, shade, refined_before)
        if self.aa == "contrast":
            sampler = antialias.ContrastSampler(self.aa_threshold, self.aa_samples, budget,
                                                _warn, lens)
            return sampler.render(band, shade, refined_before)
        n = self.aa_samples if self.aa == "grid" else 1
        return antialias.render_grid(band, n, shade, lens)

    def _note_indirect_model(self) -> None:
        """The ambient term and tinted shadows stand in for light that the
        indirect paths also gather: with both, some light counts twice."""
        doubled = [what for what, present in (
            ("the ambient term", any(c > 0 for c in self.ambient)),
            ("tinted shadows", self.shadows != "physical")) if present]
        if self.indirect_samples and doubled:
            self._note_once("indirect model", (
                f"whitted: with indirect_samples > 0, {' and '.join(doubled)} add light that "
                "the indirect paths gather as well; set 'ambient' to 0 and 'shadows' to "
                "'physical' for an image that converges to the path tracer's."))

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
        if subject not in self._last.noted:
            self._last.noted.add(subject)
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
        with self._last_valid.updating(self):
            values = self._exposed.values()
            self._validate(values)
            for name, value in values.items():
                setattr(self, name, value)

    def to_string(self):
        return (f"WhittedIntegrator[max_depth={self.max_depth}, shadows={self.shadows}, "
                f"aa={self.aa}, ambient={list(self.ambient)}]")


class CameraShader:
    """``shade(positions, keys, lens=None)``: radiance and alpha of the
    camera rays through ``positions`` (pixel units in the crop window) from
    ``lens`` (see ``camera_rays``), traced in launches of at most ``batch``
    rays."""

    def __init__(self, tracer, sensor: mi.Sensor, progress=None, indirect_samples: int = 0):
        self.tracer = tracer
        self.sensor = sensor
        self.progress = progress
        self.batch = tracer.camera_batch
        #: What the progress display calls the samples being traced.
        self.label = "camera samples"
        #: Indirect paths per pixel, shared among its camera samples.
        self.indirect_samples = indirect_samples

    def __call__(self, positions: mi.Point2f, keys: mi.UInt32, lens: mi.Point2f = None,
                 share: int = 1):
        """Radiance and alpha of the samples, and where the tracer gathers
        indirect light the radiance without it, the noiseless part that
        anti-aliasing decides by (``antialias.ShadeFn``); ``share``: the
        pattern's samples per pixel, among which a pixel's
        ``indirect_samples`` paths are shared."""
        # The frozen kernels take the scene, whose parameters may carry
        # gradients: nothing here is differentiated (``gradients``).
        with dr.suspend_grad():
            paths = None
            if self.indirect_samples:
                paths = dr.full(mi.Float, self.indirect_samples / share, dr.width(keys))
            radiance, alpha, *gathered = self.trace(positions, keys, lens, paths)
            if not gathered:
                return radiance, alpha
            return radiance, alpha, radiance - gathered[0]

    def trace(self, positions: mi.Point2f, keys: mi.UInt32, lens: mi.Point2f = None,
              paths: mi.Float = None) -> tuple:
        """The tracer's radiance, alpha (and gathered radiance) of the
        camera samples, ``paths`` indirect paths (per sample, a real number)
        per smooth hit of each."""
        total = dr.width(positions)

        def trace(start, stop, part):
            if part is None:
                # The whole batch in one launch (every adaptive level after
                # the first): no copies in and out.
                return self.tracer.trace_camera(self.sensor, positions, keys, lens, paths)
            return self.tracer.trace_camera(
                self.sensor, dr.gather(mi.Point2f, positions, part),
                dr.gather(mi.UInt32, keys, part),
                None if lens is None else dr.gather(mi.Point2f, lens, part),
                None if paths is None else dr.gather(mi.Float, paths, part))

        outputs = in_launches(total, self.batch, trace, lambda stop: self._report(stop, total))
        dr.eval(outputs)
        # Wait here, where Dr.Jit lets other Python threads run: the
        # samplers' next dr.compress would wait for these launches holding
        # the GIL, and Ctrl-C (see interrupt.py) with it.
        dr.sync_thread()
        self._report(total, total)
        return outputs

    def _report(self, done: int, total: int) -> None:
        if self.progress is not None:
            self.progress(done, total, self.label)


class _Exposed:
    """The settings as the one-entry arrays ``mi.traverse`` hands out, which
    an update writes into. Kept out of the integrator's ``__dict__``, which
    Dr.Jit traverses for the inputs of every frozen launch."""

    __slots__ = ("arrays",)

    def __init__(self, values: dict):
        self.arrays = {name: _as_array(value) for name, value in values.items()}

    def values(self) -> dict:
        """The settings as Python values (``ambient`` an RGB colour)."""
        return {name: _as_value(array) for name, array in self.arrays.items()}


def _as_array(value):
    if isinstance(value, bool):
        return mi.Bool(value)
    if isinstance(value, int):
        return mi.Int32(value)
    if isinstance(value, float):
        return mi.Float(value)
    return mi.Color3f(*value)


def _as_value(array):
    if isinstance(array, mi.Color3f):
        return mi.ScalarColor3f(array.numpy().ravel().tolist())
    convert = {mi.Bool: bool, mi.Int32: int, mi.Float: float}[type(array)]
    return convert(array.numpy().ravel()[0])


class _LastRender:
    """What the last render left (see the integrator's ``last_*``)."""

    __slots__ = ("built_from", "tracer", "stats", "sample_map", "rays", "noted", "seed")

    def __init__(self):
        self.built_from = self.tracer = self.sample_map = self.rays = None
        #: The seed of the last ``render`` (``gradients`` differentiate its image).
        self.seed = 0
        self.stats = {}
        #: Subjects of the warnings given once (``_note_once``).
        self.noted = set()


def seed_value(seed) -> int:
    """A render seed as a Python number (:func:`.parameters.check_seed`)."""
    return check_seed(seed, PLUGIN_NAME)


def _differential_seed(seed: int) -> int:
    """The seed ``mi.render`` derives for the differential phase from ``seed``."""
    return int(mi.sample_tea_32(mi.UInt32(seed), mi.UInt32(1))[0][0])


def _adjoint_pixels(grad_in, film: mi.Film):
    """``adjoint(band)``: the radiance adjoints of ``band``'s pixels, from
    ``grad_in``, an adjoint of the film's developed image in its pixel
    format (its alpha, a coverage, has no derivative): luminance and XYZ
    are linear in RGB, so their adjoints reach RGB through the transpose."""
    width, height = film.crop_size()
    channels = film.base_channels_count()
    shape = tuple(grad_in.shape)
    if shape != (height, width, channels):
        raise ParameterError(PLUGIN_NAME, "grad_in",
                             f"must have the shape of the image, {(height, width, channels)} "
                             f"(got {shape})")
    values = dr.detach(grad_in.array)
    matrix = _colour_matrix(developed_format(film))

    def adjoint(band) -> mi.Color3f:
        base = (dr.arange(mi.UInt32, band.pixels) + dr.opaque(mi.UInt32, band.first_pixel)) \
            * channels
        developed = [dr.gather(mi.Float, values, base + k) for k in range(len(matrix))]
        if matrix is IDENTITY:
            return mi.Color3f(*developed)
        return mi.Color3f(*[sum(row[c] * value for row, value in zip(matrix, developed))
                            for c in range(3)])

    return adjoint


#: The colour matrix of an RGB film.
IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _colour_matrix(pixel_format) -> tuple:
    """Rows of the linear map from RGB to the colour channels of
    ``pixel_format`` (one row for luminance, three for RGB and XYZ), as
    the film's develop applies it."""
    colour = pixel_format.name.removesuffix("A")  # the colour channels, without alpha
    if colour == "RGB":
        return IDENTITY
    unit = np.eye(3, dtype=np.float32).reshape(1, 3, 3)  # pure red, green and blue pixels
    converted = _developed(unit, mi.Bitmap.PixelFormat.__members__[colour])[0]
    return tuple(tuple(float(v) for v in converted[:, k]) for k in range(converted.shape[1]))


def _sensor(scene: mi.Scene, sensor) -> mi.Sensor:
    """The sensor ``mi.render`` names: a sensor, or an index into the scene's."""
    if not isinstance(sensor, int):
        return sensor
    sensors = scene.sensors()
    if not 0 <= sensor < len(sensors):
        raise ParameterError(PLUGIN_NAME, "sensor",
                             f"index {sensor} does not exist: the scene has {len(sensors)} "
                             "sensor(s)")
    return sensors[sensor]


def _has_aperture(sensor: mi.Sensor) -> bool:
    """Whether the sensor sees through an aperture of some size: a thin
    lens whose radius is above the float epsilon that Mitsuba puts in place
    of a radius of 0."""
    if not sensor.needs_aperture_sample():
        return False
    radius = mi.traverse(sensor).get("aperture_radius")
    return radius is None or dr.any(radius > dr.epsilon(mi.Float), axis=None)


def _band_label(index: int, count: int) -> str:
    return "camera samples" if count == 1 else f"camera samples, band {index + 1} of {count}"


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


def _require_supported_variant():
    variant = mi.variant()
    if variant.startswith("scalar"):
        raise VariantError(
            f"{PLUGIN_NAME}: the wavefront integrator needs a JIT variant such as "
            f"'llvm_ad_rgb' or 'cuda_ad_rgb' (the active variant is '{variant}').")
    if not variant.endswith("_rgb"):
        raise VariantError(
            f"{PLUGIN_NAME}: only RGB variants are supported (the active variant is "
            f"'{variant}'); use 'llvm_ad_rgb' or 'cuda_ad_rgb'.")


def _film_channels(film: mi.Film) -> int:
    """Values per pixel of the film's storage: RGB or RGBA, and a weight
    (whatever the pixel format it develops to: luminance and XYZ are
    developed from RGB)."""
    width, height = film.crop_size()
    check(width * height > 0, PLUGIN_NAME, "film",
          f"has no pixels to render ({width} x {height}): give it a 'width' and 'height' of "
          "at least 1")
    if film.flags() & mi.FilmFlags.Spectral:
        raise ParameterError(PLUGIN_NAME, "film",
                             f"must be an RGB film such as 'hdrfilm' (got {film.class_name()}, "
                             "which stores spectral bands)")
    return 5 if film.flags() & mi.FilmFlags.Alpha else 4


def _film_entries(film: mi.Film, channels: int, develop: bool = True) -> int:
    """The floats a film of ``channels`` values per pixel holds during a
    render: its storage, and where it is developed the developed image
    (one value fewer per pixel: no weight)."""
    width, height = film.crop_size()
    return width * height * (2 * channels - 1 if develop else channels)


def _settle_sampler(sensor: mi.Sensor) -> None:
    """Seed the sensor's sampler as ``mi.render`` leaves it after a render.

    Whitted draws no random numbers, but the frozen kernels take the sensor,
    and with it its sampler, as an input: a sampler seeded after the first
    render and never before it looked like a changed input, and the second
    render recorded the kernels once more."""
    sampler = sensor.sampler()
    if sampler is not None:
        sampler.seed(0, 1)


def _developed(rows: np.ndarray, pixel_format) -> np.ndarray:
    """RGB(A) ``rows`` (rows, width, 3 or 4) in ``pixel_format``, converted
    as a film's ``develop`` converts them."""
    stored = mi.Bitmap.PixelFormat.RGBA if rows.shape[2] == 4 else mi.Bitmap.PixelFormat.RGB
    if pixel_format == stored:
        return rows
    converted = np.array(mi.Bitmap(rows, stored).convert(pixel_format, mi.Struct.Type.Float32,
                                                         False))
    return converted.reshape(rows.shape[0], rows.shape[1], -1)


def _image_block(film: mi.Film, band, radiance: mi.Color3f, alpha: mi.Float,
                 channels: int):
    """An image block holding the finished pixels of ``band`` (weight 1
    each), placed on the film where the band lies."""
    values = [radiance.x, radiance.y, radiance.z]
    if channels == 5:
        values.append(alpha)
    values.append(dr.ones(mi.Float, band.pixels))
    data = dr.empty(mi.Float, band.pixels * channels)
    base = dr.arange(mi.UInt32, band.pixels) * channels
    for index, value in enumerate(values):
        dr.scatter(data, value, base + index)
    tensor = mi.TensorXf(data, shape=(band.rows, band.width, channels))
    offset = film.crop_offset() + mi.ScalarPoint2i(0, band.first_row)
    return mi.ImageBlock(tensor, offset)


def _warn(message: str) -> None:
    mi.Log(mi.LogLevel.Warn, message)


mi.register_integrator(PLUGIN_NAME, lambda props: WhittedIntegrator(props))
