"""How much memory a render takes, and how it is cut into bands of rows so
that this stays bounded whatever the film's size and anti-aliasing.

A render keeps, outside its kernels, a few numbers per camera sample that
is still to be combined into its pixel (its position, key, radiance and
alpha), a few per pixel of the band in flight (its sums, its sample count,
the block handed to the film), and the film itself. The samples kept at
once are bounded by cutting the film into bands of whole rows, each
rendered and handed to the film (or to a file) before the next starts, and
by letting no band keep more than ``band_samples`` samples: the adaptive and
contrast refinements stop there as they stop at ``aa_budget``. Bands are
sized for ``typical_samples`` per pixel (most pixels of most scenes take
the four of the first adaptive level), so a film of usual size is one band.
The cut depends only on the film's size and the integrator's settings,
never on the machine, so a render gives the same bits everywhere.

Before anything is allocated the plan's peak is compared with the memory
the machine has left (:func:`mitsuba_whitted.system.available_memory`);
a render that cannot fit is refused with one sentence that names what to
lower.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..errors import ParameterError
from ..system import available_memory, available_text
from .settings import PLUGIN_NAME

#: Bytes kept per camera sample outside the kernels (position, key,
#: radiance, alpha, the refinement's indices), with some margin.
SAMPLE_BYTES = 40
#: Bytes kept per pixel of a band (sums, sample count, the image block).
PIXEL_BYTES = 64
#: Bytes a launch takes per camera sample in flight, inside and around the
#: kernel, for the depth-first tracer and for each ray of a wavefront generation.
LAUNCH_SAMPLE_BYTES = 96
#: Dr.Jit's arrays hold fewer than 2^32 entries.
JIT_ENTRIES = 1 << 32
#: Memory the process needs besides the render (Python, Mitsuba, Dr.Jit's
#: kernels and caches), not counted in the plan.
RESERVE = 256 << 20

GIB = float(1 << 30)


@dataclass(frozen=True)
class Band:
    """Rows ``first_row`` to ``first_row + rows - 1`` of a crop window
    ``width`` x ``height`` pixels: the part of the film one pass renders."""
    width: int
    height: int
    first_row: int
    rows: int

    @classmethod
    def whole(cls, width: int, height: int) -> "Band":
        return cls(width, height, 0, height)

    @property
    def pixels(self) -> int:
        return self.width * self.rows

    @property
    def first_pixel(self) -> int:
        """Row-major index of the band's first pixel in the crop window."""
        return self.first_row * self.width

    def widened(self, margin: int) -> "Band":
        """The band with up to ``margin`` more rows above and below."""
        first = max(self.first_row - margin, 0)
        last = min(self.first_row + self.rows + margin, self.height)
        return Band(self.width, self.height, first, last - first)


@dataclass(frozen=True)
class RenderPlan:
    """Bands of ``rows_per_band`` rows over a crop window ``width`` x
    ``height``, and the peak memory each part of the render needs."""
    width: int
    height: int
    rows_per_band: int
    film_bytes: int
    band_bytes: int
    launch_bytes: int

    @property
    def peak_bytes(self) -> int:
        return self.film_bytes + self.band_bytes + self.launch_bytes

    @property
    def band_count(self) -> int:
        return -(-self.height // self.rows_per_band)

    def bands(self):
        """The bands, top to bottom."""
        for first in range(0, self.height, self.rows_per_band):
            yield Band(self.width, self.height, first,
                       min(self.rows_per_band, self.height - first))


@dataclass(frozen=True)
class Demand:
    """What a render asks for: ``samples_per_pixel`` is the most camera
    samples a pixel may keep outside the kernels at once (1 where they are
    reduced launch by launch; the integrator's ``aa_budget`` bounds it),
    ``launch_samples`` the most camera samples or rays one launch traces,
    ``film_entries`` the floats of a film that holds the whole image (0
    when the image goes to a file band by band)."""
    width: int
    height: int
    samples_per_pixel: float
    launch_samples: int
    film_entries: int
    #: The integrator's parameter that bounds ``launch_samples``.
    launch_parameter: str = "wavefront_size"
    #: What the caller keeps as the bands arrive instead of a film (a file
    #: being encoded in memory), in bytes.
    held_bytes: int = 0
    #: Bytes a launch takes per camera sample (more where it is
    #: differentiated: the AD graph of its ray trees).
    launch_sample_bytes: int = LAUNCH_SAMPLE_BYTES


@dataclass(frozen=True)
class Limits:
    """What bounds the memory of a render. An integrator's ``limits`` are
    these defaults unless set; a smaller ``band_samples`` cuts even a small
    film into bands."""
    #: Most camera samples a band may keep outside the kernels at once.
    band_samples: int = 1 << 25
    #: Camera samples per pixel that bands are sized for, where a pixel may
    #: take more (adaptive and contrast refinement).
    typical_samples: int = 16
    #: The bytes of memory the machine has left (``None``: not known).
    memory: Callable[[], int | None] = available_memory


def plan_render(demand: Demand, limits: Limits = Limits()) -> RenderPlan:
    """The bands and peak memory of a render, or a :class:`ParameterError`
    naming what to lower where it cannot fit in this machine's memory or in
    Dr.Jit's arrays."""
    _check_entries(demand.film_entries, "film", demand)
    _check_entries(3 * demand.launch_samples, demand.launch_parameter, demand)
    sized_for = min(demand.samples_per_pixel, limits.typical_samples) * demand.width
    rows = int(max(1, min(demand.height, limits.band_samples // max(sized_for, 1))))
    kept = min(rows * demand.width * demand.samples_per_pixel, limits.band_samples)
    plan = RenderPlan(
        demand.width, demand.height, rows,
        film_bytes=4 * demand.film_entries + demand.held_bytes,
        band_bytes=int(kept * SAMPLE_BYTES + rows * demand.width * PIXEL_BYTES),
        launch_bytes=demand.launch_samples * demand.launch_sample_bytes)
    _check_fits(plan, demand, limits.memory())
    return plan


def _check_entries(entries: int, parameter: str, demand: Demand) -> None:
    """Refuse an array past Dr.Jit's 2^32 entries, naming what sets its size."""
    if entries < JIT_ENTRIES:
        return
    if parameter == "film":
        raise ParameterError(
            PLUGIN_NAME, "film",
            f"of {demand.width} x {demand.height} pixels holds {entries:,} values, more than "
            "a Dr.Jit array can (2^32); lower the film's 'width' and 'height'")
    raise ParameterError(
        PLUGIN_NAME, parameter,
        f"makes one launch hold {entries:,} values, more than a Dr.Jit array can (2^32); "
        f"lower '{parameter}'")


def _check_fits(plan: RenderPlan, demand: Demand, available: int | None) -> None:
    """Refuse a plan whose peak passes what the machine has left."""
    if available is None or plan.peak_bytes + RESERVE <= available:
        return
    parts = {"film": plan.film_bytes, "band": plan.band_bytes, "launch": plan.launch_bytes}
    largest = max(parts, key=parts.get)
    parameter, advice = {
        "film": ("film", "lower the film's 'width' and 'height'" + (
            ", or render to a file with 'mitsuba-whitted render', which needs no film of the "
            "whole image" if demand.film_entries else "")),
        "band": ("aa_budget", "lower 'aa_budget'"),
        "launch": (demand.launch_parameter, f"lower '{demand.launch_parameter}'"),
    }[largest]
    raise ParameterError(
        PLUGIN_NAME, parameter,
        f"makes this {demand.width} x {demand.height} render need about "
        f"{plan.peak_bytes / GIB:.1f} GiB of memory ({largest}: {parts[largest] / GIB:.1f} GiB), "
        f"and {available_text(available)}; {advice}")
