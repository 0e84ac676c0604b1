"""``mitsuba-whitted bench``: speed, throughput bound, memory and scaling,
measured side by side in one run.

Every timed JIT computation ends with ``dr.sync_thread()`` before the clock
stops. Warm figures are medians over repeated renders in one process; the
first render of a fresh process (tracing and compiling, or loading compiled
kernels from Dr.Jit's cache) is measured in child processes, once with the
kernel cache as it is and once with an empty one.

The bound: the rays of a render are replayed through Mitsuba's own
``scene.ray_intersect`` (camera, reflected and refracted rays),
``scene.ray_test`` (shadow rays to the same lights from the same hits) and
``scene.ray_intersect`` again for the shadow rays that march through
pass-through surfaces (the blocked ones, from crossing to crossing, as the
integrator follows them), each in whichever of Embree's coherent and
incoherent modes is the faster; the time those take is what a ray tracer on
Mitsuba cannot beat, and bound / actual is the share of the render spent
casting rays. They are timed in alternating rounds (render, then each cast)
and the ratio is the median of the rounds' ratios, so that the machine's
drift from minute to minute falls on all of them alike.

Where the time goes: the render is cut where its first camera launch ends
(with adaptive anti-aliasing, the first level), and each part is timed
beside the casting of its own rays; with it, the fixed cost of one frozen
call taking the scene, which every launch pays whatever its size.
"""

from __future__ import annotations

import gc
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import drjit as dr
import mitsuba as mi

from . import gradient_bench
from .jit import timed
from .overrides import load_with
from .compare.scene_report import machine
from .compare.sweep import CONTRAST_AA, RELATION_PREFIX, speedup_text
from .integrators.lighting import MAX_SHADOW_CROSSINGS
from .integrators.offsets import spawn_ray_to
from .system import proc_field

DEFAULT_SCENE = Path(__file__).resolve().parents[2] / "scenes" / "cosc363.xml"


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far.

    Linux's ``VmHWM`` belongs to the process's own memory map, while
    ``ru_maxrss`` also keeps what its parent had resident when it started
    this process (Linux carries the larger over fork and exec): a child of
    the benchmark read the benchmark's 0.9 GiB whatever it rendered."""
    high_water = proc_field("/proc/self/status", "VmHWM")  # "1234 kB"
    if high_water is not None:
        return int(high_water.split()[0]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


@dataclass
class RenderTiming:
    first: float
    second: float
    warm: float
    warm_all: list
    stats: dict


def time_render(scene: mi.Scene, integrator, repeats: int) -> RenderTiming:
    """First render (in this process), the second, and the median of the
    warm renders after them. The second is kept apart: it is the first to
    replay the kernels the first recorded, and anything that makes it record
    them again shows there."""
    def render():
        mi.render(scene, integrator=integrator)

    (first, second), warm = timed(render, 2)[1], timed(render, repeats)[1]
    return RenderTiming(first, second, statistics.median(warm), warm,
                        dict(integrator.last_stats))


# ------------------------------------------------------------------ bound


def _concat(array_type, parts: list):
    """``parts`` one after another (``dr.concat`` refuses an empty part: a
    light that no hit sees leaves one)."""
    parts = [part for part in parts if dr.width(part)]
    return dr.concat(parts) if parts else array_type()


def _joined(vector_type, parts: list):
    """The 3-vectors of ``parts`` one after another, kept on the device (a
    round trip through NumPy would hand the kernels memory of arbitrary
    alignment, and so kernels that differ from process to process)."""
    return vector_type(*[_concat(mi.Float, [part[axis] for part in parts])
                         for axis in range(3)])


def shadow_rays_of(scene: mi.Scene, tracer, captured: list):
    """The shadow rays ``tracer`` casts from the hits of the ``captured``
    ``(generation, batch)`` rays, and the point on a light each goes to:
    from the generations that are lit, to every light, at the points the
    tracer samples (its R2 sequence per ray key on sampled lights), where
    the light could add something through a smooth BSDF part."""
    with tracer.scene_ref.holding(scene):
        parts = [part for generation, batch in captured
                 if tracer.shader.work(generation).light is not False
                 for part in _shadow_parts(tracer, batch)]
    return (_joined_rays([ray for ray, _ in parts]),
            _joined(mi.Point3f, [target for _, target in parts]))


def _shadow_parts(tracer, batch) -> list:
    """``(shadow rays, targets)`` of one batch, light sample by light sample,
    from the hits the tracer finds (exact analytic shapes included)."""
    lighting = tracer.shader.lighting
    rays = mi.Ray3f(batch.o, batch.d)
    si = tracer.intersect(rays, mi.Bool(True))
    bsdf = si.bsdf(rays)
    smooth = si.is_valid() & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)

    def towards(light, sample, active):
        ds, spectrum = light.sample_direction(si, sample, active)
        value = bsdf.eval(mi.BSDFContext(), si, si.to_local(ds.d), active) * spectrum
        keep = dr.compress(active & (ds.pdf > 0) & dr.any(value > 0))
        shadow = spawn_ray_to(si, ds.p, lighting.needs.scale)
        return _taken(shadow, keep), dr.gather(mi.Point3f, ds.p, keep)

    parts = [towards(light, mi.Point2f(0.5), smooth) for light in lighting.needs.delta_lights]
    for index, light in enumerate(lighting.needs.sampled_lights):
        point = lighting.sample_points(batch.key, index)
        reach = lighting.lights_reach(light, si, smooth)
        parts += [towards(light, point(sample), reach)
                  for sample in range(lighting.settings.emitter_samples)]
    return parts


def _taken(ray: mi.Ray3f, index: mi.UInt32) -> mi.Ray3f:
    taken = mi.Ray3f(dr.gather(mi.Point3f, ray.o, index), dr.gather(mi.Vector3f, ray.d, index))
    taken.maxt = dr.gather(mi.Float, ray.maxt, index)
    return taken


def _joined_rays(parts: list) -> mi.Ray3f:
    """The rays of ``parts`` (rays or ray batches) one after another; the
    parts' lengths where they have any."""
    ray = mi.Ray3f(_joined(mi.Point3f, [part.o for part in parts]),
                   _joined(mi.Vector3f, [part.d for part in parts]))
    if parts and hasattr(parts[0], "maxt"):
        ray.maxt = _concat(mi.Float, [part.maxt for part in parts])
    return ray


def march_rays_of(scene: mi.Scene, tracer, shadow: mi.Ray3f, targets: mi.Point3f) -> mi.Ray3f:
    """The closest-hit queries the integrator's shadow tester makes after
    the any-hit test: each blocked shadow ray, then from each crossing that
    lets light through on to the light, as far as the tester follows (its
    own intersection decides, exact analytic shapes included)."""
    tester = tracer.shader.lighting.shadows
    if tester.opaque or dr.width(shadow.o) == 0:
        return mi.Ray3f()
    index = dr.compress(scene.ray_test(shadow))
    ray, target = _taken(shadow, index), dr.gather(mi.Point3f, targets, index)
    parts = []
    with tracer.scene_ref.holding(scene):
        while dr.width(ray.o) and len(parts) < MAX_SHADOW_CROSSINGS:
            parts.append(ray)
            si = tester.intersect(ray, mi.Bool(True))
            index = dr.compress(si.is_valid() & dr.any(
                tester.pass_weight(si, ray, si.is_valid()) > 0))
            if dr.width(index) == 0:
                break
            target = dr.gather(mi.Point3f, target, index)
            ray = spawn_ray_to(dr.gather(type(si), si, index), target, tester.needs.scale)
            dr.eval(ray, target)
    return _joined_rays(parts)


@dataclass
class Bound:
    """Mitsuba's ray casting for the rays of one render, timed in rounds
    that alternate with renders: the ratio of each round compares the two
    under the same conditions (on a shared machine either drifts by 10-20%
    from one minute to the next)."""
    #: Per cast (see :data:`CASTS`): rays, median seconds, and whether
    #: Embree's coherent mode was the faster.
    rays: dict
    seconds_by_cast: dict
    coherent: dict
    #: Median of the renders timed in the same rounds.
    render_seconds: float
    #: Sum of the casts over the render, of each round.
    ratios: list

    @property
    def seconds(self) -> float:
        return sum(self.seconds_by_cast.values())

    @property
    def ratio(self) -> float:
        return statistics.median(self.ratios)


#: The casts of the bound: ``ray_intersect`` of the camera, reflected and
#: refracted rays, ``ray_test`` of the shadow rays, and ``shadow_march``,
#: ``ray_intersect`` of the closest-hit queries of blocked shadow rays.
CASTS = ("ray_intersect", "ray_test", "shadow_march")


def _faster_mode(cast) -> bool:
    """Whether ``cast(coherent)`` runs faster with Embree's coherent mode
    (the median of three calls in each mode, after one to compile)."""
    times = {}
    for coherent in (False, True):
        times[coherent] = statistics.median(timed(lambda: cast(coherent), 4)[1][1:])
    return times[True] < times[False]


#: The share of rays that two computations of the same query may classify
#: differently through float rounding alone, a ray grazing an edge: Embree's
#: two traversal modes (1 in 1.25 M on the report's scene), or the bench's
#: replay and the render, whose kernels are fused differently (none).
ROUNDING_SHARE = 1e-3


def _check_modes_agree(scene: mi.Scene, rays: mi.Ray3f, shadow: mi.Ray3f) -> None:
    """The coherent flag is only a hint: both modes must find the same hits
    but for rounding (a call that cast nothing, e.g. through a wrong
    overload, would not). Empty batches are left out: Dr.Jit aborts the
    process on a cast of an array that was never filled."""
    def hits(coherent):
        found = {}
        if dr.width(rays.o):
            found["closest"] = dr.count(scene.ray_intersect(
                rays, ray_flags=mi.RayFlags.All, coherent=coherent).is_valid())[0]
        if dr.width(shadow.o):
            found["shadow"] = dr.count(scene.ray_test(shadow, coherent=coherent))[0]
        return found

    incoherent, coherent = hits(False), hits(True)
    for kind, count in incoherent.items():
        if abs(count - coherent[kind]) > ROUNDING_SHARE * max(count, coherent[kind], 1):
            raise RuntimeError(f"mitsuba-whitted bench: Embree's coherent and incoherent "
                               f"modes found different {kind} hits: {coherent[kind]} and "
                               f"{count}.")


def _check_replay(bound: Bound, stats: dict) -> None:
    """The replay must cast the rays the render did: the same shadow rays
    and marching queries but for float rounding (the replay's kernels fuse
    differently, so a ray grazing an edge may fall the other way)."""
    pairs = {"ray_test": stats["shadow"], "shadow_march": stats["shadow_march"]}
    for cast, traced in pairs.items():
        replayed = bound.rays[cast]
        if abs(replayed - traced) > ROUNDING_SHARE * max(replayed, traced, 1):
            raise RuntimeError(f"mitsuba-whitted bench: the bound replayed {replayed} rays for "
                               f"{cast} where the render cast {traced}.")


def _casts(scene: mi.Scene, rays: mi.Ray3f, shadow: mi.Ray3f, march: mi.Ray3f) -> dict:
    """``cast(coherent)`` of each of :data:`CASTS`, and the rays it casts."""
    def intersecting(batch):
        return lambda coherent: dr.eval(scene.ray_intersect(
            batch, ray_flags=mi.RayFlags.All, coherent=coherent))

    def testing(coherent):
        dr.eval(scene.ray_test(shadow, coherent=coherent))

    return {"ray_intersect": (intersecting(rays), rays), "ray_test": (testing, shadow),
            "shadow_march": (intersecting(march), march)}


def _nonempty(casts: dict) -> dict:
    """``cast(coherent)`` of those of ``casts`` that have rays (Dr.Jit aborts
    the process on a cast of an array that was never filled)."""
    return {name: cast for name, (cast, batch) in casts.items() if dr.width(batch.o)}


def _replayed_rays(scene: mi.Scene, tracer, captured: list) -> tuple:
    """The closest-hit rays of the ``captured`` ``(generation, batch)``
    pairs, the shadow rays ``tracer`` casts from their hits and the queries
    its shadow tester marches them with."""
    rays = _joined_rays([batch for _, batch in captured])
    shadow, targets = shadow_rays_of(scene, tracer, captured)
    march = march_rays_of(scene, tracer, shadow, targets)
    dr.eval(rays, shadow, march)
    return rays, shadow, march


def ray_casting_bound(scene: mi.Scene, tracer, captured: list, render,
                      repeats: int) -> Bound:
    """Mitsuba's own ray casting for the ``captured`` ``(generation,
    batch)`` rays of a render and for the shadow rays ``tracer`` casts from
    them (with those its shadow tester marches), timed in ``repeats``
    rounds of ``render()`` and each cast, each cast in whichever of Embree's
    coherent and incoherent modes is the faster for its rays (the
    integrator uses both)."""
    rays, shadow, march = _replayed_rays(scene, tracer, captured)
    _check_modes_agree(scene, rays, shadow)
    casts = _casts(scene, rays, shadow, march)
    counts = {name: dr.width(batch.o) for name, (_, batch) in casts.items()}
    cast = _nonempty(casts)
    coherent = {name: name in cast and _faster_mode(cast[name]) for name in casts}
    steps = [render] + [lambda name=name: cast[name](coherent[name]) for name in cast]
    timed(render, 2)  # record
    rounds = [[timed(step, 1)[1][0] for step in steps] for _ in range(repeats)]
    columns = dict(zip(cast, list(zip(*rounds))[1:]))
    seconds = {name: statistics.median(columns[name]) if name in columns else 0.0
               for name in casts}
    return Bound(counts, seconds, coherent, statistics.median([row[0] for row in rounds]),
                 [sum(row[1:]) / row[0] for row in rounds])


# ------------------------------------------------- where the time goes


@dataclass
class LaunchSplit:
    """A render cut where its first camera launch ends (for adaptive
    anti-aliasing: the first level, four samples in every pixel), each part
    beside the ray casting of its own rays. Medians over rounds of a render
    and the casts of both parts."""
    first_samples: int
    #: From the render's start to the end of the first launch's tracing.
    first_seconds: float
    first_bound: float
    first_ratios: list
    #: The rest: every later launch (the refinement levels), the choice of
    #: what to refine, the combination of the levels and the film.
    rest_seconds: float
    rest_bound: float
    rest_ratios: list
    #: Camera launches, and the fixed cost of one frozen call taking the
    #: scene (Dr.Jit traverses its inputs at every call).
    launches: int
    frozen_call_seconds: float

    @property
    def first_ratio(self) -> float:
        return statistics.median(self.first_ratios)

    @property
    def rest_ratio(self) -> float:
        return statistics.median(self.rest_ratios)


class _FirstLaunchClock:
    """An integrator ``progress`` callback: the time at which the first
    launch's samples are all traced (the frozen kernels have launched their
    work when ``progress`` is called; the clock waits for it)."""

    def __init__(self):
        self.done_at = None

    def __call__(self, done: int, expected: int, message: str) -> None:
        if self.done_at is None and done == expected:
            dr.sync_thread()
            self.done_at = time.perf_counter()


def _first_launch_end(captured: list, samples: int) -> int:
    """Index in ``captured`` of the first batch of the second launch: the
    first launch traced ``samples`` camera rays, in one or more parts, each
    part's generations in turn."""
    camera = 0
    for index, (generation, batch) in enumerate(captured):
        if generation == 0:
            if camera == samples:
                return index
            camera += len(batch)
    return len(captured)


def frozen_call_seconds(scene: mi.Scene, calls: int = 50) -> float:
    """Median time of a frozen call that takes ``scene`` and adds 1 to 16
    numbers: what every launch of the integrator's frozen kernels pays
    before any of its work, whatever its size."""
    probe = dr.arange(mi.Float, 16)
    frozen = dr.freeze(lambda scene, value: value + 1)
    times = timed(lambda: frozen(scene, probe), calls + 2)[1]
    return statistics.median(times[2:])


def launch_split(scene: mi.Scene, integrator, tracer, captured: list, first_samples: int,
                 coherent: dict, repeats: int) -> LaunchSplit:
    """Time the first camera launch and the rest of a render against the
    ray casting of each part's own rays (those ``tracer`` casts, in the
    modes of ``coherent``), in ``repeats`` rounds."""
    end = _first_launch_end(captured, first_samples)
    parts = [_nonempty(_casts(scene, *_replayed_rays(scene, tracer, part)))
             for part in (captured[:end], captured[end:])]
    steps = [[lambda cast=cast, name=name: cast(coherent[name]) for name, cast in casts.items()]
             for casts in parts]

    def clocked_render():
        clock = _FirstLaunchClock()
        integrator.progress = clock
        start = time.perf_counter()
        try:
            mi.render(scene, integrator=integrator)
            dr.sync_thread()
        finally:
            integrator.progress = None
        finish = time.perf_counter()
        return clock.done_at - start, finish - clock.done_at

    rounds = []
    for _ in range(repeats):
        first, rest = clocked_render()
        bounds = [sum(timed(step, 1)[1][0] for step in part) for part in steps]
        rounds.append((first, rest, *bounds))
    first, rest, first_bound, rest_bound = (statistics.median(column)
                                            for column in zip(*rounds))
    return LaunchSplit(first_samples, first, first_bound,
                       [row[2] / row[0] for row in rounds], rest, rest_bound,
                       [row[3] / row[1] for row in rounds],
                       integrator.last_stats["batches"], frozen_call_seconds(scene))


# -------------------------------------------------------- fresh processes


def fresh_process_render(scene_path: Path, defines: dict, empty_cache: bool) -> dict:
    """Run ``mitsuba-whitted render`` in a child process, on the scene as
    a user renders it (``defines`` as ``-D``, no other settings); its wall
    time and the render time it reports. An empty kernel cache is a fresh
    HOME."""
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as tmp:
        if empty_cache:
            env["HOME"] = tmp
            env["XDG_CACHE_HOME"] = os.path.join(tmp, "cache")
        out = os.path.join(tmp, "bench.exr")
        args = [sys.executable, "-m", "mitsuba_whitted.cli", "render", str(scene_path), "-o", out]
        for name, value in defines.items():
            args += ["-D", f"{name}={value}"]
        start = time.perf_counter()
        result = subprocess.run(args, capture_output=True, text=True, env=env, timeout=1800)
        wall = time.perf_counter() - start
    if result.returncode != 0:
        raise RuntimeError(f"mitsuba-whitted bench: the child render failed: {result.stderr.strip()}")
    render = float(re.findall(r" rendered in ([0-9.]+) s", result.stdout)[-1])
    return {"process_seconds": wall, "render_seconds": render}


def child_peak_memory(scene_path: Path, defines: dict, settings: dict) -> float:
    """Peak RSS (MiB) of a child process that loads and renders the scene
    (with ``settings``, see :func:`~mitsuba_whitted.overrides.load_with`)."""
    code = ("import sys, json, mitsuba_whitted, mitsuba as mi, drjit as dr\n"
            "mitsuba_whitted.set_variant('llvm_ad_rgb')\n"
            "from mitsuba_whitted.bench import peak_rss_mib\n"
            "from mitsuba_whitted.overrides import load_with\n"
            "scene = load_with(sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3]))\n"
            "mi.render(scene); dr.sync_thread()\n"
            "print('peak_rss_mib', peak_rss_mib())\n")
    result = subprocess.run([sys.executable, "-c", code, str(scene_path), json.dumps(defines),
                             json.dumps(settings)], capture_output=True, text=True, timeout=1800)
    if result.returncode != 0:
        raise RuntimeError(f"mitsuba-whitted bench: the child render failed: {result.stderr.strip()}")
    # Mitsuba's log shares stdout (with colour codes): find our own line.
    return float(re.findall(r"peak_rss_mib ([0-9.]+)", result.stdout)[-1])


# ----------------------------------------------------------------- scaling


@dataclass
class ScalingRow:
    parameter: str
    value: object
    seconds: float
    rays: int

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.seconds


def release_scenes() -> None:
    """Free the scenes measured so far, and the memory cached for them.

    Every call of a frozen kernel traverses all live instances of the
    scene's plugin types, not only the scene's own: with five other copies
    of the report's scene alive, a frozen call on it took 3.4 ms instead of
    1.3 ms. Memory cached from a 2048^2 render slowed every later setting
    too."""
    gc.collect()
    dr.flush_malloc_cache()


def warm_timing(scene_path: Path, defines: dict, settings: dict, repeats: int) -> RenderTiming:
    scene = load_with(scene_path, defines, settings)
    return time_render(scene, scene.integrator(), repeats)


def scaling_table(scene_path: Path, defines: dict, base: dict, sweeps: dict,
                  repeats: int) -> list[ScalingRow]:
    """Warm render time as each setting of ``sweeps`` varies alone from
    ``base`` (settings of :func:`~mitsuba_whitted.overrides.load_with`)."""
    rows = []
    for parameter, values in sweeps.items():
        for value in values:
            release_scenes()
            timing = warm_timing(scene_path, defines, dict(base, **{parameter: value}), repeats)
            rows.append(ScalingRow(parameter, value, timing.warm, timing.stats["total"]))
    return rows


# -------------------------------------------------------------- equal error


#: Longest path of every render in the equal-error comparison (the
#: reference's too, so that all of them model the same light).
EQUAL_ERROR_DEPTH = 12


def fresnel_scene(resolution: int) -> dict:
    """An equivalence scene: a glass sphere before an emitting checkerboard.
    Every path of light is a chain of Fresnel reflections and refractions,
    which Whitted follows exactly and ``path`` samples one branch at a time."""
    backdrop = {"type": "checkerboard", "color0": {"type": "rgb", "value": [0.1, 0.25, 0.8]},
                "color1": {"type": "rgb", "value": [1.0, 0.8, 0.3]},
                "to_uv": mi.ScalarTransform4f().scale([6, 6, 1])}
    return {
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 5], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "rfilter": {"type": "box"}}},
        "glass": {"type": "sphere", "radius": 1.0, "bsdf": {"type": "dielectric", "int_ior": 1.5}},
        "backdrop": {"type": "rectangle",
                     "to_world": mi.ScalarTransform4f().translate([0, 0, -3]).scale(4),
                     "emitter": {"type": "area", "radiance": backdrop}},
    }


def equal_error_settings() -> dict:
    """Labelled Whitted settings for the equal-error comparison: n x n grids
    (n = 1, 2, 4, 8), and contrast-driven refinement with 64 and 256 points
    per edge pixel, each with the default ray-tree pruning and coarser ones
    (``min_throughput`` 1e-3 and 1e-2: branches carrying under 0.1% or 1%
    are left out)."""
    settings = {f"whitted grid {n}x{n}": {"aa": "grid", "aa_samples": n} for n in (1, 2, 4, 8)}
    for n in (8, 16):
        for pruning in (1e-4, 1e-3, 1e-2):
            settings[f"whitted contrast {n}x{n}, min_throughput {pruning:g}"] = {
                **CONTRAST_AA, "aa_samples": n, "min_throughput": pruning}
    return {label: {"max_depth": EQUAL_ERROR_DEPTH, **values} for label, values in settings.items()}


def equal_error_speedup(resolution: int, reference_spp: int, largest_spp: int,
                        repeats: int) -> dict:
    """Time ``path`` needs to match Whitted's error on ``fresnel_scene``,
    over Whitted's time (both warm, against one converged reference), for
    Whitted's anti-aliasing settings (:func:`equal_error_settings`): its
    only error is aliasing, which they shrink, while path's is noise. The
    headline is the best of these settings."""
    from .compare import (noise_rel_mse, path_settings, path_spp_ladder, render_reference,
                          run_sweep, speedups)

    scene = mi.load_dict(fresnel_scene(resolution))
    reference = render_reference(scene, reference_spp,
                                 settings=path_settings(EQUAL_ERROR_DEPTH))
    points = run_sweep(scene, reference, equal_error_settings(), path_spp_ladder(largest_spp),
                       repeats, path_depth=EQUAL_ERROR_DEPTH)
    rows = [{"whitted": s.point.label, "whitted_rel_mse": s.point.rel_mse,
             "whitted_seconds": s.point.seconds, "path_spp": s.path.spp,
             "path_seconds": s.path.seconds, "relation": s.path.relation,
             "speedup": s.factor} for s in speedups(points)]
    best = max(rows, key=lambda row: row["speedup"])
    return {"scene": "glass sphere before an emitting checkerboard",
            "resolution": resolution, "reference_spp": reference.spp,
            "reference_noise_rel_mse": noise_rel_mse(reference.variance, reference.image),
            "settings": rows, **best}


# ------------------------------------------------------------------- main


@dataclass
class BenchSettings:
    scene: Path = DEFAULT_SCENE
    defines: dict = field(default_factory=dict)
    #: Film width of the headline, memory and depth figures (the height
    #: keeps the film's aspect); ``None``: the scene's own.
    resolution: int | None = None
    repeats: int = 7
    #: Rounds of the bound (a render and the casts, about 0.1 s each on the
    #: report's scene): their ratios wander by 0.2 on this kind of machine,
    #: so their median takes more than ``repeats``.
    bound_rounds: int = 25
    resolutions: tuple = (256, 512, 1024, 2048)
    depths: tuple = (2, 4, 6, 10)
    aa_depths: tuple = (0, 2, 5, 10)
    memory_resolutions: tuple = (600, 2048)
    fresh_processes: bool = True
    #: Equal-error scene: resolution, reference spp, largest path spp. The
    #: reference's own noise (relMSE about 2e-6) stays below every error
    #: compared, and path's ladder reaches past Whitted's best settings.
    equal_error: tuple = (128, 65536, 16384)
    #: Gradients at equal error: resolution, largest prb spp, prb seeds.
    gradient: tuple = (64, 1024, 8)

    @classmethod
    def quick(cls, scene: Path = DEFAULT_SCENE, defines=None) -> "BenchSettings":
        """Small sizes and few repeats: every figure, in seconds."""
        return cls(scene, dict(defines or {}), resolution=96, repeats=2, bound_rounds=2,
                   resolutions=(64, 128), depths=(2, 6), aa_depths=(0, 3),
                   memory_resolutions=(96,), equal_error=(32, 512, 64), gradient=(16, 4, 2))

    @property
    def scene_settings(self) -> dict:
        """What :func:`~mitsuba_whitted.overrides.load_with` changes in the
        scene for the headline."""
        return {} if self.resolution is None else {"res": self.resolution}


def headline(scene_path: Path, settings: BenchSettings, report) -> dict:
    """Warm and first renders, rays by kind and the ray-casting bound of
    ``scene_path``; the scene is released when this returns."""
    scene = load_with(scene_path, settings.defines, settings.scene_settings)
    integrator = scene.integrator()
    if not hasattr(integrator, "capture_rays"):
        raise RuntimeError("mitsuba-whitted bench: the scene's integrator is not 'whitted'.")
    report("timing warm renders ...")
    timing = time_render(scene, integrator, settings.repeats)

    report("replaying the same rays through Mitsuba's ray casting ...")
    integrator.capture_rays = True
    mi.render(scene, integrator=integrator)
    integrator.capture_rays = False
    captured, first_samples = integrator.last_rays, integrator.last_stats["aa_per_level"][0]
    integrator.last_rays = None
    tracer = integrator.make_tracer(scene)
    bound = ray_casting_bound(scene, tracer, captured,
                              lambda: mi.render(scene, integrator=integrator),
                              settings.bound_rounds)
    _check_replay(bound, integrator.last_stats)
    report("timing the first launch and the rest apart ...")
    split = launch_split(scene, integrator, tracer, captured, first_samples, bound.coherent,
                         settings.bound_rounds)
    del captured
    return {
        "scene": str(scene_path), "defines": settings.defines,
        "settings": settings.scene_settings,
        "resolution": list(scene.sensors()[0].film().crop_size()),
        "first_render_in_process_s": timing.first,
        "second_render_in_process_s": timing.second,
        "warm_render_s": timing.warm,
        "warm_renders_s": timing.warm_all,
        "rays": {k: timing.stats[k] for k in ("camera", "reflection", "refraction", "passthrough",
                                              "shadow", "shadow_march", "refined", "total")},
        "rays_per_second": timing.stats["total"] / timing.warm,
        "aa_samples": timing.stats["aa_samples"],
        "bound": {**{f"{name}_{figure}": values[name] for name in CASTS
                     for figure, values in (("rays", bound.rays), ("s", bound.seconds_by_cast),
                                            ("coherent", bound.coherent))},
                  "seconds": bound.seconds, "render_s": bound.render_seconds,
                  "ratio": bound.ratio, "ratios": bound.ratios},
        "split": {"first_launch_samples": split.first_samples,
                  "first_launch_s": split.first_seconds, "first_launch_bound_s": split.first_bound,
                  "first_launch_ratio": split.first_ratio,
                  "rest_s": split.rest_seconds, "rest_bound_s": split.rest_bound,
                  "rest_ratio": split.rest_ratio,
                  "launches": split.launches, "frozen_call_s": split.frozen_call_seconds},
        "peak_rss_mib_this_process": peak_rss_mib(),
    }


def run(settings: BenchSettings, report=print) -> dict:
    """All measurements; ``report`` receives progress lines."""
    scene_path = Path(settings.scene)
    results = {"machine": machine(), **headline(scene_path, settings, report)}
    release_scenes()
    if settings.fresh_processes:
        report("fresh processes (warm and empty kernel cache) ...")
        results["fresh_process"] = fresh_process_render(scene_path, settings.defines, False)
        results["fresh_process_empty_cache"] = fresh_process_render(scene_path, settings.defines, True)
    report("peak memory in child processes ...")
    results["peak_rss_mib"] = {
        str(res): child_peak_memory(scene_path, settings.defines,
                                    dict(settings.scene_settings, res=res))
        for res in settings.memory_resolutions}
    report("scaling ...")
    rows = scaling_table(scene_path, settings.defines, settings.scene_settings,
                         {"res": settings.resolutions, "max_depth": settings.depths,
                          "aa_max_depth": settings.aa_depths}, settings.repeats)
    results["scaling"] = [{"parameter": r.parameter, "value": r.value, "seconds": r.seconds,
                           "rays": r.rays, "rays_per_second": r.rays_per_second} for r in rows]
    report("equal error against path ...")
    results["equal_error"] = equal_error_speedup(*settings.equal_error, settings.repeats)
    results["gradient"] = gradient_bench.measure(
        scene_path, settings.defines, settings.scene_settings, settings.repeats,
        settings.memory_resolutions[0], settings.gradient, report)
    return results


def _mode(coherent: bool) -> str:
    return "coherent" if coherent else "incoherent"


def _count(number: int, one: str, many: str) -> str:
    return f"{number} {one if number == 1 else many}"


def _split_lines(split: dict) -> list:
    more = split["launches"] - 1
    return [
        f"    first camera launch       {split['first_launch_s']:8.3f} s, its rays' bound "
        f"{split['first_launch_bound_s']:.3f} s: {split['first_launch_ratio']:.2f}"
        f"  ({split['first_launch_samples']:,} samples, from the render's start)",
        f"    the rest                  {split['rest_s']:8.3f} s, its rays' bound "
        f"{split['rest_bound_s']:.3f} s: {split['rest_ratio']:.2f}"
        f"  ({_count(more, 'later launch', 'later launches')} and all the render does"
        " between and after them)",
        f"    a frozen call's fixed cost {split['frozen_call_s'] * 1e3:7.2f} ms (Dr.Jit traverses"
        f" the scene at every call) x {_count(split['launches'], 'launch', 'launches')} = "
        f"{split['frozen_call_s'] * split['launches'] * 1e3:.1f} ms",
    ]


def format_table(results: dict) -> str:
    """The benchmark as a plain-text table."""
    rays = results["rays"]
    bound = results["bound"]
    width, height = results["resolution"]
    lines = [
        f"machine: {results['machine']}",
        f"scene {results['scene']} at {width}x{height} {results['defines']}",
        f"  warm render (median)        {results['warm_render_s']:8.3f} s",
        f"  first render in process     {results['first_render_in_process_s']:8.3f} s"
        f"  (second {results['second_render_in_process_s']:.3f} s)",
    ]
    if "fresh_process" in results:
        fresh, empty = results["fresh_process"], results["fresh_process_empty_cache"]
        lines += [
            f"  whole render process        {fresh['process_seconds']:8.3f} s  "
            f"(render {fresh['render_seconds']:.3f} s, kernel cache warm; the scene as "
            "`mitsuba-whitted render` renders it)",
            f"  same, empty kernel cache    {empty['process_seconds']:8.3f} s  "
            f"(render {empty['render_seconds']:.3f} s)",
        ]
    lines += [
        "  rays: " + ", ".join(f"{k} {v:,}" for k, v in rays.items()),
        f"  rays/s                      {results['rays_per_second'] / 1e6:8.2f} M",
        "  bound: " + " + ".join(
            f"{name} {bound[name + '_rays']:,} rays {bound[name + '_s']:.3f} s"
            f" ({_mode(bound[name + '_coherent'])})" for name in CASTS)
        + f" = {bound['seconds']:.3f} s",
        f"  bound / actual              {bound['ratio']:8.2f}  (median of {len(bound['ratios'])}"
        f" rounds of render and casts: {min(bound['ratios']):.2f}"
        f" to {max(bound['ratios']):.2f}; render {bound['render_s']:.3f} s in those rounds)",
        *_split_lines(results["split"]),
        "  peak RSS by film width: " + ", ".join(f"{res} px {mib:,.0f} MiB"
                                               for res, mib in results["peak_rss_mib"].items()),
        "  scaling (warm):",
    ]
    for row in results["scaling"]:
        lines.append(f"    {row['parameter']:>12} = {str(row['value']):>5}  {row['seconds']:8.3f} s"
                     f"  {row['rays']:>12,} rays  {row['rays_per_second'] / 1e6:6.2f} M rays/s")
    eq = results["equal_error"]
    relation = RELATION_PREFIX[eq["relation"]]
    lines.append(f"  equal-error speed-up over path: {speedup_text(eq['speedup'], eq['relation'])}"
                 f" on {eq['scene']}"
                 f" at {eq['resolution']}^2, {eq['whitted']} (relMSE {eq['whitted_rel_mse']:.2e} in "
                 f"{eq['whitted_seconds']:.3f} s; path needs {relation}{eq['path_spp']:.0f} spp, "
                 f"{eq['path_seconds']:.3f} s; reference {eq['reference_spp']} spp, its own noise "
                 f"relMSE {eq['reference_noise_rel_mse']:.1e})")
    for row in eq["settings"]:
        lines.append(f"    {row['whitted']:<46} relMSE {row['whitted_rel_mse']:.2e} "
                     f"{row['whitted_seconds']:7.3f} s  path "
                     f"{RELATION_PREFIX[row['relation']]}{row['path_spp']:.0f} spp "
                     f"{row['path_seconds']:7.3f} s  {speedup_text(row['speedup'], row['relation'])}")
    if "gradient" in results:
        lines += gradient_bench.format_lines(results["gradient"])
    return "\n".join(lines)
