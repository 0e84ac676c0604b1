"""A Markdown report with PNG images and matplotlib plots.

Images are tone mapped with the sRGB curve (``imageio.to_8bit``); error
and energy maps use a colour map with a colour bar, so their values can be
read off. Every link is relative to the report's directory, so the report
can be moved or committed as a whole.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..files import write_atomically, write_text
from ..imageio import write_image

#: Widest PNG a report holds; larger renders are box-filtered down.
MAX_WIDTH = 300
#: Marker shapes that tell the Whitted settings apart in the speed plot.
_MARKERS = "sD^vP*Xph<>"


def fit_width(image: np.ndarray, width: int = MAX_WIDTH) -> np.ndarray:
    """Box-filter ``image`` by the smallest integer factor that fits ``width``."""
    factor = math.ceil(image.shape[1] / width)
    if factor <= 1:
        return image
    height, columns = (image.shape[0] // factor) * factor, (image.shape[1] // factor) * factor
    blocks = image[:height, :columns].reshape(height // factor, factor, columns // factor,
                                              factor, *image.shape[2:])
    return blocks.mean(axis=(1, 3))


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
        """Write a linear RGB image as an sRGB PNG; returns its link."""
        path, link = self._target(name)
        write_image(path, fit_width(np.asarray(image, dtype=np.float32)[..., :3]))
        return link

    def linear(self, name: str, image: np.ndarray) -> str:
        """Write a linear float image (EXR) for exact recomputation."""
        path, link = self._target(name)
        write_image(path, np.asarray(image, dtype=np.float32)[..., :3])
        return link

    def heatmap(self, name: str, values: np.ndarray, label: str, vmax: float | None = None,
                cmap: str = "inferno") -> str:
        """A scalar map with a colour bar labelled ``label``."""
        plt = _pyplot()
        path, link = self._target(name)
        values = fit_width(values)
        vmax = vmax if vmax else max(float(np.percentile(values, 99.5)), 1e-12)
        height, width = values.shape
        figure, axes = plt.subplots(figsize=(3.2, 3.2 * height / width + 0.2), dpi=90)
        shown = axes.imshow(values, cmap=cmap, vmin=0, vmax=vmax, interpolation="nearest")
        axes.set_axis_off()
        figure.colorbar(shown, ax=axes, fraction=0.046, pad=0.04).set_label(label, fontsize=8)
        _save(figure, path, bbox_inches="tight", pad_inches=0.04)
        return link

    def speed_plot(self, name: str, points, title: str, noise_floor: float | None = None) -> str:
        """relMSE against warm render time, both logarithmic: the path curve
        through its spp ladder and one marker per Whitted setting."""
        plt = _pyplot()
        path, link = self._target(name)
        figure, axes = plt.subplots(figsize=(7.6, 4.2), dpi=80)
        curve = sorted((p for p in points if p.kind == "path"), key=lambda p: p.spp)
        axes.plot([p.seconds for p in curve], [p.rel_mse for p in curve], "o-",
                  color="tab:blue", label="path (1, 2, 4, ... spp)")
        for p in curve[::2]:
            axes.annotate(f"{p.spp}", (p.seconds, p.rel_mse), textcoords="offset points",
                          xytext=(3, 3), fontsize=7, color="tab:blue")
        whitted = [p for p in points if p.kind == "whitted"]
        colours = plt.get_cmap("tab10")
        for index, p in enumerate(whitted):
            axes.plot(p.seconds, p.rel_mse, _MARKERS[index % len(_MARKERS)], markersize=7,
                      color=colours((index + 1) % 10), label=f"whitted: {p.label}")
        if noise_floor:
            axes.axhline(noise_floor, color="grey", linestyle="--", linewidth=1,
                         label="reference's own noise")
        axes.set_xscale("log")
        axes.set_yscale("log")
        axes.set_xlabel("warm render time (s)")
        axes.set_ylabel("relMSE against the reference")
        axes.set_title(title, fontsize=10)
        axes.grid(True, which="both", alpha=0.3)
        axes.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
        figure.tight_layout()
        _save(figure, path)
        return link


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
