"""Classic Whitted ray tracing as Mitsuba 3 plugins.

The scene and the techniques come from a student report of the University
of Canterbury's computer-graphics course COSC363 (2017), on a C++ Whitted
ray tracer: Phong shading, hard shadows from two point lights, mirrors,
refraction, tinted transparency, recursive anti-aliasing, a capped
cylinder, a procedural and two mapped textures. ``scenes/cosc363.xml``
rebuilds its scene; the plugins' documentation says "the COSC363 ray
tracer" where a formula or a choice is that program's.

Importing this package registers every plugin with Mitsuba for the active
variant, and again after each ``mi.set_variant``, whichever comes first::

    import mitsuba as mi
    import mitsuba_whitted
    mi.set_variant("llvm_ad_rgb")
    scene = mitsuba_whitted.scenes.load("cosc363", res=300)
    image = mi.render(scene)

A usable libLLVM is chosen before Dr.Jit loads one (see :mod:`.llvm`), and
``mi.render`` raises the plugins' errors and Ctrl-C as they were raised
(see :mod:`.checked_render`), and so do Mitsuba's scene loaders (see
:mod:`.checked_loading`).
"""

# First, before any other import: in the command, Ctrl-C is handled from
# here on (see .startup; no "from __future__" either, which imports a module).
from . import startup

if startup.COMMAND:
    startup.start()

import importlib  # noqa: E402  (after Ctrl-C is handled)
import sys  # noqa: E402
from importlib import metadata  # noqa: E402

from . import llvm  # noqa: E402
from .errors import Error, ParameterError, VariantError  # noqa: E402,F401  (raised by the checks)

#: The installed distribution's version (pyproject.toml says it).
__version__ = metadata.version("mitsuba-whitted")

#: Plugin modules, each registering one plugin at its bottom. Their classes
#: derive from variant-specific Mitsuba types, so they are (re)imported after
#: every variant change.
PLUGIN_MODULES = (
    "shapes.capped_cylinder",
    "bsdfs.phong",
    "textures.tartan",
    "textures.sphere_map",
    "textures.planar_map",
    "integrators.whitted",
)

DEFAULT_VARIANT = "llvm_ad_rgb"

llvm.configure()

import mitsuba as mi  # noqa: E402  (after the libLLVM choice)

from .checked_loading import LOADERS, checked_loader  # noqa: E402
from .checked_render import checked  # noqa: E402
from . import scenes  # noqa: E402,F401  (mitsuba_whitted.scenes.load: the shipped scenes)
from .scene_files import check_films, check_images, parse  # noqa: E402


def _register_plugins(variant: str | None) -> None:
    if variant is None:
        return
    for name in PLUGIN_MODULES:
        full_name = f"{__name__}.{name}"
        if full_name in sys.modules:
            importlib.reload(sys.modules[full_name])
        else:
            importlib.import_module(full_name)


def _on_variant_change(old: str | None, new: str | None) -> None:
    _register_plugins(new)


def registered_plugins() -> list[str]:
    """Names of the plugins this package provides."""
    names = []
    for name in PLUGIN_MODULES:
        module = sys.modules.get(f"{__name__}.{name}")
        if module is not None:
            names.append(module.PLUGIN_NAME)
    return names


def set_variant(variant: str = DEFAULT_VARIANT) -> None:
    """``mi.set_variant`` with a clear error for an LLVM variant when no
    usable libLLVM is installed, and for a variant whose backend cannot
    start here (a CUDA variant without an NVIDIA GPU and driver)."""
    if variant.startswith("llvm"):
        llvm.require()
    if variant not in mi.variants():
        raise VariantError(
            f"variant '{variant}' is not available; "
            f"choose one of {', '.join(mi.variants())}.")
    try:
        mi.set_variant(variant)
    except ImportError as error:
        # Dr.Jit leaves the variant that was active before in place.
        needs = " (it needs an NVIDIA GPU and its driver)" if variant.startswith("cuda") else ""
        detail = str(error).splitlines()[0].split(". ")[0]
        raise VariantError(
            f"variant '{variant}' cannot be used on this machine: Dr.Jit's "
            f"backend for it did not start{needs}: {detail}; use '{DEFAULT_VARIANT}'.") from None


def load_file(path: str, **defines):
    """``mi.load_file`` that numbers the scene's objects the same way in
    every process.

    Dr.Jit compiles registry ids into the kernels' virtual calls, so ids
    that change from process to process make a new process build a new
    kernel and miss the kernel cache.
    Mitsuba's parallel loading hands ids out in thread order, and its
    merging of shapes that share a BSDF into one mesh orders them
    differently from run to run (a cube of six rectangles did); both are
    off here. Ray counts and render times of ``scenes/cosc363.xml`` are the
    same either way. A film without pixels is refused by name
    (:func:`.scene_files.check_films`), and so is an image whose pixels
    would not fit in memory (:func:`.scene_files.check_images`)."""
    state = parse(path, defines)
    check_films(state)
    check_images(state, path)
    return mi.load_file(str(path), parallel=False, optimize=False, **defines)


mi.detail.add_variant_callback(_on_variant_change)
mi.render = checked(mi.render)
for _loader in LOADERS:
    setattr(mi, _loader, checked_loader(getattr(mi, _loader)))
del _loader
_register_plugins(mi.variant())
