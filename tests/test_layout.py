"""The core is pure NumPy/SciPy: importing every one of its modules never imports bpy; and its packages import
only the ones below them, in the order the data flows."""

import ast
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def core_modules():
    out = []
    for dirpath, _dirs, files in os.walk(os.path.join(ROOT, "core")):
        for f in sorted(files):
            if f.endswith(".py") and f != "__main__.py":
                rel = os.path.relpath(os.path.join(dirpath, f), ROOT)[:-3].replace(os.sep, ".")
                out.append(rel[: -len(".__init__")] if rel.endswith(".__init__") else rel)
    return out


def loaded_after_importing(mods):
    """The names of the modules a fresh interpreter holds after importing ``mods``."""
    code = f"import importlib, sys\nfor m in {mods!r}: importlib.import_module(m)\nprint(sorted(sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    return ast.literal_eval(out.stdout)


def test_core_never_imports_bpy():
    mods = core_modules()
    assert len(mods) > 20 and "core.solve.solver" in mods
    loaded = [m for m in loaded_after_importing(mods) if m == "bpy" or m.startswith(("bpy.", "mathutils", "bmesh"))]
    assert loaded == [], loaded


#: The data flows geometry -> solve -> io -> texture (-> core.pipeline); each package may import those before it.
FLOW = ("geometry", "solve", "io", "texture")


@pytest.mark.parametrize("index", range(len(FLOW)))
def test_a_core_package_imports_only_the_packages_before_it_in_the_flow(index):
    package = FLOW[index]
    mods = [m for m in core_modules() if m.startswith(f"core.{package}.")]
    assert mods
    loaded = {m.split(".")[1] for m in loaded_after_importing(mods) if m.startswith("core.")}
    assert package in loaded
    later = set(FLOW[index + 1 :]) | {"pipeline", "cli", "evaluate", "options"}
    assert not loaded & later, f"core.{package} imports {sorted(loaded & later)}, which come after it"
