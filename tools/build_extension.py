"""Build the Delight extension for Blender 4.2+: one zip per platform.

    .venv/bin/python tools/build_extension.py [--platforms linux-x64 macos-arm64 ...] [--out DIR]

1. Download the wheels that Blender does not bundle (scipy, OpenEXR,
   threadpoolctl; Blender ships numpy), pinned in ``requirements.txt``, for
   each platform and each Python that Blender 4.2 to 5.2 run (3.11 and 3.13;
   threadpoolctl is one pure-Python wheel for all), with ``pip download``
   into the wheels folder (default ``build/wheels/``, git-ignored). Files
   already there are reused.
2. Stage a copy of ``blender_addon/`` in ``build/extension/`` with the
   symlinked ``core`` copied as real files (Blender's builder skips
   symlinks), the wheels, and a manifest listing them under ``wheels``.
3. Run Blender's own extension builder (``blender_ext.py build
   --split-platforms``, found in the bpy module, so no Blender binary is
   needed) and ``validate`` each zip. Blender installs from a zip only the
   wheels of its own Python.

Prints the paths of the zips. Exit status 0 on success.
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ADDON = os.path.join(ROOT, "blender_addon")

#: Distributions to ship; their versions are the pins in requirements.txt.
SHIPPED = ("scipy", "openexr", "threadpoolctl")

#: The Pythons of the Blenders supported: 4.2 to 5.0 run 3.11, 5.1 and 5.2 run 3.13.
PYTHONS = ("3.11", "3.13")

#: Blender platform -> pip ``--platform`` tags (pip also accepts older compatible tags).
PLATFORMS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux2014_x86_64"],
    "macos-arm64": ["macosx_12_0_arm64", "macosx_11_0_arm64"],
    "macos-x64": ["macosx_11_0_x86_64", "macosx_10_14_x86_64"],
    "windows-x64": ["win_amd64"],
}


def shipped_requirements(path: str = os.path.join(ROOT, "requirements.txt")) -> list[str]:
    """The ``name==version`` pins of :data:`SHIPPED` in ``requirements.txt``."""
    pins = {}
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            m = re.match(r"\s*([A-Za-z0-9_.-]+)\s*==\s*([^\s#;]+)", line)
            if m:
                pins[_dist_name(m.group(1))] = m.group(2)
    missing = [n for n in SHIPPED if n not in pins]
    if missing:
        raise RuntimeError(f"{path} pins no version of {', '.join(missing)} (need name==version)")
    return [f"{n}=={pins[n]}" for n in SHIPPED]


def blender_ext_cli() -> str:
    """Path of Blender's ``blender_ext.py`` inside the installed bpy module."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("error: the bpy module is not installed (pip install bpy)")
    base = list(spec.submodule_search_locations)[0]
    found = sorted(glob.glob(os.path.join(base, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")))
    if not found:
        raise SystemExit(f"error: blender_ext.py not found under {base}")
    return found[-1]


def _dist_name(req: str) -> str:
    return re.split(r"[=<>!~ ]", req, maxsplit=1)[0].lower().replace("-", "_")


def download_wheels(platform: str, wheels_dir: str, offline: bool = False) -> list[str]:
    """The shipped wheels for one Blender platform, one per package and Python, downloaded if missing."""
    platform_dir = os.path.join(wheels_dir, platform)
    os.makedirs(platform_dir, exist_ok=True)
    requirements = shipped_requirements()

    def present(python):
        tag = "cp" + python.replace(".", "")
        out = []
        for req in requirements:
            name, version = _dist_name(req), req.split("==")[1]
            hits = glob.glob(os.path.join(platform_dir, f"{name}-{version}-{tag}-*.whl")) or glob.glob(
                os.path.join(platform_dir, f"{name}-{version}-py3-none-any.whl")
            )
            if not hits:
                return None
            out.append(sorted(hits)[0])
        return out

    wheels = []
    for python in PYTHONS:
        if (have := present(python)) is None:
            if offline:
                raise RuntimeError(f"wheels for {platform}, Python {python} are missing in {platform_dir} (offline)")
            cmd = [
                sys.executable,
                "-m",
                "pip",
                "download",
                "--quiet",
                "--only-binary=:all:",
                "--no-deps",
                "--python-version",
                python,
                "--implementation",
                "cp",
                "-d",
                platform_dir,
            ]
            for tag in PLATFORMS[platform]:
                cmd += ["--platform", tag]
            subprocess.run(cmd + requirements, check=True, stdout=subprocess.DEVNULL)
            if (have := present(python)) is None:
                raise RuntimeError(f"pip did not download all wheels for {platform}, Python {python}")
        wheels += have
    return wheels


def stage(stage_dir: str, wheels: list[str], platforms: list[str]) -> str:
    """Copy the add-on (symlinks followed) plus wheels into ``stage_dir``; write its manifest."""
    if os.path.exists(stage_dir):
        shutil.rmtree(stage_dir)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "wheels", ".*")
    shutil.copytree(ADDON, stage_dir, symlinks=False, ignore=ignore)
    os.makedirs(os.path.join(stage_dir, "wheels"))
    rel = []
    for w in wheels:
        shutil.copy2(w, os.path.join(stage_dir, "wheels", os.path.basename(w)))
        rel.append("./wheels/" + os.path.basename(w))
    with open(os.path.join(ADDON, "blender_manifest.toml"), encoding="utf-8") as fh:
        manifest = fh.read()
    manifest = re.sub(r"(?m)^wheels\s*=.*$\n?", "", manifest)
    manifest = re.sub(r"(?m)^platforms\s*=.*$\n?", "", manifest)
    listing = "".join(f'  "{w}",\n' for w in rel)
    extra = f"wheels = [\n{listing}]\nplatforms = {json.dumps(list(platforms))}\n"
    # Top-level keys must come before the first [table].
    head, sep, tail = manifest.partition("\n[")
    manifest = head.rstrip("\n") + "\n\n" + extra + (sep + tail if sep else "")
    with open(os.path.join(stage_dir, "blender_manifest.toml"), "w", encoding="utf-8") as fh:
        fh.write(manifest)
    for path in glob.glob(os.path.join(stage_dir, "**"), recursive=True):
        if os.path.islink(path):
            raise RuntimeError(f"a symlink survived staging: {path}")
    return stage_dir


def build(platforms: list[str], out_dir: str, wheels_dir: str, offline: bool = False) -> list[str]:
    """Build one zip per platform; return their paths."""
    # By file name: a pure-Python wheel is the same file for every platform and Python, shipped once.
    wheels = {}
    for p in platforms:
        for w in download_wheels(p, wheels_dir, offline=offline):
            wheels.setdefault(os.path.basename(w), w)
    stage_dir = stage(os.path.join(ROOT, "build", "extension", "delight"), list(wheels.values()), platforms)
    os.makedirs(out_dir, exist_ok=True)
    cli = blender_ext_cli()
    before = set(glob.glob(os.path.join(out_dir, "*.zip")))
    subprocess.run(
        [sys.executable, cli, "build", "--source-dir", stage_dir, "--output-dir", out_dir, "--split-platforms"],
        check=True,
    )
    zips = sorted(set(glob.glob(os.path.join(out_dir, "*.zip"))) - before) or sorted(
        glob.glob(os.path.join(out_dir, "delight-*.zip"))
    )
    for z in zips:
        subprocess.run([sys.executable, cli, "validate", z], check=True, stdout=subprocess.DEVNULL)
    return zips


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--platforms",
        nargs="+",
        choices=sorted(PLATFORMS),
        default=sorted(PLATFORMS),
        help="platforms to build a zip for (default: all)",
    )
    p.add_argument("--out", default=os.path.join(ROOT, "dist"), help="output folder (default dist/)")
    p.add_argument(
        "--wheels-dir",
        default=os.path.join(ROOT, "build", "wheels"),
        help="where downloaded wheels are kept (default build/wheels/)",
    )
    p.add_argument("--offline", action="store_true", help="use only wheels already downloaded")
    args = p.parse_args(argv)
    try:
        zips = build(args.platforms, os.path.abspath(args.out), os.path.abspath(args.wheels_dir), offline=args.offline)
    except (RuntimeError, subprocess.CalledProcessError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for z in zips:
        print(z)
    return 0


if __name__ == "__main__":
    sys.exit(main())
