"""Files in and out: EXR images, problem bundles, photo decoding, safe file names, atomic writes, JSON values.
"""
from .atomic import atomic_path
from .files import read_magic
from .jsonio import json_value
from .names import safe_name, unique_names
from .exr import read_exr, write_exr, exr_parts
from .bundle import FORMAT, VERSION, save_bundle, load_bundle
from .photos import srgb_to_linear, linear_to_srgb, downscale

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
