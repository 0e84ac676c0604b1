"""A Markdown report with PNG images and matplotlib plots.

Images are tone mapped with the sRGB curve (``imageio.to_8bit``) and
written pixel for pixel, crops enlarged by whole factors; error and energy
maps use a colour map with a colour bar, so their values can be read off. Every link is relative to the report's directory, so the report
can be moved or committed as a whole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..files import write_atomically, write_text
from ..imageio import write_image, write_pixels
from .intervals import tile_sums
from .metrics import TILE_SIDES

#: Marker shapes that tell the Whitted settings apart in the speed plot.
_MARKERS = "sD^vP*Xph<>"
#: Narrowest a map's own area in a heatmap is shown, in pixels: smaller
#: maps are enlarged (each value a block), larger ones shown pixel for pixel.
MIN_MAP_WIDTH = 288
#: Dots per inch of the heatmaps, and the width their colour bar takes.
_DPI = 100
_COLOUR_BAR_WIDTH = 100


def upscaled(image: np.ndarray, factor: int) -> np.ndarray:
    """Each pixel of ``image`` as a ``factor`` x ``factor`` block (nearest
    neighbour: the pixels stay visible as they are)."""
    return np.repeat(np.repeat(image, factor, axis=0), factor, axis=1)


def worst_window(values: np.ndarray, side: int,
                 tile: int = TILE_SIDES["relmse"]) -> tuple[int, int]:
    """Top-left corner of a ``side``-pixel square of ``values`` centred on
    the ``tile``-pixel tile with the largest sum (kept inside the map)."""
    sums = tile_sums(values, tile)
    columns = -(-values.shape[1] // tile)
    row, column = divmod(int(np.argmax(sums)), columns)
    return tuple(int(np.clip(tile * index + tile // 2 - side // 2, 0, size - side))
                 for index, size in ((row, values.shape[0]), (column, values.shape[1])))


def shared_vmax(maps: list[np.ndarray]) -> float:
    """Top of one colour scale for all of ``maps``: their 99.5th percentile,
    so that a few outliers do not leave every other value dark."""
    return max(float(np.percentile(np.concatenate([m.ravel() for m in maps]), 99.5)), 1e-12)


def colour_stops(cmap: str, count: int = 11) -> list[str]:
    """``count`` colours evenly along the matplotlib colour map ``cmap``,
    as CSS hex colours: enough for a page to draw its colour bar."""
    colours = _pyplot().get_cmap(cmap)(np.linspace(0, 1, count))[:, :3]
    return ["#" + "".join(f"{round(255 * c):02x}" for c in colour) for colour in colours]


def number(value: float, digits: int = 3) -> str:
    """A number for a table: ``digits`` significant digits, '-' for NaN."""
    return "-" if value is None or math.isnan(value) else f"{value:.{digits}g}"


class MarkdownReport:
    """Collects Markdown lines; images are written next to it as they come."""

    def __init__(self, directory: str | Path, title: str, image_dir: str = "images"):
        self.directory = Path(directory)
        self.image_dir = image_dir
        self.lines = [f"# {title}", ""]

    # ------------------------------------------------------------ text

    def heading(self, text: str, level: int = 2) -> None:
        self.lines += [f"{'#' * level} {text}", ""]

    def paragraph(self, text: str) -> None:
        self.lines += [text, ""]

    def table(self, header: list[str], rows: list[list]) -> None:
        self.lines.append("| " + " | ".join(header) + " |")
        self.lines.append("|" + "|".join("---" for _ in header) + "|")
        for row in rows:
            self.lines.append("| " + " | ".join(str(cell) for cell in row) + " |")
        self.lines.append("")

    def figures(self, items: list[tuple[str, str]]) -> None:
        """A row of (image link, caption) pairs, as a table."""
        self.table([caption for _, caption in items],
                   [[f"![{caption}]({link})" for link, caption in items]])

    def figure(self, link: str, alt: str) -> None:
        self.lines += [f"![{alt}]({link})", ""]

    def write(self, name: str = "README.md") -> Path:
        return write_text(self.directory / name, "\n".join(self.lines).rstrip() + "\n")

    # ---------------------------------------------------------- images

    def _target(self, name: str) -> tuple[Path, str]:
        return self.directory / self.image_dir / name, f"{self.image_dir}/{name}"

    def image(self, name: str, image: np.ndarray) -> str:
        """Write a linear RGB image as an sRGB PNG, pixel for pixel; returns
        its link."""
        path, link = self._target(name)
        write_image(path, np.asarray(image, dtype=np.float32)[..., :3])
        return link

    def crop(self, name: str, image: np.ndarray, corner: tuple[int, int], side: int,
             factor: int) -> str:
        """The ``side``-pixel square of ``image`` at ``corner``, each pixel
        enlarged to ``factor`` x ``factor``, as an sRGB PNG; its link."""
        top, left = corner
        return self.image(name, upscaled(image[top:top + side, left:left + side], factor))

    def linear(self, name: str, image: np.ndarray) -> str:
        """Write a linear float image (EXR) for exact recomputation."""
        path, link = self._target(name)
        write_image(path, np.asarray(image, dtype=np.float32)[..., :3])
        return link

    def colour_map(self, name: str, values: np.ndarray, vmax: float, cmap: str) -> str:
        """A scalar map in false colour, pixel for pixel and without a
        colour bar (a page draws that itself); its link."""
        path, link = self._target(name)
        colours = _pyplot().get_cmap(cmap)(np.clip(values / vmax, 0, 1))[..., :3]
        write_pixels(path, np.round(colours * 255).astype(np.uint8))
        return link

    def heatmap(self, name: str, values: np.ndarray, label: str, vmax: float | None = None,
                cmap: str = "inferno") -> str:
        """A scalar map with a colour bar labelled ``label``, the map pixel
        for pixel (enlarged by a whole factor up to :data:`MIN_MAP_WIDTH`)."""
        plt = _pyplot()
        path, link = self._target(name)
        vmax = vmax if vmax else max(float(np.percentile(values, 99.5)), 1e-12)
        height, width = values.shape
        factor = max(1, -(-MIN_MAP_WIDTH // width))
        shown = width * factor
        total = shown + _COLOUR_BAR_WIDTH
        figure = plt.figure(figsize=(total / _DPI, height * factor / _DPI), dpi=_DPI)
        axes = figure.add_axes((0, 0, shown / total, 1))
        bar = figure.add_axes(((shown + 8) / total, 0.05, 12 / total, 0.9))
        mapped = axes.imshow(values, cmap=cmap, vmin=0, vmax=vmax, interpolation="nearest")
        axes.set_axis_off()
        figure.colorbar(mapped, cax=bar).set_label(label, fontsize=8)
        bar.tick_params(labelsize=7)
        _save(figure, path)
        return link

    def speed_plot(self, name: str, panels: list["Panel"], title: str) -> str:
        """Error against warm render time, both logarithmic, one panel per
        metric: path's curves, and for each Whitted setting its total error
        (filled) above its sampling error (hollow), and the model's bias
        as a line."""
        plt = _pyplot()
        path, link = self._target(name)
        figure, axes_row = plt.subplots(1, len(panels), figsize=(6.2 * len(panels) + 3.2, 5.0),
                                        dpi=100, squeeze=False, layout="constrained")
        for axes, panel in zip(axes_row[0], panels):
            _draw_panel(axes, panel, plt.get_cmap("tab20"))
        handles, labels = axes_row[0][0].get_legend_handles_labels()
        figure.legend(handles, labels, fontsize=7, loc="outside right upper")
        figure.suptitle(title, fontsize=10)
        _save(figure, path)
        return link


@dataclass
class Curve:
    """One of path's ladders: its time, error and spp at each rung."""

    label: str
    seconds: list
    errors: list
    spp: list


@dataclass
class Marker:
    """A Whitted setting: its time, total error and sampling error."""

    label: str
    seconds: float
    total: float
    sampling: float


@dataclass
class Panel:
    """One metric's panel of the speed plot; ``biases`` are (label, error)
    pairs, ``floor`` the reference's own noise in this metric if known."""

    metric: str
    curves: list
    markers: list
    biases: list
    floor: float | None = None


#: Where each model's bias line is labelled, in turn (models often err
#: alike, and their labels would cover one another at one place): the
#: share of the axes' width, the alignment, and the shift in points.
_BIAS_LABELS = ((1.0, "right", -2), (0.0, "left", 2), (0.5, "center", 0))
#: Colour and line of each of path's curves, in turn.
_CURVE_STYLES = (("tab:blue", "o-"), ("tab:cyan", "s--"), ("tab:purple", "^:"))


def _draw_panel(axes, panel: Panel, colours) -> None:
    for curve, (colour, style) in zip(panel.curves, _CURVE_STYLES):
        axes.plot(curve.seconds, curve.errors, style, color=colour, markersize=4,
                  label=f"path, {curve.label} ({curve.spp[0]} to {curve.spp[-1]} spp)")
    first = panel.curves[0]
    for seconds, error, spp in list(zip(first.seconds, first.errors, first.spp))[::2]:
        axes.annotate(f"{spp}", (seconds, error), textcoords="offset points", xytext=(3, 3),
                      fontsize=6, color=_CURVE_STYLES[0][0])
    for index, marker in enumerate(panel.markers):
        colour, shape = colours((index + 2) % 20), _MARKERS[index % len(_MARKERS)]
        axes.plot([marker.seconds] * 2, [marker.total, marker.sampling], "-", color=colour,
                  alpha=0.4, linewidth=1)
        axes.plot(marker.seconds, marker.total, shape, color=colour, markersize=7,
                  label=f"whitted: {marker.label}")
        axes.plot(marker.seconds, marker.sampling, shape, color=colour, markersize=7,
                  markerfacecolor="none")
    # A model without bias (path's own, with indirect light) has no place
    # on a logarithmic axis.
    for index, (label, error) in enumerate((label, error) for label, error in panel.biases
                                           if error > 0):
        place, align, shift = _BIAS_LABELS[index % len(_BIAS_LABELS)]
        axes.axhline(error, color="grey", linestyle=(0, (1, 1 + index)), linewidth=1)
        axes.annotate(f"model bias: {label}", (place, error), xycoords=("axes fraction", "data"),
                      xytext=(shift, 2), textcoords="offset points", ha=align, fontsize=6,
                      color="dimgrey")
    if panel.floor:
        axes.axhline(panel.floor, color="grey", linestyle="--", linewidth=1,
                     label="reference's own noise")
    axes.plot([], [], "o", color="grey", markerfacecolor="none",
              label="hollow: sampling error (against Whitted converged)")
    axes.set_xscale("log")
    axes.set_yscale("log")
    axes.set_xlabel("warm render time (s), median of the rounds")
    axes.set_ylabel(f"{panel.metric} against the reference")
    axes.grid(True, which="both", alpha=0.3)


def _save(figure, path: Path, **options) -> None:
    """A matplotlib figure as a PNG, written whole or not at all, then closed."""
    try:
        write_atomically(path, lambda file: figure.savefig(file, format="png", **options))
    finally:
        _pyplot().close(figure)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
