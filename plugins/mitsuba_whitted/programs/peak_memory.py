"""Loads a scene, renders it or takes one gradient of it, and prints
``peak_rss_mib`` and its own peak resident memory (see
:func:`mitsuba_whitted.bench.processes.child_peak_memory`).

Arguments: the scene file, its defines and its settings as JSON (see
:func:`mitsuba_whitted.overrides.load_with`), and the work, ``render`` or
``gradient``.
"""

import json
import sys

import mitsuba_whitted  # first: it chooses the libLLVM that Dr.Jit loads
import drjit as dr
import mitsuba as mi


def render(scene) -> None:
    mi.render(scene)


def gradient(scene) -> None:
    from mitsuba_whitted.bench.gradient_figures import GradientStep
    GradientStep(scene)()


WORK = {"render": render, "gradient": gradient}


def main(scene_path: str, defines: str, settings: str, work: str) -> None:
    mitsuba_whitted.set_variant("llvm_ad_rgb")
    # Imported once the variant is set, as a user's script would.
    from mitsuba_whitted.bench.processes import peak_rss_mib
    from mitsuba_whitted.overrides import load_with
    scene = load_with(scene_path, json.loads(defines), json.loads(settings))
    WORK[work](scene)
    dr.sync_thread()
    print("peak_rss_mib", peak_rss_mib())


if __name__ == "__main__":
    main(*sys.argv[1:])
