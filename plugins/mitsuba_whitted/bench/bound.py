"""The ray-casting bound of a render, and where its time goes.

The bound: a capturing render keeps every ray it casts (``capture_rays``,
:class:`~mitsuba_whitted.integrators.tracers.base.CapturedBatch`), and those rays
are cast again through Mitsuba's own ``scene.ray_intersect`` (camera,
reflected, refracted and pass-through rays), ``scene.ray_test`` (the shadow
rays) and ``scene.ray_intersect`` again (the closest-hit queries that
follow blocked shadow rays through surfaces that let light pass), each in
whichever of Embree's coherent and incoherent modes is the faster: the
time those take is what a ray tracer on Mitsuba cannot beat, and bound /
actual is the share of the render spent casting rays. They are timed in
alternating rounds (render, then each cast) and the ratio is the median of
the rounds' ratios, so that the machine's drift from minute to minute falls
on all of them alike.

The launch split: the render is cut where its first camera launch ends
(with adaptive anti-aliasing, the first level), and each part is timed
beside the casting of its own rays; with it, the fixed cost of one frozen
call taking the scene, which every launch pays whatever its size.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from ..jit import concat, timed

#: The casts of the bound: ``ray_intersect`` of the camera, reflected,
#: refracted and pass-through rays, ``ray_test`` of the shadow rays, and
#: ``shadow_march``, ``ray_intersect`` of the closest-hit queries of
#: blocked shadow rays.
CASTS = ("ray_intersect", "ray_test", "shadow_march")

#: The share of rays that Embree's two traversal modes may classify
#: differently through float rounding alone (a ray grazing an edge).
ROUNDING_SHARE = 1e-3


@dataclass
class RenderRays:
    """The rays of (a part of) a render, each kind in the order cast."""
    closest: mi.Ray3f
    shadow: mi.Ray3f
    queries: mi.Ray3f

    @classmethod
    def of(cls, captured: list) -> "RenderRays":
        """The rays of the ``captured`` batches, one batch after another."""
        rays = cls(_joined([batch.rays for batch in captured]),
                   _joined([batch.shadow for batch in captured]),
                   _joined([batch.queries for batch in captured]))
        dr.eval(rays.closest, rays.shadow, rays.queries)
        return rays


def _joined(parts: list) -> mi.Ray3f:
    """The rays of ``parts`` (rays or ray batches) one after another, kept
    on the device (a round trip through NumPy would hand the kernels memory
    of arbitrary alignment, and so kernels that differ from process to
    process); their lengths where they have any. ``dr.concat`` refuses an
    empty part."""
    parts = [part for part in parts if dr.width(part.o)]
    if not parts:
        return mi.Ray3f()
    ray = mi.Ray3f(concat([part.o for part in parts]), concat([part.d for part in parts]))
    if hasattr(parts[0], "maxt"):
        ray.maxt = concat([part.maxt for part in parts])
    return ray


@dataclass
class Bound:
    """Mitsuba's ray casting for the rays of one render, timed in rounds
    that alternate with renders: the ratio of each round compares the two
    under the same conditions (on a shared machine either drifts from one
    minute to the next)."""
    #: Per cast (see :data:`CASTS`): rays, median seconds, and whether
    #: Embree's coherent mode was the faster.
    rays: dict
    seconds_by_cast: dict
    coherent: dict
    #: Median of the renders timed in the same rounds.
    render_seconds: float
    #: Sum of the casts over the render, of each round.
    ratios: list
    #: Derived: the casts' sum and the median ratio, fields so that the
    #: bench's JSON (``dataclasses.asdict``) holds them.
    seconds: float = field(init=False)
    ratio: float = field(init=False)

    def __post_init__(self):
        self.seconds = sum(self.seconds_by_cast.values())
        self.ratio = statistics.median(self.ratios)


def _faster_mode(cast) -> bool:
    """Whether ``cast(coherent)`` runs faster with Embree's coherent mode
    (the median of three calls in each mode, after one to compile)."""
    times = {}
    for coherent in (False, True):
        times[coherent] = statistics.median(timed(lambda: cast(coherent), 4)[1][1:])
    return times[True] < times[False]


def _check_modes_agree(scene: mi.Scene, rays: RenderRays) -> None:
    """The coherent flag is only a hint: both modes must find the same hits
    but for rounding (a call that cast nothing, e.g. through a wrong
    overload, would not). Empty batches are left out: Dr.Jit aborts the
    process on a cast of an array that was never filled."""
    def hits(coherent):
        found = {}
        if dr.width(rays.closest.o):
            found["closest"] = dr.count(scene.ray_intersect(
                rays.closest, ray_flags=mi.RayFlags.All, coherent=coherent).is_valid())[0]
        if dr.width(rays.shadow.o):
            found["shadow"] = dr.count(scene.ray_test(rays.shadow, coherent=coherent))[0]
        return found

    incoherent, coherent = hits(False), hits(True)
    for kind, count in incoherent.items():
        if abs(count - coherent[kind]) > ROUNDING_SHARE * max(count, coherent[kind], 1):
            raise RuntimeError(f"mitsuba-whitted bench: Embree's coherent and incoherent "
                               f"modes found different {kind} hits: {coherent[kind]} and "
                               f"{count}.")


def _casts(scene: mi.Scene, rays: RenderRays) -> dict:
    """``cast(coherent)`` of each of :data:`CASTS`, and the rays it casts."""
    def intersecting(batch):
        return lambda coherent: dr.eval(scene.ray_intersect(
            batch, ray_flags=mi.RayFlags.All, coherent=coherent))

    def testing(coherent):
        dr.eval(scene.ray_test(rays.shadow, coherent=coherent))

    return {"ray_intersect": (intersecting(rays.closest), rays.closest),
            "ray_test": (testing, rays.shadow),
            "shadow_march": (intersecting(rays.queries), rays.queries)}


def _nonempty(casts: dict) -> dict:
    """``cast(coherent)`` of those of ``casts`` that have rays (Dr.Jit aborts
    the process on a cast of an array that was never filled)."""
    return {name: cast for name, (cast, batch) in casts.items() if dr.width(batch.o)}


def ray_casting_bound(scene: mi.Scene, captured: list, render, repeats: int) -> Bound:
    """Mitsuba's own ray casting for the rays of the ``captured`` batches of
    a render, timed in ``repeats`` rounds of ``render()`` and each cast,
    each cast in whichever of Embree's coherent and incoherent modes is the
    faster for its rays (the integrator uses both)."""
    rays = RenderRays.of(captured)
    _check_modes_agree(scene, rays)
    casts = _casts(scene, rays)
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
    #: Derived: the median ratio of each part.
    first_ratio: float = field(init=False)
    rest_ratio: float = field(init=False)

    def __post_init__(self):
        self.first_ratio = statistics.median(self.first_ratios)
        self.rest_ratio = statistics.median(self.rest_ratios)


class _FirstLaunchClock:
    """An integrator ``progress`` callback: the time at which the first
    launch's ``samples`` are all traced, read once the device is done with
    them. The count of a render in one band begins with those samples
    (:mod:`mitsuba_whitted.integrators.render_progress`)."""

    def __init__(self, samples: int):
        self.samples = samples
        self.done_at = None

    def __call__(self, done: int, total: int, message: str) -> None:
        if self.done_at is None and done >= self.samples:
            dr.sync_thread()
            self.done_at = time.perf_counter()


def first_launch_end(captured: list, samples: int) -> int:
    """Index in ``captured`` of the first batch of the second launch: the
    first launch traced ``samples`` camera rays, in one or more parts, each
    part's generations in turn."""
    camera = 0
    for index, batch in enumerate(captured):
        if batch.generation == 0:
            if camera == samples:
                return index
            camera += len(batch.rays)
    return len(captured)


def frozen_call_seconds(scene: mi.Scene, calls: int = 50) -> float:
    """Median time of a frozen call that takes ``scene`` and adds 1 to 16
    numbers: what every launch of the integrator's frozen kernels pays
    before any of its work, whatever its size."""
    probe = dr.arange(mi.Float, 16)
    frozen = dr.freeze(lambda scene, value: value + 1)
    times = timed(lambda: frozen(scene, probe), calls + 2)[1]
    return statistics.median(times[2:])


def launch_split(scene: mi.Scene, integrator, captured: list, first_samples: int,
                 coherent: dict, repeats: int) -> LaunchSplit:
    """Time the first camera launch and the rest of a render against the
    ray casting of each part's own ``captured`` rays (in the modes of
    ``coherent``), in ``repeats`` rounds."""
    end = first_launch_end(captured, first_samples)
    parts = [_nonempty(_casts(scene, RenderRays.of(part)))
             for part in (captured[:end], captured[end:])]
    steps = [[lambda cast=cast, name=name: cast(coherent[name]) for name, cast in casts.items()]
             for casts in parts]

    def clocked_render():
        clock = _FirstLaunchClock(first_samples)
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
