"""The capped cylinder: exact intersection against a float64 reference, and
the proxy mesh against geometry facts and Mitsuba's built-in shapes.

Tolerances (canonical space, where the cylinder has radius 1 and height 1):

- ``BAND``: a ray may be classified hit/miss differently from the reference
  only when some decision of the reference lies within
  ``BAND * (1 + max|o|)`` of its threshold (``margin`` of the oracle,
  ``validation/oracles/cylinder.py``). The solve runs in float64: its
  decisions err by ~1e-16 relative to the origin's size; 1e-12 leaves a
  factor 1e4 of room and is 6e4 times below the float32 spacing of the
  origin, so no ray that float32 inputs can tell apart from the threshold
  may disagree.
- ``T_RELATIVE``: returned ``t`` is float32; rounding alone is 6e-8
  relative. 1e-6 allows 16 ulp. A float32 solve fails this (4e-6 near
  tangency), so it checks the precision choice.
- ``POINT_ERROR``: the re-projected point is float32 at unit scale (6e-8);
  1e-6 again. A float32 solve is off by 2e-3 for origins 1e4 away.
- ``NORMAL_ERROR``: float32 normals of a float32 point: 1e-5 is 100 ulp.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from conftest import address, assert_finite
from mitsuba_whitted.errors import ParameterError
from mitsuba_whitted.geometry import cylinder
from mitsuba_whitted.jit import ALIGNMENT
from mitsuba_whitted.shapes import capped_cylinder
from validation.oracles import cylinder as reference
from validation.scenes import builtin_cylinder

BAND = 1e-12
T_RELATIVE = 1e-6
POINT_ERROR = 1e-6
NORMAL_ERROR = 1e-5

RNG_SEED = 20170101


# --------------------------------------------------------------------------
# Ray sets (canonical space, float32 like the renderer's rays)
# --------------------------------------------------------------------------

def unit_vectors(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def aimed(rng, origins, lo=(-1.2, -0.2, -1.2), hi=(1.2, 1.2, 1.2)):
    """Directions from ``origins`` to random points of a box around the solid."""
    d = rng.uniform(lo, hi, origins.shape) - origins
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def random_lengths(rng, n):
    """Direction lengths from 1e-2 to 1e2: t must not assume unit rays."""
    return 10.0 ** rng.uniform(-2, 2, (n, 1))


def near_rays(rng, n):
    o = rng.uniform(-3, 3, (n, 3))
    d = np.concatenate([unit_vectors(rng, n // 2), aimed(rng, o[n // 2:])])
    return o, d * random_lengths(rng, n)


def far_rays(rng, n, distance):
    o = unit_vectors(rng, n) * distance + [0, 0.5, 0]
    return o, aimed(rng, o, (-1.5, -0.5, -1.5), (1.5, 1.5, 1.5))


def circle_points(rng, n, y):
    angle = rng.uniform(0, 2 * np.pi, n)
    return np.stack([np.cos(angle), y, np.sin(angle)], 1), angle


def parallel_rays(rng, n):
    """d = (0, +-s, 0): inside, outside and exactly on the radius."""
    radius = np.concatenate([rng.uniform(0, 0.999, n // 3), rng.uniform(1.001, 2, n // 3),
                             np.ones(n - 2 * (n // 3))])
    o, _ = circle_points(rng, n, rng.uniform(-2, 3, n))
    o[:, [0, 2]] *= radius[:, None]
    o[:4, [0, 2]] = [[1, 0], [-1, 0], [0, 1], [0, -1]]  # exactly representable rim
    d = np.zeros((n, 3))
    d[:, 1] = rng.choice([-1, 1], n) * random_lengths(rng, n)[:, 0]
    return o, d


def cap_plane_rays(rng, n):
    """Rays lying in y = 0 or y = 1."""
    o = rng.uniform(-3, 3, (n, 3))
    o[:, 1] = rng.choice([0.0, 1.0], n)
    d = unit_vectors(rng, n)
    d[:, 1] = 0
    return o, d


def tangent_rays(rng, n):
    """Lines touching the side: tangent direction at a side point."""
    touch, angle = circle_points(rng, n, rng.uniform(0.05, 0.95, n))
    d = np.stack([-np.sin(angle), rng.uniform(-0.3, 0.3, n), np.cos(angle)], 1)
    return touch - rng.uniform(0.5, 3, (n, 1)) * d, d


def rim_rays(rng, n):
    """Rays aimed exactly at points of the two rims from outside."""
    rim, _ = circle_points(rng, n, rng.choice([0.0, 1.0], n))
    o = unit_vectors(rng, n) * 3 + [0, 0.5, 0]
    return o, rim - o


def inside_rays(rng, n):
    """Origins uniform in the solid."""
    o, _ = circle_points(rng, n, rng.uniform(0, 1, n))
    o[:, [0, 2]] *= np.sqrt(rng.uniform(0, 1, (n, 1)))
    return o, unit_vectors(rng, n) * random_lengths(rng, n)


def surface_points(rng, n):
    """Points on the surface away from the rim (1% of the height / radius)
    and their outward normals."""
    side = n // 2
    p_side, angle = circle_points(rng, side, rng.uniform(0.01, 0.99, side))
    n_side = np.stack([np.cos(angle), np.zeros(side), np.sin(angle)], 1)
    p_cap, _ = circle_points(rng, n - side, rng.choice([0.0, 1.0], n - side))
    p_cap[:, [0, 2]] *= np.sqrt(rng.uniform(0, 0.98, (n - side, 1)))
    n_cap = np.zeros((n - side, 3))
    n_cap[:, 1] = np.where(p_cap[:, 1] == 1, 1, -1)
    return np.concatenate([p_side, p_cap]), np.concatenate([n_side, n_cap])


# --------------------------------------------------------------------------
# Running both and comparing
# --------------------------------------------------------------------------

def as_f32(*arrays):
    return [np.asarray(a, dtype=np.float32) for a in arrays]


def run_canonical(o, d, t_min, t_max=np.inf):
    hit = cylinder.intersect_canonical(mi.Point3f(o.T), mi.Vector3f(d.T), mi.Float(t_min),
                                       mi.Float(np.broadcast_to(np.float32(t_max), len(o))))
    return {"t": hit.t.numpy(), "valid": hit.valid.numpy(), "p": hit.p.numpy().T,
            "n": hit.n.numpy().T, "uv": hit.uv.numpy().T, "part": hit.part.numpy()}


#: The gap a ray that starts on the surface leaves before it looks for
#: hits, relative to its origin's size: about 1700 float32 ulp at unit
#: scale, far above the error of a re-projected hit point (a few ulp).
SURFACE_GAP = 1e-4


def surface_t_min(o, d):
    """A ``t_min`` that skips the surface a canonical ray starts on: a
    canonical distance of ``SURFACE_GAP * (1 + max|o_i|)``, whatever the
    direction's length."""
    gap = SURFACE_GAP * (1 + np.abs(o).max(axis=1)) / np.linalg.norm(d, axis=1)
    return gap.astype(np.float32)


def worst(name, errors, o, d):
    i = int(np.argmax(errors))
    return f"{name}: worst {errors[i]:.3g} for o={o[i].tolist()} d={d[i].tolist()}"


def within_band(ref, o):
    """Rays whose classification may legitimately differ (module docstring)."""
    return ref["margin"] < BAND * (1 + np.abs(o).max(axis=1))


def relative_t_error(t, t_ref, where):
    error = np.zeros(len(t))
    error[where] = np.abs(t[where] - t_ref[where]) / t_ref[where]
    return error


def compare_with_reference(label, o, d, t_min=0.0):
    """Run implementation and reference on float32 rays; assert the contract
    and return the measured errors."""
    o, d = as_f32(o, d)
    t_min = np.broadcast_to(np.asarray(t_min, dtype=np.float32), len(o))
    got = run_canonical(o, d, t_min)
    ref = reference.intersect(o.astype(np.float64), d.astype(np.float64), t_min.astype(np.float64))

    for key in ("p", "n", "uv"):
        assert np.isfinite(got[key]).all(), f"{label}: non-finite {key}"
    assert np.isfinite(got["t"][got["valid"]]).all() and np.all(got["t"][~got["valid"]] == np.inf)

    in_band = within_band(ref, o)
    disagree = got["valid"] != ref["hit"]
    assert not np.any(disagree & ~in_band), \
        f"{label}: {np.sum(disagree & ~in_band)} hit/miss disagreements outside the band; " + \
        worst("margin", np.where(disagree & ~in_band, ref["margin"], -1), o, d)

    both = got["valid"] & ref["hit"] & ~in_band
    t_error = relative_t_error(got["t"], ref["t"], both)
    assert t_error.max() < T_RELATIVE, f"{label}: " + worst("relative t error", t_error, o, d)

    p_error = np.where(both, np.abs(got["p"] - ref["p"]).max(axis=1), 0)
    assert p_error.max() < POINT_ERROR, f"{label}: " + worst("point error", p_error, o, d)
    n_error = np.where(both, np.abs(got["n"] - ref["n"]).max(axis=1), 0)
    assert n_error.max() < NORMAL_ERROR, f"{label}: " + worst("normal error", n_error, o, d)
    assert_on_surface(label, got)

    stats = (f"{label}: {len(o)} rays, {got['valid'].sum()} hits, {disagree.sum()} disagreements "
             f"(band {in_band.sum()} rays), max rel t error {t_error.max():.2e}, "
             f"max point error {p_error.max():.2e}")
    print(stats)
    return got, ref


def assert_on_surface(label, got):
    """Hit points lie on their part of the exact surface; normals are unit and
    outward; uv follow the documented convention."""
    valid, p, n, uv, part = got["valid"], got["p"], got["n"], got["uv"], got["part"]
    side, cap = valid & (part == cylinder.PART_SIDE), valid & (part != cylinder.PART_SIDE)
    radius2 = p[:, 0] ** 2 + p[:, 2] ** 2
    # float32 x and z at unit scale: x^2 + z^2 is within a few ulp of 1.
    assert np.all(np.abs(radius2[side] - 1) < 4e-7), f"{label}: side point off the unit circle"
    assert np.all((p[side, 1] >= 0) & (p[side, 1] <= 1))
    assert np.all(p[valid & (part == cylinder.PART_BOTTOM), 1] == 0)
    assert np.all(p[valid & (part == cylinder.PART_TOP), 1] == 1)
    assert np.all(radius2[cap] <= 1 + 4e-7)
    assert np.all(np.abs(np.linalg.norm(n[valid], axis=1) - 1) < NORMAL_ERROR)

    angle = np.arctan2(p[side, 2], p[side, 0]) / (2 * np.pi) % 1.0
    seam_distance = np.abs((uv[side, 0] - angle + 0.5) % 1.0 - 0.5)
    assert np.all(seam_distance < 1e-6) and np.all((uv[side, 0] >= 0) & (uv[side, 0] < 1))
    assert np.allclose(uv[side, 1], p[side, 1], atol=1e-7)
    assert np.allclose(uv[cap], (p[cap][:, [0, 2]] + 1) / 2, atol=1e-7)


# --------------------------------------------------------------------------
# Exact intersection
# --------------------------------------------------------------------------

def test_random_rays_near_and_far_match_reference():
    rng = np.random.default_rng(RNG_SEED)
    compare_with_reference("near", *near_rays(rng, 100_000))
    compare_with_reference("far 1e4", *far_rays(rng, 20_000, 1e4))
    compare_with_reference("far 1e6", *far_rays(rng, 5_000, 1e6))


def test_rays_parallel_to_the_axis_hit_only_caps():
    o, d = parallel_rays(np.random.default_rng(RNG_SEED + 1), 3000)
    got, ref = compare_with_reference("parallel", o, d)
    assert np.all(got["part"][got["valid"]] != cylinder.PART_SIDE)
    # Inside the radius, a ray that starts in the slab or moves towards it
    # certainly hits a cap; outside the radius it certainly misses.
    o, d = as_f32(o, d)
    radius = np.hypot(o[:, 0], o[:, 2])
    reaches_slab = (((o[:, 1] < 0) & (d[:, 1] > 0)) | ((o[:, 1] > 1) & (d[:, 1] < 0))
                    | ((o[:, 1] >= 0) & (o[:, 1] <= 1)))
    assert np.all(got["valid"][radius < 0.999] == reaches_slab[radius < 0.999])
    assert not np.any(got["valid"][radius > 1.001])
    # Exactly on the radius: the closed solid's rim is hit (inclusive test).
    assert np.all(got["valid"][:4] == reaches_slab[:4])


def test_rays_in_a_cap_plane_hit_the_side_at_the_rim():
    o, d = cap_plane_rays(np.random.default_rng(RNG_SEED + 2), 3000)
    got, ref = compare_with_reference("cap plane", o, d)
    # With d_y == 0 the height test is exact in both codes, so the rays on
    # the band (all heights are exactly 0 or 1) must agree too.
    assert np.array_equal(got["valid"], ref["hit"])
    assert relative_t_error(got["t"], ref["t"], ref["hit"]).max() < T_RELATIVE
    assert got["valid"].sum() > 300
    assert np.all(got["part"][got["valid"]] == cylinder.PART_SIDE)
    assert np.all(got["p"][got["valid"], 1] == o.astype(np.float32)[got["valid"], 1])


def test_tangent_and_rim_rays():
    rng = np.random.default_rng(RNG_SEED + 3)
    got, ref = compare_with_reference("tangent", *tangent_rays(rng, 5000))
    o, d = rim_rays(rng, 5000)
    got, ref = compare_with_reference("rim", o, d)
    # Rays that cross the rim edge into the solid (pointing strictly into
    # both the side's and the cap's half-space there) must not fall through
    # a crack between side and cap. The solid is convex, so the segment from
    # outside to the rim point enters nowhere else: t = 1 (d = rim - o).
    rim = o + d
    radial = rim * [1, 0, 1]
    into_side = np.sum(d * radial, axis=1) < -0.05 * np.linalg.norm(d, axis=1)
    top = np.round(rim[:, 1]) == 1
    into_cap = np.where(top, -d[:, 1], d[:, 1]) > 0.05 * np.linalg.norm(d, axis=1)
    entering = into_side & into_cap
    assert entering.sum() > 200
    assert got["valid"][entering].all()
    assert np.allclose(got["t"][entering], 1, rtol=1e-5)


def test_origins_inside_return_the_exit():
    o, d = inside_rays(np.random.default_rng(RNG_SEED + 4), 10_000)
    got, ref = compare_with_reference("inside", o, d)
    # A ray from inside a closed solid always leaves it.
    assert got["valid"].all()


def test_rays_from_the_surface_skip_it_with_a_t_min():
    rng = np.random.default_rng(RNG_SEED + 5)
    p, normal = surface_points(rng, 10_000)
    d = unit_vectors(rng, len(p)) * random_lengths(rng, len(p))
    p, d = as_f32(p, d)
    cosine = np.sum(d * normal, axis=1) / np.linalg.norm(d, axis=1)
    t_min = surface_t_min(p, d)
    got, ref = compare_with_reference("surface", p, d, t_min)
    # The solid is convex: leaving the surface outward never hits it again,
    # entering it always reaches the far side (points are 1% from the rim).
    assert not np.any(got["valid"][cosine > 0.01])
    assert np.all(got["valid"][cosine < -0.1])
    assert np.all(got["t"][got["valid"]] > t_min[got["valid"]])


def test_t_max_and_inactive_lanes_are_respected():
    o, d = as_f32([[-3, 0.5, 0]] * 3, [[1, 0, 0]] * 3)
    hit = cylinder.intersect_canonical(mi.Point3f(o.T), mi.Vector3f(d.T), mi.Float(0),
                                       mi.Float([10, 1.5, 10]), mi.Bool([True, True, False]))
    # Entry at t = 2 (x = -1): within t_max only for the first lane.
    assert hit.valid.numpy().tolist() == [True, False, False]
    assert hit.t.numpy()[0] == 2 and np.all(hit.t.numpy()[1:] == np.inf)


def world_placement(scale, segments=64):
    """A rotated, translated, uniformly scaled cylinder (the scale via
    ``to_world``), its world base point, unit axis and world radius."""
    rotation = mi.ScalarTransform4f().rotate(list(np.array([1, 2, 3]) / np.sqrt(14)), 40)
    to_world = mi.ScalarTransform4f().translate([5 * scale, -2 * scale, 3 * scale]) @ rotation @ \
        mi.ScalarTransform4f().scale(scale)
    shape = mi.load_dict({"type": "capped_cylinder", "center": [0.1, 0.2, -0.3],
                          "radius": 0.7, "height": 1.3, "segments": segments,
                          "to_world": to_world})
    m = shape.canonical_to_world_matrix()
    base, axis = m[:3, 3], m[:3, 1]
    return shape, base, axis / np.linalg.norm(axis), 0.7 * scale


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_world_rays_at_tiny_and_huge_scales(scale):
    shape, base, axis, world_radius = world_placement(scale)
    rng = np.random.default_rng(RNG_SEED + 6)
    w2c = shape.world_to_canonical_matrix()
    c2w = shape.canonical_to_world_matrix()
    o_c, d_c = near_rays(rng, 20_000)
    o_w, d_w = as_f32(o_c @ c2w[:3, :3].T + c2w[:3, 3], d_c @ c2w[:3, :3].T)

    o_mi, d_mi = cylinder.world_ray_to_canonical(mi.Matrix4d(w2c), mi.Point3d(o_w.T.astype(np.float64)),
                                                 mi.Vector3d(d_w.T.astype(np.float64)))
    hit = cylinder.intersect_canonical(o_mi, d_mi, mi.Float(0), mi.Float(np.inf))
    valid, t = hit.valid.numpy(), hit.t.numpy()
    o_ref = o_w @ w2c[:3, :3].T + w2c[:3, 3]
    ref = reference.intersect(o_ref, d_w @ w2c[:3, :3].T, 0.0)
    in_band = within_band(ref, o_ref)
    assert np.all((valid == ref["hit"]) | in_band)
    both = valid & ref["hit"] & ~in_band
    assert valid.sum() > 1000
    t_error = relative_t_error(t, ref["t"], both)
    assert t_error.max() < T_RELATIVE, t_error.max()

    # Independent of the matrices: the world point o + t d lies on the world
    # cylinder (distance from the axis = world radius on the side).
    p_w = o_w[both] + t[both, None].astype(np.float64) * d_w[both]
    side = hit.part.numpy()[both] == cylinder.PART_SIDE
    rel = p_w[side] - base
    axis_distance = np.linalg.norm(rel - (rel @ axis)[:, None] * axis, axis=1)
    assert np.allclose(axis_distance, world_radius, rtol=1e-5)
    # World normals: radial on the side, along the axis on the caps.
    n_w = cylinder.canonical_normal_to_world(mi.Matrix4f(w2c), hit.n).numpy().T[both]
    radial = rel - (rel @ axis)[:, None] * axis
    assert np.all(np.sum(n_w[side] * radial, axis=1) / np.linalg.norm(radial, axis=1) > 1 - 1e-5)
    cap_sign = np.where(hit.part.numpy()[both][~side] == cylinder.PART_TOP, 1, -1)
    assert np.all(n_w[~side] @ axis * cap_sign > 1 - 1e-5)
    print(f"scale {scale}: {both.sum()} hits, max rel t error {t_error.max():.2e}")


# --------------------------------------------------------------------------
# The plugin and its proxy mesh
# --------------------------------------------------------------------------

def mesh_arrays(shape):
    params = mi.traverse(shape)
    return (np.array(params["vertex_positions"].numpy(), dtype=np.float64).reshape(-1, 3),
            np.array(params["faces"].numpy()).reshape(-1, 3),
            np.array(params["vertex_normals"].numpy(), dtype=np.float64).reshape(-1, 3))


@pytest.mark.parametrize("segments", [3, 7, 64])
def test_proxy_is_watertight_and_outward(segments):
    shape, *_ = world_placement(2.0, segments)
    positions, faces, normals = mesh_arrays(shape)
    # Weld by exact position: shared rim vertices must coincide bit for bit.
    _, welded = np.unique(positions, axis=0, return_inverse=True)
    corners = welded.ravel()[faces]
    directed = np.concatenate([corners[:, [0, 1]], corners[:, [1, 2]], corners[:, [2, 0]]])
    undirected = np.sort(directed, axis=1)
    _, edge_uses = np.unique(undirected, axis=0, return_counts=True)
    assert np.all(edge_uses == 2), "every edge must be shared by exactly two triangles"
    # Consistent winding: each directed edge occurs once.
    assert len(np.unique(directed, axis=0)) == len(directed)

    # Divergence theorem: the signed volume is the prism's, times det(M).
    v0, v1, v2 = (positions[faces[:, i]] for i in range(3))
    volume = np.sum(np.einsum("ij,ij->i", v0, np.cross(v1, v2))) / 6
    ring = 1 / np.cos(np.pi / segments)
    # The proxy reaches CAP_PAD past each cap.
    prism = (segments / 2 * ring ** 2 * np.sin(2 * np.pi / segments)
             * (1 + 2 * capped_cylinder.CAP_PAD))
    det = np.linalg.det(shape.canonical_to_world_matrix()[:3, :3])
    assert volume == pytest.approx(prism * det, rel=1e-5)

    # Shading normals agree with the winding at every corner.
    face_normals = np.cross(v1 - v0, v2 - v0)
    for i in range(3):
        assert np.all(np.einsum("ij,ij->i", face_normals, normals[faces[:, i]]) > 0)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-6)


@pytest.mark.parametrize("segments", [3, 7, 64, 1000])
def test_proxy_buffers_are_aligned_as_drjit_aligns_its_own(segments):
    """Intersections gather from these buffers in every kernel; Dr.Jit emits
    other code for an unaligned buffer, so a kernel would differ from process
    to process (as NumPy's allocations fall) and miss the kernel cache."""
    shape, *_ = world_placement(2.0, segments)
    params = mi.traverse(shape)
    for name in ("vertex_positions", "vertex_normals", "vertex_texcoords", "faces"):
        assert address(params[name]) % ALIGNMENT == 0, name


def test_proxy_circumscribes_the_true_surface():
    shape, *_ = world_placement(3.0)
    positions, faces, _ = mesh_arrays(shape)
    v0, v1, v2 = (positions[faces[:, i]] for i in range(3))
    plane_normals = np.cross(v1 - v0, v2 - v0)
    plane_normals /= np.linalg.norm(plane_normals, axis=1, keepdims=True)
    rng = np.random.default_rng(RNG_SEED + 7)
    side, _ = circle_points(rng, 4000, rng.uniform(0, 1, 4000))
    rims, _ = circle_points(rng, 2000, rng.choice([0.0, 1.0], 2000))
    caps = rims.copy()
    caps[:, [0, 2]] *= np.sqrt(rng.uniform(0, 1, (2000, 1)))
    samples = np.concatenate([side, rims, caps])
    m = shape.canonical_to_world_matrix()
    world = samples @ m[:3, :3].T + m[:3, 3]
    # Inside a convex polyhedron = behind every face plane. Tolerance: float32
    # vertices at world size ~20 round by ~1e-6; the true surface touches the
    # proxy along its edges' midlines, so points there sit on the planes.
    signed = np.einsum("pfi,fi->pf", world[:, None, :] - v0[None], plane_normals)
    assert signed.max() < 1e-5 * np.abs(positions).max(), signed.max()


def test_proxy_hit_is_never_behind_the_exact_hit_and_uv_agree():
    shape, *_ = world_placement(1.5)
    scene = mi.load_dict({"type": "scene", "cyl": shape})
    segments = shape.segments
    rng = np.random.default_rng(RNG_SEED + 8)
    c2w, w2c = shape.canonical_to_world_matrix(), shape.world_to_canonical_matrix()
    o_c = unit_vectors(rng, 20_000) * 4 + [0, 0.5, 0]
    d_c = aimed(rng, o_c)
    o_w, d_w = as_f32(o_c @ c2w[:3, :3].T + c2w[:3, 3], d_c @ c2w[:3, :3].T)
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(o_w.T), mi.Vector3f(d_w.T)))
    o_mi, d_mi = cylinder.world_ray_to_canonical(mi.Matrix4f(w2c), mi.Point3f(o_w.T), mi.Vector3f(d_w.T))
    exact = cylinder.intersect_canonical(o_mi, d_mi, mi.Float(0), mi.Float(np.inf))
    proxy_valid, exact_valid = si.is_valid().numpy(), exact.valid.numpy()
    assert np.all(proxy_valid[exact_valid]), "an exact hit must hit the circumscribed proxy"
    both = proxy_valid & exact_valid
    assert np.all(si.t.numpy()[both] <= exact.t.numpy()[both] * (1 + 1e-5))

    uv_proxy, uv_exact = si.uv.numpy().T[both], exact.uv.numpy().T[both]
    on_cap = exact.part.numpy()[both] != cylinder.PART_SIDE
    proxy_on_cap = np.abs(si.n.numpy().T[both] @ (c2w[:3, 1] / np.linalg.norm(c2w[:3, 1]))) > 0.999
    same_cap = on_cap & proxy_on_cap
    # Cap uv are linear in the point; the proxy cap lies CAP_PAD above the
    # true one, so along the ray the two points differ by CAP_PAD times
    # the ray's horizontal over vertical slope (canonical), uv by half that.
    d_c_both = d_c[both][same_cap]
    slope = np.hypot(d_c_both[:, 0], d_c_both[:, 2]) / np.abs(d_c_both[:, 1])
    allowed = 1e-4 + capped_cylinder.CAP_PAD * slope / 2
    assert (np.abs(uv_proxy[same_cap] - uv_exact[same_cap]).max(axis=1) < allowed).all()
    # Side: the proxy point is on a chord next to the exact point; u may
    # differ by at most one polygon cell (away from the seam).
    on_side = ~on_cap & ~proxy_on_cap
    du = np.abs((uv_proxy[on_side, 0] - uv_exact[on_side, 0] + 0.5) % 1.0 - 0.5)
    assert du.max() < 1 / segments, du.max()


def builtin_equivalent(shape):
    """Mitsuba's open ``cylinder`` plus two ``disk``s, placed on the same solid."""
    to_world = mi.ScalarTransform4f(shape.canonical_to_world_matrix().tolist())
    return {"type": "scene", **builtin_cylinder(to_world)}


def pinhole_rays(eye, target, size=96, fov=0.25):
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0, 1, 0.1])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    s = np.linspace(-fov, fov, size)
    x, y = np.meshgrid(s, s)
    d = forward + x.ravel()[:, None] * right + y.ravel()[:, None] * up
    return np.broadcast_to(eye, d.shape).copy(), d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("eye", [(6, 3, 5), (0.5, -4, 7)])
def test_silhouette_matches_builtin_cylinder_and_disks(eye):
    proxy = world_placement(1.0, segments=24)[0]
    proxy_scene = mi.load_dict({"type": "scene", "cyl": proxy})
    builtin_scene = mi.load_dict(builtin_equivalent(proxy))
    center = proxy.canonical_to_world_matrix() @ [0, 0.5, 0, 1]
    o, d = as_f32(*pinhole_rays(center[:3] + eye, center[:3]))
    ray = mi.Ray3f(mi.Point3f(o.T), mi.Vector3f(d.T))
    proxy_mask = proxy_scene.ray_test(ray).numpy()
    builtin_mask = builtin_scene.ray_test(ray).numpy()
    assert builtin_mask.sum() > 500
    # The proxy contains the true solid: the built-in shapes never show
    # outside it (up to float32 ties where the proxy touches the surface).
    assert np.sum(builtin_mask & ~proxy_mask) <= 2
    # Extra proxy pixels lie between the true surface and the circumscribing
    # cylinder of radius 1/cos(pi/segments): the oracle is the reference run
    # against that larger cylinder.
    extra = proxy_mask & ~builtin_mask
    w2c = proxy.world_to_canonical_matrix()
    ring = 1 / np.cos(np.pi / proxy.segments)
    widen = np.array([ring, 1, ring])
    o_c = (o[extra] @ w2c[:3, :3].T + w2c[:3, 3]) / widen
    d_c = (d[extra] @ w2c[:3, :3].T) / widen
    assert np.all(reference.intersect(o_c, d_c, 0.0)["hit"])
    print(f"eye {eye}: {builtin_mask.sum()} built-in pixels, {extra.sum()} extra proxy pixels")


def cylinder_scene(integrator, **cylinders):
    return {"type": "scene", "integrator": integrator,
            "sensor": {"type": "perspective", "fov": 45,
                       "to_world": mi.ScalarTransform4f().look_at(origin=[4, 3, 6], target=[0, 0.5, 0],
                                                                   up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 32, "height": 32,
                                "rfilter": {"type": "box"}}},
           "light": {"type": "constant"}, **cylinders}


def two_cylinders():
    return {
        "glass": {"type": "capped_cylinder", "center": [-1, 0, 0], "radius": 0.6, "height": 1.5,
                  "segments": 32, "bsdf": {"type": "dielectric"}},
        "tinted": {"type": "capped_cylinder", "center": [1, 0, 0], "radius": 0.4,
                   "to_world": mi.ScalarTransform4f().rotate([0, 0, 1], 20),
                   "bsdf": {"type": "diffuse",
                            "reflectance": {"type": "rgb", "value": [0.8, 0.6, 0.1]}}},
    }


def test_renders_under_path_with_several_cylinders():
    scene = mi.load_dict(cylinder_scene({"type": "path", "max_depth": 6}, **two_cylinders()))
    assert len(scene.shapes()) == 2
    image = mi.render(scene, spp=4).numpy()
    assert_finite(image)
    # Background (constant 1) is white; the diffuse cylinder is darker and
    # yellow, so the image is not uniform.
    assert image.min() < 0.9 and image.max() > 0.5


def test_renders_under_aov_with_unit_normals_and_depth():
    integrator = {"type": "aov", "aovs": "nn:sh_normal,dd.y:depth"}
    scene = mi.load_dict(cylinder_scene(integrator, **two_cylinders()))
    image = mi.render(scene, spp=1).numpy()
    assert_finite(image)
    normals, depth = image[..., :3], image[..., 3]
    covered = depth > 0
    assert 50 < covered.sum() < covered.size
    # One centred sample per pixel: interpolated shading normals are unit.
    assert np.allclose(np.linalg.norm(normals[covered], axis=1), 1, atol=1e-3)


def test_area_emitter_on_the_proxy():
    radiance = [2.0, 3.0, 0.5]
    scene = mi.load_dict(cylinder_scene(
        {"type": "path", "max_depth": 3},
        lamp={"type": "capped_cylinder", "center": [0, -0.5, 0], "radius": 1.5, "height": 2,
              "emitter": {"type": "area", "radiance": {"type": "rgb", "value": radiance}}},
        floor={"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, -0.5, 0])
               @ mi.ScalarTransform4f().rotate([1, 0, 0], -90) @ mi.ScalarTransform4f().scale(10)}))
    lamp = [s for s in scene.shapes() if s.is_emitter()]
    assert len(lamp) == 1 and lamp[0].surface_area()[0] > 0
    image = mi.render(scene, spp=4).numpy()
    assert_finite(image)
    # The camera looks at the lamp's middle: seen directly, an area emitter
    # shows exactly its radiance.
    assert np.allclose(image[16, 16], radiance, rtol=1e-5)


XML_WITH_BSDF = """
<scene version="3.0.0">
    <shape type="capped_cylinder" id="yellow">
        <point name="center" x="1" y="-1" z="2"/>
        <float name="radius" value="0.5"/>
        <float name="height" value="2"/>
        <integer name="segments" value="12"/>
        <transform name="to_world"><rotate x="1" angle="30"/></transform>
        <bsdf type="roughconductor"><float name="alpha" value="0.31"/></bsdf>
    </shape>
</scene>"""


def test_loads_from_xml_and_dict_with_nested_bsdf():
    from_xml = mi.load_string(XML_WITH_BSDF).shapes()[0]
    from_dict = mi.load_dict({"type": "capped_cylinder", "center": [1, -1, 2], "radius": 0.5,
                              "height": 2, "segments": 12,
                              "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 30),
                              "bsdf": {"type": "roughconductor", "alpha": 0.31}})
    for shape in (from_xml, from_dict):
        assert mi.traverse(shape)["bsdf.alpha.value"].numpy()[0] == pytest.approx(0.31)
        assert (shape.radius, shape.height, shape.segments) == (0.5, 2.0, 12)
        assert np.allclose(shape.center, [1, -1, 2])
        assert shape.vertex_count() == 4 * 12 + 4 and shape.face_count() == 4 * 12
        assert "CappedCylinder[" in str(shape)
    assert np.allclose(mesh_arrays(from_xml)[0], mesh_arrays(from_dict)[0], atol=1e-6)
    # The two transforms are inverse to each other.
    product = from_xml.canonical_to_world_matrix() @ from_xml.world_to_canonical_matrix()
    assert np.allclose(product, np.eye(4), atol=1e-12)


def test_traverse_update_rebuilds_mesh_and_scene():
    scene = mi.load_dict({"type": "scene", "cyl": {"type": "capped_cylinder"}})
    ray = mi.Ray3f(mi.Point3f(1.5, 0.5, -5), mi.Vector3f(0, 0, 1))
    assert not scene.ray_test(ray).numpy()[0]
    params = mi.traverse(scene)
    params["cyl.radius"] = 2.0
    params.update()
    shape = scene.shapes()[0]
    assert shape.radius == 2.0
    assert scene.ray_test(ray).numpy()[0], "the acceleration structure must see the new mesh"
    params["cyl.radius"] = -1.0
    with pytest.raises(ValueError, match="capped_cylinder: parameter 'radius'"):
        params.update()


@pytest.mark.parametrize("parameter, value", [
    ("radius", 0.0), ("radius", -1.0), ("radius", float("nan")),
    ("height", 0.0), ("height", -2.0),
    ("segments", 2),
    ("center", [0, float("inf"), 0]),
    ("to_world", "singular"),
])
def test_bad_input_names_the_parameter(parameter, value):
    if value == "singular":
        value = mi.ScalarTransform4f().scale([1, 0, 1])
    with pytest.raises(ParameterError, match=f"^capped_cylinder: parameter '{parameter}'"):
        mi.load_dict({"type": "capped_cylinder", parameter: value})


def test_the_capped_cylinder_is_marked_analytic_and_built_in_shapes_are_not():
    from mitsuba_whitted.shapes.analytic import analytic, is_analytic

    scene = mi.load_dict({"type": "scene", "cyl": {"type": "capped_cylinder"},
                          "ball": {"type": "sphere"}})
    marked = {shape.id(): is_analytic(shape) for shape in scene.shapes()}
    assert marked == {"cyl": True, "ball": False}
    with pytest.raises(TypeError, match="lacks canonical_to_world_matrix"):
        analytic(type("Unplaced", (), {"world_to_canonical_matrix": lambda self: None}))


# --------------------------------------------------------------------------
# Sizes float32 ray tests cannot hit
# --------------------------------------------------------------------------

@pytest.mark.parametrize("props, named", [
    ({"radius": 1e20}, "radius"), ({"radius": 1e30}, "radius"), ({"height": 1e25}, "height"),
    ({"radius": 1e-25}, "radius"), ({"to_world": 1e21}, "to_world"),
    ({"radius": 1e10, "to_world": 1e10}, "radius"), ({"to_world": 1e-20}, "to_world"),
], ids=lambda value: "-".join(f"{k}={v}" for k, v in value.items())
    if isinstance(value, dict) else value)
def test_sizes_whose_ray_test_overflows_float32_are_refused_in_one_sentence(props, named):
    """A cylinder whose proxy triangles float32 cannot intersect (it
    vanished from the image, measured at radius 3e18): one sentence naming
    the radius or height out of range, else the placement (``to_world``, a
    scale here), and the limit."""
    props = {key: mi.ScalarTransform4f().scale(value) if key == "to_world" else value
             for key, value in props.items()}
    with pytest.raises(ParameterError) as refused:
        mi.load_dict({"type": "capped_cylinder", **props})
    sentence = str(refused.value)
    assert sentence.startswith(f"capped_cylinder: parameter '{named}' makes "
                               "the cylinder's triangles"), sentence
    assert f"{capped_cylinder.MAX_LENGTH:.2g} long" in sentence


def test_a_cylinder_near_the_largest_size_renders_its_cap_as_a_lit_plane():
    """Radius 1e17, height 1, seen from a few units above its top cap: the
    cap fills the view as a plane. Oracle: a diffuse plane under a point
    light in float64 (albedo / pi x I cos / d^2) at the pixel centres."""
    from mitsuba_whitted.camera import camera_rays, pixel_centres
    from validation.scenes import camera, integrator, scene

    albedo, intensity, light, top = 0.7, 10.0, np.array([1.0, 3.0, 1.0]), 0.5
    loaded = mi.load_dict(scene(
        {"type": "capped_cylinder", "radius": 1e17, "height": 1.0, "center": [0, -0.5, 0],
         "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}}},
        {"type": "point", "position": light.tolist(),
         "intensity": {"type": "rgb", "value": [intensity] * 3}},
        sensor=camera(origin=(0, 3, 5), target=(0, 0, 0), size=16),
        whitted=integrator(aa="none")))
    image = np.array(mi.render(loaded))[..., 0].ravel()
    assert_finite(image)
    sensor = loaded.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    o, d = np.array(ray.o, dtype=np.float64).T, np.array(ray.d, dtype=np.float64).T
    t = (top - o[:, 1]) / d[:, 1]
    p = o + t[:, None] * d
    to_light = light - p
    distance = np.linalg.norm(to_light, axis=1)
    expected = albedo / np.pi * intensity * (to_light[:, 1] / distance) / distance ** 2
    hits = t > 0
    assert hits.sum() > 100
    np.testing.assert_allclose(image[hits], expected[hits], rtol=1e-4)
