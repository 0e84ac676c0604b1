"""The interactive page of a comparison: ``index.html`` beside ``report.md``.

The page is one HTML file that needs no network and no build step: the
templates of this folder (``viewer.html``, with ``viewer.css`` and
``viewer.js`` put inline) and the data it shows in a JSON block. The images
are files next to it, in the report's image folder: the renders are the
report's own 8-bit sRGB PNGs, pixel for pixel, and each error map is a
false-colour PNG, pixel for pixel, whose colour bar the page draws from the
colours given in the data.

Exposure is applied in the page to those 8-bit sRGB PNGs, in linear light:
an SVG filter looks each 8-bit level up in a table that the script makes,
the level decoded from sRGB, scaled by 2^stops and encoded again. (The
filter's own ``linearRGB`` conversion would do the same through 8-bit
linear values, which turns the darkest sRGB levels black.) A page
opened from ``file://`` can neither fetch a binary file next to it nor read
back the pixels of an image it drew on a canvas (the canvas is tainted), so
float images would have to be inlined as text, a dozen megabytes per image
at 600 x 600; the PNGs cost nothing more, as the report writes them anyway.
What they lose: values above 1 were clipped when written, so a negative
exposure shows bright highlights as flat, and a strong positive one shows
the 8-bit steps of dark regions.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...files import write_text
from ..metrics import METRIC_NAMES, error_maps
from ..report import MarkdownReport, colour_stops, shared_vmax

TEMPLATES = Path(__file__).parent
#: Colour map and colour bar label of each metric's error map. FLIP's
#: values lie in [0, 1], so its scale is fixed; relMSE's is shared by the
#: maps of one page (see :func:`shared_vmax`).
MAP_STYLES = {"relmse": ("inferno", "relative squared error"),
              "flip": ("magma", "FLIP")}


@dataclass
class ViewerImage:
    """A render the page shows: its label, ``key`` (the name
    ``results.json`` gives its image), link to its PNG and linear pixels
    (for its error maps)."""

    label: str
    key: str
    link: str
    pixels: np.ndarray


@dataclass
class ViewerTable:
    """A table of the page, its cells already as text."""

    title: str
    header: list
    rows: list


def write_viewer(report: MarkdownReport, title: str, summary: str, images: list[ViewerImage],
                 results: dict, tables: list[ViewerTable]) -> Path:
    """``index.html`` in the report's folder, showing ``images`` (the
    reference first) with their error maps, the speed plot of ``results``
    (``results.json``'s data) and ``tables``; its path. The maps are
    written into the report's image folder."""
    maps, scales = _error_maps(report, images)
    data = {"title": title, "summary": summary, "results": results,
            "metricNames": METRIC_NAMES, "scales": scales,
            "images": [{"label": image.label, "key": image.key,
                        "src": image.link, "maps": maps.get(image.key, {})}
                       for image in images],
            "tables": [vars(table) for table in tables]}
    return write_text(report.directory / "index.html", page(data))


def _error_maps(report: MarkdownReport, images: list[ViewerImage]) -> tuple[dict, dict]:
    """The false-colour maps of every image against the first (the
    reference), as {image key: {metric: link}}, and each metric's scale."""
    reference = images[0].pixels
    values = {image.key: error_maps(image.pixels, reference) for image in images[1:]}
    metrics = [m for m in MAP_STYLES if all(m in found for found in values.values())]
    scales = {}
    for metric in metrics:
        cmap, label = MAP_STYLES[metric]
        vmax = 1.0 if metric == "flip" else shared_vmax([v[metric] for v in values.values()])
        scales[metric] = {"label": label, "max": vmax, "colours": colour_stops(cmap)}
    links = {key: {metric: report.colour_map(f"{key}_{metric}.png", found[metric],
                                             scales[metric]["max"], MAP_STYLES[metric][0])
                   for metric in metrics}
             for key, found in values.items()}
    return links, scales


def page(data: dict) -> str:
    """The HTML of the page: the template with its style, script and
    ``data`` inline. ``</`` is escaped in the JSON so that no string in it
    can end its script element."""
    template = (TEMPLATES / "viewer.html").read_text()
    blob = json.dumps(_without_nan(data), allow_nan=False).replace("</", "<\\/")
    return (template.replace("/*STYLE*/", (TEMPLATES / "viewer.css").read_text())
            .replace("/*SCRIPT*/", (TEMPLATES / "viewer.js").read_text())
            .replace("/*DATA*/", blob))


def _without_nan(value):
    """``value`` with every NaN (a metric not measured, such as FLIP
    without its package) as ``None``: JavaScript's JSON has no NaN."""
    if isinstance(value, dict):
        return {key: _without_nan(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_without_nan(item) for item in value]
    return None if isinstance(value, float) and math.isnan(value) else value
