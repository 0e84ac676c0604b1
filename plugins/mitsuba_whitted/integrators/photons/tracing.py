"""Photon paths from the lights, one bounce at a time, and the photons
they leave on smooth surfaces.

Each bounce is one kernel over the photons still travelling: intersect,
store a photon where the surface has a smooth (diffuse or glossy) part and
the path so far carries light the rest of the integrator leaves out, then
draw the next direction from the BSDF in importance transport. Stored
photons and survivors are compacted in order (``dr.compress``), so the
photon set is the same, in the same order, on every run.

What a photon carries is set by :class:`PhotonKinds`:

- ``bends``: which scattering makes the light one the tree does not
  have. Light that reached a surface only in straight lines (through null
  surfaces, masks, index-matched or thin dielectrics) is what ``physical``
  shadow rays count, so such a crossing is not a bend for ``whitted``; a
  path tracer's shadow rays stop at every surface, so for the reference
  that completes ``path`` every delta or null crossing is one.
- ``smooth_bounces``: whether a photon goes on past a smooth surface (the
  indirect light of classic Whitted) or ends there (only the light a path
  tracer's own paths cannot find: delta light, through delta surfaces, onto
  a smooth one).

The random numbers are Owen-scrambled Sobol points indexed by the photon
(:mod:`..sequence`), two pairs a bounce, seeded by the pass: a pure
function of the photon and the pass, with no state to carry through the
loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ...errors import ParameterError
from ..indirect import STRAIGHT_COSINE
from ..offsets import spawn_ray
from ..sequence import PaddedSobol
from ..settings import PLUGIN_NAME
from .emission import EmitterShare, emitted_rays

#: Photon paths start Russian roulette at this bounce.
ROULETTE_FROM = 3
#: Most a photon survives a roulette with.
ROULETTE_CAP = 0.95
#: Bytes a stored photon takes: position, direction, power, segments.
PHOTON_BYTES = 40
#: Bytes a travelling photon takes in a bounce's kernel, its arrays in and out.
TRAVELLING_BYTES = 2 * 48


@dataclass(frozen=True)
class PhotonKinds:
    """Which light the photons carry (see the module's docstring)."""
    straight_bends: bool
    smooth_bounces: bool


@dataclass
class Photons:
    """Stored photons: where they landed, the direction they came from
    (world, away from the surface), their power (over the photons
    emitted), and the segments of their path from the light."""
    position: mi.Point3f
    direction: mi.Vector3f
    power: mi.Color3f
    segments: mi.UInt32

    def __len__(self) -> int:
        return dr.width(self.segments)

    @classmethod
    def empty(cls) -> "Photons":
        return cls(dr.zeros(mi.Point3f, 0), dr.zeros(mi.Vector3f, 0), dr.zeros(mi.Color3f, 0),
                   dr.zeros(mi.UInt32, 0))

    @classmethod
    def joined(cls, parts: list) -> "Photons":
        if not parts:
            return cls.empty()
        if len(parts) == 1:
            return parts[0]
        fields = [_concatenated([getattr(part, name) for part in parts])
                  for name in ("position", "direction", "power", "segments")]
        return cls(*fields)


def _concatenated(arrays: list):
    kind = type(arrays[0])
    total = sum(dr.width(a) for a in arrays)
    whole = dr.empty(kind, total)
    start = 0
    for array in arrays:
        width = dr.width(array)
        if width:
            dr.scatter(whole, array, dr.arange(mi.UInt32, width) + start)
        start += width
    dr.eval(whole)
    return whole


@dataclass
class Travelling:
    """Photons on their way: their ray, power, Sobol index and whether
    their light has bent yet."""
    ray: mi.Ray3f
    power: mi.Color3f
    index: mi.UInt32
    bent: mi.Bool

    def __len__(self) -> int:
        return dr.width(self.index)

    def kept(self, mask: mi.Bool) -> "Travelling":
        keep = dr.compress(mask)
        return Travelling(dr.gather(mi.Ray3f, self.ray, keep),
                          dr.gather(mi.Color3f, self.power, keep),
                          dr.gather(mi.UInt32, self.index, keep),
                          dr.gather(mi.Bool, self.bent, keep))


class PhotonTracer:
    """``trace(shares, salt)``: the photons of one pass."""

    def __init__(self, intersect, scale: float, kinds: PhotonKinds, max_segments: int,
                 budget_bytes: int):
        self.intersect = intersect
        self.scale = scale
        self.kinds = kinds
        #: A stored photon needs a segment from the camera too.
        self.max_segments = max_segments
        #: Most bytes the stored photons may take.
        self.budget_bytes = budget_bytes

    def trace(self, shares: list, salt: int) -> tuple:
        """The stored photons of every emitter's share, and how many
        photons were emitted and how many segments they traced."""
        sequence = PaddedSobol(dr.opaque(mi.UInt32, salt))
        stored, emitted, segments = [], 0, 0
        for share in shares:
            traced = self._trace_share(share, sequence, stored)
            emitted += share.count
            segments += traced
        return Photons.joined(stored), emitted, segments

    def _trace_share(self, share: EmitterShare, sequence: PaddedSobol, stored: list):
        index = dr.arange(mi.UInt32, share.count)
        ray, power = emitted_rays(share, index, sequence)
        travelling = Travelling(ray, power, index, dr.full(mi.Bool, False, share.count))
        travelling = travelling.kept(dr.any(power > 0))
        traced = 0
        for bounce in range(self.max_segments - 1):
            if not len(travelling):
                break
            traced += len(travelling)
            landed, travelling = self._bounce(travelling, bounce, sequence)
            if len(landed):
                stored.append(landed)
                self._check_budget(stored)
        return traced

    def _check_budget(self, stored: list) -> None:
        held = sum(len(part) for part in stored) * PHOTON_BYTES
        if held > self.budget_bytes:
            raise ParameterError(
                PLUGIN_NAME, "photons",
                f"store more than the {self.budget_bytes / 2**20:.0f} MiB of photons this "
                "machine has room for in one pass; lower 'photons'")

    def _bounce(self, travelling: Travelling, bounce: int, sequence: PaddedSobol):
        """One segment of every travelling photon: the photons it stores,
        and those that go on."""
        ray = travelling.ray
        active = mi.Bool(True)
        si = self.intersect(ray, active)
        hit = si.is_valid()
        bsdf = si.bsdf(ray)
        smooth = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        segments = bounce + 1
        store = hit & smooth & travelling.bent & (segments + 1 <= self.max_segments)
        pair = 2 + 2 * bounce
        u_lobe = sequence.point(travelling.index, pair)
        u_dir = sequence.point(travelling.index, pair + 1)
        mask = (mi.BSDFFlags.All if self.kinds.smooth_bounces
                else mi.BSDFFlags.Delta | mi.BSDFFlags.Null)
        ctx = mi.BSDFContext(mi.TransportMode.Importance, mask)
        bs, weight = bsdf.sample(ctx, si, u_lobe.x, u_dir, hit)
        wo = si.to_world(bs.wo)
        straight = self._straight(bs, wo, ray.d)
        bent = travelling.bent | ~straight
        power = travelling.power * mi.Color3f(weight)
        go = hit & (bs.pdf > 0) & dr.any(power > 0) & (segments + 2 <= self.max_segments)
        if bounce >= ROULETTE_FROM:
            # Survival by the bounce's own weight: a surviving photon keeps
            # about the power it had.
            survival = dr.minimum(dr.max(mi.Color3f(weight)), ROULETTE_CAP)
            go &= u_lobe.y < survival
            power = dr.select(go, power / survival, power)
        landed_index = dr.compress(store)
        landed = Photons(dr.gather(mi.Point3f, si.p, landed_index),
                         dr.gather(mi.Vector3f, -ray.d, landed_index),
                         dr.gather(mi.Color3f, travelling.power, landed_index),
                         dr.full(mi.UInt32, segments, dr.width(landed_index)))
        dr.eval(landed.position, landed.direction, landed.power, landed.segments)
        following = Travelling(spawn_ray(si, wo, self.scale), power, travelling.index, bent)
        return landed, following.kept(go)

    def _straight(self, bs: mi.BSDFSample3f, wo: mi.Vector3f, incoming: mi.Vector3f) -> mi.Bool:
        """Whether the sampled lobe let the light on without bending it,
        for the kinds of photon in which that is no bend."""
        if self.kinds.straight_bends:
            return mi.Bool(False)
        null = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
        transmitted = mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaTransmission)
        return null | (transmitted & (dr.dot(wo, incoming) >= STRAIGHT_COSINE))
