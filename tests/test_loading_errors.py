"""Errors of Mitsuba's scene loaders from Python: a parameter that a
plugin of this package refuses reaches the user who catches it as the
package's own exception, its sentence in ``str(error)`` on one line with
where the loader found the plugin, not as the loader's ``RuntimeError``
around the plugin's traceback. Mitsuba's own plugins' errors pass as
Mitsuba raises them.

Oracles: the plugins' sentences as their checks word them, and Mitsuba's
errors from the loaders with the package's wrapper taken away."""

import subprocess
import sys

import mitsuba as mi
import pytest

from mitsuba_whitted.errors import ParameterError


def textured(texture: dict) -> dict:
    return {"type": "sphere", "bsdf": {"type": "diffuse", "reflectance": texture}}


#: A refused parameter of an integrator, a texture and a shape of the
#: package: the plugin in a scene dictionary, in XML, the parameter, the
#: start of its sentence and the dictionary node it is at.
REFUSALS = {
    "integrator": (
        {"type": "whitted", "max_depth": -7},
        '<integrator type="whitted"><integer name="max_depth" value="-7"/></integrator>',
        "max_depth", "whitted: parameter 'max_depth' must be", "refused"),
    "texture": (
        textured({"type": "tartan", "frequency": float("inf")}),
        '<shape type="sphere"><bsdf type="diffuse"><texture type="tartan" name="reflectance">'
        '<float name="frequency" value="inf"/></texture></bsdf></shape>',
        "frequency", "tartan: parameter 'frequency' must be", "refused.bsdf.reflectance"),
    "shape": (
        {"type": "capped_cylinder", "radius": -1.0},
        '<shape type="capped_cylinder"><float name="radius" value="-1"/></shape>',
        "radius", "capped_cylinder: parameter 'radius' must be", "refused"),
}


def assert_one_sentence(error: BaseException, parameter: str, start: str, where: str) -> None:
    text = str(error)
    assert type(error) is ParameterError and error.parameter == parameter, repr(error)
    assert text.startswith(start) and text[text.rfind(", at "):].startswith(where), text
    assert "\n" not in text and "Traceback" not in text, text
    assert error.__cause__ is None and error.__suppress_context__


@pytest.mark.parametrize("kind", REFUSALS)
def test_load_dict_raises_the_plugins_sentence(kind):
    plugin, _, parameter, start, node = REFUSALS[kind]
    with pytest.raises(ParameterError) as refused:
        mi.load_dict({"type": "scene", "refused": plugin})
    assert_one_sentence(refused.value, parameter, start, f', at dictionary node "{node}"')


@pytest.mark.parametrize("kind", REFUSALS)
def test_load_string_and_load_file_raise_the_plugins_sentence(kind, tmp_path):
    _, xml, parameter, start, _ = REFUSALS[kind]
    text = f'<scene version="3.0.0">{xml}</scene>'
    with pytest.raises(ParameterError) as refused:
        mi.load_string(text)
    assert_one_sentence(refused.value, parameter, start, ", at string (line 1, col ")
    path = tmp_path / "Refused scene.xml"
    path.write_text(text)
    with pytest.raises(ParameterError) as refused:
        mi.load_file(str(path))
    assert_one_sentence(refused.value, parameter, start, f", at {path} (line 1, col ")


def test_the_sentence_is_the_plugins_own_with_its_place():
    with pytest.raises(ParameterError) as refused:
        mi.load_dict(REFUSALS["integrator"][0])
    assert str(refused.value) == ("whitted: parameter 'max_depth' must be -1 (unbounded) or >= 0 "
                                  "(got -7), at dictionary node \"root\"")


@pytest.mark.parametrize("loader, description", [
    ("load_dict", {"type": "scene", "s": {"type": "sphere", "radius": "one"}}),
    ("load_string", '<scene version="3.0.0"><shape type="no_such_plugin"/></scene>'),
    ("load_dict", {"type": "scene", "i": {"type": "whitted", "no_such_parameter": 1}}),
], ids=["wrong type", "unknown plugin", "unused parameter"])
def test_mitsubas_own_errors_pass_unchanged(loader, description):
    checked = getattr(mi, loader)
    with pytest.raises(RuntimeError) as through_the_package:
        checked(description)
    with pytest.raises(RuntimeError) as mitsubas:
        checked.__wrapped__(description)
    assert type(through_the_package.value) is type(mitsubas.value) is RuntimeError
    assert str(through_the_package.value) == str(mitsubas.value)


#: A scene dictionary with ``None`` for a value, which Mitsuba 3.9.1's
#: load_dict ends the interpreter on, for its plugins as for the package's.
NONE_INSIDE = {"type": "scene", "ball": textured({"type": "tartan", "color": None})}


def test_a_none_value_is_refused_naming_its_plugin_key_and_node():
    with pytest.raises(ParameterError) as refused:
        mi.load_dict(NONE_INSIDE)
    assert str(refused.value) == ("tartan: parameter 'color' is None: give it a value or leave "
                                  'it out, at dictionary node "ball.bsdf.reflectance"')
    with pytest.raises(ParameterError, match="^diffuse: parameter 'reflectance' is None"):
        mi.load_dict(dict={"type": "diffuse", "reflectance": None})


def test_a_none_value_does_not_end_the_interpreter():
    """In a process of its own: without the check, Mitsuba's loader dies
    of a segmentation fault there (the oracle: the same call on Mitsuba's
    own load_dict, taken from under the package's wrapper)."""
    call = ("import mitsuba as mi; mi.set_variant(%r); import mitsuba_whitted\n"
            "try:\n    LOAD(%r)\nexcept ValueError as e:\n    print(e)\n") % (mi.variant(), NONE_INSIDE)
    checked = subprocess.run([sys.executable, "-c", call.replace("LOAD", "mi.load_dict")],
                             capture_output=True, text=True, timeout=120)
    assert checked.returncode == 0, checked.stderr
    assert checked.stdout.startswith("tartan: parameter 'color' is None")
    bare = subprocess.run([sys.executable, "-c", call.replace("LOAD", "mi.load_dict.__wrapped__")],
                          capture_output=True, text=True, timeout=120)
    assert bare.returncode < 0


def test_a_sentence_of_the_package_ends_once_before_its_place():
    """A refusal that is not a parameter's (a variant without RGB) keeps its
    sentence and its place in one sentence, without a full stop between."""
    scene = '<scene version="3.0.0"><integrator type="whitted"/></scene>'
    variant = mi.variant()
    try:
        mi.set_variant("llvm_ad_mono")
        with pytest.raises(Exception) as refused:
            mi.load_string(scene)
    finally:
        mi.set_variant(variant)
    assert str(refused.value).startswith("whitted: only RGB variants are supported")
    assert "'cuda_ad_rgb', at string" in str(refused.value)
