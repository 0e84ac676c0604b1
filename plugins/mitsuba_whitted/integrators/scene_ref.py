"""The scene a tracer renders, held only while it renders.

The Whitted integrator keeps its last tracer so that the next render of the
same scene replays the frozen kernels. The scene holds the integrator, so a
tracer that held the scene would close a cycle through Mitsuba's C++
references, which Python's garbage collector cannot see: every rendered
scene would stay alive for the rest of the process, and since each frozen
call traverses all live instances of the scene's plugin types, every later
render would slow down. The tracer's parts read the scene through one
shared :class:`SceneRef` instead, which the integrator fills for the length
of a render and empties after it.
"""

from __future__ import annotations

from contextlib import contextmanager

import mitsuba as mi


class SceneRef:
    """A scene, or none between renders (see :meth:`holding`)."""

    __slots__ = ("_scene",)

    def __init__(self, scene: mi.Scene):
        self._scene = scene

    @contextmanager
    def holding(self, scene: mi.Scene):
        """Holds ``scene`` for the length of a ``with`` block, and nothing
        after it."""
        self._scene = scene
        try:
            yield
        finally:
            self._scene = None

    def get(self) -> mi.Scene:
        if self._scene is None:
            raise RuntimeError("whitted: a tracer was used outside of a render.")
        return self._scene


class ReadsScene:
    """Base of the tracer's parts that read the scene through a
    :class:`SceneRef` (``scene_ref``)."""

    scene_ref: SceneRef

    @property
    def scene(self) -> mi.Scene:
        return self.scene_ref.get()


def identity(scene: mi.Scene) -> tuple:
    """What tells a scene from another without holding it: its shapes,
    emitters and sensors (none of which refers back to the scene),
    compared object by object."""
    return tuple(scene.shapes()), tuple(scene.emitters()), tuple(scene.sensors())


def plain_values(scene: mi.Scene) -> tuple:
    """The scene's traversed parameters that are plain Python values (a
    dielectric's ``eta``, a sensor's ``near_clip``): a frozen kernel records
    them as constants, unlike arrays, which reach it as arguments, so an
    update of one through ``mi.traverse`` must lead to a new tracer."""
    params = mi.traverse(scene)
    values = ((key, params[key]) for key in params.keys())
    return tuple((key, value) for key, value in values
                 if isinstance(value, (bool, int, float, str)))
