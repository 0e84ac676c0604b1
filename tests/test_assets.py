"""The committed texture images are what ``textures/make_textures.py`` draws."""

import importlib.util
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

TEXTURES = Path(__file__).resolve().parent.parent / "textures"


@pytest.fixture(scope="module")
def make_textures():
    spec = importlib.util.spec_from_file_location("make_textures", TEXTURES / "make_textures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def read_png(path: Path) -> np.ndarray:
    image = oiio.ImageInput.open(str(path))
    assert image is not None, oiio.geterror()
    pixels = image.read_image("uint8")
    image.close()
    return pixels


@pytest.mark.parametrize("name", ["lemons.png", "pink_elephant.png"])
def test_committed_png_is_reproduced_by_the_script(make_textures, name):
    path = TEXTURES / name
    assert path.stat().st_size < 1_000_000
    committed = read_png(path)
    assert committed.shape == (make_textures.SIZE, make_textures.SIZE, 3)
    drawn = make_textures.to_uint8(make_textures.DRAWINGS[name]())
    # One level of slack: libm's sin/sqrt may differ in the last bit between
    # machines, which can move a value across a rounding boundary.
    assert np.abs(drawn.astype(int) - committed.astype(int)).max() <= 1


def test_lemon_wallpaper_tiles_without_a_seam():
    """Across the wrap (last column to first, last row to first) the image
    changes no more than between neighbouring pixels inside it."""
    lemons = read_png(TEXTURES / "lemons.png").astype(float)
    inner_columns = np.abs(np.diff(lemons, axis=1)).mean(axis=(0, 2))
    inner_rows = np.abs(np.diff(lemons, axis=0)).mean(axis=(1, 2))
    wrap_column = np.abs(lemons[:, 0] - lemons[:, -1]).mean()
    wrap_row = np.abs(lemons[0] - lemons[-1]).mean()
    assert wrap_column <= np.percentile(inner_columns, 95)
    assert wrap_row <= np.percentile(inner_rows, 95)
    # Lemons do cross the vertical edges, so the wrap check is not vacuous.
    background = np.array([0.96, 0.95, 0.86]) * 255
    assert (np.abs(lemons[:, 0] - background).max(axis=1) > 30).mean() > 0.1
