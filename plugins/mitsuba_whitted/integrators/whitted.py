from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..jit import index_range
from ..errors import ParameterError, VariantError, check, check_choice
from . import antialias
from .analytic import AnalyticRefiner
from .lighting import DirectLighting, LightingSettings, ShadowTester
from .raytree import RayBatch, RayTreeTracer
from .shading import HitShader, TreeSettings
from .stacktree import StackTreeTracer
from .scene_needs import SceneNeeds, analyse
from .scene_ref import SceneRef, identity

PLUGIN_NAME = "whitted"

AA_MODES = ("none", "grid", "adaptive", "contrast")
SHADOW_MODES = ("physical", "seed")
#: ``max_depth = -1`` means "until pruned"; this cap keeps two facing
#: perfect mirrors from looping forever.
UNBOUNDED_DEPTH = 256
#: Deeper adaptive levels would place samples closer than float32 resolves.
AA_DEPTH_LIMIT = 16


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
         only, 3 one mirror or refraction bounce, ... (Default: 10)
     * - ambient
       - |rgb|
       - Ambient light, multiplied by the diffuse albedo of each hit
         (``eval_diffuse_reflectance``; zero for BSDFs without a diffuse
         lobe). (Default: 0, no ambient term)
     * - shadows
       - |string|
       - ``"physical"``: shadow rays pass only surfaces that transmit
         without bending light (index-matched or thin dielectrics, null,
         mask), tinted by their transmittance, as Mitsuba's path tracer
         sees them. ``"seed"``: refracting surfaces pass tinted light too,
         the report's lightened shadows behind glass. (Default: physical)
     * - emitter_samples
       - |int|
       - Shadow rays per hit for each area or environment emitter, placed
         by a rotated low-discrepancy sequence. (Default: 16)
     * - min_throughput
       - |float|
       - Ray-tree pruning (Hall & Greenberg 1983): a reflected or refracted
         ray whose throughput is below this in every channel is not traced.
         0 traces every ray up to ``max_depth``. (Default: 1e-4)
     * - hide_emitters
       - |bool|
       - Hide directly visible emitters. (Default: false)
     * - aa
       - |string|
       - Anti-aliasing: ``"none"`` (pixel centres), ``"grid"``
         (``aa_samples`` x ``aa_samples`` stratified samples),
         ``"adaptive"`` (the report's recursive four-way split) or
         ``"contrast"`` (pixel centres, then ``aa_samples``\ :sup:`2`
         Hammersley points in each pixel whose neighbourhood contrast is
         high, after Mitchell 1987). (Default: none)
     * - aa_samples
       - |int|
       - Grid: samples per pixel side. Contrast: a refined pixel takes
         ``aa_samples``\ :sup:`2` points. (Default: 2)
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
       - Adaptive and contrast: most camera samples per pixel, on average
         over the image. Adaptive refinement stops with a warning where a
         level would pass it; contrast refinement takes fewer points per
         pixel, with a warning. (Default: 64)
     * - wavefront_size
       - |int|
       - Most rays of one generation in the wavefront tracer; the stack
         tracer, which keeps far less per ray outside its kernel, launches
         up to 8 times as many camera samples at once. Wider batches are
         split so memory stays bounded. (Default: 262144)

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
        super().__init__(props)
        self.max_depth = props.get("max_depth", 10)
        self.ambient = mi.ScalarColor3f(props.get("ambient", mi.ScalarColor3f(0)))
        self.shadows = check_choice(props.get("shadows", "physical"), SHADOW_MODES,
                                    PLUGIN_NAME, "shadows")
        self.emitter_samples = props.get("emitter_samples", 16)
        self.min_throughput = props.get("min_throughput", 1e-4)
        self.hide_emitters = props.get("hide_emitters", False)
        self.aa = check_choice(props.get("aa", "none"), AA_MODES, PLUGIN_NAME, "aa")
        self.aa_samples = props.get("aa_samples", 2)
        self.aa_threshold = props.get("aa_threshold", 0.1)
        self.aa_max_depth = props.get("aa_max_depth", 3)
        self.aa_budget = props.get("aa_budget", 64.0)
        self.wavefront_size = props.get("wavefront_size", 1 << 18)
        self._validate()
        #: Called as ``progress(done, expected, message)`` while rendering.
        self.progress = None
        #: Set to keep every ray batch of the next render in ``last_rays``.
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
        """``(generation, ray batch)`` of every batch the last render traced,
        if ``capture_rays`` was set."""
        return self._last.rays

    @last_rays.setter
    def last_rays(self, value):
        self._last.rays = value

    def _validate(self):
        check(self.max_depth >= -1, PLUGIN_NAME, "max_depth",
              f"must be -1 (unbounded) or >= 0 (got {self.max_depth})")
        check(self.emitter_samples >= 1, PLUGIN_NAME, "emitter_samples",
              f"must be >= 1 (got {self.emitter_samples})")
        check(self.min_throughput >= 0, PLUGIN_NAME, "min_throughput",
              f"must be >= 0 (got {self.min_throughput})")
        check(self.aa_samples >= 1, PLUGIN_NAME, "aa_samples",
              f"must be >= 1 (got {self.aa_samples})")
        check(self.aa_threshold >= 0, PLUGIN_NAME, "aa_threshold",
              f"must be >= 0 (got {self.aa_threshold})")
        check(0 <= self.aa_max_depth <= AA_DEPTH_LIMIT, PLUGIN_NAME, "aa_max_depth",
              f"must be between 0 and {AA_DEPTH_LIMIT} (got {self.aa_max_depth})")
        check(self.aa_budget >= 4, PLUGIN_NAME, "aa_budget",
              f"must be >= 4 samples per pixel (got {self.aa_budget})")
        check(self.wavefront_size >= 1024, PLUGIN_NAME, "wavefront_size",
              f"must be >= 1024 (got {self.wavefront_size})")
        check(all(c >= 0 for c in self.ambient), PLUGIN_NAME, "ambient",
              f"must not be negative (got {list(self.ambient)})")

    # ------------------------------------------------------------------ setup

    def make_tracer(self, scene: mi.Scene, seed: int = 0, wavefront: bool = False,
                    needs: SceneNeeds = None):
        """A ray-tree tracer specialised to what ``scene`` contains: the
        stack tracer where its stack is deep enough, else (or when asked,
        e.g. to capture each generation's rays) the wavefront tracer."""
        needs = needs or analyse(scene)
        scene_ref = SceneRef(scene)
        refiner = (AnalyticRefiner(scene_ref, needs.analytic_shapes)
                   if needs.analytic_shapes else None)
        intersect = refiner.intersect if refiner else _plain_intersect(scene_ref)
        shadows = ShadowTester(scene_ref, needs, self.shadows, intersect)
        lighting = DirectLighting(
            needs, LightingSettings(self.ambient, self.emitter_samples, seed),
            shadows)
        depth = UNBOUNDED_DEPTH if self.max_depth == -1 else self.max_depth
        settings = TreeSettings(depth, self.min_throughput, self.hide_emitters,
                                self.wavefront_size)
        shader = HitShader(scene_ref, needs, settings, lighting)
        if not wavefront and StackTreeTracer.supports(shader):
            return StackTreeTracer(shader, intersect, refiner)
        return RayTreeTracer(shader, intersect, refiner)

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
                self.hide_emitters, self.wavefront_size, tuple(self.ambient))

    # ---------------------------------------------------------------- render

    def render(self, scene: mi.Scene, sensor=0, seed=0, spp=0,
               develop: bool = True, evaluate: bool = True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        film = sensor.film()
        channels = _prepare_film(film)
        _settle_sampler(sensor)
        tracer = self._tracer_for(scene, int(seed))
        tracer.captured = [] if self.capture_rays else None
        width, height = film.crop_size()
        with dr.suspend_grad(), tracer.scene_ref.holding(scene):
            shade = self._camera_shader(tracer, sensor)
            radiance, alpha, count = self._sample_pixels(width, height, shade)
            block = _image_block(film, radiance, alpha, channels)
        film.put_block(block)
        stats = tracer.statistics()
        stats["aa_samples"] = count.samples
        stats["aa_per_level"] = count.per_level
        stats["aa_levels"] = count.levels
        stats["aa_budget_hit_at"] = count.budget_hit_at
        self._last.stats, self._last.sample_map = stats, count.per_pixel
        self._last.rays = tracer.captured
        return film.develop() if develop else mi.TensorXf()

    def _sample_pixels(self, width, height, shade):
        if self.aa == "adaptive":
            sampler = antialias.AdaptiveSampler(self.aa_threshold, self.aa_max_depth,
                                                self.aa_budget, _warn)
            return sampler.render(width, height, shade)
        if self.aa == "contrast":
            sampler = antialias.ContrastSampler(self.aa_threshold, self.aa_samples,
                                                self.aa_budget, _warn)
            return sampler.render(width, height, shade)
        n = self.aa_samples if self.aa == "grid" else 1
        return antialias.render_grid(width, height, n, shade)

    def _camera_shader(self, tracer, sensor: mi.Sensor):
        """``shade(positions, keys)``: trace camera rays through crop pixels,
        in parts of at most the tracer's ``camera_batch`` rays."""
        def shade(positions: mi.Point2f, keys: mi.UInt32):
            total = dr.width(positions)
            radiance, alpha = dr.empty(mi.Color3f, total), dr.empty(mi.Float, total)
            for start in range(0, total, tracer.camera_batch):
                stop = min(start + tracer.camera_batch, total)
                if stop - start == total:
                    # The whole batch in one part (every adaptive level after
                    # the first): no copies in and out.
                    radiance, alpha = tracer.trace_camera(sensor, positions, keys)
                else:
                    part = index_range(start, stop)
                    part_radiance, part_alpha = tracer.trace_camera(
                        sensor, dr.gather(mi.Point2f, positions, part),
                        dr.gather(mi.UInt32, keys, part))
                    dr.scatter(radiance, part_radiance, part)
                    dr.scatter(alpha, part_alpha, part)
                if self.progress is not None:
                    self.progress(stop, total, "camera samples")
            dr.eval(radiance, alpha)
            # Wait here, where Dr.Jit lets other Python threads run: the
            # samplers' next dr.compress would wait for these launches
            # holding the GIL, and Ctrl-C (see interrupt.py) with it.
            dr.sync_thread()
            return radiance, alpha

        return shade

    def trace_rays(self, scene: mi.Scene, ray: mi.Ray3f, seed: int = 0):
        """Whitted radiance and alpha along arbitrary rays."""
        tracer = self.make_tracer(scene, seed)
        keys = dr.arange(mi.UInt32, dr.width(ray.o))
        return tracer.trace(RayBatch(mi.Point3f(ray.o), mi.Vector3f(ray.d),
                                     mi.Color3f(1), keys))

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """Whitted radiance along arbitrary rays (no anti-aliasing)."""
        radiance, alpha = self.trace_rays(scene, ray)
        return mi.Spectrum(radiance), alpha > 0, []

    # ------------------------------------------------------------ interfaces

    def aov_names(self):
        return []

    def traverse(self, callback):
        flags = mi.ParamFlags.NonDifferentiable
        for name in ("max_depth", "shadows", "emitter_samples", "min_throughput",
                     "hide_emitters", "aa", "aa_samples", "aa_threshold",
                     "aa_max_depth", "aa_budget", "wavefront_size"):
            callback.put(name, getattr(self, name), flags)
        callback.put("ambient", self.ambient, flags)

    def parameters_changed(self, keys):
        check_choice(self.aa, AA_MODES, PLUGIN_NAME, "aa")
        check_choice(self.shadows, SHADOW_MODES, PLUGIN_NAME, "shadows")
        self._validate()

    def to_string(self):
        return (f"WhittedIntegrator[max_depth={self.max_depth}, shadows={self.shadows}, "
                f"aa={self.aa}, ambient={list(self.ambient)}]")


class _LastRender:
    """What the last render left (see the integrator's ``last_*``)."""

    __slots__ = ("built_from", "tracer", "stats", "sample_map", "rays")

    def __init__(self):
        self.built_from = self.tracer = self.sample_map = self.rays = None
        self.stats = {}


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


def _plain_intersect(scene_ref: SceneRef):
    """``intersect(ray, active, coherent)``: Mitsuba's own intersection.

    The tracers pass ``coherent=True`` for the rays of a ray tree (Embree's
    packet traversal): camera rays, and the mirror and refracted rays of
    Whitted's smooth surfaces, stay coherent. That took 10% off the
    report's scene (1200^2, pixel centres) and about 20% off the mirror and
    cylinder case scenes (1024^2); shadow rays are faster in the incoherent
    mode."""
    def intersect(ray: mi.Ray3f, active: mi.Bool,
                  coherent: bool = False) -> mi.SurfaceInteraction3f:
        return scene_ref.get().ray_intersect(ray, mi.RayFlags.All, coherent, active)
    return intersect


def _prepare_film(film: mi.Film) -> int:
    channels = film.prepare([])
    if channels not in (4, 5):
        raise ParameterError(PLUGIN_NAME, "film",
                             f"must be an RGB(A) film such as 'hdrfilm' (got {film.class_name()})")
    return channels


def _settle_sampler(sensor: mi.Sensor) -> None:
    """Seed the sensor's sampler as ``mi.render`` leaves it after a render.

    Whitted draws no random numbers, but the frozen kernels take the sensor,
    and with it its sampler, as an input: a sampler seeded after the first
    render and never before it looked like a changed input, and the second
    render recorded the kernels once more (about 50 ms)."""
    sampler = sensor.sampler()
    if sampler is not None:
        sampler.seed(0, 1)


def _image_block(film: mi.Film, radiance: mi.Color3f, alpha: mi.Float, channels: int):
    """An image block holding the finished pixels (weight 1 each)."""
    width, height = film.crop_size()
    values = [radiance.x, radiance.y, radiance.z]
    if channels == 5:
        values.append(alpha)
    values.append(dr.ones(mi.Float, width * height))
    data = dr.empty(mi.Float, width * height * channels)
    base = dr.arange(mi.UInt32, width * height) * channels
    for index, value in enumerate(values):
        dr.scatter(data, value, base + index)
    tensor = mi.TensorXf(data, shape=(height, width, channels))
    return mi.ImageBlock(tensor, film.crop_offset())


def _warn(message: str) -> None:
    mi.Log(mi.LogLevel.Warn, message)


mi.register_integrator(PLUGIN_NAME, lambda props: WhittedIntegrator(props))
