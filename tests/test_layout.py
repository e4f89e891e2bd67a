"""The core is pure NumPy/SciPy: importing every one of its modules never imports bpy."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def core_modules():
    out = []
    for dirpath, _dirs, files in os.walk(os.path.join(ROOT, "core")):
        for f in sorted(files):
            if f.endswith(".py") and f != "__main__.py":
                rel = os.path.relpath(os.path.join(dirpath, f), ROOT)[:-3].replace(os.sep, ".")
                out.append(rel[: -len(".__init__")] if rel.endswith(".__init__") else rel)
    return out


def test_core_never_imports_bpy():
    mods = core_modules()
    assert len(mods) > 20 and "core.solve.solver" in mods
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}: importlib.import_module(m)\n"
        "print(sorted(m for m in sys.modules if m == 'bpy' or m.startswith(('bpy.', 'mathutils', 'bmesh'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
