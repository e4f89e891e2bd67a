"""Checks of the inputs before the solve, by stated rules: photos that cannot be images of light on the mesh."""
from __future__ import annotations

import numpy as np

from .errors import DelightError

__all__ = ["NEGATIVE_MAX_SHARE", "check_photos"]

#: Share of a photo's pixels on the mesh that may be negative before the photo is refused; below it the
#: negative pixels are left out (a few come from denoisers and resampling).
NEGATIVE_MAX_SHARE = 0.01


def check_photos(names, photos, masks) -> list:
    """Refuse photos that are negative or black on the mesh; leave out the few negative pixels.

    Parameters
    ----------
    names : list of str
        The views' names, for messages.
    photos : list of (H, W, 3) float arrays
        Linear photos.
    masks : list of (H, W) bool arrays
        Pixels that see the mesh; negative pixels are removed from them in place.

    Returns
    -------
    warnings : list of str
        One line per photo that had negative pixels left out.

    Raises
    ------
    DelightError
        A photo with more than :data:`NEGATIVE_MAX_SHARE` of its mesh pixels negative, or with no positive
        value on the mesh.
    """
    warnings = []
    for name, photo, mask in zip(names, photos, masks):
        px = photo[mask]
        if px.size == 0:
            continue
        negative = (px < 0).any(axis=1)
        share = float(negative.mean())
        if share > NEGATIVE_MAX_SHARE:
            raise DelightError(f"camera {name!r}: {100 * share:.0f} % of its photo's pixels on the mesh are "
                               "negative, so it is not a linear image of light: check how the photo was exported "
                               "and its colour space")
        if not (px > 0).any():
            raise DelightError(f"camera {name!r}: its photo is black wherever it sees the mesh: check that it is "
                               "the right photo and that it is exposed")
        if negative.any():
            mask[mask] = ~negative
            warnings.append(f"camera {name!r}: {int(negative.sum())} negative pixels on the mesh were left out")
    return warnings
