"""``mitsuba-whitted``: render scenes and report on the installation.

    mitsuba-whitted render SCENE.xml -o OUT.png [--variant V] [-D name=value ...]
    mitsuba-whitted render-many SCENE.xml... --out DIR [--workers N] [--cluster ADDRESS] [-D ...]
    mitsuba-whitted compare SCENE.xml [--out DIR] [--reference-spp N] [--quick]
                            [--workers N] [--cluster ADDRESS] [-D ...]
    mitsuba-whitted bench [SCENE.xml] [--quick] [--json FILE] [-D ...]
    mitsuba-whitted preview SCENE.xml [-D ...] [--port N] [--host ADDR] [--no-browser]
    mitsuba-whitted info

SCENE.xml may also be the name of a scene the package ships (``cosc363``,
see :mod:`.scenes`).
"""

from __future__ import annotations

import argparse
import sys
import time

import mitsuba as mi

from . import files, scenes
from .command import CommandParser, add_cluster_options, count, run_command
from .errors import UsageError
from .integrators.settings import is_whitted
from .interrupt import last_write
from .progress import Progress
from .scene_files import check_not_read, first_sensor


def _parse_defines(pairs: list[str]) -> dict:
    defines = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name:
            raise UsageError(f"-D expects name=value (got '{pair}').")
        defines[name] = value
    return defines


def _load_scene(path: str, defines: dict):
    import mitsuba_whitted

    return mitsuba_whitted.load_file(path, **defines)


def _resolve_arguments(args) -> None:
    """The ``-D`` pairs as a dictionary (``args.defines``), and every SCENE
    argument of ``args`` as the file it names (a path, or a shipped scene's
    name), so the commands read files only: the arguments' own form is
    checked before any file."""
    if getattr(args, "define", None) is not None:
        args.defines = _parse_defines(args.define)
    if getattr(args, "scene", None) is not None:
        args.scene = scenes.resolve(args.scene)
    if getattr(args, "scenes", None) is not None:
        args.scenes = [scenes.resolve(scene) for scene in args.scenes]


def command_render(args) -> int:
    import drjit as dr

    import mitsuba_whitted
    from .imageio import check_image_path, write_image

    check_image_path(args.output)
    mitsuba_whitted.set_variant(args.variant)
    defines = args.defines
    check_not_read([args.output], args.scene, defines)
    started = time.perf_counter()
    scene = _load_scene(args.scene, defines)
    loaded = time.perf_counter()
    integrator = scene.integrator()
    sensor = first_sensor(scene, args.scene)
    progress = Progress()
    if is_whitted(integrator):
        integrator.progress = progress
        with last_write():
            _render_whitted_to_file(scene, integrator, args.output)
    else:
        image = mi.render(scene)
        dr.sync_thread()
        with last_write():
            write_image(args.output, image.numpy())
    rendered = time.perf_counter()
    progress.finish()
    width, height = sensor.film().crop_size()
    seconds = rendered - loaded
    stats = getattr(integrator, "last_stats", {})
    rays = stats.get("total")
    ray_text = (f", {rays / 1e6:.2f} M rays" if rays >= 10_000 else f", {rays:,} rays") \
        + f", {rays / seconds / 1e6:.3g} M rays/s" if rays else ""
    print(f"{args.output}: {width}x{height} rendered and written in {seconds:.3f} s{ray_text} "
          f"(scene loaded in {loaded - started:.2f} s)")
    return 0


def _render_whitted_to_file(scene, integrator, output) -> None:
    """The image band by band into the file's encoder (see
    ``WhittedIntegrator.render_rows``): no film of the whole image is ever
    held, so films larger than memory render."""
    from .imageio import stored_bytes, write_rows

    film = scene.sensors()[0].film()
    width, height = film.crop_size()
    channels = film.base_channels_count()
    held = stored_bytes(output, width, height, channels)
    write_rows(output, width, height, channels,
               lambda put: integrator.render_rows(scene, put, held_bytes=held))


def command_info(args) -> int:
    import drjit as dr

    import mitsuba_whitted
    from . import llvm

    mitsuba_whitted.set_variant(args.variant)
    path = llvm.loaded_library() or llvm.configure()
    version = ".".join(str(v) for v in dr.detail.llvm_version()) if args.variant.startswith("llvm") else "-"
    print(f"mitsuba-whitted {mitsuba_whitted.__version__}")
    print(f"mitsuba {mi.__version__}, drjit {dr.__version__}, variant {mi.variant()}")
    print(f"libLLVM: {path} (version {version})")
    print(f"plugins: {', '.join(mitsuba_whitted.registered_plugins())}")
    return 0


def command_compare(args) -> int:
    from pathlib import Path

    import mitsuba_whitted
    from .compare import CompareOptions, check_report_folder, compare_scene, estimate_text
    from .distributed import backend

    options = CompareOptions.make(args.quick, args.reference_spp)
    out = check_report_folder(args.out or f"compare-{Path(args.scene).stem}")
    mitsuba_whitted.set_variant(args.variant)
    with backend(args.workers, args.cluster) as runner:
        result = compare_scene(args.scene, out, options, args.defines,
                               progress=Progress(), backend=runner)
    crossing = result.results.crossing["relmse"]
    print(f"{result.report}: reference {result.reference.spp} spp"
          f"{' (cached)' if result.reference.cached else ''}; path overtakes the most "
          f"accurate Whitted setting in relMSE ({crossing.label}) at "
          f"{estimate_text(crossing.path_seconds, ' s')}")
    return 0


def command_render_many(args) -> int:
    import mitsuba_whitted
    from .distributed import backend
    from .distributed.batch import render_many

    mitsuba_whitted.set_variant(args.variant)
    started = time.perf_counter()
    progress = Progress()
    with backend(args.workers, args.cluster) as runner:
        written = render_many(args.scenes, args.out, args.defines, runner,
                              progress, f".{args.format}")
    progress.finish()
    print(f"{args.out}: {len(written)} images in {time.perf_counter() - started:.1f} s "
          f"({runner.description})")
    return 0


def command_bench(args) -> int:
    import json

    import mitsuba_whitted
    from . import bench

    if args.json:
        files.check_writable(args.json)
    mitsuba_whitted.set_variant(args.variant)
    scene = args.scene or bench.DEFAULT_SCENE
    defines = args.defines
    if args.json:
        check_not_read([args.json], scene, defines)
    settings = (bench.BenchSettings.quick(scene, defines) if args.quick
                else bench.BenchSettings(scene, defines))
    results = bench.run(settings, report=lambda line: print(line, file=sys.stderr, flush=True),
                        show=lambda table: print(table, flush=True))
    if args.json:
        with last_write():
            files.write_text(args.json, json.dumps(bench.results_json(results), indent=2))
    return 0


def command_preview(args) -> int:
    import mitsuba_whitted
    from .preview import serve

    mitsuba_whitted.set_variant(args.variant)
    return serve(args.scene, args.defines, args.host, args.port, not args.no_browser)


def _port(text: str) -> int:
    """An argument's type: a TCP port, 0 for a free one."""
    if not text.isdigit() or int(text) > 65535:
        raise argparse.ArgumentTypeError(f"expected a port from 0 to 65535, got '{text}'")
    return int(text)


def _add_scene_options(parser: argparse.ArgumentParser) -> None:
    """Options every scene-reading command shares."""
    from . import DEFAULT_VARIANT

    parser.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                        help="set a $NAME default of the scene")
    parser.add_argument("--variant", default=DEFAULT_VARIANT)


#: What ``bench --help`` says of the bench's parts and how long each takes
#: on a 2-core machine, so that a user knows what waits ahead.
BENCH_DESCRIPTION = (
    "Speed, ray-casting bound, memory and scaling of a scene whose integrator is "
    "'whitted', then the equal-error speed-up over path and the cost of a gradient, "
    "measured in one run; each part's table is printed as soon as it is done. On a "
    "2-core machine the full bench takes about 3.5 minutes: the scene's renders and "
    "bound about 30 s, fresh processes and peak memory 10 s, scaling 30 s, equal error "
    "against path 90 s, gradients 50 s. --quick takes about 20 s.")


#: What a SCENE argument may be (see :func:`.scenes.resolve`).
SCENE_HELP = "Mitsuba scene file (XML), or a shipped scene's name (cosc363, glass_box, ...)"


def build_parser() -> argparse.ArgumentParser:
    from . import DEFAULT_VARIANT

    parser = CommandParser(
        prog="mitsuba-whitted",
        description="Whitted ray tracing for Mitsuba 3 scenes.")
    commands = parser.add_subparsers(dest="command", required=True)

    render = commands.add_parser("render", help="render a scene to an image")
    render.add_argument("scene", help=SCENE_HELP)
    render.add_argument("-o", "--output", required=True,
                        help="output image (.png, .jpg, .exr, .hdr, .pfm)")
    _add_scene_options(render)
    render.set_defaults(run=command_render)

    compare = commands.add_parser(
        "compare", help="whitted against Mitsuba's path tracer: images, errors, times, report")
    compare.add_argument("scene", help=SCENE_HELP)
    compare.add_argument("--out", help="report directory (default compare-SCENE); the path "
                         "reference is cached in OUT/cache")
    compare.add_argument("--reference-spp", type=count,
                         help="samples per pixel of the path reference (default 1024, quick 64)")
    compare.add_argument("--quick", action="store_true",
                         help="fewer settings and a cheaper reference, for a first look")
    _add_scene_options(compare)
    add_cluster_options(compare)
    compare.set_defaults(run=command_compare)

    many = commands.add_parser(
        "render-many", help="render many scenes or frames, one image each, on one machine "
        "or a Ray cluster")
    many.add_argument("scenes", nargs="+", metavar="SCENE", help=SCENE_HELP)
    many.add_argument("--out", required=True, help="directory of the images, "
                      "OUT/<scene file's stem>.<format>")
    many.add_argument("--format", default="exr", choices=["exr", "hdr", "pfm", "png", "jpg"],
                      help="image format (default exr)")
    _add_scene_options(many)
    add_cluster_options(many)
    many.set_defaults(run=command_render_many)

    bench_ = commands.add_parser(
        "bench", help="speed, ray-casting bound, memory and scaling, measured in one run",
        description=BENCH_DESCRIPTION)
    bench_.add_argument("scene", nargs="?", help=f"{SCENE_HELP} (default: cosc363, the "
                        "report's scene)")
    bench_.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    bench_.add_argument("--quick", action="store_true", help="small sizes, few repeats")
    _add_scene_options(bench_)
    bench_.set_defaults(run=command_bench)

    preview = commands.add_parser(
        "preview", help="a live view of a scene in the browser, re-rendered as its files change")
    preview.add_argument("scene", help="Mitsuba scene file (XML)")
    preview.add_argument("--port", type=_port, default=0,
                         help="port to listen on (default: a free one)")
    preview.add_argument("--host", default="127.0.0.1",
                         help="address to listen on (default 127.0.0.1, this machine only)")
    preview.add_argument("--no-browser", action="store_true",
                         help="print the URL without opening a browser")
    _add_scene_options(preview)
    preview.set_defaults(run=command_preview)

    info = commands.add_parser("info", help="variant, libLLVM and plugins")
    info.add_argument("--variant", default=DEFAULT_VARIANT)
    info.set_defaults(run=command_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(_run, args)


def _run(args) -> int:
    _resolve_arguments(args)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
