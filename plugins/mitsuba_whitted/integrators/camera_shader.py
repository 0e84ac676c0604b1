"""The camera's side of a render: the sensor it renders, and what traces
its camera samples for the anti-aliasing patterns."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from ..errors import ParameterError
from ..jit import in_launches
from .indirect import camera_key
from .settings import PLUGIN_NAME


class CameraShader:
    """``shade(positions, keys, lens=None)``: radiance and alpha of the
    camera rays through ``positions`` (pixel units in the crop window) from
    ``lens`` (see ``camera_rays``), traced in launches of at most ``batch``
    rays. ``progress(done, total)``, where given, hears of each call's
    launches: ``done`` of its ``total`` samples traced, ``done == total``
    once, when all of them are (:class:`.render_progress.RenderProgress`
    tells the calls apart by it)."""

    def __init__(self, tracer, sensor: mi.Sensor, progress=None, indirect_samples: int = 0):
        self.tracer = tracer
        self.sensor = sensor
        self.progress = progress
        self.batch = tracer.camera_batch
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
                keys = pixel_keys(positions, share, self.sensor.film().crop_size()[0])
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

        outputs = in_launches(total, self.batch, trace, lambda stop: self._launched(stop, total))
        dr.eval(outputs)
        # Wait here, where Dr.Jit lets other Python threads run: the
        # samplers' next dr.compress would wait for these launches holding
        # the GIL, and Ctrl-C (see interrupt.py) with it.
        dr.sync_thread()
        self._report(total, total)
        return outputs

    def _launched(self, stop: int, total: int) -> None:
        """Report a launch but the last: the call's end is reported once,
        after its samples are traced."""
        if stop < total:
            self._report(stop, total)

    def _report(self, done: int, total: int) -> None:
        if self.progress is not None:
            self.progress(done, total)


def pixel_keys(positions: mi.Point2f, share: int, width: int) -> mi.UInt32:
    """Keys of camera samples that gather indirect light
    (:func:`.indirect.camera_key`): their pixel in a crop window ``width``
    wide, and a slot that tells apart the ``share`` samples per pixel of a
    pattern by their place in the pixel. A pattern of n x n cells (a grid,
    a level of the adaptive split, a Hammersley net of 4^k points) numbers
    its cells, in Morton order where n is a power of two, so that the four
    children of an adaptive cell take the slots, and with them the paths,
    of their parent; any other pattern numbers ``share`` columns."""
    pixel_x, pixel_y = dr.floor(positions.x), dr.floor(positions.y)
    within_x, within_y = positions.x - pixel_x, positions.y - pixel_y
    pixel = mi.UInt32(pixel_y) * width + mi.UInt32(pixel_x)
    side = math.isqrt(share)
    if side * side != share:
        return camera_key(pixel, mi.UInt32(dr.minimum(within_x * share, share - 1)))
    cell_x = mi.UInt32(dr.minimum(within_x * side, side - 1))
    cell_y = mi.UInt32(dr.minimum(within_y * side, side - 1))
    if side & (side - 1):
        return camera_key(pixel, cell_y * side + cell_x)
    slot = mi.UInt32(0)
    for bit in range(side.bit_length() - 1):
        slot |= ((cell_x >> bit) & 1) << (2 * bit)
        slot |= ((cell_y >> bit) & 1) << (2 * bit + 1)
    return camera_key(pixel, slot)


def sensor_of(scene: mi.Scene, sensor) -> mi.Sensor:
    """The sensor ``mi.render`` names: a sensor, or an index into the scene's."""
    if not isinstance(sensor, int):
        return sensor
    sensors = scene.sensors()
    if not 0 <= sensor < len(sensors):
        raise ParameterError(PLUGIN_NAME, "sensor",
                             f"index {sensor} does not exist: the scene has {len(sensors)} "
                             "sensor(s)")
    return sensors[sensor]


def has_aperture(sensor: mi.Sensor) -> bool:
    """Whether the sensor sees through an aperture of some size: a thin
    lens whose radius is above the float epsilon that Mitsuba puts in place
    of a radius of 0."""
    if not sensor.needs_aperture_sample():
        return False
    radius = mi.traverse(sensor).get("aperture_radius")
    return radius is None or dr.any(radius > dr.epsilon(mi.Float), axis=None)


def settle_sampler(sensor: mi.Sensor) -> None:
    """Seed the sensor's sampler as ``mi.render`` leaves it after a render.

    Whitted draws no random numbers, but the frozen kernels take the sensor,
    and with it its sampler, as an input: a sampler seeded after the first
    render and never before it looked like a changed input, and the second
    render recorded the kernels once more."""
    sampler = sensor.sampler()
    if sampler is not None:
        sampler.seed(0, 1)
