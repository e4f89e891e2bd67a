"""Every setting of a run, declared once: name, type, default, range, label and help.

The operator and the panel (:mod:`blender_addon.operator`, :mod:`blender_addon.panel`), the add-on's command
line (:mod:`blender_addon.cli`) and the core's (:mod:`core.cli`) are all built from :data:`SPEC`, and
:func:`check` is the one range check, so every front end accepts the same values and refuses the others with the
same words. The solver's defaults come from :class:`core.solve.params.SolverParams`.
"""

from __future__ import annotations

import argparse
import math
import numbers
from dataclasses import dataclass, field, make_dataclass

from .errors import DelightError
from .solve.albedo_weight import ALBEDO_LAMBDA
from .solve.discretization import NEAREST_MIN_PIXELS_PER_TEXEL
from .solve.lambda_choice import LAMBDA_FIXED, LAMBDA_VARYING, LIGHT_LAMBDA
from .solve.params import SolverParams

__all__ = [
    "Option",
    "SPEC",
    "OPTIONS",
    "RUN_FIELDS",
    "SOLVER_FIELDS",
    "Options",
    "check",
    "validate",
    "requirement",
    "add_arguments",
    "cli_help",
]

_SOLVER = SolverParams()
_AUTO_LAMBDA = (
    f"{LIGHT_LAMBDA:g} for the lighting stage; with the albedo stage off (the paper's one stage), picked from how "
    f"much the lighting changes between the photos: {LAMBDA_FIXED:g} under one lighting, {LAMBDA_VARYING:g} when "
    "it changes"
)


@dataclass(frozen=True)
class Option:
    """One setting.

    Attributes
    ----------
    name : str
        Its name in :class:`Options` (or on the operator, for the settings only the UI has) and argparse's
        ``dest``.
    kind : {"int", "float", "bool", "str", "dir", "names", "choice"}
        "dir" is a folder path, "names" a list of names.
    default : object
        The value when it is not given. None means "chosen for you" (``shown`` is what a UI field starts at).
    label : str
        The UI's name for it, in words an artist knows.
    help : str
        Tooltip and command-line help (the command line appends the default).
    min, max : float, optional
        Hard range, inclusive; ``min_open`` makes ``min`` itself refused.
    soft_min, soft_max : float, optional
        The range of the UI's slider.
    unit : str
        Unit of a number, shown after the default.
    choices : tuple of (value, label, help)
        For ``kind="choice"``.
    flag, metavar : str, optional
        The command-line option; no flag: not on the command line.
    auto : str, optional
        The value may also be "auto" (None); this says what auto does.
    none : str, optional
        The value may also be "none" (None); this says what none does.
    shown : object, optional
        What a UI field starts at when ``default`` is None.
    noun : str, optional
        The setting in messages (default: the label in lower case).
    """

    name: str
    kind: str
    default: object
    label: str
    help: str
    min: float | None = None
    max: float | None = None
    min_open: bool = False
    soft_min: float | None = None
    soft_max: float | None = None
    unit: str = ""
    choices: tuple = ()
    flag: str | None = None
    metavar: str | None = None
    auto: str | None = None
    none: str | None = None
    shown: object = None
    noun: str | None = None

    @property
    def values(self) -> tuple:
        """The allowed values of a choice."""
        return tuple(c[0] for c in self.choices)

    @property
    def what(self) -> str:
        """The setting in messages."""
        return self.noun or self.label.lower()

    @property
    def ui_default(self):
        """What a UI field starts at."""
        if self.default is not None:
            return self.default
        if self.shown is not None:
            return self.shown
        return "" if self.kind in ("str", "dir") else None


SPEC = (
    Option(
        "object_name",
        "str",
        None,
        "Mesh",
        "The mesh to delight; its active UV map is used (default: the active object)",
        flag="--object",
        metavar="NAME",
    ),
    Option(
        "camera_names",
        "names",
        None,
        "Cameras",
        "The cameras whose photos are used (default: all)",
        flag="--cameras",
        metavar="NAME",
    ),
    Option(
        "cameras",
        "choice",
        "ALL",
        "Cameras",
        "Which cameras' photos are used",
        choices=(
            ("ALL", "All", "Every camera in the scene"),
            ("SELECTED", "Selected", "The selected cameras"),
            ("COLLECTION", "Collection", "The cameras in one collection"),
        ),
    ),
    Option(
        "camera_collection",
        "str",
        None,
        "Camera collection",
        "The collection whose cameras are used (Cameras: Collection)",
    ),
    Option("selected_only", "bool", False, "Selected cameras only", "Use the selected cameras when no camera is named"),
    Option(
        "images_dir",
        "dir",
        None,
        "Images folder",
        "Folder of photos named like the cameras, for cameras without a background image or image plane",
        flag="--images",
        metavar="DIR",
    ),
    Option(
        "method",
        "choice",
        "texture",
        "Method",
        "How the albedo is estimated",
        choices=(
            ("texture", "Texture", "Solve one albedo per texel (fast)"),
            (
                "image",
                "Image",
                "Solve per photo pixel with cross-view consistency, as in the paper, then fuse (slower)",
            ),
            ("project", "Project only", "No delighting: fuse the photos as they are, for comparison"),
        ),
        flag="--method",
    ),
    Option("auto_lambda", "bool", True, "Automatic lambda", f"Let lambda be {_AUTO_LAMBDA}"),
    Option(
        "lam",
        "float",
        None,
        "Lambda (smoothness)",
        "Weight of the smoothness (total variation) term: larger removes more shading, and more detail with it",
        min=0.0,
        soft_min=0.0,
        soft_max=100.0,
        flag="--lambda",
        metavar="L|auto",
        auto=_AUTO_LAMBDA,
        shown=LIGHT_LAMBDA,
        noun="lambda",
    ),
    Option(
        "albedo_lam",
        "float",
        ALBEDO_LAMBDA,
        "Albedo lambda",
        "Smoothness weight of the second stage, which solves the albedo again under the lighting of the first; "
        "lowered across changes of colour, so it smooths leftover shading; smaller keeps finer detail",
        min=0.0,
        soft_min=0.0,
        soft_max=100.0,
        flag="--albedo-lambda",
        metavar="L|none",
        none="one stage, as the paper",
        noun="albedo lambda",
    ),
    Option(
        "albedo_adapt",
        "bool",
        _SOLVER.albedo_adapt,
        "Albedo lambda from texture",
        "Scale the albedo lambda by how much fine colour texture the photos show and how sparse its changes "
        "are: less smoothing where the albedo changes colour everywhere, more on flat patches with a few edges "
        "(the albedo lambda is then the weight for an average texture; Texture method)",
        flag="--albedo-adapt",
    ),
    Option(
        "lighting",
        "choice",
        "auto",
        "Lighting",
        "How the lighting of the photos is modelled",
        choices=(
            (
                "auto",
                "Auto",
                "Coupled when the photos share one light, per photo when it moves (measured on the photos)",
            ),
            ("coupled", "Coupled", "One lighting per photo, held to one shared world lighting"),
            (
                "shared",
                "Shared",
                "One world lighting for all photos, times an exposure and white balance gain per photo",
            ),
            ("per_view", "Per photo", "A free lighting per photo, as the paper"),
        ),
        flag="--lighting",
    ),
    Option(
        "occlusion",
        "bool",
        True,
        "Occlusion",
        "Shade with the light each point really receives "
        "(self-shadowing by the mesh), not the paper's shading by the normal alone",
        flag="--occlusion",
    ),
    Option(
        "sun",
        "bool",
        True,
        "Sun shadows",
        "Find a sun's direction from the shadows in the photos and take the shadows it casts out of the albedo "
        "(one sun for all photos; none when the light changes between them)",
        flag="--sun",
    ),
    Option(
        "align_photos",
        "bool",
        True,
        "Align photos",
        "Move each camera by the sub-pixel shift that lines its photo's fine detail up with the other photos' "
        "(photogrammetry cameras are often about a pixel off); the scene's cameras are not changed",
        flag="--align-photos",
    ),
    Option(
        "mask_clipped",
        "bool",
        False,
        "Leave out clipped pixels",
        "Leave all pixels at an 8-bit photo's ceiling out of the solve (off: where other photos show a highlight)",
        flag="--mask-clipped",
    ),
    Option(
        "fill_outlines",
        "bool",
        True,
        "Fill outline texels",
        "With the Texture method, texels the photos show only at the object's outline, where the background blends "
        "into the pixels, take their albedo from the texels around them (off: from those pixels)",
        flag="--fill-outlines",
    ),
    Option(
        "mu",
        "float",
        _SOLVER.mu,
        "Mu (consistency)",
        "Weight of the cross-view consistency term, for the Image method",
        min=0.0,
        soft_min=0.0,
        soft_max=100.0,
        flag="--mu",
        metavar="M",
        noun="mu",
    ),
    Option(
        "max_iter",
        "int",
        _SOLVER.max_iter,
        "Iterations",
        "Most solver iterations at the full size (coarser copies of the problem are solved first)",
        min=1,
        soft_min=1,
        soft_max=500,
        flag="--max-iter",
        metavar="K",
    ),
    Option(
        "working_res_mp",
        "float",
        1.0,
        "Working resolution (MP)",
        "Photos are downscaled to at most this many megapixels before solving",
        min=0.0,
        min_open=True,
        soft_min=0.01,
        soft_max=16.0,
        unit="MP",
        flag="--working-res",
        metavar="MP",
        noun="working resolution (MP)",
    ),
    Option(
        "working_total_mp",
        "float",
        50.0,
        "Working total (MP)",
        "All the photos together are downscaled to at most this many megapixels before solving: with many photos, "
        "each gets less than the working resolution, and the solve's memory stays bounded (0: no limit)",
        min=0.0,
        soft_min=0.0,
        soft_max=400.0,
        unit="MP",
        flag="--working-total",
        metavar="MP",
        noun="working total (MP)",
    ),
    Option(
        "detail",
        "choice",
        "auto",
        "Full-resolution detail",
        "When the photos are larger than the working resolution, make the albedo again from each photo at its "
        "full resolution, one photo at a time, under the lighting solved at the working resolution",
        choices=(
            (
                "auto",
                "Auto",
                "Where the albedo has fine changes of colour (measured on the photos); where it is flat, solve it at "
                "the working resolution instead, which takes more of the shading out",
            ),
            ("on", "On", "Whenever the photos are larger than the working resolution"),
            ("off", "Off", "Never: the albedo has the working resolution's detail"),
        ),
        flag="--detail",
    ),
    Option(
        "texture_size",
        "int",
        1024,
        "Texture size (px)",
        "Width and height of the square albedo texture",
        min=8,
        max=16384,
        soft_min=64,
        soft_max=8192,
        unit="px",
        flag="--texture-size",
        metavar="N",
        noun="texture size",
    ),
    Option(
        "threads",
        "int",
        None,
        "Threads",
        "CPU threads the run uses for the bake, the occlusion and the solve",
        min=1,
        max=4096,
        soft_min=1,
        soft_max=64,
        flag="--threads",
        metavar="N|auto",
        auto="every core this process may use",
    ),
    Option(
        "out_dir",
        "dir",
        None,
        "Output folder",
        "Where the EXR textures and reports go (empty: a folder delight_<mesh> beside the .blend)",
        flag="--out",
        metavar="DIR",
        shown="",
    ),
    Option(
        "save_blend",
        "bool",
        False,
        "Save the .blend",
        "Save the .blend with the new material (never otherwise)",
        flag="--save",
    ),
    Option(
        "overwrite",
        "bool",
        False,
        "Overwrite files",
        "Replace files in the way that Delight did not write "
        "(its own earlier outputs are always replaced); otherwise the run stops before the bake",
        flag="--overwrite",
    ),
    Option(
        "delta",
        "float",
        _SOLVER.delta,
        "Huber delta",
        "Huber loss parameter: residuals below it count quadratically, above it linearly",
        min=0.0,
        min_open=True,
        flag="--delta",
        metavar="D",
        noun="Huber delta",
    ),
    Option(
        "data_model",
        "choice",
        _SOLVER.data_model,
        "Data model",
        "Texture domain: how a photo pixel sees the texels",
        choices=(
            (
                "nearest",
                "Nearest",
                "A pixel sees the texel it falls nearest to (where the photos have at least "
                f"{NEAREST_MIN_PIXELS_PER_TEXEL} pixels per texel; else it splats)",
            ),
            ("splat", "Splat", "A pixel splats onto its 4 texels"),
            (
                "interpolate",
                "Interpolate",
                "A pixel sees the bilinear mix of its 4 texels, as a "
                "renderer does (slower, exact for a textured surface)",
            ),
        ),
        flag="--data-model",
    ),
    Option(
        "gauss_newton",
        "bool",
        _SOLVER.gauss_newton,
        "Gauss-Newton step",
        "Add a joint Gauss-Newton step "
        "on reflectance and lighting to each iteration (about 3x slower; helps where lighting varies "
        "between views and lambda is small)",
        flag="--gauss-newton",
    ),
)

#: The settings by name.
OPTIONS = {o.name: o for o in SPEC}

#: The fields of :class:`Options`, in order: what a run needs.
RUN_FIELDS = (
    "object_name",
    "camera_names",
    "images_dir",
    "selected_only",
    "lam",
    "albedo_lam",
    "albedo_adapt",
    "lighting",
    "occlusion",
    "sun",
    "align_photos",
    "mask_clipped",
    "fill_outlines",
    "mu",
    "max_iter",
    "working_res_mp",
    "working_total_mp",
    "detail",
    "texture_size",
    "method",
    "threads",
    "out_dir",
    "save_blend",
    "overwrite",
)

#: The solver's settings that ``python -m core solve`` takes.
SOLVER_FIELDS = ("lam", "mu", "max_iter", "delta", "data_model", "gauss_newton", "threads")


def _number(x) -> str:
    """-1.0 as "-1", 3 as "3" (anything else as str)."""
    return f"{x:g}" if isinstance(x, numbers.Real) and not isinstance(x, numbers.Integral) else str(x)


def requirement(option: Option) -> str:
    """What a value of ``option`` must be, in words: "an integer between 8 and 16384"."""
    o = option
    if o.kind == "choice":
        return f"one of {', '.join(o.values)}"
    text = "an integer" if o.kind == "int" else "a number"
    if o.min is not None and o.max is not None:
        text += f" between {_number(o.min)} and {_number(o.max)}"
    elif o.min is not None:
        text += f" greater than {_number(o.min)}" if o.min_open else f" of at least {_number(o.min)}"
    elif o.max is not None:
        text += f" of at most {_number(o.max)}"
    return text + (" or auto" if o.auto else "") + (" or none" if o.none else "")


def check(name: str, value):
    """Return ``value`` if it is allowed for the setting ``name``; raise :class:`DelightError` if not.

    The message reads "<setting> must be <requirement>, got <value>", e.g. "texture size must be an
    integer between 8 and 16384, got 3".
    """
    o = OPTIONS[name]
    if value is None and (o.default is None or o.none):  # chosen for you (auto lambda, ...), or "none"
        return value
    if o.kind == "choice":
        if value not in o.values:
            raise DelightError(f"{o.what} must be {requirement(o)}, got {value!r}")
    elif o.kind in ("int", "float"):
        bad = isinstance(value, bool) or not isinstance(value, numbers.Real)
        if not bad and not math.isfinite(value):
            raise DelightError(f"{o.what} must be a finite number, got {value}")
        bad = bad or (o.kind == "int" and value != int(value))
        bad = bad or (o.min is not None and (value <= o.min if o.min_open else value < o.min))
        bad = bad or (o.max is not None and value > o.max)
        if bad:
            shown = _number(value) if isinstance(value, numbers.Real) else repr(value)
            raise DelightError(f"{o.what} must be {requirement(o)}, got {shown}")
    return value


def validate(options) -> None:
    """Check every setting of ``options`` (an :class:`Options`) with :func:`check`."""
    for name in RUN_FIELDS:
        check(name, getattr(options, name))


def _parser(option: Option):
    """argparse ``type`` for a number: parse only (the range is :func:`check`'s, so the words are its)."""
    kind = int if option.kind == "int" else float

    def parse(text):
        if (option.auto and text.strip().lower() == "auto") or (option.none and text.strip().lower() == "none"):
            return None
        try:
            return kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{option.what} must be {requirement(option)}, got {text!r}") from None

    return parse


def cli_help(option: Option) -> str:
    """The command-line help: the help, the choices, and the default."""
    o, text = option, option.help
    if o.kind == "choice":
        text += ": " + "; ".join(f"{v}: {h[0].lower()}{h[1:]}" for v, _, h in o.choices)
    if o.none:
        text += f"; none: {o.none}"
    if o.auto:
        text += f" (default auto: {o.auto})"
    elif o.kind != "bool" and o.default is not None:
        text += f" (default {_number(o.default)}{' ' + o.unit if o.unit else ''})"
    return text


def add_arguments(parser: argparse.ArgumentParser, names) -> None:
    """Add the settings ``names`` to ``parser`` as options (their flags; ``dest`` is the name)."""
    for name in names:
        o = OPTIONS[name]
        kw = dict(dest=o.name, default=o.default, help=cli_help(o))
        if o.kind == "bool":
            # A setting that is on by default needs its --no- form to be turned off.
            kw["action"] = argparse.BooleanOptionalAction if o.default else "store_true"
        elif o.kind == "choice":
            kw["choices"] = o.values
        else:
            kw["metavar"] = o.metavar
            if o.kind in ("int", "float"):
                kw["type"] = _parser(o)
            elif o.kind == "names":
                kw["nargs"] = "+"
        parser.add_argument(o.flag, **kw)


def _options_class():
    types = {
        "int": "int",
        "float": "float",
        "bool": "bool",
        "str": "str",
        "dir": "str",
        "names": "list",
        "choice": "str",
    }
    lines = [
        "What to delight and how; ``None`` means chosen for you. Built from :data:`SPEC`.",
        "",
        "Parameters",
        "----------",
    ]
    fields_ = []
    for name in RUN_FIELDS:
        o = OPTIONS[name]
        kind = types[o.kind] + (" or None" if o.default is None else "")
        lines += [f"{name} : {kind}", f"    {o.label}: {o.help}."]
        fields_.append((name, kind.replace(" or None", " | None"), field(default=o.default)))
    lines += [
        "solver : dict or None",
        "    Further :class:`core.solve.params.SolverParams` fields, for experts and "
        "benchmarks (the settings above take precedence).",
    ]
    fields_.append(("solver", "dict | None", field(default=None)))

    def validate_self(self):
        """Raise :class:`DelightError` for a bad value (see :func:`check`)."""
        validate(self)

    return make_dataclass(
        "Options", fields_, namespace={"__doc__": "\n".join(lines), "__module__": __name__, "validate": validate_self}
    )


#: What to delight and how (a dataclass with the :data:`RUN_FIELDS`; ``validate()`` checks it).
Options = _options_class()
