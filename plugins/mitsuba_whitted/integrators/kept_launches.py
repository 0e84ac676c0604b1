"""The camera launches of the last render, kept for its derivative.

``mi.render(scene, params)`` renders the image, and ``dr.backward`` then
asks for its derivative (``render_backward``), which replays the render's
anti-aliasing to place the same camera samples and learn how the sampler
combined them (:mod:`.gradients`). The anti-aliasing decides by the
samples' radiance; the render already traced it. So ``render`` keeps what
each of its launches returned, in order, and the derivative's sampler reads
it back instead of tracing the samples again, where nothing has changed in
between: the same scene objects, sensor and seed, and every parameter the
same array (``mi.traverse``: an update puts new arrays in place) or the
same plain value. Each launch's sample keys must match too, which they do
only if the sampler placed the same samples; a launch that does not match
makes the derivative start again, tracing.

Kept only in variants with derivatives, and only up to :data:`KEPT_BYTES`
or an eighth of the memory available when the render starts, whichever is
less: a larger render keeps none, and its derivative traces as before.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..errors import Error
from .camera_shader import CameraShader
from .scene_ref import identity
from .settings import PLUGIN_NAME

#: Most bytes of launches kept (radiance, alpha and key per camera sample:
#: 20 bytes, so about 13 million samples).
KEPT_BYTES = 256 << 20
SAMPLE_BYTES = 20
#: Share of the available memory the kept launches may hold at most.
MEMORY_SHARE = 1 / 8


class LaunchesDiffer(Error):
    """A derivative's sampler asked for a launch other than the kept one:
    raised before it is used, for the caller to start again, tracing."""

    def __init__(self):
        super().__init__("the render's kept camera launches do not match its derivative's.",
                         PLUGIN_NAME)


def fingerprint(scene: mi.Scene, sensor: mi.Sensor, seed: int) -> tuple:
    """What a render's samples depend on: the scene's objects, the sensor,
    the seed, and each traversed parameter's arrays (by their variables)
    or plain value."""
    params = mi.traverse(scene)
    values = []
    for key in params.keys():
        value = params[key]
        if dr.is_jit_v(value):
            value = tuple(dr.detail.collect_indices(value))
        values.append((key, value))
    return identity(scene), sensor, seed, tuple(values)


class KeptLaunches:
    """The outputs of a render's launches (radiance, alpha) and their
    samples' keys, in order, while they fit in ``limit`` bytes
    (``complete`` false once they did not). ``available``: the memory
    available, in bytes (``None`` if unknown)."""

    def __init__(self, key: tuple, available: int | None):
        self.key = key
        self.limit = KEPT_BYTES if available is None else min(KEPT_BYTES,
                                                              int(available * MEMORY_SHARE))
        self.launches = []
        self.bytes = 0
        self.complete = True

    def keep(self, keys: mi.UInt32, outputs: tuple) -> None:
        if not self.complete:
            return
        self.bytes += dr.width(keys) * SAMPLE_BYTES
        if self.bytes > self.limit:
            self.complete = False
            self.launches = []
            return
        self.launches.append((keys, outputs))

    def reader(self):
        """``read(keys)``: the next launch's outputs, for samples with
        ``keys``; :class:`LaunchesDiffer` if they are not the kept ones."""
        launches = iter(self.launches)

        def read(keys: mi.UInt32) -> tuple:
            kept_keys, outputs = next(launches, (None, None))
            if (kept_keys is None or dr.width(kept_keys) != dr.width(keys)
                    or not dr.all(kept_keys == keys, axis=None)):
                raise LaunchesDiffer()
            return outputs

        return read


class KeepingShader(CameraShader):
    """A camera shader that keeps each launch's outputs in ``kept``."""

    def __init__(self, tracer, sensor, progress=None, indirect_samples=0,
                 kept: KeptLaunches = None):
        super().__init__(tracer, sensor, progress, indirect_samples)
        self.kept = kept

    def __call__(self, positions, keys, lens=None, share=1):
        outputs = super().__call__(positions, keys, lens, share)
        self.kept.keep(keys, outputs)
        return outputs
