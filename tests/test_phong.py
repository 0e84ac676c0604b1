"""The ``phong`` BSDF against independent oracles: Mitsuba's chi-square test
of sample() against pdf(), a float64 numpy evaluation of the modified Phong
formula, numerical quadrature, Mitsuba's own ``diffuse`` and ``checkerboard``
plugins, and renders by Mitsuba's ``path`` and ``direct`` integrators."""

import re
from contextlib import contextmanager
from fractions import Fraction

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

from conftest import assert_finite

RHO_D = [0.5, 0.3, 0.1]
RHO_S = [0.2, 0.35, 0.45]


def phong(rho_d=RHO_D, rho_s=RHO_S, exponent=10.0):
    return mi.load_dict({
        "type": "phong",
        "diffuse_reflectance": {"type": "rgb", "value": rho_d},
        "specular_reflectance": {"type": "rgb", "value": rho_s},
        "exponent": exponent,
    })


def incident(theta_deg):
    theta = np.radians(theta_deg)
    return [float(np.sin(theta)), 0.0, float(np.cos(theta))]


def interactions(wi):
    """Surface interactions in the local frame, one per row of ``wi``."""
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(*np.asarray(wi, np.float32).T)
    return si


def reference_eval(wi, wo, rho_d, rho_s, exponent):
    """f(wi, wo) cos(theta_o) of the modified Phong BRDF, float64, shape (N, 3)."""
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    mirror = wi * [-1.0, -1.0, 1.0]
    cos_alpha = np.sum(wo * mirror, axis=1)
    # The lobe is the hemisphere about the mirror direction (so that it
    # equals what sample() draws), also for n = 0 where numpy has 0**0 = 1.
    lobe = np.where(cos_alpha > 0, np.clip(cos_alpha, 0, None) ** exponent, 0.0)
    f = (np.asarray(rho_d)[None, :] / np.pi
         + np.asarray(rho_s)[None, :] * (exponent + 2) / (2 * np.pi) * lobe[:, None])
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(above[:, None], f * wo[:, 2:3], 0.0)


def random_directions(rng, count):
    v = rng.normal(size=(count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def near_mirror(rng, wi, spread):
    """Directions scattered about the mirror directions of ``wi``, where a
    sharp lobe is far from 0."""
    v = wi * [-1.0, -1.0, 1.0] + spread * rng.normal(size=wi.shape)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def hemisphere_grid(res):
    """Midpoint rule on the upper hemisphere in (cos theta, phi), an
    area-preserving parameterization: directions and the solid angle each
    stands for."""
    mu = (np.arange(res) + 0.5) / res
    phi = (np.arange(2 * res) + 0.5) / (2 * res) * 2 * np.pi
    mu, phi = np.meshgrid(mu, phi, indexing="ij")
    sin = np.sqrt(1 - mu**2)
    wo = np.stack([sin * np.cos(phi), sin * np.sin(phi), mu], -1).reshape(-1, 3)
    return wo, 2 * np.pi / (2 * res * res)


def evaluate(bsdf, wi, wo, ctx=None):
    """eval (N, 3) and pdf (N,) of ``bsdf`` at one ``wi`` and many ``wo``."""
    ctx = ctx or mi.BSDFContext()
    si = interactions(np.broadcast_to(wi, np.shape(wo)))
    value, pdf = bsdf.eval_pdf(ctx, si, mi.Vector3f(*np.asarray(wo, np.float32).T))
    return value.numpy().T, pdf.numpy()


def draw_samples(bsdf, wi, count, seed=7, ctx=None):
    rng = np.random.default_rng(seed)
    u = rng.random((3, count), dtype=np.float32)
    si = interactions(np.broadcast_to(wi, (count, 3)))
    bs, weight = bsdf.sample(ctx or mi.BSDFContext(), si, mi.Float(u[0]),
                             mi.Point2f(u[1], u[2]))
    return bs, weight, si


# --- Sampling against density: mitsuba.chi2 ---------------------------------

EXPONENTS = (1.0, 10.0, 100.0)
ANGLES = (0.0, 30.0, 60.0, 80.0)
CONFIGURATIONS = {"both_lobes": (RHO_D, RHO_S), "specular_only": (0.0, 0.8)}
GLOSSY_ONLY = mi.BSDFContext()
GLOSSY_ONLY.component = 1
CHI2_RUNS = len(EXPONENTS) * len(ANGLES) * len(CONFIGURATIONS) + len(EXPONENTS)


def run_chi2(bsdf_dict, wi, ctx=None):
    sample_func, pdf_func = BSDFAdapter("phong", bsdf_dict, wi=wi, ctx=ctx)
    # 200k samples on the default 202 x 101 grid keep the file fast. Cells are
    # 0.02 wide in cos(theta), where the exponent-100 lobe at normal incidence
    # (cos^100) changes 8-fold across one cell: the default 4 x 4 trapezoid
    # rule overestimates it by 4 %, 16 x 16 brings that under 0.2 %.
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func,
                         pdf_func=pdf_func, sample_dim=3, sample_count=200_000,
                         ires=16)
    # Sidak-corrected over every chi2 run of this file: 1 % for all together.
    assert test.run(significance_level=0.01, test_count=CHI2_RUNS), test.messages


@pytest.mark.parametrize("configuration", CONFIGURATIONS)
@pytest.mark.parametrize("exponent", EXPONENTS)
@pytest.mark.parametrize("theta", ANGLES)
def test_chi2_sample_matches_pdf(configuration, exponent, theta):
    rho_d, rho_s = CONFIGURATIONS[configuration]
    run_chi2({"type": "phong", "exponent": exponent,
              "diffuse_reflectance": {"type": "rgb", "value": rho_d},
              "specular_reflectance": {"type": "rgb", "value": rho_s}},
             incident(theta))


@pytest.mark.parametrize("exponent", EXPONENTS)
def test_chi2_highlight_component_alone(exponent):
    """ctx.component = 1 samples only the highlight, with pdf() to match."""
    run_chi2({"type": "phong", "exponent": exponent}, incident(45.0),
             ctx=GLOSSY_ONLY)


# --- Closed forms ------------------------------------------------------------

@pytest.mark.parametrize("exponent", (0.0, 1.0, 10.0, 100.0, 1000.0))
def test_eval_matches_float64_formula(exponent):
    rng = np.random.default_rng(1)
    wi = random_directions(rng, 4000)
    # Half the pairs uniform (one-sidedness, the flat part of the lobe), half
    # near the mirror direction (the peak of a sharp lobe).
    wo = np.concatenate([random_directions(rng, 2000),
                         near_mirror(rng, wi[2000:], 0.3 / np.sqrt(1 + exponent))])
    si = interactions(wi)
    value = phong(exponent=exponent).eval(
        mi.BSDFContext(), si, mi.Vector3f(*wo.astype(np.float32).T)).numpy().T
    expected = reference_eval(wi.astype(np.float32), wo.astype(np.float32),
                              RHO_D, RHO_S, exponent)
    # float32 cos(alpha) carries ~1e-7 relative error, which cos^n amplifies
    # n-fold (1e-4 at n = 1000); atol covers lanes where the lobe is ~0.
    np.testing.assert_allclose(value, expected, rtol=2e-4, atol=1e-6)
    assert (expected[:, 0] == 0).sum() > 1000, "one-sided zeros were exercised"


@pytest.mark.parametrize("component, expected_part", [
    (0, lambda wi, wo: reference_eval(wi, wo, RHO_D, [0, 0, 0], 10.0)),
    (1, lambda wi, wo: reference_eval(wi, wo, [0, 0, 0], RHO_S, 10.0)),
])
def test_context_component_selects_one_lobe(component, expected_part):
    ctx = mi.BSDFContext()
    ctx.component = component
    wi = np.array(incident(40.0))
    wo = near_mirror(np.random.default_rng(2), np.tile(wi, (500, 1)), 0.3)
    value, _ = evaluate(phong(), wi, wo, ctx)
    np.testing.assert_allclose(value, expected_part(np.tile(wi, (500, 1)), wo),
                               rtol=2e-5, atol=1e-7)
    bs, _, _ = draw_samples(phong(), wi, 1000, ctx=ctx)
    assert (bs.sampled_component.numpy() == component).all()


def test_type_mask_selects_one_lobe():
    ctx = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.DiffuseReflection)
    wi = np.array(incident(20.0))
    wo = random_directions(np.random.default_rng(3), 500)
    value, pdf = evaluate(phong(), wi, wo, ctx)
    expected = reference_eval(np.tile(wi, (500, 1)), wo, RHO_D, [0, 0, 0], 10.0)
    np.testing.assert_allclose(value, expected, rtol=2e-5, atol=1e-7)
    # Only the diffuse lobe is sampled, so the density is cos(theta_o) / pi.
    np.testing.assert_allclose(pdf, np.clip(wo[:, 2], 0, None) / np.pi,
                               rtol=2e-5, atol=1e-7)
    nothing = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Delta)
    value, pdf = evaluate(phong(), wi, wo, nothing)
    assert not value.any() and not pdf.any()


@pytest.mark.parametrize("exponent", (1.0, 10.0, 100.0))
@pytest.mark.parametrize("theta", (0.0, 60.0, 80.0))
def test_pdf_integrates_to_the_sampler_acceptance(exponent, theta):
    """The pdf's integral over the hemisphere is at most 1, exactly 1 at
    normal incidence (the whole lobe lies above the surface), and equals the
    fraction of samples that sample() does not reject below the surface."""
    wo, d_omega = hemisphere_grid(600)
    _, pdf = evaluate(phong(rho_d=0.3, rho_s=0.7, exponent=exponent),
                      incident(theta), wo)
    integral = pdf.sum(dtype=np.float64) * d_omega
    # Midpoint rule on 600 x 1200 cells: relative error ~ (n / 600)^2 / 24,
    # under 2e-3 for n = 100.
    quadrature_error = 2e-3
    assert integral <= 1 + quadrature_error
    count = 1_000_000
    bs, _, _ = draw_samples(phong(rho_d=0.3, rho_s=0.7, exponent=exponent),
                            incident(theta), count)
    accepted = np.mean(bs.pdf.numpy() > 0)
    binomial_sigma = np.sqrt(max(accepted * (1 - accepted), 1 / count) / count)
    assert abs(integral - accepted) < 5 * binomial_sigma + quadrature_error
    if theta == 0.0:
        assert integral == pytest.approx(1.0, abs=quadrature_error)
    if theta == 80.0 and exponent == 1.0:
        assert integral < 0.95, "a wide lobe at grazing incidence loses mass"


@pytest.mark.parametrize("exponent", (1.0, 30.0))
@pytest.mark.parametrize("theta", (0.0, 45.0, 85.0))
def test_sample_weight_is_eval_over_pdf(exponent, theta):
    bsdf = phong(exponent=exponent)
    bs, weight, si = draw_samples(bsdf, incident(theta), 20_000)
    value, pdf = bsdf.eval_pdf(mi.BSDFContext(), si, bs.wo)
    pdf, value, weight = pdf.numpy(), value.numpy(), weight.numpy()
    valid = pdf > 0
    assert valid.mean() > 0.5
    np.testing.assert_allclose(bs.pdf.numpy(), pdf, rtol=1e-5)
    # Same float32 operations in a different order: a few ulps.
    np.testing.assert_allclose(weight[:, valid], value[:, valid] / pdf[valid],
                               rtol=1e-5)
    assert not weight[:, ~valid].any(), "rejected samples carry no weight"
    sampled_type = np.where(bs.sampled_component.numpy() == 1,
                            int(mi.BSDFFlags.GlossyReflection),
                            int(mi.BSDFFlags.DiffuseReflection))
    assert (bs.sampled_type.numpy() == sampled_type).all()


@pytest.mark.parametrize("theta", (0.0, 45.0, 80.0))
def test_white_diffuse_furnace(theta):
    """rho_d = 1, rho_s = 0 reflects everything it receives: every sample
    weight is exactly rho_d (cosine sampling of a cosine-weighted integrand,
    so no Monte Carlo error), and the hemisphere quadrature of eval is 1."""
    bsdf = phong(rho_d=1.0, rho_s=0.0)
    _, weight, _ = draw_samples(bsdf, incident(theta), 100_000)
    np.testing.assert_allclose(weight, 1.0, rtol=1e-6)
    wo, d_omega = hemisphere_grid(300)
    value, _ = evaluate(bsdf, incident(theta), wo)
    # Midpoint rule of the linear cos(theta): exact up to float32 summation.
    assert value.sum(axis=0, dtype=np.float64) * d_omega == pytest.approx(
        [1.0] * 3, abs=1e-4)


@pytest.mark.parametrize("exponent", (1.0, 10.0, 100.0))
def test_white_highlight_furnace_at_normal_incidence(exponent):
    """(n + 2) / (2 pi) makes the highlight's albedo exactly rho_s at normal
    incidence: the mean sample weight is 1 within its Monte Carlo error."""
    _, weight, _ = draw_samples(phong(rho_d=0.0, rho_s=1.0, exponent=exponent),
                                incident(0.0), 400_000)
    weight = weight.numpy()[0].astype(np.float64)
    standard_error = weight.std() / np.sqrt(weight.size)
    assert abs(weight.mean() - 1.0) < 4 * standard_error + 1e-6


def test_eval_diffuse_reflectance_constant_and_checkerboard():
    rng = np.random.default_rng(4)
    si = interactions(random_directions(rng, 256))
    si.uv = mi.Point2f(*rng.random((2, 256), dtype=np.float32))
    assert np.allclose(phong().eval_diffuse_reflectance(si).numpy().T, RHO_D)

    checker = {"type": "checkerboard",
               "color0": {"type": "rgb", "value": [0.1, 0.2, 0.3]},
               "color1": {"type": "rgb", "value": [0.7, 0.6, 0.5]}}
    bsdf = mi.load_dict({"type": "phong", "diffuse_reflectance": checker})
    expected = mi.load_dict(checker).eval(si).numpy()
    np.testing.assert_array_equal(bsdf.eval_diffuse_reflectance(si).numpy(), expected)
    assert len(np.unique(expected[0])) == 2, "both checker colours were hit"


# --- Rendering with Mitsuba's integrators -------------------------------------

def scene_dict(bsdf, integrator="path"):
    # path: depth 4 stays below the default rr_depth of 5 (no Russian roulette).
    depth = {"max_depth": 4} if integrator == "path" else {}
    return {
        "type": "scene",
        "integrator": {"type": integrator, **depth},
        "sensor": {
            "type": "perspective", "fov": 40,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[0, 1, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 24, "height": 24},
            "sampler": {"type": "independent", "sample_count": 8},
        },
        "ball": {"type": "sphere", "bsdf": bsdf},
        "floor": {"type": "rectangle", "bsdf": bsdf,
                  "to_world": mi.ScalarTransform4f().translate([0, -1, 0])
                  .rotate([1, 0, 0], -90).scale(3)},
        "lamp": {"type": "point", "position": [2, 3, 2],
                 "intensity": {"type": "rgb", "value": 20.0}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.3}},
    }


def render(scene):
    image = mi.render(scene, seed=3).numpy()
    assert_finite(image)
    assert image.mean() > 0.01, "the scene is lit"
    return image


@pytest.mark.parametrize("integrator", ("path", "direct"))
def test_renders_from_dict_with_checkerboard(integrator):
    bsdf = {"type": "phong", "exponent": 40.0,
            "diffuse_reflectance": {"type": "checkerboard"}}
    render(mi.load_dict(scene_dict(bsdf, integrator)))


@pytest.mark.parametrize("integrator", ("path", "direct"))
def test_renders_from_xml_with_bitmap(tmp_path, integrator):
    texels = np.random.default_rng(5).random((8, 8, 3)).astype(np.float32) * 0.7
    mi.Bitmap(texels).write(str(tmp_path / "albedo.exr"))
    scene = mi.load_string(f"""
    <scene version="3.0.0">
        <integrator type="{integrator}"/>
        <sensor type="perspective">
            <float name="fov" value="40"/>
            <transform name="to_world">
                <lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/>
            </transform>
            <film type="hdrfilm"><integer name="width" value="24"/>
                <integer name="height" value="24"/></film>
            <sampler type="independent"><integer name="sample_count" value="8"/></sampler>
        </sensor>
        <shape type="sphere">
            <bsdf type="phong">
                <texture type="bitmap" name="diffuse_reflectance">
                    <string name="filename" value="{tmp_path / 'albedo.exr'}"/>
                </texture>
                <rgb name="specular_reflectance" value="0.25"/>
                <float name="exponent" value="20"/>
            </bsdf>
        </shape>
        <emitter type="point">
            <point name="position" x="2" y="3" z="3"/>
            <rgb name="intensity" value="20"/>
        </emitter>
    </scene>""")
    render(scene)


def test_path_traced_like_diffuse_without_highlight():
    """With rho_s = 0, phong samples and evaluates exactly Lambert's law,
    consuming the same random numbers as Mitsuba's diffuse: under the same
    seed the two path-traced images agree to float32 rounding. (No Russian
    roulette at this depth, which could turn a rounding into a new path.)"""
    albedo = {"type": "rgb", "value": [0.6, 0.4, 0.2]}
    ours = render(mi.load_dict(scene_dict(
        {"type": "phong", "diffuse_reflectance": albedo,
         "specular_reflectance": {"type": "rgb", "value": 0.0}})))
    builtin = render(mi.load_dict(scene_dict({"type": "diffuse", "reflectance": albedo})))
    np.testing.assert_allclose(ours, builtin, rtol=1e-4, atol=1e-5)


# --- Parameters ---------------------------------------------------------------

def test_traverse_and_update_change_the_result():
    bsdf = phong(exponent=10.0)
    params = mi.traverse(bsdf)
    assert {"diffuse_reflectance.value", "specular_reflectance.value",
            "exponent"} <= set(params.keys())
    wi = np.array(incident(30.0))
    wo = near_mirror(np.random.default_rng(6), np.tile(wi, (200, 1)), 0.2)
    before, _ = evaluate(bsdf, wi, wo)

    params["exponent"] = 50.0
    params["diffuse_reflectance.value"] = mi.Color3f(0.1, 0.2, 0.3)
    params.update()
    after, _ = evaluate(bsdf, wi, wo)
    expected = reference_eval(np.tile(wi, (200, 1)), wo, [0.1, 0.2, 0.3], RHO_S, 50.0)
    np.testing.assert_allclose(after, expected, rtol=1e-4, atol=1e-7)
    assert not np.allclose(before, after)


@pytest.mark.parametrize("exponent", (-1.0, float("inf"), float("nan")))
def test_bad_exponent_names_plugin_and_parameter(exponent):
    with pytest.raises(Exception, match="phong: parameter 'exponent'"):
        phong(exponent=exponent)


def test_bad_exponent_through_update():
    params = mi.traverse(phong())
    params["exponent"] = -2.0
    with pytest.raises(Exception, match="phong: parameter 'exponent'"):
        params.update()


class _Recorder(mi.Appender):
    def __init__(self):
        mi.Appender.__init__(self)
        self.lines = []

    def append(self, level, text):
        self.lines.append(text)

    def log_progress(self, *args):
        pass


@contextmanager
def warnings_logged():
    """The lines Mitsuba's log receives in the block."""
    logger = mi.logger()
    recorder = _Recorder()
    logger.add_appender(recorder)
    try:
        yield recorder.lines
    finally:
        logger.remove_appender(recorder)


def energy_warnings(lines):
    return [line for line in lines if "phong: diffuse_reflectance + specular_reflectance" in line]


#: Reflectances as written, just under, at and over a sum of 1 (some
#: coloured); the oracle is their exact decimal sum.
SUMS = [("0.8", "0.2"), ("0.7", "0.3"), ("0.5", "0.5"), ("0.1", "0.9"), ("0.79999995", "0.2"),
        ("0.8", "0.2000001"), ("0.8", "0.3"), ("0.9999999", "0.0000002"), ("1", "0"),
        ("0.9, 0.2, 0.2", "0.2"), ("0.9, 0.1, 0.1", "0.1, 0.5, 0.5"),
        ("0.3, 0.6, 0.1", "0.7, 0.4000001, 0.2")]


def exceeds_one(rho_d: str, rho_s: str) -> bool:
    """Whether some channel's written reflectances sum to more than 1."""
    channels = np.broadcast_arrays([Fraction(v) for v in rho_d.split(",")],
                                   [Fraction(v) for v in rho_s.split(",")])
    return any(d + s > 1 for d, s in zip(*channels))


def phong_xml(rho_d: str, rho_s: str, name: str = "shiny") -> str:
    return (f'<scene version="3.0.0"><bsdf type="phong" id="{name}">'
            f'<rgb name="diffuse_reflectance" value="{rho_d}"/>'
            f'<rgb name="specular_reflectance" value="{rho_s}"/></bsdf></scene>')


@pytest.mark.parametrize("rho_d, rho_s", SUMS, ids=[f"{d}+{s}" for d, s in SUMS])
def test_warns_only_when_the_reflectances_exceed_one(rho_d, rho_s):
    """0.8 + 0.2 warned that it reached "1 > 1": in float32 the two are
    0.800000012 + 0.200000003. The warning names the BSDF and shows the
    sum over 1 as written and as a number visibly above 1."""
    with warnings_logged() as lines:
        mi.load_string(phong_xml(rho_d, rho_s))
    warned = energy_warnings(lines)
    assert bool(warned) == exceeds_one(rho_d, rho_s), warned
    for line in warned:
        shown = re.search(r"of bsdf 'shiny' reach ([\d.]+) \+ ([\d.]+) = ([\d.]+) > 1,", line)
        assert shown, line
        d, s, total = shown.groups()
        assert d in rho_d.split(", ") and s in rho_s.split(", ") and float(total) > 1
        assert Fraction(total) == round(Fraction(d) + Fraction(s), 7)


def test_an_update_warns_by_name_only_past_one():
    """Through ``mi.traverse``: as from XML."""
    params = mi.traverse(mi.load_string(phong_xml("0.5", "0.2", name="ball_bsdf")))
    updates = [(0.8, 0.2, False), (0.8, 0.2000001, True), (0.79999995, 0.2, False),
               (0.9, 0.3, True)]
    for rho_d, rho_s, warns in updates:
        params["ball_bsdf.diffuse_reflectance.value"] = mi.Color3f(rho_d)
        params["ball_bsdf.specular_reflectance.value"] = mi.Color3f(rho_s)
        with warnings_logged() as lines:
            params.update()
        warned = energy_warnings(lines)
        assert len(warned) == warns, (rho_d, rho_s, warned)
        assert all("of bsdf 'ball_bsdf' reach" in line for line in warned)


def test_a_bsdf_without_an_id_is_said_to_have_none():
    with warnings_logged() as lines:
        phong(rho_d=0.8, rho_s=0.3)
    assert any("of a bsdf without an id reach 0.8 + 0.3 = 1.1 > 1" in line
               for line in energy_warnings(lines))
