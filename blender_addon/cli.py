"""The headless contract: delight a mesh in a .blend from the command line.

Two ways to run it, with the same options::

    python -m blender_addon SCENE.blend [options]                 # bpy module
    blender -b SCENE.blend -P blender_addon/cli.py -- [options]   # Blender binary

Options::

    --object NAME         the mesh (default: the active object)
    --cameras NAME ...    the cameras (default: all)
    --images DIR          photos named like the cameras, for cameras without one
    --lambda L|auto  --mu M  --max-iter K   (lambda: auto; the rest: core.solve.solver.SolverParams)
    --albedo-lambda L|none   TV weight of the albedo stage; none: one stage, as the paper
    --lighting auto|per_view|shared|coupled   the lighting model (default auto)
    --occlusion / --no-occlusion   shade with the occlusion-aware transfer or the paper's nu(n)
    --mask-clipped / --no-mask-clipped   leave 8-bit pixels at the ceiling out of the solve
    --working-res MP      downscale photos to at most MP megapixels (default 1)
    --texture-size N      N x N albedo texture (default 1024)
    --method texture|image|project   (default texture; project = no delighting)
    --out DIR             output folder (default: beside the .blend)
    --save                save the .blend with the new material (never otherwise)
    --overwrite           replace existing output files

It writes ``<object>_albedo.exr``, ``views/<camera>.exr``, ``lighting.json``
and ``report.json`` into ``--out`` and prints progress lines. Exit status: 0
on success; 1 on bad input, with one line ``error: ...`` on stderr, nothing
written and the .blend untouched; 2 on a usage error; 130 when interrupted.
"""
if __name__ == "__main__" and not __package__:
    # Run as a script by `blender -P`: import the package by name from beside
    # this file (the package itself only uses relative imports).
    import os
    import sys
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from blender_addon.cli import main, script_argv
    sys.exit(main(script_argv(sys.argv), blend_loaded=True))

import argparse
import os
import sys

__all__ = ["build_parser", "main", "script_argv", "options_from_args"]


def script_argv(argv) -> list:
    """The arguments after ``--`` (Blender's own come before)."""
    argv = list(argv)
    return argv[argv.index("--") + 1:] if "--" in argv else []


def _albedo_lambda(text):
    """argparse type for ``--albedo-lambda``: a number >= 0, or ``none`` (one stage)."""
    if text.strip().lower() == "none":
        return None
    v = float(text)
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0 or 'none', got {text!r}")
    return v


def build_parser(with_blend: bool) -> argparse.ArgumentParser:
    from .core.cli import lambda_arg
    from .core.pipeline import LIGHTING_MODES, Options
    from .pipeline import DEFAULTS
    p = argparse.ArgumentParser(
        prog="python -m blender_addon" if with_blend else "blender -b SCENE.blend -P blender_addon/cli.py --",
        description="Estimate the albedo of a mesh from its photos and cameras (Melou et al. 2018) "
                    "and write it as a linear EXR texture.")
    if with_blend:
        p.add_argument("blend", metavar="SCENE.blend", help="the scene to read")
    p.add_argument("--object", metavar="NAME", help="the mesh object (default: the active object)")
    p.add_argument("--cameras", metavar="NAME", nargs="+", help="the cameras to use (default: all)")
    p.add_argument("--images", metavar="DIR", help="folder of photos named like the cameras")
    p.add_argument("--lambda", dest="lam", type=lambda_arg, default=None, metavar="L",
                   help="TV weight, or 'auto' (default): 5 when the photos share one lighting, 0.5 when it "
                        "changes between them (measured on the photos)")
    p.add_argument("--mu", type=float, default=DEFAULTS.mu, metavar="M",
                   help=f"consistency weight, image method (default {DEFAULTS.mu:g})")
    p.add_argument("--albedo-lambda", dest="albedo_lam", type=_albedo_lambda, default=Options.albedo_lam,
                   metavar="L", help="TV weight of the albedo stage, after the lighting stage, or 'none' for one "
                                     f"stage as the paper (default {Options.albedo_lam})")
    p.add_argument("--lighting", choices=LIGHTING_MODES, default=Options.lighting,
                   help="one lighting per photo, one shared by all (times a gain per photo), per photo held to a "
                        "shared one, or auto: coupled when the photos share one light (default "
                        f"{Options.lighting})")
    p.add_argument("--occlusion", action=argparse.BooleanOptionalAction, default=Options.occlusion,
                   help="shade with the occlusion-aware SH transfer instead of the paper's nu(n) "
                        f"(default {'on' if Options.occlusion else 'off'})")
    p.add_argument("--mask-clipped", action=argparse.BooleanOptionalAction, default=Options.mask_clipped,
                   help="leave pixels at an 8-bit photo's ceiling out of the solve "
                        f"(default {'on' if Options.mask_clipped else 'off'})")
    p.add_argument("--max-iter", type=int, default=DEFAULTS.max_iter, metavar="K",
                   help=f"outer iterations at the finest level (default {DEFAULTS.max_iter})")
    p.add_argument("--working-res", type=float, default=1.0, metavar="MP",
                   help="downscale photos to at most MP megapixels (default 1)")
    p.add_argument("--texture-size", type=int, default=1024, metavar="N", help="texture size (default 1024)")
    p.add_argument("--method", choices=("texture", "image", "project"), default="texture",
                   help="texture or image domain, or project (no delighting) (default texture)")
    p.add_argument("--out", metavar="DIR", help="output folder (default: beside the .blend)")
    p.add_argument("--save", action="store_true", help="save the .blend with the new material")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    return p


def options_from_args(args):
    from .pipeline import Options
    return Options(object_name=args.object, camera_names=args.cameras, images_dir=args.images,
                   lam=args.lam, mu=args.mu, max_iter=args.max_iter, working_res_mp=args.working_res,
                   texture_size=args.texture_size, method=args.method, out_dir=args.out,
                   save_blend=args.save, overwrite=args.overwrite, albedo_lam=args.albedo_lam,
                   lighting=args.lighting, occlusion=args.occlusion, mask_clipped=args.mask_clipped)


class _Progress:
    """Prints a line when the message changes or the bar moves by 5 %."""

    def __init__(self, stream):
        self.stream, self.last = stream, (None, -1.0)

    def __call__(self, fraction, message=""):
        if message != self.last[0] or fraction - self.last[1] >= 0.05:
            print(f"delight: {100 * fraction:5.1f}% {message}", file=self.stream, flush=True)
            self.last = (message, fraction)


def main(argv=None, blend_loaded: bool = False) -> int:
    """Run the command line; return the exit status.

    Parameters
    ----------
    argv : list of str, optional
        The options (default ``sys.argv[1:]``), with the .blend path first
        unless ``blend_loaded``.
    blend_loaded : bool
        True when Blender already opened the .blend (``blender -b X -P``).
    """
    parser = build_parser(with_blend=not blend_loaded)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)

    import bpy

    from .core.errors import Cancelled
    from .core.errors import DelightError
    from .pipeline import run

    def fail(msg):
        print(f"error: {msg}", file=sys.stderr, flush=True)
        return 1

    try:
        if args.images is not None and not os.path.isdir(args.images):
            raise DelightError(f"the images folder {args.images} does not exist")
        if not blend_loaded:
            path = os.path.abspath(args.blend)
            if not os.path.isfile(path):
                raise DelightError(f"no such .blend file: {args.blend}")
            try:
                bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
            except RuntimeError as exc:
                raise DelightError(f"cannot open {args.blend}: {str(exc).strip()}") from None
        elif not bpy.data.filepath:
            raise DelightError("no .blend was loaded (run: blender -b SCENE.blend -P cli.py -- ...)")
        options = options_from_args(args)
        print(f"delight: {bpy.data.filepath}: method {options.method}", flush=True)
        report = run(bpy.context.scene, options, progress=_Progress(sys.stdout))
    except (DelightError, ValueError) as exc:
        return fail(str(exc))
    except (Cancelled, KeyboardInterrupt):
        print("delight: interrupted; nothing was written", file=sys.stderr, flush=True)
        return 130
    for w in report.warnings:
        print(f"warning: {w}", flush=True)
    times = ", ".join(f"{k} {v:.2f} s" for k, v in report.times.items())
    print(f"delight: wrote {report.albedo_path} ({report.iterations} iterations, {report.lambda_text}; {times})",
          flush=True)
    if report.saved_blend:
        print(f"delight: saved {report.saved_blend}", flush=True)
    return 0
