"""The headless contract: delight a mesh in a .blend from the command line.

Two ways to run it, with the same options::

    python -m blender_addon SCENE.blend [options]                 # bpy module
    blender -b SCENE.blend -P blender_addon/cli.py -- [options]   # Blender binary

The options (``--help`` lists them) are built from :data:`core.options.SPEC`,
the settings the panel shows, and checked by the same :func:`core.options.check`.

It writes ``<object>_albedo.exr``, ``views/<camera>.exr``, ``lighting.json``,
``lighting.exr`` and ``report.json`` into ``--out`` and prints progress lines. Exit status: 0
on success; 1 on bad input, with one line ``error: ...`` on stderr, nothing
written and the .blend untouched (a setting out of its range included), and on
any other failure (a full disk, out of memory, a bug), with one ``error:`` line
too (``--debug`` prints the traceback before it); 2 on a usage error (an
unknown option, a word where a number belongs); 130 when interrupted.
"""

if __name__ == "__main__" and not __package__:
    # Run as a script by `blender -P`: import the package from beside this file by its folder's own name
    # (blender_addon in the repository, the extension's id where Blender installed it).
    import importlib
    import os
    import sys

    _here = os.path.dirname(os.path.abspath(__file__))
    sys.path.insert(0, os.path.dirname(_here))
    _cli = importlib.import_module(os.path.basename(_here) + ".cli")
    sys.exit(_cli.main(_cli.script_argv(sys.argv), blend_loaded=True))

import argparse
import os
import sys

from .core.options import OPTIONS, RUN_FIELDS

__all__ = ["build_parser", "main", "script_argv", "options_from_args", "CLI_FIELDS"]


def script_argv(argv) -> list:
    """The arguments after ``--`` (Blender's own come before)."""
    argv = list(argv)
    return argv[argv.index("--") + 1 :] if "--" in argv else []


#: The settings the command line takes (those of a run with a flag), in the order of ``--help``.
CLI_FIELDS = tuple(name for name in RUN_FIELDS if OPTIONS[name].flag)


def build_parser(with_blend: bool) -> argparse.ArgumentParser:
    from .core.failures import DEBUG_HELP
    from .core.options import add_arguments

    p = argparse.ArgumentParser(
        prog="python -m blender_addon" if with_blend else "blender -b SCENE.blend -P blender_addon/cli.py --",
        description="Estimate the albedo of a mesh from its photos and cameras (Melou et al. 2018) "
        "and write it as a linear EXR texture.",
    )
    if with_blend:
        p.add_argument("blend", metavar="SCENE.blend", help="the scene to read")
    add_arguments(p, CLI_FIELDS)
    # The flag that --detail off replaced: old scripts keep working.
    p.add_argument("--no-detail", dest="detail", action="store_const", const="off", help=argparse.SUPPRESS)
    p.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    return p


def options_from_args(args):
    """The :class:`core.options.Options` of parsed arguments."""
    from .core.options import Options

    return Options(**{name: getattr(args, name) for name in CLI_FIELDS})


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

    from .core.errors import DelightError
    from .core.failures import report_failure
    from .core.progress import ProgressPrinter
    from .pipeline import run

    try:
        options = options_from_args(args)
        options.validate()
        if args.images_dir is not None and not os.path.isdir(args.images_dir):
            raise DelightError(f"the images folder {args.images_dir} does not exist")
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
        print(f"delight: {bpy.data.filepath}: method {options.method}", flush=True)
        report = run(bpy.context.scene, options, progress=ProgressPrinter(sys.stdout))
    except (Exception, KeyboardInterrupt) as exc:  # one line for any failure; the traceback with --debug
        return report_failure(exc, sys.stderr, debug=args.debug)
    for w in report.warnings:
        print(f"warning: {w}", flush=True)
    times = ", ".join(f"{k} {v:.2f} s" for k, v in report.times.items())
    print(
        f"delight: wrote {report.albedo_path} ({report.iterations} iterations, {report.lambda_text}; {times})",
        flush=True,
    )
    if report.saved_blend:
        print(f"delight: saved {report.saved_blend}", flush=True)
    return 0
