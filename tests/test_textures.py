"""The ``tartan``, ``sphere_map`` and ``planar_map`` textures against
independent oracles: the report's formulas evaluated in float64 numpy,
Mitsuba's own ``bitmap`` evaluated at the uv those formulas predict, and
Mitsuba's ``diffuse``, ``plastic``, ``path`` and ``direct`` plugins using the
textures. Also: finiteness at poles and seams, traversal, and errors."""

from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite
from mitsuba_whitted.errors import ParameterError

TEXTURES = Path(__file__).resolve().parent.parent / "textures"
LEMONS = str(TEXTURES / "lemons.png")
ELEPHANT = str(TEXTURES / "pink_elephant.png")

# Rec. 709 / sRGB relative luminance (the Y row of the RGB→XYZ matrix).
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])

# Float32 evaluation of inputs of magnitude <= 10: sin/asin/atan2 of arguments
# rounded to float32 (relative 6e-8) differ from float64 by ~1e-6 at most;
# 1e-5 leaves a margin of 10 and still catches any wrong term or sign.
ATOL = 1e-5

RNG_SEED = 363


@pytest.fixture(scope="module")
def uv_probe(variant):
    """A nested texture that returns its uv as the colour (u, v, 0): it lets
    the tests read the uv a mapping hands to its nested texture."""

    class UVProbe(mi.Texture):
        def __init__(self, props):
            mi.Texture.__init__(self, props)

        def eval(self, si, active=True):
            return mi.Color3f(si.uv.x, si.uv.y, 0.0)

        def mean(self):
            return mi.Float(0.25)

        def is_spatially_varying(self):
            return True

        def to_string(self):
            return "UVProbe[]"

    mi.register_texture("uv_probe", lambda props: UVProbe(props))
    return {"type": "uv_probe"}


def interaction(p, n=None, uv=(0.123, 0.456)):
    """A surface interaction at points ``p`` (N×3) with shading normals ``n``;
    uv is set to a value the mappings must replace."""
    p = np.asarray(p, dtype=np.float64)
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1)) if n is None else np.asarray(n, dtype=np.float64)
    si = dr.zeros(mi.SurfaceInteraction3f, len(p))
    si.p = mi.Point3f(*p.T)
    si.n = mi.Normal3f(*n.T)
    # Frame3f(n) would normalise; the tests need the raw vector (|n| != 1).
    si.sh_frame.n = mi.Normal3f(*n.T)
    si.uv = mi.Point2f(*np.broadcast_to(uv, (len(p), 2)).T)
    return si


def colors(texture, si):
    return np.array(texture.eval(si)).T.astype(np.float64)


def random_unit(rng, count):
    v = rng.normal(size=(count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def wrap_difference(a, b):
    """a − b on the circle of period 1 (uv at a seam may be 0 or 1)."""
    return (a - b + 0.5) % 1.0 - 0.5


# --- tartan ---

def tartan_reference(p, frequency, color, to_world=np.eye(4)):
    local = (np.linalg.inv(to_world) @ np.c_[p, np.ones(len(p))].T).T[:, :3]
    x, y, z = local.T
    in_square = (np.sin(frequency * x) > 0) & (np.cos(frequency * y) > 0)
    background = np.clip(np.sin(local), 0.0, 1.0)
    return np.where(in_square[:, None], np.asarray(color), background), local


@pytest.mark.parametrize("frequency, color, transform", [
    (3.0, None, None),
    (1.7, [0.2, 0.7, 0.4],
     lambda: mi.ScalarTransform4f().translate([0.3, -1, 2]).rotate([1, 2, 3], 40).scale([2, 1, 0.5])),
])
def test_tartan_matches_report_formula(frequency, color, transform):
    transform = transform and transform()  # built after the variant is set
    rng = np.random.default_rng(RNG_SEED)
    p = rng.uniform(-5, 5, size=(4000, 3))
    props = {"type": "tartan", "frequency": frequency}
    if color is not None:
        props["color"] = {"type": "rgb", "value": color}
    if transform is not None:
        props["to_world"] = transform
    texture = mi.load_dict(props)
    matrix = np.eye(4) if transform is None else np.array(transform.matrix, dtype=np.float64)
    expected, local = tartan_reference(p, frequency, color or [1.0, 0.5, 0.0], matrix)
    # Points within float32 rounding of a square's edge may fall either side.
    clear = ((np.abs(np.sin(frequency * local[:, 0])) > 1e-4)
             & (np.abs(np.cos(frequency * local[:, 1])) > 1e-4))
    si = interaction(p)
    rgb = colors(texture, si)
    assert np.abs(rgb - expected)[clear].max() < ATOL
    assert np.abs(np.array(texture.eval_3(si)).T - rgb).max() == 0
    assert np.abs(np.array(texture.eval_1(si)) - expected @ LUMINANCE)[clear].max() < ATOL
    # Both branches of the pattern are exercised.
    in_square = np.all(expected == np.asarray(color or [1.0, 0.5, 0.0]), axis=1)
    assert 0.1 < in_square.mean() < 0.5


def test_tartan_mean_is_the_spatial_average_at_the_default_frequency():
    """Oracle: the average of the report's formula over one period (2π)³,
    computed from 1D midpoint sums: the pattern factors into functions of x,
    y and z alone, E[A(x)B(y)·c + (1 − A(x)B(y))·s(·)]."""
    color = np.array([0.9, 0.3, 0.6])
    texture = mi.load_dict({"type": "tartan", "color": {"type": "rgb", "value": list(color)}})
    t = (np.arange(12000) + 0.5) * (2 * np.pi / 12000)  # grid aligned with every edge
    square_x, square_y = (np.sin(3 * t) > 0), (np.cos(3 * t) > 0)
    background = np.clip(np.sin(t), 0, 1)
    p_square = square_x.mean() * square_y.mean()
    channel = np.array([
        (square_x * background).mean() * square_y.mean(),
        square_x.mean() * (square_y * background).mean(),
        p_square * background.mean(),
    ])
    mean_rgb = p_square * color + background.mean() - channel
    # 1e-5: the midpoint sums are exact to ~1e-8; the rest is float32.
    assert abs(float(texture.mean()[0]) - mean_rgb @ LUMINANCE) < 1e-5


def test_tartan_traverse_updates_frequency_and_color():
    texture = mi.load_dict({"type": "tartan"})
    params = mi.traverse(texture)
    assert {"frequency", "color", "to_world"} <= set(params.keys())
    rng = np.random.default_rng(RNG_SEED)
    p = rng.uniform(-3, 3, size=(500, 3))
    si = interaction(p)
    params["frequency"] = 5.0
    params["color"] = mi.Color3f(0.1, 0.2, 0.9)
    params.update()
    expected, local = tartan_reference(p, 5.0, [0.1, 0.2, 0.9])
    clear = ((np.abs(np.sin(5 * local[:, 0])) > 1e-4) & (np.abs(np.cos(5 * local[:, 1])) > 1e-4))
    assert np.abs(colors(texture, si) - expected)[clear].max() < ATOL
    params["frequency"] = -1.0
    with pytest.raises(ValueError, match="tartan: parameter 'frequency'"):
        params.update()


# --- sphere_map ---

def sphere_uv_reference(n, mapping):
    """The report's formulas (float64) for unit directions n (N×3)."""
    nx, ny, nz = n.T
    v_asin = 0.5 - np.arcsin(ny) / np.pi
    if mapping == "asin":
        return np.c_[0.5 - np.arcsin(nx) / np.pi, v_asin]
    if mapping == "atan":
        return np.c_[0.5 + np.arctan2(ny, nx) / (2 * np.pi), v_asin]
    return np.c_[0.5 + np.arctan2(nx, nz) / (2 * np.pi), np.arccos(ny) / np.pi]


def probe_uv(texture, si):
    return colors(texture, si)[:, :2]


def assert_uv_close(uv, expected):
    # |n| <= 0.98 away from poles: asin' <= 5, so float32 inputs give < ATOL.
    error = np.abs(wrap_difference(uv, expected))
    assert error.max() < ATOL, error.max()


@pytest.mark.parametrize("mapping", ["asin", "atan", "equirect"])
def test_sphere_map_uv_from_normal(uv_probe, mapping):
    rng = np.random.default_rng(RNG_SEED)
    n = random_unit(rng, 2000)
    n = n[np.abs(n[:, 1]) < 0.98]  # poles are checked for finiteness below
    texture = mi.load_dict({"type": "sphere_map", "mapping": mapping, "texture": uv_probe})
    expected = sphere_uv_reference(n, mapping)
    assert_uv_close(probe_uv(texture, interaction(rng.normal(size=n.shape), n)), expected)
    # Normals of any length give the same uv (the direction is normalised).
    assert_uv_close(probe_uv(texture, interaction(np.zeros_like(n), 3.5 * n)), expected)


def test_sphere_map_default_mapping_is_the_reports_asin(uv_probe):
    rng = np.random.default_rng(RNG_SEED)
    n = random_unit(rng, 200)
    n = n[np.abs(n[:, 1]) < 0.98]
    texture = mi.load_dict({"type": "sphere_map", "texture": uv_probe})
    assert_uv_close(probe_uv(texture, interaction(np.zeros_like(n), n)),
                    sphere_uv_reference(n, "asin"))


def test_sphere_map_center_and_to_world(uv_probe):
    """With ``center`` the direction is p − center (the normal is ignored);
    ``to_world`` rotates the mapping frame (directions map by its inverse)."""
    rng = np.random.default_rng(RNG_SEED)
    center = np.array([1.0, -2.0, 0.5])
    d = random_unit(rng, 1000)
    axis = np.array([0.3, 1, -0.2]) / np.linalg.norm([0.3, 1, -0.2])
    rotation = mi.ScalarTransform4f().rotate(axis.tolist(), 70)
    local = d @ np.linalg.inv(np.array(rotation.matrix, dtype=np.float64)[:3, :3]).T
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    keep = np.abs(local[:, 1]) < 0.98
    d, local = d[keep], local[keep]
    texture = mi.load_dict({"type": "sphere_map", "mapping": "equirect", "texture": uv_probe,
                            "center": center.tolist(), "to_world": rotation})
    si = interaction(center + 2.5 * d, random_unit(rng, len(d)))
    assert_uv_close(probe_uv(texture, si), sphere_uv_reference(local, "equirect"))


def hard_directions():
    """Poles, seams, lengths 1 ± 1e-6, zero, subnormal and huge vectors."""
    eps = 1e-6
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    seams = np.array([[-1, 1e-30, 0], [-1, -1e-30, 0], [-1, 0, -0.0], [0, 1e-30, -1],
                      [-0.0, 0, -1], [1e-7, 1, 0], [0, 1, -1e-7]], float)
    diagonal = np.full((1, 3), 1 / np.sqrt(3))
    return np.vstack([axes, axes * (1 + eps), axes * (1 - eps), seams, diagonal * (1 + eps),
                      np.zeros((1, 3)), np.full((1, 3), 1e-30), np.full((1, 3), 1e30)])


@pytest.mark.parametrize("mapping", ["asin", "atan", "equirect"])
def test_sphere_map_is_finite_at_poles_seams_and_degenerate_normals(uv_probe, mapping):
    n = hard_directions()
    texture = mi.load_dict({"type": "sphere_map", "mapping": mapping, "texture": uv_probe})
    uv = probe_uv(texture, interaction(np.zeros_like(n), n))
    assert_finite(uv)
    assert (uv >= 0).all() and (uv <= 1).all()
    # The exact axes have closed-form uv; the zero vector maps to the centre.
    unit = np.abs(np.linalg.norm(n, axis=1) - 1) < 1e-5
    assert np.abs(wrap_difference(uv[unit][:6], sphere_uv_reference(n[unit][:6], mapping))).max() < ATOL
    assert np.allclose(uv[-3], [0.5, 0.5])
    # Directions far too short or long to square in float32 keep their uv
    # (checked away from the poles, where one ulp of n moves uv by ~1e-4).
    generic = random_unit(np.random.default_rng(RNG_SEED), 100)
    generic = generic[np.abs(generic).max(axis=1) < 0.98]
    expected = sphere_uv_reference(generic, mapping)
    for scale in (1e-25, 1e25):
        assert_uv_close(probe_uv(texture, interaction(np.zeros_like(generic), scale * generic)),
                        expected)
    # A surface point exactly at the centre is the zero direction too.
    centred = mi.load_dict({"type": "sphere_map", "mapping": mapping, "texture": uv_probe,
                            "center": [1.0, 2.0, 3.0]})
    assert np.allclose(probe_uv(centred, interaction([[1.0, 2.0, 3.0]])), [[0.5, 0.5]])


def test_sphere_map_nested_bitmap_equals_bitmap_at_predicted_uv():
    """Oracle: Mitsuba's ``bitmap`` evaluated directly at the uv predicted by
    the float64 formula (the lemons image, sRGB decoded and bilinear)."""
    rng = np.random.default_rng(RNG_SEED)
    n = random_unit(rng, 1000)
    n = n[np.abs(n[:, 1]) < 0.98]
    bitmap = mi.load_dict({"type": "bitmap", "filename": LEMONS})
    for mapping in ("asin", "atan", "equirect"):
        texture = mi.load_dict({"type": "sphere_map", "mapping": mapping,
                                "texture": {"type": "bitmap", "filename": LEMONS}})
        si = interaction(np.zeros_like(n), n)
        direct = interaction(np.zeros_like(n), n, uv=sphere_uv_reference(n, mapping))
        # A uv error of ATOL moves 512·ATOL = 0.005 texel; bilinear values
        # then change by at most 0.005 × the largest texel step (< 1).
        assert np.abs(colors(texture, si) - colors(bitmap, direct)).max() < 512 * ATOL
        assert abs(float(texture.mean()[0]) - float(bitmap.mean()[0])) == 0


# --- planar_map ---

BOUNDS = {"x_min": -3.0, "x_max": 5.0, "z_min": -8.0, "z_max": -2.0}


def planar_uv_reference(p, b=BOUNDS):
    return np.c_[(p[:, 0] - b["x_min"]) / (b["x_max"] - b["x_min"]),
                 (p[:, 2] - b["z_min"]) / (b["z_min"] - b["z_max"])]


def test_planar_map_uv_is_the_reports_formula(uv_probe):
    rng = np.random.default_rng(RNG_SEED)
    p = rng.uniform([-6, -1, -10], [8, 1, 0], size=(2000, 3))  # inside and outside
    texture = mi.load_dict({"type": "planar_map", "texture": uv_probe, **BOUNDS})
    uv = probe_uv(texture, interaction(p))
    assert np.abs(uv - planar_uv_reference(p)).max() < ATOL


def test_planar_map_default_bounds_span_the_unit_rectangle(uv_probe):
    texture = mi.load_dict({"type": "planar_map", "texture": uv_probe})
    p = np.array([[-1.0, 0, -1.0], [1.0, 0, 1.0], [0.5, 7, -0.25]])
    unit = {"x_min": -1.0, "x_max": 1.0, "z_min": -1.0, "z_max": 1.0}
    assert np.abs(probe_uv(texture, interaction(p)) - planar_uv_reference(p, unit)).max() < ATOL


def test_planar_map_puts_the_images_top_row_at_z_max(tmp_path):
    """The documented orientation: a 2×2 image (top row red, green; bottom
    row blue, white) lies with its top edge along z_max, left edge at x_min."""
    path = tmp_path / "quadrants.exr"
    quadrants = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], dtype=np.float32)
    mi.Bitmap(quadrants).write(str(path))
    nested = {"type": "bitmap", "filename": str(path), "filter_type": "nearest", "raw": True}
    bitmap = mi.load_dict(nested)
    texture = mi.load_dict({"type": "planar_map", "texture": nested, **BOUNDS})
    margin = 0.1
    corners = np.array([
        [BOUNDS["x_min"] + margin, 0, BOUNDS["z_max"] - margin],
        [BOUNDS["x_max"] - margin, 0, BOUNDS["z_max"] - margin],
        [BOUNDS["x_min"] + margin, 0, BOUNDS["z_min"] + margin],
        [BOUNDS["x_max"] - margin, 0, BOUNDS["z_min"] + margin],
    ])
    # The bitmap itself: uv (0.25, 0.25) is the first (top) row of the array.
    top_left = colors(bitmap, interaction(corners[:1], uv=(0.25, 0.25)))
    assert np.array_equal(top_left, [[1, 0, 0]])
    assert np.array_equal(colors(texture, interaction(corners)), quadrants.reshape(4, 3))


def test_planar_map_nested_bitmap_equals_bitmap_at_predicted_uv():
    rng = np.random.default_rng(RNG_SEED)
    p = rng.uniform([-3, 0, -8], [5, 0, -2], size=(1000, 3))
    nested = {"type": "bitmap", "filename": ELEPHANT}
    texture = mi.load_dict({"type": "planar_map", "texture": nested, **BOUNDS})
    bitmap = mi.load_dict(nested)
    direct = interaction(p, uv=planar_uv_reference(p))
    assert np.abs(colors(texture, interaction(p)) - colors(bitmap, direct)).max() < 512 * ATOL
    assert np.abs(np.array(texture.eval_1(interaction(p))) - np.array(bitmap.eval_1(direct))).max() \
        < 512 * ATOL


def test_mapping_traverse_exposes_nested_texture_and_updates(uv_probe):
    texture = mi.load_dict({"type": "planar_map", "texture": {"type": "bitmap", "filename": LEMONS},
                            **BOUNDS})
    params = mi.traverse(texture)
    assert {"texture.data", "x_min", "x_max", "z_min", "z_max"} <= set(params.keys())
    probe = mi.load_dict({"type": "planar_map", "texture": uv_probe, **BOUNDS})
    params = mi.traverse(probe)
    params["x_max"] = 13.0
    params.update()
    p = np.array([[0.0, 0.0, -5.0], [4.0, 1.0, -3.0]])
    assert np.abs(probe_uv(probe, interaction(p)) - planar_uv_reference(p, {**BOUNDS, "x_max": 13.0})
                  ).max() < ATOL
    params["z_max"] = -9.0
    with pytest.raises(ValueError, match="planar_map: parameter 'z_max'"):
        params.update()
    sphere = mi.load_dict({"type": "sphere_map", "texture": {"type": "bitmap", "filename": LEMONS},
                           "center": [0, 0, 0]})
    assert {"texture.data", "center", "to_world"} <= set(mi.traverse(sphere).keys())


# --- inside Mitsuba's BSDFs and integrators ---

def texture_cases():
    return {
        "tartan": {"type": "tartan"},
        "sphere_map": {"type": "sphere_map", "texture": {"type": "bitmap", "filename": LEMONS}},
        "planar_map": {"type": "planar_map", "texture": {"type": "bitmap", "filename": ELEPHANT}},
    }


XML_CASES = {
    "tartan": '<texture type="tartan" name="{slot}"><float name="frequency" value="4"/>'
              '<rgb name="color" value="0.9, 0.4, 0.1"/></texture>',
    "sphere_map": '<texture type="sphere_map" name="{slot}"><string name="mapping" value="atan"/>'
                  '<texture type="bitmap" name="texture"><string name="filename" value="' + LEMONS
                  + '"/></texture></texture>',
    "planar_map": '<texture type="planar_map" name="{slot}"><float name="x_min" value="-2"/>'
                  '<texture type="bitmap" name="texture"><string name="filename" value="' + ELEPHANT
                  + '"/></texture></texture>',
}


@pytest.mark.parametrize("name", sorted(XML_CASES))
def test_diffuse_plastic_and_phong_use_the_texture_from_xml_and_dict(name):
    """Oracle: the BSDF's own albedo lookup must return the texture's value
    at the same interaction, and ``diffuse`` must evaluate to albedo·cosθ/π."""
    rng = np.random.default_rng(RNG_SEED)
    n = random_unit(rng, 200)
    si = interaction(rng.uniform(-2, 2, size=(200, 3)), n)
    si.sh_frame = mi.Frame3f(si.sh_frame.n)
    si.wi = mi.Vector3f(0, 0, 1)
    wo = mi.Vector3f(0.6, 0, 0.8)
    for bsdf_type, slot in (("diffuse", "reflectance"), ("plastic", "diffuse_reflectance"),
                            ("phong", "diffuse_reflectance")):
        from_xml = mi.load_string(f'<bsdf version="3.0.0" type="{bsdf_type}">'
                                  + XML_CASES[name].format(slot=slot) + '</bsdf>')
        from_dict = mi.load_dict({"type": bsdf_type, slot: texture_cases()[name]})
        for bsdf in (from_xml, from_dict):
            texture = mi.traverse(bsdf)  # the nested texture is exposed under the slot
            assert any(key.startswith(slot + ".") for key in texture.keys())
            albedo = np.array(bsdf.eval_diffuse_reflectance(si)).T
            assert_finite(albedo)
            assert albedo.max() > 0
            value = np.array(bsdf.eval(mi.BSDFContext(), si, wo)).T
            assert_finite(value)
            if bsdf_type == "diffuse":
                assert np.abs(value - albedo * 0.8 / np.pi).max() < 1e-6
        own = mi.load_dict(texture_cases()[name])
        assert np.abs(np.array(from_dict.eval_diffuse_reflectance(si)).T
                      - colors(own, si)).max() == 0


def textured_sphere_scene(texture, integrator):
    ground = (mi.ScalarTransform4f().translate([0, -1, 0]).rotate([1, 0, 0], -90).scale(3))
    return mi.load_dict({
        "type": "scene",
        "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 45,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1, 4], target=[0, 0, 0],
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 32, "height": 32}},
        "light": {"type": "point", "position": [2, 3, 3], "intensity": {"type": "rgb", "value": 30}},
        "ball": {"type": "sphere", "radius": 1, "bsdf": {"type": "diffuse", "reflectance": texture}},
        "second": {"type": "sphere", "radius": 0.4, "center": [1.4, -0.6, 0.5],
                   "bsdf": {"type": "phong", "diffuse_reflectance": texture}},
        "ground": {"type": "rectangle", "to_world": ground,
                   "bsdf": {"type": "plastic", "diffuse_reflectance": texture}},
    })


@pytest.mark.parametrize("texture", [
    {"type": "tartan", "frequency": 6.0},
    {"type": "sphere_map", "texture": {"type": "bitmap", "filename": LEMONS}}])
def test_whitted_replay_follows_a_to_world_update(texture):
    """The kernels read the inverse placement, not ``to_world`` itself: after
    an update through ``mi.traverse``, the integrator's replayed kernels must
    render what kernels recorded anew for the updated scene render."""
    def rotated(scene):
        params = mi.traverse(scene)
        keys = [k for k in params.keys() if ".bsdf." in k and k.endswith(".to_world")]
        assert keys, "the texture's to_world must be exposed"
        for key in keys:
            params[key] = mi.AffineTransform4f(
                mi.ScalarTransform4f().rotate([0, 1, 0], 50).rotate([1, 0, 0], 20))
        params.update()
        return scene

    def load():
        return textured_sphere_scene(texture, {"type": "whitted", "max_depth": 3})

    loaded = load()
    before = np.array(mi.render(loaded))
    mi.render(loaded)  # the second render records the kernels once more
    replayed = np.array(mi.render(rotated(loaded)))
    recorded_anew = np.array(mi.render(rotated(load())))
    assert not np.allclose(before, recorded_anew, atol=1e-2), "the rotation must show"
    np.testing.assert_array_equal(replayed, recorded_anew)


@pytest.mark.parametrize("name", sorted(XML_CASES))
def test_path_and_direct_render_textured_scene_without_nan(name):
    for integrator in ({"type": "path", "max_depth": 4}, {"type": "direct"}):
        scene = textured_sphere_scene(texture_cases()[name], integrator)
        image = np.array(mi.render(scene, spp=4, seed=1))
        assert_finite(image)
        assert image.mean() > 0.01  # the lit, textured objects are visible


# --- bad parameters ---

BITMAP = {"type": "bitmap", "filename": LEMONS}


@pytest.mark.parametrize("props, message", [
    ({"type": "tartan", "frequency": 0.0}, "tartan: parameter 'frequency'"),
    ({"type": "tartan", "frequency": -3.0}, "tartan: parameter 'frequency'"),
    ({"type": "tartan", "to_world": lambda: mi.ScalarTransform4f().scale([1, 0, 1])},
     "tartan: parameter 'to_world'"),
    ({"type": "sphere_map", "mapping": "polar", "texture": BITMAP},
     "sphere_map: parameter 'mapping'"),
    ({"type": "sphere_map"}, "sphere_map: parameter 'texture'"),
    ({"type": "planar_map"}, "planar_map: parameter 'texture'"),
    ({"type": "planar_map", "texture": BITMAP, "x_min": 2.0, "x_max": 2.0},
     "planar_map: parameter 'x_max'"),
    ({"type": "planar_map", "texture": BITMAP, "z_min": 1.0, "z_max": -1.0},
     "planar_map: parameter 'z_max'"),
])
def test_bad_parameters_raise_one_clear_error(props, message):
    # Transforms are built here, after the variant is set.
    props = {key: value() if callable(value) else value for key, value in props.items()}
    with pytest.raises(ParameterError, match=f"^{message}.*, at dictionary node"):
        mi.load_dict(props)


def test_a_missing_image_is_mitsubas_own_error_naming_the_file():
    with pytest.raises(RuntimeError, match="no_such_lemons.png"):
        mi.load_dict({"type": "sphere_map",
                      "texture": {"type": "bitmap", "filename": "no_such_lemons.png"}})


PLANAR_XML = ('<texture version="3.0.0" type="planar_map">{}'
              f'<texture type="bitmap" name="texture"><string name="filename" value="{LEMONS}"/>'
              '</texture></texture>')


def planar_bounds_xml(bounds: dict) -> str:
    return PLANAR_XML.format("".join(f'<float name="{name}" value="{value!r}"/>'
                                     for name, value in bounds.items()))


#: Bounds whose span float32 cannot resolve where it lies: the report's,
#: and spans below 1e-6 of their position (at least 1) elsewhere.
UNRESOLVABLE_SPANS = [
    {"x_min": -1e-30, "x_max": 1e-30},
    {"z_min": 0.0, "z_max": 5e-7},
    {"x_min": 1e6, "x_max": 1e6 + 0.5},
    {"z_min": -3e8, "z_max": -3e8 + 256.0},
]


@pytest.mark.parametrize("bounds", UNRESOLVABLE_SPANS, ids=lambda b: "-".join(map(repr, b.values())))
def test_planar_map_refuses_a_span_float32_cannot_resolve_where_it_lies(bounds):
    axis = next(iter(bounds))[0]
    with pytest.raises(ParameterError) as refused:
        mi.load_string(planar_bounds_xml(bounds))
    sentence = str(refused.value)
    assert sentence.startswith(f"planar_map: parameter '{axis}_max' must be "
                               f"greater than {axis}_min by at least "), sentence


@pytest.mark.parametrize("bounds", UNRESOLVABLE_SPANS, ids=lambda b: "-".join(map(repr, b.values())))
def test_planar_map_refuses_such_a_span_in_an_update_and_keeps_its_bounds(bounds, uv_probe):
    """Through ``mi.traverse``, the bounds written in any order: refused,
    and the texture maps as before, read back with the old bounds."""
    texture = mi.load_dict({"type": "planar_map", "texture": uv_probe, **BOUNDS})
    p = np.random.default_rng(RNG_SEED).uniform([-6, -1, -10], [8, 1, 0], size=(64, 3))
    before = probe_uv(texture, interaction(p))
    params = mi.traverse(texture)
    for name, value in bounds.items():
        params[name] = value
    with pytest.raises(ParameterError, match=f"planar_map: parameter '{next(iter(bounds))[0]}_m"):
        params.update()
    assert {name: params[name][0] for name in BOUNDS} == BOUNDS
    np.testing.assert_array_equal(probe_uv(texture, interaction(p)), before)


def test_planar_map_maps_a_span_just_above_its_resolution_as_float64_does(uv_probe):
    """Far from the origin, a span of 2^-22 of its position (four times the
    least): uv as the formula gives them in float64 from the same float32
    points, to the rounding of one subtraction there."""
    bounds = {"x_min": 1e6, "x_max": 1e6 + 4.0, "z_min": -1.0, "z_max": 1.0}
    texture = mi.load_dict({"type": "planar_map", "texture": uv_probe, **bounds})
    x = np.float32(1e6) + np.arange(0, 4.25, 0.25, dtype=np.float32)
    p = np.c_[x, np.zeros_like(x), np.zeros_like(x)]
    uv = probe_uv(texture, interaction(p))
    np.testing.assert_allclose(uv[:, 0], planar_uv_reference(p, bounds)[:, 0], atol=1e-6)


def test_bad_parameter_from_xml_names_plugin_and_parameter():
    xml = ('<texture version="3.0.0" type="sphere_map"><string name="mapping" value="cube"/>'
           '<rgb name="texture" value="0.5"/></texture>')
    with pytest.raises(ParameterError, match="^sphere_map: parameter 'mapping'.*, at string"):
        mi.load_string(xml)
