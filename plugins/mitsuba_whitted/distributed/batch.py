"""``mitsuba-whitted render-many``: one image per scene file, each the
image ``mitsuba-whitted render`` writes for it, rendered by any backend."""

from __future__ import annotations

from pathlib import Path

from ..errors import Error
from ..files import check_folder, check_readable
from ..scene_files import check_not_read
from .backends import InProcess, run_job
from .scene import SceneSource
from .task import Task


class BatchError(Error, ValueError):
    """Two scenes of a batch would write the same image."""


def output_paths(scenes: list[Path], out_dir: Path, suffix: str) -> list[Path]:
    """``out_dir/<scene file's stem><suffix>`` for each scene; a scene that
    is not a readable file, an ``out_dir`` that cannot be a folder, and two
    scenes that would write the same image, are refused."""
    check_folder(out_dir)
    outputs, seen = [], {}
    for scene in scenes:
        check_readable(scene)
        output = out_dir / f"{scene.stem}{suffix}"
        if output in seen:
            raise BatchError(f"'{seen[output]}' and '{scene}' would both be "
                             f"written to '{output}'; rename one of them.")
        seen[output] = scene
        outputs.append(output)
    return outputs


def render_many(scenes, out_dir, defines: dict | None = None, backend=None, progress=None,
                suffix: str = ".exr") -> list[Path]:
    """Render each scene as ``mitsuba.render(scene)`` does (its own
    integrator, sampler and seed 0) and write its image as soon as it is
    done; the paths written, in the scenes' order."""
    from ..imageio import write_image

    scenes = [Path(scene) for scene in scenes]
    outputs = output_paths(scenes, Path(out_dir), suffix)
    for scene in scenes:  # one scene's image may be another's texture
        check_not_read(outputs, scene, defines or {})
    sources = [SceneSource(scene, defines or {}) for scene in scenes]
    tasks = [Task(source.digest) for source in sources]

    def write(index, image):
        write_image(outputs[index], image)

    run_job(backend or InProcess(), tasks, {source.digest: source for source in sources},
            write, progress, "scenes")
    return outputs
