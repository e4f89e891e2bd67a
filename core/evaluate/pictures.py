"""Small pictures of a run, drawn with NumPy: lighting spheres, side-by-side strips, the energy curve.

Everything returns uint8 sRGB ``(H, W, 3)`` arrays, row 0 at the top, ready
for :func:`core.evaluate.png.write_png` or a Blender image. Linear inputs are
tone-mapped by :func:`to_srgb8` (clip to [0, white], then the sRGB curve).
Labels use a built-in 3x5 pixel font (capitals, digits, ``+-._``), so no
imaging library is needed.
"""
from __future__ import annotations

import numpy as np

from ..solve.sh import sh_basis

__all__ = ["to_srgb8", "sphere_normals", "shade_sphere", "lighting_spheres", "strip", "grid", "energy_plot",
           "draw_text", "text_size", "BACKGROUND"]

#: Grey behind pictures and where an image has no value (NaN).
BACKGROUND = (40, 40, 40)

_FONT = {
    "0": "###|#.#|#.#|#.#|###", "1": ".#.|##.|.#.|.#.|###", "2": "###|..#|###|#..|###",
    "3": "###|..#|.##|..#|###", "4": "#.#|#.#|###|..#|..#", "5": "###|#..|###|..#|###",
    "6": "###|#..|###|#.#|###", "7": "###|..#|..#|.#.|.#.", "8": "###|#.#|###|#.#|###",
    "9": "###|#.#|###|..#|###", "-": "...|...|###|...|...", "+": "...|.#.|###|.#.|...",
    ".": "...|...|...|...|.#.", "_": "...|...|...|...|###", " ": "...|...|...|...|...",
    "A": ".#.|#.#|###|#.#|#.#", "B": "##.|#.#|##.|#.#|##.", "C": "###|#..|#..|#..|###",
    "D": "##.|#.#|#.#|#.#|##.", "E": "###|#..|##.|#..|###", "F": "###|#..|##.|#..|#..",
    "G": "###|#..|#.#|#.#|###", "H": "#.#|#.#|###|#.#|#.#", "I": "###|.#.|.#.|.#.|###",
    "J": "..#|..#|..#|#.#|###", "K": "#.#|#.#|##.|#.#|#.#", "L": "#..|#..|#..|#..|###",
    "M": "#.#|###|###|#.#|#.#", "N": "##.|#.#|#.#|#.#|#.#", "O": "###|#.#|#.#|#.#|###",
    "P": "##.|#.#|##.|#..|#..", "Q": "###|#.#|#.#|###|..#", "R": "##.|#.#|##.|#.#|#.#",
    "S": "###|#..|###|..#|###", "T": "###|.#.|.#.|.#.|.#.", "U": "#.#|#.#|#.#|#.#|###",
    "V": "#.#|#.#|#.#|#.#|.#.", "W": "#.#|#.#|###|###|#.#", "X": "#.#|#.#|.#.|#.#|#.#",
    "Y": "#.#|#.#|.#.|.#.|.#.", "Z": "###|..#|.#.|#..|###",
}


def to_srgb8(linear, white=1.0, background=BACKGROUND) -> np.ndarray:
    """Tone-map linear RGB to 8-bit sRGB: divide by ``white``, clip to [0, 1], encode; NaN -> background."""
    a = np.asarray(linear, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    a = np.repeat(a, 3, axis=2) if a.shape[2] == 1 else a[:, :, :3]
    bad = ~np.all(np.isfinite(a), axis=2)
    v = np.clip(np.nan_to_num(a / float(white)), 0.0, 1.0)
    v = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    out = np.round(v * 255).astype(np.uint8)
    out[bad] = background
    return out


def sphere_normals(size: int):
    """World normals of a unit sphere seen from the front (from -Y, +Z up, +X to the right).

    Returns
    -------
    normals : (size, size, 3) float64, NaN outside the disc
    inside : (size, size) bool
    """
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, z = np.meshgrid(c, -c)            # row 0 at the top = +Z
    r2 = x * x + z * z
    inside = r2 < 1
    n = np.stack([x, -np.sqrt(np.clip(1 - r2, 0, None)), z], axis=-1)
    n[~inside] = np.nan
    return n, inside


def shade_sphere(sh, size: int = 96) -> np.ndarray:
    """Linear shading ``sigma . nu(n)`` of the front-facing sphere, ``(size, size, C)``, NaN outside.

    ``sh`` is ``(C, 9)`` (or ``(9,)``), in the basis of :mod:`core.solve.sh`.
    """
    s = np.atleast_2d(np.asarray(sh, dtype=np.float64))
    n, inside = sphere_normals(size)
    out = np.full((size, size, s.shape[0]), np.nan)
    out[inside] = sh_basis(n[inside], dtype=np.float64) @ s.T
    return out


def _glyphs(text):
    return [_FONT.get(ch, _FONT[" "]) for ch in str(text).upper()]


def text_size(text, scale=2):
    """(height, width) in pixels of :func:`draw_text`'s output."""
    return 5 * scale, max(len(str(text)) * 4 * scale - scale, 0)


def draw_text(canvas, text, row, col, colour=(255, 255, 255), scale=2):
    """Draw ``text`` with the 3x5 font into a uint8 canvas, top-left at (row, col); clipped at the edges."""
    h, w = canvas.shape[:2]
    for k, glyph in enumerate(_glyphs(text)):
        for r, line in enumerate(glyph.split("|")):
            for c, ch in enumerate(line):
                if ch != "#":
                    continue
                r0, c0 = row + r * scale, col + (4 * k + c) * scale
                r1, c1 = min(r0 + scale, h), min(c0 + scale, w)
                if r1 > max(r0, 0) and c1 > max(c0, 0):
                    canvas[max(r0, 0):r1, max(c0, 0):c1] = colour
    return canvas


def strip(pictures, labels=None, gap=6, background=BACKGROUND, scale=2) -> np.ndarray:
    """Put uint8 pictures side by side (top-aligned), each with an optional label above it."""
    pics = [np.asarray(p, dtype=np.uint8) for p in pictures]
    labels = list(labels) if labels is not None else [None] * len(pics)
    top = (5 * scale + 2 * gap) if any(labels) else gap
    h = top + max(p.shape[0] for p in pics) + gap
    w = gap + sum(p.shape[1] + gap for p in pics)
    out = np.empty((h, w, 3), dtype=np.uint8)
    out[:] = background
    col = gap
    for p, label in zip(pics, labels):
        out[top:top + p.shape[0], col:col + p.shape[1]] = p[..., :3]
        if label:
            draw_text(out, label, gap, col, scale=scale)
        col += p.shape[1] + gap
    return out


def grid(pictures, labels=None, columns=4, gap=6, background=BACKGROUND, scale=2) -> np.ndarray:
    """Rows of :func:`strip`, ``columns`` pictures each, stacked (all rows padded to one width)."""
    pics = list(pictures)
    labels = list(labels) if labels is not None else [None] * len(pics)
    rows = [strip(pics[i:i + columns], labels[i:i + columns], gap, background, scale)
            for i in range(0, len(pics), columns)]
    w = max(r.shape[1] for r in rows)
    out = np.empty((sum(r.shape[0] for r in rows), w, 3), dtype=np.uint8)
    out[:] = background
    y = 0
    for r in rows:
        out[y:y + r.shape[0], :r.shape[1]] = r
        y += r.shape[0]
    return out


def lighting_spheres(sigmas, names=None, size=96, columns=4, white=None) -> np.ndarray:
    """One shaded sphere per view (``sigmas`` is ``(m, C, 9)``), in a grid, on one common exposure.

    ``white`` (default: 1.2 x the 99th percentile of all the shading shown) maps to
    full brightness, so the views' lights keep their relative strengths.
    """
    shades = [shade_sphere(s, size) for s in np.asarray(sigmas, dtype=np.float64)]
    if white is None:
        vals = np.concatenate([s[np.isfinite(s)] for s in shades])
        p99 = float(np.percentile(vals, 99)) if vals.size else 0.0
        white = 1.2 * p99 if p99 > 0 else 1.0     # a little headroom so bright sides keep their gradient
    pics = [to_srgb8(s, white) for s in shades]
    return grid(pics, names, columns=columns)


def _nice_step(span, target=6):
    raw = max(span, 1e-12) / target
    p = 10 ** np.floor(np.log10(raw))
    return next(m * p for m in (1, 2, 5, 10) if m * p >= raw)


def _line(canvas, r0, c0, r1, c1, colour, width=2):
    n = int(max(abs(r1 - r0), abs(c1 - c0))) + 1
    rr = np.round(np.linspace(r0, r1, n)).astype(int)
    cc = np.round(np.linspace(c0, c1, n)).astype(int)
    h, w = canvas.shape[:2]
    for dr in range(width):
        for dc in range(width):
            r, c = rr + dr - width // 2, cc + dc - width // 2
            ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            canvas[r[ok], c[ok]] = colour


def energy_plot(energy, width=480, height=300, title="ENERGY PER ITERATION") -> np.ndarray:
    """The convergence curve: energy against iteration, log-scale y with decade ticks, as uint8 RGB.

    Non-positive energies are drawn at the smallest positive one.
    """
    e = np.asarray(energy, dtype=np.float64).ravel()
    if e.size == 0 or not np.any(np.isfinite(e) & (e > 0)):
        raise ValueError("energy_plot: no positive energy to draw")
    pos = e[np.isfinite(e) & (e > 0)]
    e = np.where(np.isfinite(e) & (e > 0), e, pos.min())
    ink, grid_c, curve = (20, 20, 20), (215, 215, 215), (200, 40, 40)
    out = np.full((height, width, 3), 255, dtype=np.uint8)
    left, right, top, bottom = 62, 16, 28, 40
    x0, x1, y0, y1 = left, width - right, height - bottom, top      # plot box; y0 is the bottom row
    lo, hi = np.floor(np.log10(pos.min())), np.ceil(np.log10(pos.max()))
    if hi <= lo:
        hi = lo + 1
    xmax = max(len(e) - 1, 1)

    def px(i):
        return x0 + (x1 - x0) * i / xmax

    def py(v):
        return y0 + (y1 - y0) * (np.log10(v) - lo) / (hi - lo)

    # Grid and ticks: every decade labelled, 2..9 as light lines.
    for d in range(int(lo), int(hi) + 1):
        for m in ((1,) if d == hi else range(1, 10)):
            r = int(round(py(m * 10.0 ** d)))
            _line(out, r, x0, r, x1, grid_c if m > 1 else (175, 175, 175), width=1)
        r = int(round(py(10.0 ** d)))
        label = f"1E{d}"
        th, tw = text_size(label)
        draw_text(out, label, r - th // 2, x0 - 8 - tw, ink)
    step = _nice_step(xmax)
    for i in np.arange(0, xmax + 1e-9, step):
        c = int(round(px(i)))
        _line(out, y0, c, y0 + 5, c, ink, width=1)
        label = str(int(i))
        th, tw = text_size(label)
        draw_text(out, label, y0 + 9, c - tw // 2, ink)
    _line(out, y0, x0, y0, x1, ink, width=1)
    _line(out, y0, x0, y1, x0, ink, width=1)
    th, tw = text_size("ITERATION")
    draw_text(out, "ITERATION", height - th - 4, (x0 + x1 - tw) // 2, ink)
    draw_text(out, title, 8, x0, ink)
    rows, cols = py(e), px(np.arange(len(e)))
    for k in range(len(e) - 1):
        _line(out, rows[k], cols[k], rows[k + 1], cols[k + 1], curve, width=2)
    if len(e) == 1:
        _line(out, rows[0], cols[0], rows[0], cols[0], curve, width=4)
    return out
