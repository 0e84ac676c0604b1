"""Values of Mitsuba's own plugins that the integrator refuses, and pixels
that are never NaN.

Mitsuba 3.9.1 loads an emitter of NaN intensity, a negative radiance or an
infinite transform without a word; each case here renders NaN or a silently
wrong image without the integrator's own checks (verified for each)."""

import math

import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite
from mitsuba_whitted.errors import ParameterError
from validation.scenes import camera, diffuse, floor, integrator, point_light, rgb, scene, sphere

NAN, INF = math.nan, math.inf


def lit(*extra, **named):
    return mi.load_dict(scene(floor(), *extra, sensor=camera(size=8), **named))


def render_refusal(loaded) -> str:
    """The sentence a render of ``loaded`` is refused with (``mi.render``
    raises the integrator's own error, unwrapped)."""
    with pytest.raises(ParameterError) as error:
        mi.render(loaded, integrator=mi.load_dict(integrator()))
    return str(error.value)


EMITTERS = {
    "point intensity NaN": ({"type": "point", "position": [0, 2, 0],
                             "intensity": rgb(NAN, 1, 1)}, "intensity.value", "NaN"),
    "point intensity negative": ({"type": "point", "position": [0, 2, 0],
                                  "intensity": rgb(-5, 1, 1)}, "intensity.value", "negative"),
    "point position infinite": ({"type": "point", "position": [0, INF, 0],
                                 "intensity": rgb(5, 5, 5)}, "position", "NaN or an infinite"),
    "directional irradiance infinite": ({"type": "directional", "direction": [0, -1, 0],
                                         "irradiance": rgb(INF, 1, 1)}, "irradiance.value",
                                        "NaN or an infinite"),
    "spot intensity negative": ({"type": "spot", "intensity": rgb(-1, -1, -1),
                                 "to_world": mi.ScalarTransform4f().look_at([0, 2, 0], [0, 0, 0],
                                                                            [0, 0, 1])},
                                "intensity.value", "negative"),
    "environment radiance NaN": ({"type": "constant", "radiance": rgb(NAN, 0, 0)},
                                 "radiance.value", "NaN"),
}


@pytest.mark.parametrize("name", EMITTERS)
def test_an_emitter_with_a_bad_value_is_named(name):
    emitter, parameter, problem = EMITTERS[name]
    message = render_refusal(lit(light=emitter))
    assert message.startswith(f"whitted: parameter '{parameter}' of emitter 'light' (")
    assert problem in message


def test_an_area_light_is_named_by_its_shape():
    bad = {"type": "sphere", "radius": 0.2,
           "emitter": {"type": "area", "radiance": rgb(1, NAN, 1)}}
    message = render_refusal(lit(point_light((0, 3, 0)), lamp=bad))
    assert "'radiance.value' of the AreaLight of shape 'lamp' (Sphere)" in message


def test_an_unnamed_object_is_named_by_its_kind_index_and_class():
    loaded = mi.load_string("""<scene version="3.0.0">
        <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/>
            <integer name="height" value="8"/></film></sensor>
        <emitter type="point"><rgb name="intensity" value="1, 1, 1"/></emitter>
        <emitter type="point"><rgb name="intensity" value="-1, 1, 1"/></emitter>
    </scene>""")
    assert "'intensity.value' of emitter 1 (PointLight) is negative" in render_refusal(loaded)


def test_an_emitter_updated_to_nan_is_refused_at_the_next_render():
    loaded = lit(light=point_light((0, 3, 0)))
    whitted = mi.load_dict(integrator())
    assert_finite(mi.render(loaded, integrator=whitted))
    params = mi.traverse(loaded)
    params["light.intensity.value"] = mi.Color3f(NAN, 1, 1)
    params.update()
    assert "intensity.value" in render_refusal(loaded)


def test_a_shape_placed_at_infinity_is_named():
    far = sphere((0, INF, 0), 1.0, diffuse(0.5, 0.5, 0.5))
    message = render_refusal(lit(point_light((0, 3, 0)), ball=far))
    assert "of shape 'ball'" in message and "NaN or an infinite" in message


def test_a_sensor_with_a_nan_transform_is_named():
    sensor = camera(size=8)
    sensor["to_world"] = mi.ScalarTransform4f().translate([NAN, 0, 0])
    loaded = mi.load_dict(scene(floor(), point_light((0, 3, 0)), sensor=sensor))
    assert "to_world' of sensor" in render_refusal(loaded)


def test_pixels_whose_rays_hit_nothing_are_zero_not_nan():
    empty = mi.load_dict(scene(sensor=camera(size=8)))
    image = np.array(mi.render(empty, integrator=mi.load_dict(integrator(aa="contrast"))))
    np.testing.assert_array_equal(image, 0.0)


def test_radiance_past_float32_is_refused_not_rendered_as_inf():
    """An intensity near float32's largest value times a reflectance above
    one overflows: the render stops with a sentence instead of an image
    holding Inf."""
    loaded = lit(light=point_light((0, -0.99, 0), 3e38))
    assert "NaN or infinite value" in render_refusal(loaded)


@pytest.mark.parametrize("aa", ["none", "grid", "adaptive", "contrast"])
def test_a_scene_with_nothing_to_shade_renders_black_in_every_mode(aa):
    """No light and no emitter: every sample's radiance is one constant 0,
    which the samplers must widen to their samples before summing them (the
    grid and adaptive modes stopped with a Dr.Jit size error)."""
    unlit = mi.load_dict(scene(sphere((0, 0, 0), 1.0, diffuse(0.5, 0.5, 0.5)),
                               sensor=camera(size=8)))
    image = np.array(mi.render(unlit, integrator=mi.load_dict(integrator(aa=aa))))
    np.testing.assert_array_equal(image[..., :3], 0.0)


def test_a_film_without_pixels_is_refused():
    sensor = camera(size=8)
    sensor["film"]["width"] = 0
    message = render_refusal(mi.load_dict(scene(floor(), point_light((0, 3, 0)),
                                                sensor=sensor)))
    assert message.startswith("whitted: parameter 'film' has no pixels to render (0 x 8)")
