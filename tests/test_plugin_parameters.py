"""Bad parameters of ``phong``, ``capped_cylinder``, ``tartan``,
``sphere_map`` and ``planar_map``: refused with one sentence naming the
plugin and the parameter, from a dictionary, from XML and through
``mi.traverse(...).update()``; a refused update changes nothing.

Oracles: the traversed values and a ``whitted`` render from before the
refused update (bit for bit), and a scene loaded anew with the values of a
later, valid update through the same ``SceneParameters``."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite, read_only
from mitsuba_whitted.errors import ParameterError
from validation.scenes import camera, diffuse, floor, integrator, point_light, rgb, scene, sphere

LEMONS = str(Path(__file__).resolve().parent.parent / "textures" / "lemons.png")
NAN, INF = math.nan, math.inf


def bitmap(**props):
    return {"type": "bitmap", "filename": LEMONS, **props}


def textured(texture):
    return {"type": "diffuse", "reflectance": texture}


def phong(**props):
    return sphere((0, 0, 0), 1.0, {"type": "phong", **props})


def capped_cylinder(**props):
    return {"type": "capped_cylinder", "center": [0, -0.6, 0], "radius": 0.8, "height": 1.2,
            "segments": 24, "bsdf": diffuse(0.7, 0.7, 0.7), **props}


def tartan(**props):
    return sphere((0, 0, 0), 1.0, textured({"type": "tartan", **props}))


def sphere_map(**props):
    return sphere((0, 0, 0), 1.0, textured({"type": "sphere_map", "texture": bitmap(),
                                            "center": [0, 0, 0], **props}))


def planar_map(**props):
    return floor(bsdf=textured({"type": "planar_map", "texture": bitmap(), **props}))


#: Each plugin: the scene object using it (its keyword arguments become the
#: plugin's properties), where its parameters sit in ``mi.traverse(scene)``,
#: and one valid update (a value that works as a property to load too).
PLUGINS = {
    "phong": (phong, "obj.bsdf.", ("exponent", 80.0)),
    "capped_cylinder": (capped_cylinder, "obj.", ("radius", 0.5)),
    "tartan": (tartan, "obj.bsdf.reflectance.", ("frequency", 7.0)),
    "sphere_map": (sphere_map, "obj.bsdf.reflectance.",
                   ("to_world", lambda: mi.ScalarTransform4f().rotate([0, 1, 0], 50))),
    "planar_map": (planar_map, "obj.bsdf.reflectance.", ("x_max", 3.0)),
}


def load(plugin, **props):
    make, _, _ = PLUGINS[plugin]
    return mi.load_dict(scene(point_light((2, 3, 4), 30.0), sensor=camera(size=16),
                              whitted=integrator(aa="none"), obj=make(**props)))


def render(loaded) -> np.ndarray:
    image = np.array(mi.render(loaded))
    assert_finite(image)
    return image


def evaluated(value):
    """A value built here only once a variant is set (transforms)."""
    return value() if callable(value) else value


@functools.lru_cache(maxsize=None)
def loaded_with_valid_update(plugin) -> np.ndarray:
    """The image of a scene loaded anew with the plugin's valid update: the
    same for every case of the plugin, so rendered once."""
    _, _, (good_key, good_value) = PLUGINS[plugin]
    return read_only(render(load(plugin, **{good_key: evaluated(good_value)})))


def snapshot(params, prefix: str) -> dict:
    """Copies of every traversed value under ``prefix`` (transforms by
    their matrix; a Dr.Jit vector answers ``.matrix`` too, as a swizzle)."""
    values = {}
    for key in params.keys():
        if key.startswith(prefix):
            value = params[key]
            if not dr.is_array_v(value):
                value = getattr(value, "matrix", value)
            values[key] = np.array(value, dtype=np.float64)
    return values


def assert_same_values(now: dict, before: dict) -> None:
    assert now.keys() == before.keys()
    for key in before:
        np.testing.assert_array_equal(now[key], before[key], err_msg=key)


def named(name, make):
    make.__name__ = name
    return make


def lanes(count):
    """The traversed value with ``count`` lanes instead of one."""
    def make(current):
        row = [1.0] * count
        size = dr.size_v(type(current))
        return type(current)(row) if size == dr.Dynamic else type(current)(*[row] * size)
    return named(f"{count}-lanes", make)


def filled(value):
    """The traversed value with every entry ``value``."""
    return named(f"all-{value}", lambda current: dr.full(type(current), value, dr.width(current)))


def transform(name, *rows):
    return named(name, lambda current=None: mi.ScalarTransform4f(np.array(rows, dtype=np.float64)))


SINGULAR = transform("singular", [1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1])
NAN_MATRIX = transform("nan-matrix", [NAN, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1])
PROJECTIVE = transform("projective", [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 3])
NAN_UV = named("nan-to_uv", lambda current: mi.ScalarTransform3f(
    np.array([[NAN, 0, 0], [0, 1, 0], [0, 0, 1]])))


#: (plugin, parameter, a bad value for an update or a function of the
#: traversed value that makes one, a mistake in the same parameter as a
#: property to load (None where it is not one), and as XML).
CASES = [
    ("phong", "exponent", NAN, NAN, '<float name="exponent" value="nan"/>'),
    ("phong", "exponent", INF, INF, '<float name="exponent" value="inf"/>'),
    ("phong", "exponent", -1.0, -1.0, '<float name="exponent" value="-1"/>'),
    ("phong", "exponent", lanes(2), "30", '<string name="exponent" value="30"/>'),
    ("phong", "diffuse_reflectance.value", filled(NAN), rgb(NAN, 0.5, 0.5),
     '<rgb name="diffuse_reflectance" value="nan, 0.5, 0.5"/>'),
    ("phong", "diffuse_reflectance.value", filled(-0.5), -0.5,
     '<float name="diffuse_reflectance" value="-0.5"/>'),
    ("phong", "specular_reflectance.value", filled(INF), rgb(-1, 0, 0),
     '<rgb name="specular_reflectance" value="-1, 0, 0"/>'),
    ("phong", "specular_reflectance.value", filled(-1.0), "white",
     '<string name="specular_reflectance" value="white"/>'),
    ("capped_cylinder", "radius", -1.0, -1.0, '<float name="radius" value="-1"/>'),
    ("capped_cylinder", "radius", 0.0, 0.0, '<float name="radius" value="0"/>'),
    ("capped_cylinder", "radius", NAN, NAN, '<float name="radius" value="nan"/>'),
    ("capped_cylinder", "radius", lanes(2), [1, 2, 3], '<string name="radius" value="1"/>'),
    ("capped_cylinder", "height", 0.0, 0.0, '<float name="height" value="0"/>'),
    ("capped_cylinder", "radius", 1e20, 1e30, '<float name="radius" value="1e30"/>'),
    ("capped_cylinder", "height", 1e-25, 1e25, '<float name="height" value="1e25"/>'),
    ("capped_cylinder", "height", INF, INF, '<float name="height" value="inf"/>'),
    ("capped_cylinder", "segments", 2, 2, '<integer name="segments" value="2"/>'),
    ("capped_cylinder", "segments", 1 << 20, 6.5, '<float name="segments" value="6.5"/>'),
    ("capped_cylinder", "segments", 0, -1, '<integer name="segments" value="-1"/>'),
    ("capped_cylinder", "center", [NAN, 0, 0], [NAN, 0, 0],
     '<point name="center" x="nan" y="0" z="0"/>'),
    ("capped_cylinder", "center", [0, INF, 0], 5.0, '<float name="center" value="5"/>'),
    ("capped_cylinder", "vertex_positions", filled(NAN), None, None),
    ("tartan", "frequency", INF, INF, '<float name="frequency" value="inf"/>'),
    ("tartan", "frequency", NAN, NAN, '<float name="frequency" value="nan"/>'),
    ("tartan", "frequency", 0.0, "3", '<string name="frequency" value="3"/>'),
    ("tartan", "frequency", 1e7, 1e30, '<float name="frequency" value="1e30"/>'),
    ("tartan", "color", [NAN, 0, 0], rgb(NAN, 0, 0), '<rgb name="color" value="nan, 0, 0"/>'),
    ("tartan", "color", [-1, 0.5, 0], rgb(-1, 0.5, 0), '<rgb name="color" value="-1, 0.5, 0"/>'),
    ("tartan", "color", lanes(2), "orange", '<string name="color" value="orange"/>'),
    ("tartan", "to_world", SINGULAR, SINGULAR,
     '<transform name="to_world"><scale x="1" y="0" z="1"/></transform>'),
    ("tartan", "to_world", NAN_MATRIX, NAN_MATRIX,
     '<transform name="to_world"><matrix value="nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"/></transform>'),
    ("tartan", "to_world", PROJECTIVE, "identity", '<string name="to_world" value="identity"/>'),
    ("sphere_map", "center", [NAN, 0, 0], [NAN, 0, 0],
     '<point name="center" x="nan" y="0" z="0"/>'),
    ("sphere_map", "center", [INF, 0, 0], 1.0, '<float name="center" value="1"/>'),
    ("sphere_map", "center", lanes(2), "middle", '<string name="center" value="middle"/>'),
    ("sphere_map", "to_world", SINGULAR, SINGULAR,
     '<transform name="to_world"><scale x="0"/></transform>'),
    ("sphere_map", "to_world", PROJECTIVE, NAN_MATRIX,
     '<transform name="to_world"><matrix value="1 0 0 0 0 1 0 0 0 0 1 inf 0 0 0 1"/></transform>'),
    ("sphere_map", "texture.to_uv", NAN_UV, None, None),
    ("planar_map", "x_min", NAN, NAN, '<float name="x_min" value="nan"/>'),
    ("planar_map", "x_min", 1.0, True, '<boolean name="x_min" value="true"/>'),
    ("planar_map", "x_max", INF, INF, '<float name="x_max" value="inf"/>'),
    ("planar_map", "x_max", -1.0, "two", '<string name="x_max" value="two"/>'),
    ("planar_map", "z_min", lanes(2), [1, 2, 3], '<vector name="z_min" x="1" y="2" z="3"/>'),
    ("planar_map", "z_min", 5.0, "-5", '<string name="z_min" value="-5"/>'),
    ("planar_map", "z_max", NAN, NAN, '<float name="z_max" value="nan"/>'),
    ("planar_map", "z_max", -2.0, -2.0, '<float name="z_max" value="-2"/>'),
    ("planar_map", "x_max", -0.9999999, -0.9999999, '<float name="x_max" value="-0.9999999"/>'),
    ("planar_map", "z_min", 0.9999999, None, None),
]

XML_SCENE = """<scene version="3.0.0">
    <integrator type="whitted"/>
    <sensor type="perspective">
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    {}
</scene>"""

XML_OBJECTS = {
    "phong": '<shape type="sphere"><bsdf type="phong">{}</bsdf></shape>',
    "capped_cylinder": '<shape type="capped_cylinder">{}</shape>',
    "tartan": '<shape type="sphere"><bsdf type="diffuse">'
              '<texture type="tartan" name="reflectance">{}</texture></bsdf></shape>',
    "sphere_map": '<shape type="sphere"><bsdf type="diffuse">'
                  '<texture type="sphere_map" name="reflectance">{}'
                  f'<texture type="bitmap" name="texture"><string name="filename" value="{LEMONS}"/>'
                  '</texture></texture></bsdf></shape>',
    "planar_map": '<shape type="rectangle"><bsdf type="diffuse">'
                  '<texture type="planar_map" name="reflectance">{}'
                  f'<texture type="bitmap" name="texture"><string name="filename" value="{LEMONS}"/>'
                  '</texture></texture></bsdf></shape>',
}


def assert_one_sentence(message: str, plugin: str, parameter: str, *, loading: bool) -> None:
    """``message`` is the plugin's one sentence about ``parameter`` (or
    about the nested object that holds it), on one line. When loading, it
    ends with where Mitsuba's loader found the plugin."""
    assert "\n" not in message.strip(), message
    sentence, _, place = message.partition(", at ")
    assert bool(place) == loading, message
    assert sentence.startswith(f"{plugin}: parameter '{parameter.split('.')[0]}"), message
    assert ". " not in sentence, message


def case_id(case):
    plugin, parameter, bad = case[:3]
    return f"{plugin}-{parameter}-{getattr(bad, '__name__', bad)}"


@pytest.mark.parametrize("plugin, parameter, bad, load_bad, xml", CASES,
                         ids=[case_id(case) for case in CASES])
def test_bad_value_is_refused_and_a_refused_update_changes_nothing(plugin, parameter, bad,
                                                                   load_bad, xml):
    if load_bad is not None:
        with pytest.raises(ParameterError) as refused:
            load(plugin, **{parameter.split(".")[0]: evaluated(load_bad)})
        assert_one_sentence(str(refused.value), plugin, parameter, loading=True)
        with pytest.raises(ParameterError) as refused:
            mi.load_string(XML_SCENE.format(XML_OBJECTS[plugin].format(xml)))
        assert_one_sentence(str(refused.value), plugin, parameter, loading=True)

    loaded = load(plugin)
    _, prefix, (good_key, good_value) = PLUGINS[plugin]
    params = mi.traverse(loaded)
    key = prefix + parameter
    values_before = snapshot(params, "obj.")
    image_before = render(loaded)

    params[key] = bad(params[key]) if callable(bad) else bad
    with pytest.raises(ParameterError) as refused:
        params.update()
    assert_one_sentence(str(refused.value), plugin, parameter, loading=False)
    assert_same_values(snapshot(params, "obj."), values_before)
    np.testing.assert_array_equal(render(loaded), image_before)

    # A valid update through the same parameters is applied in full.
    params[prefix + good_key] = evaluated(good_value)
    params.update()
    updated = render(loaded)
    assert not np.array_equal(updated, image_before)
    np.testing.assert_array_equal(updated, loaded_with_valid_update(plugin))


def test_a_refused_update_of_several_values_restores_them_all():
    """Radius valid, height not: the radius comes back too, and so does the
    mesh built from neither."""
    loaded = load("capped_cylinder")
    params = mi.traverse(loaded)
    values_before = snapshot(params, "obj.")
    image_before = render(loaded)
    params["obj.radius"] = 0.3
    params["obj.height"] = -1.0
    with pytest.raises(ParameterError, match="capped_cylinder: parameter 'height'"):
        params.update()
    assert_same_values(snapshot(params, "obj."), values_before)
    np.testing.assert_array_equal(render(loaded), image_before)


def test_a_nested_texture_rebuilds_itself_from_the_restored_values():
    """A nested ``bitmap`` rebuilds its texture and its mean from new data
    before ``sphere_map`` sees it; after the refusal both are the old ones
    again (oracle: the same evaluations before the update)."""
    data = np.random.default_rng(16).uniform(0, 1, (8, 8, 3)).astype(np.float32)
    texture = mi.load_dict({"type": "sphere_map", "texture": {
        "type": "bitmap", "raw": True, "data": mi.TensorXf(data)}})
    si = dr.zeros(mi.SurfaceInteraction3f, 64)
    si.sh_frame.n = mi.Normal3f(np.random.default_rng(7).normal(size=(3, 64)).astype(np.float32))

    def evaluations():
        return np.array(texture.eval(si)), np.array(texture.mean())

    before = evaluations()
    params = mi.traverse(texture)
    poisoned = data.copy()
    poisoned[3, 4, 1] = NAN
    params["texture.data"] = mi.TensorXf(poisoned)
    with pytest.raises(ParameterError, match="sphere_map: parameter 'texture.data'"):
        params.update()
    for now, then in zip(evaluations(), before):
        np.testing.assert_array_equal(now, then)


#: The integrator's settings: (parameter, a bad value for an update, a bad
#: property to load (None where an update is the only way in), the XML).
INTEGRATOR_CASES = [
    ("max_depth", -2, "deep", '<string name="max_depth" value="deep"/>'),
    ("max_depth", -5, 2.5, '<float name="max_depth" value="2.5"/>'),
    ("emitter_samples", 0, 0, '<integer name="emitter_samples" value="0"/>'),
    ("indirect_samples", -1, 1.5, '<float name="indirect_samples" value="1.5"/>'),
    ("indirect_samples", 1 << 21, -3, '<integer name="indirect_samples" value="-3"/>'),
    ("min_throughput", NAN, NAN, '<float name="min_throughput" value="nan"/>'),
    ("min_throughput", -1.0, INF, '<float name="min_throughput" value="inf"/>'),
    ("aa_samples", 0, 0, '<integer name="aa_samples" value="0"/>'),
    ("aa_samples", -3, 1e10, '<float name="aa_samples" value="1e10"/>'),
    ("aa_threshold", -0.1, -0.1, '<float name="aa_threshold" value="-0.1"/>'),
    ("aa_threshold", INF, "0.5", '<vector name="aa_threshold" x="1" y="2" z="3"/>'),
    ("aa_max_depth", 17, 17, '<integer name="aa_max_depth" value="17"/>'),
    ("aa_budget", 1.0, 1.0, '<float name="aa_budget" value="1"/>'),
    ("aa_budget", NAN, "many", '<string name="aa_budget" value="many"/>'),
    ("wavefront_size", 100, 100, '<integer name="wavefront_size" value="100"/>'),
    ("ambient", [-1.0, 0.0, 0.0], rgb(-1, 0, 0), '<rgb name="ambient" value="-1, 0, 0"/>'),
    ("ambient", [NAN, 0.0, 0.0], "grey", '<string name="ambient" value="grey"/>'),
    ("hide_emitters", None, "yes", '<string name="hide_emitters" value="yes"/>'),
    # Whole numbers past the 32 bits the settings are kept in.
    ("max_depth", None, 1 << 40, '<integer name="max_depth" value="1099511627776"/>'),
    ("aa_samples", None, -(1 << 33), '<integer name="aa_samples" value="-8589934592"/>'),
    ("wavefront_size", None, "1e20", '<string name="wavefront_size" value="1e20"/>'),
]


def integrator_values(params) -> dict:
    return {key: np.array(params[key]).tolist() for key in params.keys()
            if key not in ("aa", "shadows")}


def integrator_scene(**settings):
    """A mirror ball before a lit wall and a lamp, rendered with a grid: a
    change of any setting changes the image."""
    lamp = {"type": "sphere", "center": [0, 1.5, 1], "radius": 0.2,
            "emitter": {"type": "area", "radiance": rgb(5, 5, 5)}}
    return mi.load_dict(scene(floor(), sphere((0, 0, 0), 0.7, {"type": "conductor"}), lamp,
                              point_light((2, 3, 4), 30.0), sensor=camera(size=16),
                              whitted=integrator(**{"aa": "grid", **settings})))


#: The valid update that follows each refused one.
VALID_MAX_DEPTH = 2


@functools.lru_cache(maxsize=None)
def loaded_with_valid_max_depth() -> np.ndarray:
    """The image of the integrator's scene loaded anew with the valid
    update: the same for every case, so rendered once."""
    return read_only(render(integrator_scene(max_depth=VALID_MAX_DEPTH)))


@pytest.mark.parametrize("parameter, bad, load_bad, xml", INTEGRATOR_CASES,
                         ids=[f"{case[0]}-{case[2]}" for case in INTEGRATOR_CASES])
def test_integrator_settings_are_checked_and_a_refused_update_changes_nothing(
        parameter, bad, load_bad, xml):
    with pytest.raises(ParameterError) as refused:
        integrator_scene(**{parameter: load_bad})
    assert_one_sentence(str(refused.value), "whitted", parameter, loading=True)
    with pytest.raises(ParameterError) as refused:
        mi.load_string(XML_SCENE.replace('<integrator type="whitted"/>',
                                         f'<integrator type="whitted">{xml}</integrator>')
                       .format(""))
    assert_one_sentence(str(refused.value), "whitted", parameter, loading=True)
    if bad is None:
        return

    loaded = integrator_scene()
    params = mi.traverse(loaded.integrator())
    values_before = integrator_values(params)
    image_before = render(loaded)
    params[parameter] = bad
    with pytest.raises(ParameterError) as refused:
        params.update()
    assert_one_sentence(str(refused.value), "whitted", parameter, loading=False)
    assert integrator_values(params) == values_before
    np.testing.assert_array_equal(render(loaded), image_before)

    params["max_depth"] = VALID_MAX_DEPTH
    params.update()
    updated = render(loaded)
    assert not np.array_equal(updated, image_before)
    np.testing.assert_array_equal(updated, loaded_with_valid_max_depth())


@pytest.mark.parametrize("text", ["2.5", "deep"])
def test_a_whole_number_setting_given_text_asks_for_a_whole_number(text):
    with pytest.raises(ParameterError) as refused:
        integrator_scene(max_depth=text)
    assert str(refused.value).startswith(
        f"whitted: parameter 'max_depth' must be a whole number (got '{text}')")


def test_integrator_modes_are_shown_but_not_updated():
    params = mi.traverse(integrator_scene().integrator())
    assert params["aa"] == "grid" and params["shadows"] == "physical"
    with pytest.raises(Exception, match="aa is a Read-Only parameter"):
        params["aa"] = "none"


def test_integrator_properties_load_an_integrator_that_renders_alike():
    loaded = integrator_scene(max_depth=3, ambient=0.1, aa_samples=3, aa_threshold=0.2)
    twin = mi.load_dict({"type": "whitted", **loaded.integrator().properties()})
    np.testing.assert_array_equal(np.array(mi.render(loaded, integrator=twin)), render(loaded))
    assert twin.properties() == loaded.integrator().properties()
