"""From the solver's result to a full texture: per-view maps fused onto the texels, unseen texels filled, and the
texture sampled back at the pixels.
"""

from .fill import fill_scaled_up, fill_unseen, outline_only, outline_pixels
from .fuse import fuse_views
from .sample import sample_texture

__all__ = [
    "fuse_views",
    "fill_unseen",
    "fill_scaled_up",
    "outline_only",
    "outline_pixels",
    "sample_texture",
]
