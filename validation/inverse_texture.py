"""Inverse rendering with whitted's exact gradients: recover the texture of a
ball that the camera sees only in a mirror and through a glass ball.

    python -m validation.inverse_texture [--iterations N] [--out DIR]

The ball stands behind the camera; the camera looks at a mirror, and at a
glass ball before it. The texture starts grey; the target is a render of
the true texture (the lemons picture, 64 x 64). Each iteration renders the
image with ``mi.render(scene, params)``, differentiates the mean squared
difference to the target with ``dr.backward`` and takes a step of
``mi.ad.Adam``. The loss and the texture's error (RMS over the texels the
image sees, against the true texture) are printed per iteration; the
recovered texture, the images and a plot of both errors against time are
written to ``--out``, with this run's history, so that the plot shows the
``prb`` run (``python -m validation.inverse_texture_prb``) beside it.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import mitsuba_whitted
import drjit as dr
import mitsuba as mi
import numpy as np

from mitsuba_whitted.command import CommandParser, count, run_command
from mitsuba_whitted.files import check_folder, write_text
from mitsuba_whitted.imageio import write_image
from validation.scenes import camera, point_light, rgb, sphere, wall

ROOT = Path(__file__).resolve().parent.parent
#: Not under report/, which ``make validate`` writes anew.
OUT = Path(__file__).resolve().parent / "inverse_texture_results"
TEXTURE_SIZE = 64
RESOLUTION = 128
KEY = "ball.bsdf.reflectance.data"
#: Texels count as seen where they change the image at least this much,
#: relative to the texel that changes it most: the texture's error is
#: measured there (texels the image samples at grazing angles, or between
#: pixel centres, barely constrain it).
SEEN = 1e-2


def true_texture(size: int = TEXTURE_SIZE) -> np.ndarray:
    """The lemons picture, linear, ``size`` x ``size``."""
    bitmap = mi.Bitmap(str(ROOT / "textures" / "lemons.png"))
    bitmap = bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False)
    return np.clip(np.array(bitmap.resample([size, size]), dtype=np.float32), 0.0, 1.0)


def scene_description(texture: np.ndarray, integrator: dict,
                      resolution: int = RESOLUTION) -> dict:
    """The mirror, the glass ball, the textured ball behind the camera and
    two point lights."""
    mirror = {"type": "conductor", "material": "none",
              "specular_reflectance": rgb(0.9, 0.9, 0.9)}
    return {
        "type": "scene",
        "integrator": integrator,
        "sensor": camera(origin=[0, 0.3, 5], size=resolution),
        "mirror": wall(z=-0.5, size=3, bsdf=mirror),
        "glass": sphere((0.55, 0.15, 2.2), 0.55, {"type": "dielectric", "int_ior": 1.5}),
        # Turned so that the lemons face the mirror.
        "ball": {"type": "sphere",
                 "to_world": mi.ScalarTransform4f().translate([0, 0.3, 7.0]).rotate([0, 1, 0], 90)
                 .scale(1.6),
                 "bsdf": {"type": "diffuse", "reflectance": {
                     "type": "bitmap", "bitmap": mi.Bitmap(texture), "format": "variant",
                     "raw": True}}},
        "key": point_light((2, 3, 3), 60),
        "fill": point_light((-3, 1, 2), 25),
    }


def whitted_integrator() -> dict:
    return {"type": "whitted", "max_depth": 6}


class Problem:
    """The scene with a grey texture, its target image, and the texels the
    image sees."""

    def __init__(self, integrator: dict, target_spp: int = 0, resolution: int = RESOLUTION,
                 texture_size: int = TEXTURE_SIZE):
        self.truth = true_texture(texture_size)
        truth_scene = mi.load_dict(scene_description(self.truth, integrator, resolution))
        self.target = mi.render(truth_scene, spp=target_spp)
        self.seen = _seen_texels(self.truth, resolution)
        grey = np.full_like(self.truth, 0.5)
        self.scene = mi.load_dict(scene_description(grey, integrator, resolution))
        self.params = mi.traverse(self.scene)

    def texture(self) -> np.ndarray:
        return np.array(self.params[KEY], dtype=np.float32)

    def texture_error(self) -> float:
        """RMS difference from the true texture over the texels seen."""
        difference = (self.texture() - self.truth)[self.seen]
        return float(np.sqrt(np.mean(difference ** 2)))


def _seen_texels(texture: np.ndarray, resolution: int) -> np.ndarray:
    """Texels whose change changes whitted's image: where the gradient of
    the image's sum is not (relatively) zero, any channel."""
    scene = mi.load_dict(scene_description(texture, whitted_integrator(), resolution))
    params = mi.traverse(scene)
    dr.enable_grad(params[KEY])
    params.update()
    dr.backward(mi.render(scene, params))
    weight = np.abs(np.array(dr.grad(params[KEY]))).max(axis=2)
    return np.repeat((weight > SEEN * weight.max())[..., None], 3, axis=2)


def optimise(problem: Problem, iterations: int, learning_rate: float, spp: int = 0,
             report=print) -> list:
    """Adam on the texture; one row per iteration: loss, texture error and
    the seconds since the start."""
    optimiser = mi.ad.Adam(lr=learning_rate)
    optimiser[KEY] = problem.params[KEY]
    problem.params.update(optimiser)
    history = []
    start = time.perf_counter()
    for iteration in range(iterations):
        image = mi.render(problem.scene, problem.params, seed=iteration, spp=spp)
        loss = dr.mean(dr.square(image - problem.target), axis=None)
        dr.backward(loss)
        optimiser.step()
        optimiser[KEY] = dr.clip(optimiser[KEY], 0.0, 1.0)
        problem.params.update(optimiser)
        dr.sync_thread()
        row = {"iteration": iteration, "loss": float(loss.array[0]),
               "texture_error": problem.texture_error(),
               "seconds": time.perf_counter() - start}
        history.append(row)
        report(f"iteration {iteration:3d}  loss {row['loss']:.3e}  texture error "
               f"{row['texture_error']:.4f}  {row['seconds']:7.2f} s")
    return history


def write_results(problem: Problem, history: list, name: str, out: Path) -> None:
    """The recovered texture, the final and target images, this run's
    history, and the plot of every history found in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    write_image(out / f"{name}_texture.png", problem.texture())
    write_image(out / f"{name}_target.png", np.array(problem.target))
    write_image(out / f"{name}_final.png", np.array(mi.render(problem.scene, spp=0)))
    write_image(out / "true_texture.png", problem.truth)
    write_image(out / "start_texture.png", np.full_like(problem.truth, 0.5))
    seen = problem.seen.astype(np.float32)
    write_image(out / "seen_texels.png", seen)
    write_text(out / f"{name}_history.json", json.dumps(history, indent=1))
    plot_histories(out)


def plot_histories(out: Path) -> Path:
    """Loss and texture error against time of every ``*_history.json`` in
    ``out``, written to ``out/loss.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (loss_axes, error_axes) = plt.subplots(1, 2, figsize=(10, 3.8), dpi=80)
    for path in sorted(out.glob("*_history.json")):
        history = json.loads(path.read_text())
        name = path.name[:-len("_history.json")]
        seconds = [row["seconds"] for row in history]
        loss_axes.plot(seconds, [row["loss"] for row in history], "-", label=name)
        error_axes.plot(seconds, [row["texture_error"] for row in history], "-", label=name)
    for axes, label in ((loss_axes, "image loss (MSE against its target)"),
                        (error_axes, "texture error (RMS over the texels seen)")):
        axes.set_xlabel("time (s)")
        axes.set_ylabel(label)
        axes.set_yscale("log")
        axes.grid(True, which="both", alpha=0.3)
        axes.legend()
    figure.tight_layout()
    target = out / "loss.png"
    figure.savefig(target)
    plt.close(figure)
    return target


def main(argv=None, name: str = "whitted", integrator=whitted_integrator, spp: int = 0,
         target_spp: int = 0, learning_rate: float = 0.05,
         program: str = "validation.inverse_texture") -> int:
    parser = CommandParser(prog=program, description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=count, default=80)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    check_folder(args.out)  # before the optimisation, not after
    mitsuba_whitted.set_variant("llvm_ad_rgb")
    problem = Problem(integrator(), target_spp)
    print(f"{name}: texture error {problem.texture_error():.4f} at the start")
    history = optimise(problem, args.iterations, learning_rate, spp)
    write_results(problem, history, name, args.out)
    last = history[-1]
    print(f"{name}: texture error {last['texture_error']:.4f} after {len(history)} iterations, "
          f"{last['seconds']:.1f} s; written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main, program="validation.inverse_texture"))
