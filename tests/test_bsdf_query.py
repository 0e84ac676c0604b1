"""One dispatch per hit (``bsdf_query``) against each BSDF asked on its own."""

import drjit as dr
import mitsuba as mi
import numpy as np

from validation.scenes import camera, diffuse, rgb, scene, sphere
from mitsuba_whitted.integrators.bsdf_query import (KIND_CODES, BsdfQuery, has_delta_lobe,
                                                    query_bsdf)

#: Two local light directions, both above the surface.
DIRECTIONS = ((0.3, 0.2, 0.9), (-0.5, 0.1, 0.8))
COMPONENTS = (("delta", 0), ("delta", 1), ("null", None))
SIZE = 128

BSDFS = {
    "phong": {"type": "phong", "diffuse_reflectance": {"type": "checkerboard"},
              "specular_reflectance": rgb(0.3, 0.3, 0.3)},
    "glass": {"type": "dielectric"},
    "mirror": {"type": "conductor"},
    "blend": {"type": "blendbsdf", "weight": 0.4,
              "a": {"type": "phong"}, "b": {"type": "conductor"}},
    "mask": {"type": "mask", "opacity": 0.3, "bsdf": diffuse(0.2, 0.7, 0.4)},
    "thin": {"type": "thindielectric"},
    "rough": {"type": "roughconductor", "alpha": 0.2},
}


def _scene():
    """The BSDFs on spheres side by side, filling most of the view."""
    spheres = [sphere((1.1 * (i - 3), 0, 0), 0.55, bsdf) for i, bsdf in enumerate(BSDFS.values())]
    return mi.load_dict(scene(*spheres, sensor=camera(origin=(0, 0, 7), fov=65, size=SIZE)))


def _hits(loaded):
    sensor = loaded.sensors()[0]
    index = dr.arange(mi.UInt32, SIZE * SIZE)
    position = mi.Point2f(mi.Float(index % SIZE) + 0.5, mi.Float(index // SIZE) + 0.5) / SIZE
    ray, _ = sensor.sample_ray(0, 0.5, position, mi.Point2f(0.5))
    return ray, loaded.ray_intersect(ray)


def _directions():
    return [dr.normalize(mi.Vector3f(*d)) for d in DIRECTIONS]


def _expected(bsdf, si, lanes):
    """The same answers, asked of one BSDF object method by method."""
    si = dr.gather(mi.SurfaceInteraction3f, si, lanes)
    flags = bsdf.flags()
    albedo = (bsdf.eval_diffuse_reflectance(si) if mi.has_flag(flags, mi.BSDFFlags.Diffuse)
              else mi.Color3f(0))
    values = [bsdf.eval(mi.BSDFContext(), si, wo) if mi.has_flag(flags, mi.BSDFFlags.Smooth)
              else mi.Color3f(0) for wo in _directions()]
    children = []
    for kind, component in COMPONENTS:
        if kind == "null":
            has = mi.has_flag(flags, mi.BSDFFlags.Null)
            weight = bsdf.eval_null_transmission(si) if has else mi.Color3f(0)
            children.append((weight, has and dr.any(weight > 0)))
            continue
        if not has_delta_lobe(bsdf, component):
            children.append((mi.Color3f(0), False))
            continue
        ctx = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Delta, component)
        bs, weight = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5))
        children.append((weight, (bs.pdf > 0) & dr.any(weight > 0)))
    return albedo, values, children


def _close(actual, lanes, expected):
    actual = np.array(dr.gather(type(actual), actual, lanes))
    np.testing.assert_allclose(actual, np.broadcast_to(np.array(expected), actual.shape),
                               rtol=1e-6, atol=1e-7)


def test_one_dispatch_answers_as_each_method_does():
    loaded = _scene()
    ray, si = _hits(loaded)
    query = BsdfQuery(albedo=True, components=COMPONENTS)
    terms = query_bsdf(si.bsdf(ray), si, query, _directions(), si.is_valid())
    shape_of = np.array(dr.reinterpret_array(mi.UInt32, si.shape))
    checked = set()
    for shape in loaded.shapes():
        lanes = np.nonzero(shape_of == dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])[0]
        assert len(lanes) > 100, "every BSDF must be seen by many lanes"
        lanes = mi.UInt32(lanes)
        albedo, values, children = _expected(shape.bsdf(), si, lanes)
        _close(terms.albedo, lanes, albedo)
        for value, wanted in zip(terms.values, values):
            _close(value, lanes, wanted)
        for child, (weight, ok) in zip(terms.children, children):
            ok_lanes = np.array(dr.gather(mi.Bool, child.ok, lanes))
            assert (ok_lanes == np.broadcast_to(np.array(ok), ok_lanes.shape)).all()
            _close(child.weight, lanes, weight)
        checked.add(shape.bsdf().class_name())
    assert len(checked) == len(BSDFS)


def test_children_carry_their_kind_and_only_where_the_lobe_exists():
    loaded = _scene()
    ray, si = _hits(loaded)
    query = BsdfQuery(albedo=False, components=COMPONENTS)
    terms = query_bsdf(si.bsdf(ray), si, query, [], si.is_valid())
    reflection, refraction, passthrough = terms.children
    codes = {name: np.unique(np.array(child.code)[np.array(child.ok)])
             for name, child in (("reflection", reflection), ("refraction", refraction),
                                 ("passthrough", passthrough))}
    assert list(codes["reflection"]) == [KIND_CODES["reflection"]]
    assert list(codes["refraction"]) == [KIND_CODES["refraction"]]
    assert list(codes["passthrough"]) == [KIND_CODES["passthrough"]]
    # Misses have no BSDF and get nothing.
    missed = ~np.array(si.is_valid())
    assert missed.any()
    for child in terms.children:
        assert not np.array(child.ok)[missed].any()


def test_an_empty_query_calls_nothing():
    loaded = _scene()
    ray, si = _hits(loaded)
    terms = query_bsdf(si.bsdf(ray), si, BsdfQuery(False, ()), [], si.is_valid())
    assert terms.values == [] and terms.children == []
