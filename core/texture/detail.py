"""The albedo at the photos' full resolution, one photo at a time (the "detail" stage).

The solve runs on photos downscaled to the working resolution. That is plenty for the lighting, which is smooth
by nature, but the albedo then holds no finer detail than those copies. Under the solved lighting, a pixel's
albedo is its value divided by its shading (what :func:`core.solve.lighting.division_start` does for one
observation), and that needs no solve: so this stage takes each photo at its own resolution in turn, bakes that
view in bands of rows (:func:`core.geometry.bake.row_bands`), divides every pixel by its shading
``sigma_v . T`` (T the transfer at the pixel, :class:`core.geometry.transfer.OcclusionGrid`; the shading floored
as the solve floors it) and adds the quotient into the texel that holds its UV (as
:func:`core.texture.fuse.fuse_views` does), each pixel weighted by

* its view weight (the cosine to the camera), as the fusion weighs views,
* its squared shading, so that the mean is the least-squares albedo of the texel's pixels (as
  :func:`core.solve.lighting.division_start` takes it) and dark pixels, whose quotient is noisiest, count least,
  and
* how well its view agreed with the other views at the working resolution (:func:`agreement`): Tukey's
  biweight of the log ratio between the view's own quotient and the median of all views' quotients, so that a
  highlight, a misregistered edge or a shadow the lighting does not explain, seen in one photo, drops out.

The bands are baked and divided on the stage's threads, a few at a time, and added in by the calling thread in
their order (so the texture does not depend on the threads). Memory holds the texture's accumulators and one
photo, or two while the next one is read (on a thread of its own, beside the bands). A texel's value is the
weighted mean of its pixels, with a small weight (:data:`PRIOR_WEIGHT`) of the working-resolution albedo; a texel
no pixel reached takes its neighbours' pixels, or else the working-resolution albedo.
"""

from __future__ import annotations

import contextlib
import time
from concurrent.futures import wait

import numpy as np

from ..errors import DelightError
from ..geometry.bake import mesh_normals, row_bands
from ..geometry.bilinear import interpolate
from ..geometry.raycast import Triangles
from ..geometry.texels import MATCHED_SIZE_MAX, bilinear_texels, pixel_matched_size, texel_index, texels_reached
from ..geometry.transfer import shading_rows
from ..io.photos import photo_pixels
from ..masks import masked
from ..parallel import resolve_threads, start, streamed, thread_map
from ..progress import check_cancel
from ..solve.highlights import clipped_regions, highlights
from ..solve.lighting import dark_floor_bounds, raised
from .fill import outline_pixels
from .fuse import fuse_views

__all__ = ["PRIOR_WEIGHT", "shading", "view_shadings", "shading_floors", "agreement", "detail_albedo"]

#: Weight of the working-resolution albedo in every texel's mean: a texel reached by full-resolution pixels of
#: total weight w takes w / (w + PRIOR_WEIGHT) of their mean (a pixel seen head-on weighs 1).
PRIOR_WEIGHT = 0.05
# The agreement weight is Tukey's biweight of the log ratio, zero beyond this many robust standard deviations
# (Tukey's constant, 95 % efficient on normal data) and never for less than the floor (a 10 % disagreement);
# the least weight keeps a texel whose every view disagrees (strong detail) a weighted mean.
_SCALE_SIGMAS = 4.685
_SCALE_MIN = 0.1
_LEAST_AGREEMENT = 1e-3
# Pixels per band of rows of the full-resolution bake.
_BAND_PIXELS = 1_000_000
# Texel rows per block of the final means (:func:`_mean`).
_MEAN_ROWS = 32


def shading(normal, uv, sigma_view, cells=None, floor=None, sun=None, position=None, values=None) -> np.ndarray:
    """The shading ``sigma_v . T`` of pixels, ``(P, C)`` float32, raised to its floor if ``floor`` is given.

    Parameters
    ----------
    normal, uv : (P, 3), (P, 2) arrays
        The pixels' unit normals and UVs.
    sigma_view : (C, K) array
        The view's lighting.
    cells : core.geometry.transfer.OcclusionGrid, optional
        The occlusion; without it T is ``nu(n)``, the paper's model.
    floor : (C, 3) array, optional
        Per channel, :func:`core.solve.lighting.dark_floor_bounds` (:func:`shading_floors`); ``values`` (P, C)
        the pixels' photo values, which the floor follows as the albedo stage's does.
    sun : core.geometry.sun.SunLight, optional
        A sun term, the last of the lighting's coefficients; ``position`` (P, 3) the pixels' world points.
    """
    s = shading_rows(sigma_view, normal, uv, cells, sun, position)
    if floor is None:
        return s
    if values is None:
        raise ValueError("shading: a floor follows the pixels' values; none were given")
    return _floored(s, values, floor)


def _floored(shade, values, floor) -> np.ndarray:
    """``shade`` (P, C) raised in place, channel by channel, to the floor that ``values`` (P, C) give under the
    bounds ``floor`` (C, 3) (:func:`core.solve.lighting.raised`); returns it."""
    for c in range(shade.shape[1]):
        shade[:, c] = raised(shade[:, c], values[:, c], floor[c])
    return shade


def view_shadings(sigma, normals, uvs, masks, cells=None, sun=None, positions=None, threads=None) -> list:
    """Per view, the shading of its masked pixels, ``(P_v, C)`` float32, not floored (:func:`shading`).

    Both :func:`shading_floors` and :func:`agreement` take it, so the working-resolution views are shaded once.
    ``sun`` and the views' world ``positions``: as :func:`shading`. ``threads``: views shaded at once (None:
    every available core).
    """

    def view(v):
        m = masks[v]
        return shading(
            masked(normals[v], m),
            masked(uvs[v], m),
            sigma[v],
            cells,
            sun=sun,
            position=None if sun is None else masked(positions[v], m),
        )

    return thread_map(view, range(len(masks)), threads)


def shading_floors(shades, photos, masks) -> np.ndarray:
    """Per channel, the albedo stage's floor bounds over every view's pixels: ``(C, 3)``.

    :func:`core.solve.lighting.dark_floor_bounds` of the working-resolution ``photos`` under ``shades``
    (:func:`view_shadings`).
    """
    shade = np.concatenate(shades)
    values = np.concatenate([masked(p, m) for p, m in zip(photos, masks)])
    return np.array(
        [dark_floor_bounds(shade[:, c].astype(np.float64), values[:, c]) for c in range(shade.shape[1])],
        np.float64,
    )


def _log_ratio(q, b):
    """Per pixel, the RMS over the channels of ``log(q / b)``, both kept off zero."""
    eps = 1e-3 + 0.02 * float(np.median(b)) if b.size else 1e-3
    e = np.log(np.maximum(q, 0) + eps) - np.log(np.maximum(b, 0) + eps)
    return np.sqrt(np.mean(e * e, axis=1))


def agreement(photos, masks, uvs, shades, weights, floor, clipped=None, threads=None) -> list:
    """Per view, a weight in (0, 1] per working-resolution pixel: how well the view agrees with the others.

    Each pixel's own albedo (its value over its floored shading) is compared with the weighted median of all
    views' own albedos in its texel of a coarse reference texture (:func:`core.texture.fuse.fuse_views`, whose
    median a highlight or a misregistered edge in one view does not move); the log ratio e (RMS over the
    channels) gives Tukey's biweight ``(1 - min(e / s, 1)^2)^2``, at least a small floor, with s 4.685 robust
    standard deviations of e over all pixels of all views (at least 0.1). Clipped pixels in a highlight
    (:mod:`core.solve.highlights`, judged on the reference texture's texels) take the floor, as the albedo stage
    leaves them out: where no other view sees their texels, the median cannot tell them.

    Parameters
    ----------
    photos, masks, uvs, weights : lists of (H, W, ...) arrays
        The working-resolution photos and their bakes (``weights`` the view weights).
    shades : list of (P_v, C) arrays
        The views' shading, not floored (:func:`view_shadings`).
    floor : (C, 3) array
        :func:`shading_floors`.
    clipped : list of (H, W) bool arrays (or None per view), optional
        The working-resolution pixels that hold a clipped photo pixel.
    threads : int or None
        Views worked on at once (None: every available core).

    Returns
    -------
    list of (H, W) float32 arrays
        0 outside the masks.
    """

    def own_albedo(v):
        photo, m = photos[v], masks[v]
        q = np.zeros(photo.shape, np.float32)
        values = masked(photo, m)
        q[m] = values / _floored(shades[v].copy(), values, floor)
        return q

    own = thread_map(own_albedo, range(len(masks)), threads)
    size = pixel_matched_size(masks, uvs, MATCHED_SIZE_MAX)
    ref = fuse_views(own, masks, uvs, size, margin=1)[..., :-1]
    flat = ref.reshape(size * size, -1)
    everywhere = np.ones((size, size), bool)

    def error(v):
        m, uv = masks[v], uvs[v]
        idx, w = bilinear_texels(masked(uv, m), everywhere)
        return _log_ratio(masked(own[v], m), interpolate(flat, idx, w))

    errors = thread_map(error, range(len(masks)), threads)
    pooled = np.concatenate(errors) if errors else np.zeros(0)
    scale = max(_SCALE_SIGMAS * 1.4826 * float(np.median(pooled)) if pooled.size else 0.0, _SCALE_MIN)
    agree = np.maximum((1.0 - np.minimum(pooled / scale, 1.0) ** 2) ** 2, _LEAST_AGREEMENT)
    region = None if clipped is None else clipped_regions(clipped, masks)
    if region is not None:
        texel = np.concatenate([texel_index(masked(uv, m), size) for uv, m in zip(uvs, masks)]).astype(np.int64)
        off = texel < 0  # a UV off the texture: a texel of its own, that no other view sees
        texel[off] = size * size + np.arange(np.count_nonzero(off))
        view = np.repeat(np.arange(len(masks)), [np.count_nonzero(m) for m in masks])
        weight = np.concatenate([w[m] for w, m in zip(weights, masks)])
        agree[highlights(region, texel, view, weight, len(masks))] = _LEAST_AGREEMENT
    out, start = [], 0
    for m in masks:
        a = np.zeros(m.shape, np.float32)
        k = np.count_nonzero(m)
        a[m] = agree[start : start + k]
        start += k
        out.append(a)
    return out


def _rows_kept(keep):
    """The rows a bool mask ``keep`` keeps, as indices for :func:`_kept`, or None where it keeps them all."""
    return None if keep.all() else np.flatnonzero(keep)


def _kept(a, rows):
    """``a``'s rows ``rows`` (:func:`_rows_kept`): ``a`` itself where all are kept. np.take of indices copies an
    (n, 3) array's rows about 5x faster than a bool mask does."""
    return a if rows is None else np.take(a, rows, axis=0)


def _channel_mean(a):
    """``np.mean(a, axis=1)`` of ``(P, C)`` float32, the same sum and division over whole columns."""
    out = a[:, 0].copy()
    for k in range(1, a.shape[1]):
        out += a[:, k]
    out /= a.shape[1]
    return out


def _working_pixel(n_full, n_work):
    """For each full-resolution row (or column), the working-resolution one whose area holds its centre."""
    return np.minimum(((np.arange(n_full) + 0.5) * (n_work / n_full)).astype(np.intp), n_work - 1)


def _texel_sums(texel, w, q):
    """Pixels summed per texel (flat indices), weights ``w`` (P,) and quotients ``q`` (P, C).

    Returns the texels (each once) and per texel the sum of w, then of w q per channel: ``(T, 1 + C)``.
    """
    texels, at = texels_reached(texel)
    sums = np.empty((texels.size, 1 + q.shape[1]), np.float32)
    sums[:, 0] = np.bincount(at, w, texels.size)
    for k in range(q.shape[1]):
        sums[:, 1 + k] = np.bincount(at, w * q[:, k], texels.size)
    return texels, sums


def _box_mean(a):
    """The mean of each 3 x 3 neighbourhood of ``a`` (N, N) float32, zeros beyond the edges.

    ``scipy.ndimage.uniform_filter(a, 3, mode="constant")`` to a float32 rounding or two, by shifted sums over
    whole rows: eight times faster on an 8192² texture, where scipy's filter walks the columns one by one.
    """
    v = a.copy()
    v[1:] += a[:-1]
    v[:-1] += a[1:]
    out = v.copy()
    out[:, 1:] += v[:, :-1]
    out[:, :-1] += v[:, 1:]
    out /= np.float32(9)
    return out


def _mean(sums, base, prior, threads=None):
    """Each texel's weighted mean quotient, with weight ``prior`` of ``base``; ``sums`` ``(N * N, 1 + C)`` as
    :func:`_texel_sums` gives them.

    A texel no pixel reached takes the mean of its 3 x 3 neighbourhood's pixels where there are some (photos a
    little coarser than the texture), else ``base``. Returns the texture and the texels some pixel reached.
    Worked out in blocks of rows (each with the rows either side, for the neighbourhoods) on ``threads``
    threads: the same numbers as over the whole texture, with each block's arrays in the cache.
    """
    n, c = base.shape[0], base.shape[2]
    sums = sums.reshape(n, n, 1 + c)
    direct = sums[..., 0] > 0
    out = np.empty((n, n, c), np.float32)

    def rows(r0):
        r1 = min(r0 + _MEAN_ROWS, n)
        lo, hi = max(r0 - 1, 0), min(r1 + 1, n)
        inner = slice(r0 - lo, r1 - lo)
        part = sums[lo:hi]
        wsum = part[..., 0]
        near = _box_mean(wsum)[inner]
        wsum = wsum[inner]
        for k in range(c):
            a = part[..., 1 + k]
            b = base[r0:r1, :, k]
            own = (a[inner] + prior * b) / (wsum + prior)
            around = (_box_mean(a)[inner] + prior * b) / (near + prior)
            out[r0:r1, :, k] = np.where(direct[r0:r1], own, around)

    thread_map(rows, range(0, n, _MEAN_ROWS), threads)
    return out, direct


def detail_albedo(
    mesh,
    cameras,
    load,
    sigma,
    base,
    inside,
    floor,
    weights=None,
    cells=None,
    use_clipped=False,
    progress=None,
    cancel=None,
    band_pixels: int = _BAND_PIXELS,
    sun=None,
    outlines=False,
    threads=None,
    shared=None,
):
    """The albedo texture from the photos at their full resolution, one photo at a time.

    Parameters
    ----------
    mesh : core.scene.MeshArrays
    cameras : list of core.geometry.camera.Camera
        Each view's camera on its full-resolution pixel grid.
    load : callable(i) -> (photo, clipped)
        View i's photo, ``(H, W, C)`` float32 linear (row 0 at the top) or an 8-bit one's codes
        (:class:`core.io.photos.CodedPhoto`), and its clipped pixels ``(H, W)`` bool or None. Called once per
        view, in order, from the calling thread; the photo is let go once its bands are done.
    sigma : (m, C, K) array
        The solved lighting of each view (in the scale of ``base``).
    base : (N, N, C) array
        The working-resolution albedo, filled: the fallback and the prior of every texel.
    inside : (N, N) bool array
        The texels inside the UV islands; pixels outside them are left out.
    floor : (C, 3) array
        The shading's floor bounds (:func:`shading_floors`).
    weights : list of (H', W') arrays, optional
        Per view, a weight per working-resolution pixel (:func:`agreement`); a full-resolution pixel takes the
        weight of the working pixel whose area holds its centre. Default 1.
    cells : OcclusionGrid, optional
        The occlusion, as in the solve.
    use_clipped : bool
        Leave out the pixels that ``load`` reports clipped.
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
    band_pixels : int
        Pixels per band of the bake, at most (a photo has a band per thread at least).
    sun : core.geometry.sun.SunLight, optional
        The sun term, as in the solve (the last of ``sigma``'s coefficients).
    outlines : bool
        Leave out the pixels on each photo's outline, which hold the background blended in
        (:func:`core.texture.fill.outline_only`): a texel only they land in takes its neighbours' pixels, or
        ``base``, and counts as reached.
    threads : int or None
        Bands at work at once (None: every available core).
    shared : core.geometry.raycast.Triangles, optional
        ``mesh`` as shared vertices, if already made (the shadows' casters): each vertex is projected once per
        photo to tell which rows its triangles reach. Made here if not given.

    Returns
    -------
    albedo : (N, N, C) float32
    reached : (N, N) bool
        Texels that some full-resolution pixel landed in.

    Raises
    ------
    DelightError
        A photo's size differs from its camera's.
    Cancelled
    """
    n, c = base.shape[0], base.shape[2]
    sums = np.zeros((n * n, 1 + c), np.float32)
    # A texel's sums as one record: each band's texels are read and written a record at a time, 16 bytes for
    # three channels, about 3x faster than channel by channel across four arrays.
    records = sums.view(np.dtype((np.void, sums.itemsize * (1 + c)))).ravel()
    corner, face = mesh_normals(mesh)
    if shared is None:
        shared = Triangles.of(mesh.tri_pos, mesh.tri_vert)
    floor = np.asarray(floor, np.float64).copy()
    floor[:, :2] = np.maximum(floor[:, :2], 1e-6)
    inside_flat = np.asarray(inside, bool).ravel()
    outlined = np.zeros(n * n, bool)
    m = len(cameras)
    workers = resolve_threads(threads)
    done = 0.0
    total = float(sum(cam.width * cam.height for cam in cameras)) or 1.0
    t0 = time.perf_counter()

    def bands():
        ahead = None  # the next photo, read on a thread of its own while this one's bands are at work
        try:
            for v, cam in enumerate(cameras):
                photo, clipped = ahead.result() if ahead is not None else load(v)
                ahead = None
                if photo.shape[:2] != (cam.height, cam.width):
                    raise DelightError(
                        f"photo {v + 1} is {photo.shape[1]}x{photo.shape[0]}, its camera {cam.width}x{cam.height}"
                    )
                cells_of = None
                if weights is not None:
                    cells_of = (
                        _working_pixel(cam.height, weights[v].shape[0]),
                        _working_pixel(cam.width, weights[v].shape[1]),
                    )
                # More bands than threads: once band `workers` is drawn, every band of the last photo has been
                # added in, and the next photo is read; so no more than two are held at once.
                pixels = min(band_pixels, -(-cam.height // (workers + 1)) * cam.width)
                for j, (r0, bake) in enumerate(row_bands(cam, mesh, pixels, corner, face, shared)):
                    if workers > 1 and j == workers and v + 1 < m:
                        ahead = start(load, v + 1)
                    yield v, photo, clipped, cells_of, r0, bake
                del photo, clipped  # this generator's hold on it, before the next one is read
        finally:
            if ahead is not None:  # stopped early: the photo being read is waited for
                wait([ahead])

    def divided(band):
        """A band baked and divided by its shading: the texels its pixels land in, and their sums there."""
        v, photo, clipped, cells_of, r0, bake = band
        b = bake()
        h, width = b.shape
        keep = np.ones(b.pixel.size, bool)
        if clipped is not None and use_clipped:
            keep &= ~clipped[r0 : r0 + h].ravel()[b.pixel]
        edge = None
        if outlines:
            mask = np.zeros(h * width, bool)
            mask[b.pixel] = True
            on_edge = outline_pixels(mask.reshape(h, width)).ravel()[b.pixel]
            edge = texel_index(b.uv[keep & on_edge], n)
            keep &= ~on_edge
        keep = _rows_kept(keep)
        pixel, uv = _kept(b.pixel, keep), _kept(b.uv, keep)
        pos = None if sun is None else _kept(b.position, keep)
        values = photo_pixels(photo, slice(r0, r0 + h), pixel)
        a = shading(_kept(b.normal, keep), uv, sigma[v], cells, floor, sun, pos, values)
        q = values / a
        # Weighted by the squared shading, the mean is the least-squares albedo of the pixels
        # (division_start's): dark pixels, whose quotient carries the most noise, count least.
        w = _kept(b.view_weight, keep) * _channel_mean(a) ** 2
        if cells_of is not None:
            rr, cc = np.divmod(pixel, width)
            w = w * weights[v][cells_of[0][r0 + rr], cells_of[1][cc]]
        texel = texel_index(uv, n)
        keep = texel >= 0
        keep[keep] = inside_flat[texel[keep]]
        keep = _rows_kept(keep)
        return v, h, edge, *_texel_sums(_kept(texel, keep), _kept(w, keep), _kept(q, keep))

    check_cancel(cancel)
    if progress is not None:
        progress(0.0, f"photo 1/{m}")
    last = None
    # Bands are baked and divided on the threads while the last one is added in, in order, here.
    source = bands()
    work = streamed(divided, source, workers)
    with contextlib.closing(source), contextlib.closing(work):  # stopped early: no thread left at work
        for v, h, edge, texels, band_sums in work:
            check_cancel(cancel)
            if v != last:
                last = v
                if progress is not None:
                    progress(done / total, f"photo {v + 1}/{m}")
            if edge is not None:
                outlined[edge[edge >= 0]] = True
            added = np.take(records, texels).view(np.float32).reshape(band_sums.shape)
            added += band_sums
            records[texels] = added.view(records.dtype).ravel()
            done += h * cameras[v].width
            if progress is not None:
                progress(done / total, f"photo {v + 1}/{m}")
    if progress is not None:
        progress(1.0, f"{m} photos in {time.perf_counter() - t0:.0f} s")
    albedo, reached = _mean(sums, np.asarray(base, np.float32), np.float32(PRIOR_WEIGHT), threads)
    return albedo, reached | (outlined & inside_flat).reshape(n, n)
