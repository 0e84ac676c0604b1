"""Values of Mitsuba's own plugins that would make a Whitted image NaN.

Mitsuba's emitters, sensors and shapes accept any number: an intensity of
NaN, a negative radiance, an infinite transform. The integrator reads them,
so it checks them itself and names the object and the value, before a
render rather than after it has filled the image with NaN.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..errors import ParameterError
from .settings import PLUGIN_NAME

#: Parameters (by the first part of their traversed name) that are amounts
#: of light: spectra and the textures that scale them.
LIGHT_AMOUNTS = ("intensity", "radiance", "irradiance", "texture", "data", "scale")


def scene_object_name(obj, kind: str, index: int) -> str:
    """How an error names ``obj``: its id if the scene gave one, else its
    kind, index and class (``emitter 2 (PointLight)``)."""
    name = obj.id()
    if name and not name.startswith("_unnamed"):
        return f"{kind} '{name}' ({obj.class_name()})"
    return f"{kind} {index} ({obj.class_name()})"


def check_emitters(scene: mi.Scene) -> None:
    """Every emitter's values finite, its amounts of light not negative."""
    shapes = list(scene.shapes())
    for index, emitter in enumerate(scene.emitters()):
        _check_values(emitter, _emitter_name(emitter, index, shapes), LIGHT_AMOUNTS)


def _emitter_name(emitter, index: int, shapes: list) -> str:
    """An area light is named by the shape it sits on (its own id is only
    the name of the property it was given in)."""
    shape = emitter.get_shape()
    if shape is None:
        return scene_object_name(emitter, "emitter", index)
    position = next(i for i, candidate in enumerate(shapes) if candidate == shape)
    return f"the {emitter.class_name()} of {scene_object_name(shape, 'shape', position)}"


def check_placements(scene: mi.Scene) -> None:
    """Every sensor's and shape's traversed values finite (transforms,
    positions, radii, vertices)."""
    for kind, objects in (("sensor", scene.sensors()), ("shape", scene.shapes())):
        for index, obj in enumerate(objects):
            _check_values(obj, scene_object_name(obj, kind, index), ())


def _check_values(obj, name: str, non_negative: tuple) -> None:
    for key, value in mi.traverse(obj).items():
        if not _is_real(value):
            continue
        array = _flat(value)
        if not dr.all(dr.isfinite(array), axis=None):
            raise ParameterError(PLUGIN_NAME, key,
                                 f"of {name} holds NaN or an infinite value")
        if key.split(".")[0] in non_negative and dr.any(array < 0, axis=None):
            raise ParameterError(PLUGIN_NAME, key, f"of {name} is negative")


def _is_real(value) -> bool:
    """Whether ``value`` holds floating-point numbers worth checking."""
    if isinstance(value, float):
        return True
    if isinstance(value, (mi.AffineTransform4f, mi.ScalarAffineTransform4f)):
        return True
    return dr.is_array_v(value) and dr.is_float_v(value)


def _flat(value):
    """``value`` as a Dr.Jit array to reduce over (a transform by its matrix)."""
    if isinstance(value, (mi.AffineTransform4f, mi.ScalarAffineTransform4f)):
        return dr.ravel(value.matrix)
    if isinstance(value, float):
        return mi.Float(value)
    return value
