"""The shadow rays of a capturing render, as its shadow test casts them.

A capturing render (the wavefront tracer with ``captured`` set) hands the
kernel of each batch that tests shadows a :class:`ShadowLog`, and the
shadow test (:class:`~.lighting.ShadowTester`) writes into it every shadow
ray it tests and every closest-hit query with which it follows a blocked
one through surfaces that let light pass.

The kernel is frozen, and the Python code of a frozen function runs only
while it is recorded: so the log is made of arrays that the kernel
scatters into, given to it as arguments, which every replay fills anew.
The batch's width is among them as data rather than as a constant, so that
one recording serves every width. A frozen kernel copies an argument
before it writes to it, so the log has no more room than it needs:

- a lane tests at most ``slots`` shadow rays (one per delta light, one per
  sample of each sampled light: :attr:`.DirectLighting.shadow_slots`);
  shadow ray ``slot`` of lane ``lane`` has entry ``slot x lanes + lane`` of
  ``tests``, which also counts the queries that followed it;
- how many queries there are is known only once the kernel has run: it
  runs again with room for exactly those (:meth:`ShadowLog.make_room`),
  each shadow ray's queries one after another in entry order. Kernels give
  the same bits for the same input, so the second run casts the same rays.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ...jit import to_int


def no_rays() -> mi.Ray3f:
    """No ray (``mi.Ray3f()`` has a length, ``maxt``, all the same)."""
    ray = mi.Ray3f(mi.Point3f(), mi.Vector3f())
    ray.maxt = mi.Float()
    return ray


@dataclass
class RayLog:
    """Rays kept at chosen entries."""
    o: mi.Point3f
    d: mi.Vector3f
    maxt: mi.Float

    @classmethod
    def empty(cls, entries: int) -> "RayLog":
        return cls(dr.empty(mi.Point3f, entries), dr.empty(mi.Vector3f, entries),
                   dr.empty(mi.Float, entries))

    def write(self, index: mi.UInt32, ray: mi.Ray3f, active: mi.Bool) -> None:
        for target, value in ((self.o, ray.o), (self.d, ray.d), (self.maxt, ray.maxt)):
            dr.scatter(target, value, index, active)

    def taken(self, index: mi.UInt32) -> mi.Ray3f:
        """The rays at entries ``index``."""
        ray = mi.Ray3f(dr.gather(mi.Point3f, self.o, index),
                       dr.gather(mi.Vector3f, self.d, index))
        ray.maxt = dr.gather(mi.Float, self.maxt, index)
        return ray


@dataclass
class ShadowLog:
    """Where the shadow test of one batch of ``lanes`` hits writes its rays
    (see the module's description)."""
    lane: mi.UInt32
    #: The batch's width, one opaque value.
    lanes: mi.UInt32
    slots: int
    tests: RayLog
    tested: mi.Bool
    #: Per test, the queries that followed it; ``None`` where shadow rays
    #: are never followed past their test (opaque scenes).
    crossings: mi.UInt32 | None
    #: Where each test's queries start in ``queries``, and the queries:
    #: ``None`` until :meth:`make_room`.
    first_query: mi.UInt32 | None = None
    queries: RayLog | None = None

    @classmethod
    def for_batch(cls, lanes: int, slots: int, marching: bool) -> "ShadowLog":
        entries = slots * lanes
        log = cls(dr.arange(mi.UInt32, lanes), dr.opaque(mi.UInt32, lanes), slots,
                  RayLog.empty(entries), dr.zeros(mi.Bool, entries),
                  dr.zeros(mi.UInt32, entries) if marching else None)
        # Memory, not literals: the kernel scatters into them.
        dr.make_opaque(log)
        return log

    def make_room(self) -> bool:
        """Room for the queries the kernel counted, if it counted any it
        has not written: then it must run again to write them."""
        if self.crossings is None or self.queries is not None:
            return False
        total = to_int(dr.sum(self.crossings))
        if total == 0:
            return False
        self.first_query = dr.prefix_sum(self.crossings)
        self.queries = RayLog.empty(total)
        dr.make_opaque(self.first_query, self.queries)
        return True

    def _entry(self, slot) -> mi.UInt32:
        return slot * self.lanes + self.lane

    def test(self, slot, ray: mi.Ray3f, active: mi.Bool) -> None:
        """Shadow ray ``slot`` of each ``active`` lane, as tested."""
        self.tests.write(self._entry(slot), ray, active)
        dr.scatter(self.tested, True, self._entry(slot), active)

    def followed(self, slot, crossings: mi.UInt32, active: mi.Bool) -> None:
        """How many queries followed shadow ray ``slot``."""
        if self.crossings is not None:
            dr.scatter(self.crossings, crossings, self._entry(slot), active)

    def query(self, slot, crossing, ray: mi.Ray3f, active: mi.Bool) -> None:
        """The closest-hit query ``crossing`` along shadow ray ``slot``."""
        if self.queries is not None:
            first = dr.gather(mi.UInt32, self.first_query, self._entry(slot), active)
            self.queries.write(first + crossing, ray, active)

    def shadow_rays(self) -> mi.Ray3f:
        """The shadow rays tested, light sample by light sample, each in
        lane order."""
        return self.tests.taken(dr.compress(self.tested))

    def query_rays(self) -> mi.Ray3f:
        """The queries, crossing by crossing, each in the order of the
        shadow rays they follow."""
        if self.queries is None:
            return no_rays()
        starts = []
        for crossing in range(to_int(dr.max(self.crossings))):
            followed = dr.compress(self.crossings > crossing)
            starts.append(dr.gather(mi.UInt32, self.first_query, followed) + crossing)
        return self.queries.taken(dr.concat(starts))
