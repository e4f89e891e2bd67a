"""The photos brought to one level before the solve, per channel: the solve does not depend on their exposure.

:func:`core.pipeline.compute` solves on the photos times :func:`channel_gains` (:func:`with_gains`) and divides
the gains out of the albedo (docs/measurements.md).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .io.photos import photo_scaled
from .masks import masked
from .scene import FullPhoto

__all__ = ["CHANNEL_GAIN_MAX", "PHOTO_LEVEL", "channel_gains", "with_gains"]


#: :func:`channel_gains` changes no channel by more than this factor either way: a channel the photos hardly
#: have (a red object under red light, in blue) is not raised to the others' level, its noise with it.
CHANNEL_GAIN_MAX = 10.0


#: The mean the photos are brought to over the mesh's pixels before the solve: the solve does not depend on
#: the photos' exposure. Chosen on the 40 scenes (docs/measurements.md); their own means are 0.07-0.42.
PHOTO_LEVEL = 0.1


def channel_gains(photos, masks, level: float | None = None) -> np.ndarray:
    """Per channel, the factor that brings its mean over the masked pixels to the mean of the channels' means,
    times the one factor that brings that mean to ``level`` (None: the photos' own).

    The solver's constants (the Huber loss's delta, the stages' thresholds) are in the photos' units: without
    this a dark channel (the blue of a warm-lit red object, a tenth of the red) is held to a looser fit than a
    bright one, and photos twice as bright give another albedo. :func:`core.pipeline.compute` solves on the photos times
    these gains, at :data:`PHOTO_LEVEL`, and divides them out of the albedo (docs/measurements.md).
    """
    total, count = 0.0, 0
    for photo, mask in zip(photos, masks):
        total = total + masked(photo, mask).sum(axis=0, dtype=np.float64)
        count += int(np.count_nonzero(mask))
    means = np.asarray(total, np.float64) / max(count, 1)
    good = np.isfinite(means) & (means > 0)
    gains = np.ones(np.shape(means))
    if good.any():
        mean = means[good].mean()
        gains[good] = np.clip(mean / means[good], 1 / CHANNEL_GAIN_MAX, CHANNEL_GAIN_MAX)
        if level is not None:
            gains = gains * (level / mean)
    return gains.astype(np.float32)


def with_gains(inputs, gains):
    """``inputs`` with every photo (the full-resolution ones as they are read) times ``gains``, per channel."""

    def scaled(full):
        if full is None:
            return None

        def load():
            photo, clipped = full.load()
            return photo_scaled(photo, gains), clipped

        return FullPhoto(camera=full.camera, load=load)

    views = [replace(v, photo=v.photo * gains, full=scaled(v.full)) for v in inputs.views]
    return replace(inputs, views=views)
