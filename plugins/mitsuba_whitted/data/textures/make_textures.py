"""Draw the image textures of the report's scene: lemons and a pink elephant.

The report textured a sphere with a lemon wallpaper and its ground plane
with a pink-elephant picture found on the web; neither can be shipped, so
this script draws stand-ins. It is deterministic (no randomness): running it
again reproduces ``lemons.png`` and ``pink_elephant.png`` next to it::

    python textures/make_textures.py

Shapes are drawn as signed distances in pixels, and a pixel is covered by
``clip(0.5 - distance, 0, 1)``: a one-pixel-wide linear ramp across every
edge, which anti-aliases without supersampling. Colours are sRGB in [0, 1].
Needs only numpy and OpenImageIO.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mitsuba_whitted.imageio import write_pixels

SIZE = 512
HERE = Path(__file__).resolve().parent


# --- shapes: signed distance (pixels, negative inside) on a pixel grid ---

def pixel_grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """x (column) and y (row, downwards) of every pixel centre."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64) + 0.5
    return x, y


def wrapped(delta: np.ndarray, period: float | None) -> np.ndarray:
    """The offset to the nearest periodic copy, so shapes tile seamlessly."""
    if period is None:
        return delta
    return (delta + period / 2) % period - period / 2


def ellipse(x, y, center, radii, angle_deg=0.0, period=None) -> np.ndarray:
    """Approximate signed distance to a rotated ellipse: the implicit
    function divided by its gradient length, exact on the boundary, which is
    all the one-pixel coverage ramp needs."""
    dx = wrapped(x - center[0], period)
    dy = wrapped(y - center[1], period)
    angle = np.radians(angle_deg)
    u = np.cos(angle) * dx + np.sin(angle) * dy
    v = -np.sin(angle) * dx + np.cos(angle) * dy
    a, b = radii
    f = np.hypot(u / a, v / b)
    gradient = np.hypot(u / a**2, v / b**2) / np.maximum(f, 1e-12)
    return (f - 1.0) / np.maximum(gradient, 1e-12)


def stroke(x, y, points, width) -> np.ndarray:
    """Signed distance to a polyline of the given width with round ends."""
    points = np.asarray(points, dtype=np.float64)
    distance = np.full(x.shape, np.inf)
    for (ax, ay), (bx, by) in zip(points[:-1], points[1:]):
        ex, ey = bx - ax, by - ay
        t = np.clip(((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        distance = np.minimum(distance, np.hypot(x - ax - t * ex, y - ay - t * ey))
    return distance - width / 2


def polygon(x, y, vertices) -> np.ndarray:
    """Signed distance to a simple polygon (even-odd inside test)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    closed = np.vstack([vertices, vertices[:1]])
    outline = stroke(x, y, closed, 0.0)
    inside = np.zeros(x.shape, dtype=bool)
    for (ax, ay), (bx, by) in zip(closed[:-1], closed[1:]):
        crosses = (ay > y) != (by > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = ax + (y - ay) * (bx - ax) / (by - ay)
        inside ^= crosses & (x < x_cross)
    return np.where(inside, -outline, outline)


def paint(image: np.ndarray, distance: np.ndarray, color, opacity: float = 1.0) -> None:
    """Composite ``color`` over ``image`` where ``distance`` < 0, anti-aliased."""
    coverage = opacity * np.clip(0.5 - distance, 0.0, 1.0)[..., None]
    image *= 1.0 - coverage
    image += coverage * np.asarray(color, dtype=np.float64)


def canvas(size: int, color) -> np.ndarray:
    return np.broadcast_to(np.asarray(color, dtype=np.float64), (size, size, 3)).copy()


# --- lemons: a seamless wallpaper ---

LEMON_BACKGROUND = (0.96, 0.95, 0.86)
LEMON_RIND = (0.98, 0.84, 0.12)
LEMON_EDGE = (0.87, 0.64, 0.05)
LEMON_HIGHLIGHT = (1.0, 0.98, 0.78)
LEAF = (0.33, 0.62, 0.22)
LEAF_VEIN = (0.20, 0.42, 0.13)


def draw_lemon(image, x, y, center, angle_deg, scale, period) -> None:
    """One lemon: darker rim, rind, the two pointed ends, a highlight, a leaf."""
    angle = np.radians(angle_deg)
    axis = np.array([np.cos(angle), np.sin(angle)])
    normal = np.array([-axis[1], axis[0]])
    center = np.asarray(center, dtype=np.float64)

    def at(along: float, across: float = 0.0):
        return center + scale * (along * axis + across * normal)

    length, girth = 46 * scale, 33 * scale
    for grow, color in ((2.5, LEMON_EDGE), (0.0, LEMON_RIND)):
        for end in (-1, 1):
            paint(image, ellipse(x, y, at(end * 44), (11 * scale + grow, 8 * scale + grow),
                                 angle_deg, period), color)
        paint(image, ellipse(x, y, center, (length + grow, girth + grow), angle_deg, period),
              color)
    paint(image, ellipse(x, y, at(-12, -14), (17 * scale, 6 * scale), angle_deg - 12, period),
          LEMON_HIGHLIGHT, opacity=0.8)
    leaf_center = at(50, -14)
    paint(image, ellipse(x, y, leaf_center, (24 * scale, 9 * scale), angle_deg - 40, period),
          LEAF)
    paint(image, ellipse(x, y, leaf_center, (20 * scale, 1.2 * scale), angle_deg - 40, period),
          LEAF_VEIN)


def draw_lemons(size: int = SIZE) -> np.ndarray:
    """A wallpaper of lemons on a cream background; it tiles seamlessly
    (every shape is drawn with coordinates wrapped at the image size)."""
    image = canvas(size, LEMON_BACKGROUND)
    x, y = pixel_grid(size)
    cells = 4
    cell = size / cells
    angles = (25.0, -35.0, 70.0, 160.0, -10.0, 115.0)
    for row in range(cells):
        for column in range(cells):
            # Brick layout: odd rows shifted by half a cell.
            center = ((column + 0.5 + 0.5 * (row % 2)) * cell, (row + 0.5) * cell)
            angle = angles[(row * cells + column) % len(angles)]
            draw_lemon(image, x, y, center, angle, scale=cell / 128, period=size)
    return image


# --- a pink cartoon elephant ---

ELEPHANT_BACKGROUND = (0.88, 0.95, 0.98)
PINK = (0.96, 0.62, 0.76)
PINK_SHADE = (0.88, 0.50, 0.66)
PINK_LIGHT = (0.99, 0.78, 0.86)
TOENAIL = (1.0, 0.95, 0.93)
EYE_WHITE = (1.0, 1.0, 1.0)
PUPIL = (0.12, 0.08, 0.10)
GROUND_SHADOW = (0.55, 0.62, 0.66)


def trunk_curve() -> np.ndarray:
    """Points (512-pixel layout) of the trunk's centre line: a quadratic
    Bézier down from the face, then an arc curling back towards the body."""
    t = np.linspace(0.0, 1.0, 24)[:, None]
    start, control, end = np.array([(420, 225), (478, 290), (452, 372)], dtype=np.float64)
    bezier = (1 - t) ** 2 * start + 2 * (1 - t) * t * control + t**2 * end
    centre, radius = np.array([428.0, 366.0]), 24.5
    angles = np.radians(np.linspace(14.0, 200.0, 10)[1:])
    arc = centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return np.vstack([bezier, arc])


def draw_pink_elephant(size: int = SIZE) -> np.ndarray:
    """A pink cartoon elephant facing right on a pale blue background: body,
    four legs with toenails, head, ear, curled trunk, eye, tail."""
    image = canvas(size, ELEPHANT_BACKGROUND)
    x, y = pixel_grid(size)
    s = size / 512  # the drawing is laid out on a 512-pixel canvas

    def p(px: float, py: float):
        return (px * s, py * s)

    paint(image, ellipse(x, y, p(250, 452), (185 * s, 22 * s)), GROUND_SHADOW, opacity=0.35)
    # Far legs first, in the darker shade, then the body over their tops.
    far_legs = [(160, 168), (300, 308)]
    near_legs = [(130, 126), (270, 266)]
    for top_x, foot_x in far_legs:
        paint(image, stroke(x, y, [p(top_x, 330), p(foot_x, 430)], 50 * s), PINK_SHADE)
    paint(image, stroke(x, y, [p(95, 290), p(58, 330), p(52, 360)], 9 * s), PINK_SHADE)
    paint(image, polygon(x, y, [p(52, 352), p(40, 380), p(52, 372), p(64, 380)]), PINK_SHADE)
    paint(image, ellipse(x, y, p(230, 300), (145 * s, 105 * s)), PINK)
    paint(image, ellipse(x, y, p(205, 255), (90 * s, 35 * s), -8), PINK_LIGHT, opacity=0.6)
    for top_x, foot_x in near_legs:
        paint(image, stroke(x, y, [p(top_x, 340), p(foot_x, 440)], 54 * s), PINK)
    for (_, foot_x), foot_y in [(leg, 446) for leg in far_legs] + [(leg, 457) for leg in near_legs]:
        for nail in (-14, 0, 14):
            paint(image, ellipse(x, y, p(foot_x + nail, foot_y), (5 * s, 6 * s)), TOENAIL)
    # Trunk: a curve from the head down, curling up at the tip, tapering in
    # overlapping steps.
    trunk = trunk_curve()
    for start, width in ((0, 46), (12, 38), (22, 30)):
        paint(image, stroke(x, y, [p(*point) for point in trunk[start:]], width * s), PINK)
    paint(image, ellipse(x, y, p(370, 200), (85 * s, 78 * s)), PINK)
    paint(image, ellipse(x, y, p(318, 215), (58 * s, 80 * s), 12), PINK_SHADE)
    paint(image, ellipse(x, y, p(322, 218), (42 * s, 62 * s), 12), PINK_LIGHT)
    paint(image, ellipse(x, y, p(408, 180), (14 * s, 17 * s)), EYE_WHITE)
    paint(image, ellipse(x, y, p(412, 184), (7 * s, 9 * s)), PUPIL)
    paint(image, ellipse(x, y, p(409, 179), (2.5 * s, 2.5 * s)), EYE_WHITE)
    paint(image, ellipse(x, y, p(420, 225), (16 * s, 10 * s)), PINK_SHADE, opacity=0.5)
    return image


def to_uint8(image: np.ndarray) -> np.ndarray:
    return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)


DRAWINGS = {"lemons.png": draw_lemons, "pink_elephant.png": draw_pink_elephant}


def main() -> None:
    for name, draw in DRAWINGS.items():
        write_pixels(HERE / name, to_uint8(draw()))
        print(f"wrote {HERE / name}")


if __name__ == "__main__":
    main()
