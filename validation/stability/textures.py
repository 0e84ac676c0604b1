"""Stability of the textures at their numerical edges: ``sphere_map`` at
the poles and on its seams, and ``tartan`` at coordinates far from the
origin."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from validation.stability.common import ULP32, CaseResult, f32, random_units, unit_rows

#: The plugin normalises n in float32 (a few ulp per component) and rounds
#: uv to float32 (ulp <= 6e-8, which moves a component recovered through a
#: sine by at most pi * 2 pi * 6e-8 ~ 4e-7): 8 ulp of 1 is 9.5e-7.
COMPONENT_BOUND = 8 * ULP32


def hard_normals(n: int, rng) -> np.ndarray:
    """Poles (±y and ±z), both sides of every mapping's seam, directions
    1e-7 from the poles, and random directions, all at lengths 1 and
    1 ± 1e-6 (the plugin normalises)."""
    special = np.array([[0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [1e-7, 1, 0], [0, -1, 1e-7],
                        [-1, 1e-30, 0], [-1, -1e-30, 0], [-1, 0, 0], [-1, 1e-7, 0], [-1, -1e-7, 0],
                        [1e-30, 0, -1], [-1e-30, 0, -1], [0, 0.6, -0.8], [1e-7, 0.6, -0.8],
                        [-1e-7, 0.6, -0.8]], float)
    directions = unit_rows(np.vstack([special, random_units(rng, max(n // 3 - len(special), 1))]))
    return np.vstack([directions, directions * (1 + 1e-6), directions * (1 - 1e-6)])


def _azimuth_error(phi, a, b):
    """Error of a longitude ``phi`` measuring the direction of (a, b), as a
    distance in the (a, b) plane: zero at the pole, no jump at the seam."""
    length = np.hypot(a, b)
    return np.hypot(length * np.cos(phi) - a, length * np.sin(phi) - b)


def mapping_error(uv: np.ndarray, mapping: str, n: np.ndarray) -> np.ndarray:
    """How far the components that ``uv`` encodes (recovered by inverting
    the documented mapping in float64) are from those of the true unit
    ``n``. Componentwise, because that is well conditioned everywhere: uv
    itself is not (u is arbitrary at a pole, 0 and 1 meet at a seam, and
    asin/acos amplify a rounding of n near ±1 without bound)."""
    u, v = uv.T
    x, y, z = n.T
    if mapping == "asin":
        return np.maximum(np.abs(np.sin(np.pi * (0.5 - u)) - x), np.abs(np.sin(np.pi * (0.5 - v)) - y))
    if mapping == "atan":
        return np.maximum(_azimuth_error(2 * np.pi * (u - 0.5), x, y),
                          np.abs(np.sin(np.pi * (0.5 - v)) - y))
    return np.maximum(_azimuth_error(2 * np.pi * (u - 0.5), z, x), np.abs(np.cos(np.pi * v) - y))


def sphere_map_uv(mapping: str, normals: np.ndarray) -> np.ndarray:
    """The uv ``sphere_map`` hands its nested texture, for shading normals."""
    texture = mi.load_dict({"type": "sphere_map", "mapping": mapping,
                            "texture": {"type": "rgb", "value": [0.5, 0.5, 0.5]}})
    si = dr.zeros(mi.SurfaceInteraction3f, len(normals))
    # Set the raw normal (Frame3f(n) would normalise it: |n| = 1 ± 1e-6 is the point).
    si.sh_frame.n = mi.Normal3f(*normals.astype(np.float32).T)
    return np.array(texture.remap_uv(si), dtype=np.float64).T


def sphere_map_poles(n: int, rng, mapping: str) -> CaseResult:
    """``sphere_map`` at the poles, on its seam, 1e-7 off them and at
    |n| = 1 ± 1e-6: asin/acos of a component past ±1 would be NaN and
    atan2 flips by a whole turn across the seam. The uv must be finite and
    in [0, 1], and encode the float64 unit direction of the float32 input
    within COMPONENT_BOUND."""
    normals = hard_normals(n, rng)
    uv = sphere_map_uv(mapping, normals)
    truth = unit_rows(f32(normals))
    finite = np.isfinite(uv).all(axis=1)
    outside = int((finite & ((uv < 0) | (uv > 1)).any(axis=1)).sum())
    error = mapping_error(uv[finite], mapping, truth[finite])
    worst = float(error.max())
    return CaseResult(
        name=f"sphere_map {mapping}: poles and seams", measures="uv from sphere_map.remap_uv",
        reference="float64 inverse of the documented mapping", samples=len(normals),
        nonfinite=int((~finite).sum()), disagreements=outside, excused=0,
        band="none (uv outside [0, 1] counted)", worst_error=worst,
        unit="components encoded by uv vs unit n", bound=COMPONENT_BOUND,
        passed=bool(finite.all() and outside == 0 and worst <= COMPONENT_BOUND))


def tartan_far(n: int, rng) -> CaseResult:
    """``tartan`` at coordinates of 1e6, 1e9 and 1e15 (float32 ulp 0.06 at
    1e6, so f·x is rounded by up to 0.125 rad before the sine): no
    meaningful float64 pattern exists there, so the bound is the texture's
    contract: finite and every channel in [0, 1] (a reflectance). Dr.Jit's
    float32 sine leaves [-1, 1] above ~1e8 (the clamp hides it) and returns
    NaN above ~1e19, where this texture is NaN too: a known limit."""
    tartan = mi.load_dict({"type": "tartan"})
    p = rng.uniform(-1, 1, (n, 3)) * np.choose(np.arange(n) % 3, [1e6, 1e9, 1e15])[:, None]
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.p = mi.Point3f(*p.astype(np.float32).T)
    color = np.array(tartan.eval(si), dtype=np.float64).T
    finite = np.isfinite(color).all(axis=1)
    excess = max(float(np.maximum(color[finite] - 1, -color[finite]).max(initial=0)), 0.0)
    return CaseResult(
        name="tartan: coordinates 1e6 to 1e15", measures="tartan.eval",
        reference="contract: finite, within [0, 1]", samples=n, nonfinite=int((~finite).sum()),
        disagreements=0, excused=0, band="n/a", worst_error=excess + 0.0,
        unit="distance outside [0, 1]", bound=0.0,
        passed=bool(finite.all() and excess <= 0))
