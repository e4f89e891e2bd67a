"""Files in and out: EXR images, problem bundles, photo decoding, safe file names, atomic writes, JSON values."""

from .atomic import atomic_path
from .bundle import FORMAT, VERSION, load_bundle, save_bundle
from .exr import exr_parts, read_exr, write_exr
from .files import read_magic
from .jsonio import json_value
from .names import safe_name, unique_names
from .photos import downscale, linear_to_srgb, srgb_to_linear

__all__ = [
    "atomic_path",
    "read_magic",
    "json_value",
    "safe_name",
    "unique_names",
    "read_exr",
    "write_exr",
    "exr_parts",
    "FORMAT",
    "VERSION",
    "save_bundle",
    "load_bundle",
    "srgb_to_linear",
    "linear_to_srgb",
    "downscale",
]
