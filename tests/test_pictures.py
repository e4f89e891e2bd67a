"""core.evaluate.pictures and core.evaluate.png: the demo's and the panel's pictures."""
from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from core.evaluate.pictures import energy_plot, lighting_spheres, shade_sphere, sphere_normals, to_srgb8
from core.evaluate.png import encode_png
from core.solve.sh import DIFFUSE


def test_png_bytes_decode_to_the_pixels():
    img = np.arange(5 * 7 * 3, dtype=np.uint8).reshape(5, 7, 3)
    data = encode_png(img)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    n = struct.unpack(">I", data[8:12])[0]
    assert data[12:16] == b"IHDR" and struct.unpack(">II", data[16:24]) == (7, 5)
    start = 8 + 12 + n
    m = struct.unpack(">I", data[start:start + 4])[0]
    assert data[start + 4:start + 8] == b"IDAT"
    raw = np.frombuffer(zlib.decompress(data[start + 8:start + 8 + m]), np.uint8).reshape(5, 1 + 21)
    np.testing.assert_array_equal(raw[:, 1:].reshape(5, 7, 3), img)
    with pytest.raises(ValueError):
        encode_png(img.astype(np.float32))


def test_srgb_tone_map_matches_the_standard_curve():
    out = to_srgb8(np.array([[[0.0, 0.0031308, 0.5], [1.0, 2.0, np.nan]]]))
    np.testing.assert_array_equal(out[0, 0], [0, 10, 188])   # 0.5 linear -> 0.7354 sRGB -> 188
    np.testing.assert_array_equal(out[0, 1], [40, 40, 40])   # NaN -> background


def test_sphere_shading_follows_the_sh_basis():
    n, inside = sphere_normals(32)
    assert np.allclose(np.linalg.norm(n[inside], axis=1), 1)
    assert n[0, 16, 2] > 0.8 and n[16, 0, 0] < -0.8 and n[16, 16, 1] < -0.99   # top +Z, left -X, centre faces -Y
    np.testing.assert_allclose(shade_sphere(DIFFUSE, 32)[inside], 1.0)
    top_light = np.zeros(9)
    top_light[2], top_light[3] = 0.5, 1.0       # brighter towards +Z
    s = shade_sphere(top_light, 32)[..., 0]
    assert s[4, 16] > s[16, 16] > s[28, 16]


def test_lighting_grid_and_energy_plot_shapes():
    sig = np.stack([np.tile(DIFFUSE, (3, 1))] * 6)
    g = lighting_spheres(sig, [f"v{i}" for i in range(6)], size=20, columns=4)
    assert g.shape[1] == 6 + 4 * 26 and g.dtype == np.uint8
    e = energy_plot(np.geomspace(1e5, 2e3, 30), width=300, height=200)
    assert e.shape == (200, 300, 3)
    red = (e[..., 0] > 150) & (e[..., 1] < 90)
    # The curve falls from the top left to the bottom right of the plot box.
    rows, cols = np.nonzero(red)
    assert rows[cols.argmin()] < rows[cols.argmax()]
    with pytest.raises(ValueError):
        energy_plot([0.0, -1.0])
