"""A :class:`~core.solve.problem.Problem` on disk: the problem bundle (.npz).

A bundle lets pipelines outside Blender feed the solver
(``python -m core solve BUNDLE --out DIR``), and lets a problem exported from
Blender be solved or inspected elsewhere. It is a NumPy ``.npz`` archive
(a zip of ``.npy`` files, written with :func:`numpy.savez_compressed`) that
holds plain numeric and string arrays only, so it loads with
``allow_pickle=False``. See :mod:`core.solve.problem` for the conventions (row 0 at
the top, pixel centre of (row r, col c) at (x, y) = (c, r), Blender UV with v
up, textures with row 0 at v = 1).

Format, version 1
-----------------
m views; view i is H_i x W_i pixels (sizes may differ between views); C is
1 or 3, the same for every view. Integer arrays may be any integer type,
float arrays any float type; the dtypes below are what :func:`save_bundle`
writes.

Required keys::

    format          ()              str    "delight-problem-bundle"
    version         ()              int    1
    n_views         ()              int    m >= 1
    names           (m,)            str    view names
    image_<i>       (H_i, W_i, C)   f32    linear image of view i
    mask_<i>        (H_i, W_i)      bool   pixels that see the surface (not empty)
    normal_<i>      (H_i, W_i, 3)   f32    unit world-space normals inside the mask

Optional, per view (for every view or for none)::

    uv_<i>          (H_i, W_i, 2)   f32    Blender UV of each pixel's surface point
    view_weight_<i> (H_i, W_i)      f32    per-pixel confidence >= 0

Optional correspondences (the first four together; K pairs)::

    corr_view_a     (K,)            int64  view of pixel a
    corr_pixel_a    (K,)            int64  flat index row * W + col in view_a
    corr_view_b     (K,)            int64  view of point b
    corr_xy_b       (K, 2)          f64    continuous (x, y) of b in view_b
    corr_weight     (K,)            f64    pair weights >= 0 (default 1)

Optional texture layout (needs uv_<i>)::

    texel_pos       (N, N, 3)       f32    texel centres in world space, NaN
                                           outside the UV islands
    seam_pairs      (S, 2)          int64  flat texel indices r * N + c of
                                           neighbours across UV seams (default none)

``<i>`` runs over 0 .. m-1 in decimal without padding. Index arrays
(``corr_view_a``, ``corr_pixel_a``, ``corr_view_b``, ``seam_pairs``) must have
an integer dtype and masks a bool or integer dtype. Readers ignore unknown
keys, so later versions may add optional keys; a change that old readers
would misread bumps ``version``.

A minimal bundle written without this package::

    np.savez_compressed("problem.npz", format="delight-problem-bundle",
                        version=1, n_views=1, names=["photo"],
                        image_0=img, mask_0=mask, normal_0=normals)

Values outside the masks are not used (they may be NaN). Validation is the
:class:`~core.solve.problem.Problem` constructor's; :func:`load_bundle` adds the
file name to its messages.
"""

from __future__ import annotations

import os
import zipfile

import numpy as np

from ..solve.problem import Correspondences, Problem, TextureLayout
from .atomic import atomic_path
from .files import read_magic

__all__ = ["FORMAT", "VERSION", "save_bundle", "load_bundle"]

FORMAT = "delight-problem-bundle"
VERSION = 1

_CORR = ("view_a", "pixel_a", "view_b", "xy_b", "weight")  # keys corr_<name>
_PER_VIEW_OPTIONAL = ("uv", "view_weight")


def save_bundle(path, problem: Problem) -> None:
    """Write ``problem`` to ``path`` as a bundle (see the module docstring).

    The file is written exactly at ``path`` (no ``.npz`` is appended) and
    atomically: a failure leaves any existing file untouched.
    """
    if not isinstance(problem, Problem):
        raise TypeError(f"save_bundle: expected a core.solve.problem.Problem, got {type(problem).__name__}")
    arrays = {
        "format": np.array(FORMAT),
        "version": np.array(VERSION, dtype=np.int64),
        "n_views": np.array(problem.n_views, dtype=np.int64),
        "names": np.array([str(n) for n in problem.names], dtype=str),
    }
    for i in range(problem.n_views):
        arrays[f"image_{i}"] = np.asarray(problem.images[i], dtype=np.float32)
        arrays[f"mask_{i}"] = np.asarray(problem.masks[i], dtype=bool)
        arrays[f"normal_{i}"] = np.asarray(problem.normals[i], dtype=np.float32)
        if problem.uv is not None:
            arrays[f"uv_{i}"] = np.asarray(problem.uv[i], dtype=np.float32)
        if problem.view_weight is not None:
            arrays[f"view_weight_{i}"] = np.asarray(problem.view_weight[i], dtype=np.float32)
    c = problem.correspondences
    if c is not None:
        arrays["corr_view_a"] = c.view_a.astype(np.int64)
        arrays["corr_pixel_a"] = c.pixel_a.astype(np.int64)
        arrays["corr_view_b"] = c.view_b.astype(np.int64)
        arrays["corr_xy_b"] = c.xy_b.astype(np.float64)
        arrays["corr_weight"] = c.weight.astype(np.float64)
    t = problem.texture
    if t is not None:
        arrays["texel_pos"] = t.texel_pos.astype(np.float32)
        arrays["seam_pairs"] = t.seam_pairs.astype(np.int64).reshape(-1, 2)
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:  # a file object: savez would append ".npz" to a name
            np.savez_compressed(fh, **arrays)


def load_bundle(path) -> Problem:
    """Read a bundle written by :func:`save_bundle` (or by another pipeline).

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        Not a bundle, a required key is missing, or the problem it holds is
        invalid; the message names the file and the key or view.
    """
    path = os.fspath(path)
    if read_magic(path, 2, "bundle") != b"PK":
        raise ValueError(f"bundle {path}: not an .npz archive")
    try:
        with np.load(path, allow_pickle=False) as z:
            return _problem_from(path, _Keys(path, z))
    except (zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"bundle {path}: not a readable .npz archive ({exc})") from exc
    except ValueError as exc:
        if str(exc).startswith(f"bundle {path}"):
            raise
        # the Problem's own validation: say which file it came from
        raise ValueError(f"bundle {path}: {exc}") from exc


class _Keys:
    """Lazy access to the archive with messages that name the file and key."""

    def __init__(self, path, npz):
        self.path, self.npz, self.files = path, npz, set(npz.files)

    def __contains__(self, key):
        return key in self.files

    def __getitem__(self, key):
        if key not in self.files:
            raise ValueError(f"bundle {self.path}: missing key {key!r}")
        try:
            return self.npz[key]
        except ValueError as exc:  # e.g. an object array, refused without pickle
            raise ValueError(f"bundle {self.path}: key {key!r} cannot be read: {exc}") from exc
        except (zipfile.BadZipFile, EOFError, OSError) as exc:
            raise ValueError(f"bundle {self.path}: key {key!r} is corrupt: {exc}") from exc

    def numeric(self, key):
        a = self[key]
        if not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
            raise ValueError(f"bundle {self.path}: key {key!r} has dtype {a.dtype}, expected numbers")
        return a

    def index(self, key):
        a = self.numeric(key)
        if not np.issubdtype(a.dtype, np.integer):
            raise ValueError(
                f"bundle {self.path}: key {key!r} holds indices and must have an integer dtype, got {a.dtype}"
            )
        return a

    def mask(self, key):
        a = self.numeric(key)
        if not (a.dtype == bool or np.issubdtype(a.dtype, np.integer)):
            raise ValueError(f"bundle {self.path}: key {key!r} is a mask and must be bool or integer, got {a.dtype}")
        return a

    def integer(self, key):
        a = self.numeric(key)
        if a.ndim != 0 or not np.issubdtype(a.dtype, np.integer):
            raise ValueError(
                f"bundle {self.path}: key {key!r} must be an integer scalar, got {a.dtype} of shape {a.shape}"
            )
        return int(a)


def _problem_from(path, z: _Keys) -> Problem:
    raw = z["format"]
    fmt = raw.item() if raw.ndim == 0 else raw.tolist()
    fmt = fmt.decode("utf-8", "replace") if isinstance(fmt, bytes) else fmt
    if not isinstance(fmt, str) or fmt != FORMAT:
        raise ValueError(f"bundle {path}: format is {fmt!r}, expected {FORMAT!r}")
    version = z.integer("version")
    if version > VERSION:
        raise ValueError(f"bundle {path}: version {version} is newer than this reader ({VERSION})")
    m = z.integer("n_views")
    if m < 1:
        raise ValueError(f"bundle {path}: n_views is {m}, needs at least 1")
    names = z["names"]
    if names.shape != (m,) or names.dtype.kind not in "US":
        raise ValueError(f"bundle {path}: 'names' must be {m} strings, got {names.dtype} of shape {names.shape}")
    images = [z.numeric(f"image_{i}") for i in range(m)]
    masks = [z.mask(f"mask_{i}") for i in range(m)]
    normals = [z.numeric(f"normal_{i}") for i in range(m)]
    optional = {}
    for what in _PER_VIEW_OPTIONAL:
        have = [f"{what}_{i}" in z for i in range(m)]
        if any(have) and not all(have):
            raise ValueError(
                f"bundle {path}: missing key {f'{what}_{have.index(False)}'!r} "
                f"({what} must be given for every view or for none)"
            )
        optional[what] = [z.numeric(f"{what}_{i}") for i in range(m)] if all(have) else None
    corr = None
    if any(f"corr_{k}" in z for k in _CORR):
        weight = z.numeric("corr_weight") if "corr_weight" in z else None
        corr = Correspondences(
            z.index("corr_view_a"), z.index("corr_pixel_a"), z.index("corr_view_b"), z.numeric("corr_xy_b"), weight
        )
    texture = None
    if "texel_pos" in z:
        seams = z.index("seam_pairs") if "seam_pairs" in z else None
        texture = TextureLayout(z.numeric("texel_pos"), seams)
    return Problem(
        images=images,
        masks=masks,
        normals=normals,
        correspondences=corr,
        uv=optional["uv"],
        texture=texture,
        view_weight=optional["view_weight"],
        names=[str(n) for n in names],
    )
