"""The operator's and the panel's properties are the spec's, and the operator refuses what the command line does.

The bpy-free side of the spec is in tests/test_options.py.
"""

from __future__ import annotations

import math

import pytest

bpy = pytest.importorskip("bpy")

from conftest import build_scene  # noqa: E402
from scene_state import scene_state  # noqa: E402

import blender_addon  # noqa: E402
from blender_addon import cli  # noqa: E402
from blender_addon.core.options import OPTIONS  # noqa: E402
from blender_addon.panel import DelightSettings, operator_settings  # noqa: E402

pytestmark = pytest.mark.bpy

#: Operator property -> setting of the spec (the UI-only settings included).
OPERATOR = {
    "object_name": "object_name",
    "cameras": "cameras",
    "camera_collection": "camera_collection",
    "images_dir": "images_dir",
    "auto_lambda": "auto_lambda",
    "lam": "lam",
    "mu": "mu",
    "max_iter": "max_iter",
    "working_res": "working_res_mp",
    "working_total": "working_total_mp",
    "detail": "detail",
    "texture_size": "texture_size",
    "method": "method",
    "out_dir": "out_dir",
    "overwrite": "overwrite",
    "albedo_lam": "albedo_lam",
    "albedo_adapt": "albedo_adapt",
    "lighting": "lighting",
    "occlusion": "occlusion",
    "sun": "sun",
    "align_photos": "align_photos",
    "mask_clipped": "mask_clipped",
    "fill_outlines": "fill_outlines",
}

#: Bad values: operator keywords, the command line's arguments, and the one message both give.
BAD = [
    (dict(texture_size=3), ["--texture-size", "3"], "texture size must be an integer between 8 and 16384, got 3"),
    (dict(auto_lambda=False, lam=-1.0), ["--lambda", "-1"], "lambda must be a number of at least 0 or auto, got -1"),
    (dict(auto_lambda=False, lam=math.inf), ["--lambda", "inf"], "lambda must be a finite number, got inf"),
    (dict(auto_lambda=False, lam=math.nan), ["--lambda", "nan"], "lambda must be a finite number, got nan"),
    (dict(working_res=0.0), ["--working-res", "0"], "working resolution (MP) must be a number greater than 0, got 0"),
    (dict(max_iter=0), ["--max-iter", "0"], "iterations must be an integer of at least 1, got 0"),
    (dict(working_total=-1.0), ["--working-total", "-1"], "working total (MP) must be a number of at least 0, got -1"),
]


@pytest.fixture(autouse=True)
def addon():
    blender_addon.register()
    yield
    blender_addon.unregister()


def _props(rna):
    return {k: rna.properties[k] for k in rna.properties.keys() if k not in ("rna_type", "name")}


def _check_words_and_defaults(prop, o):
    assert prop.name == o.label and prop.description == o.help, o.name
    if o.kind == "choice":
        assert prop.default == o.default
        assert [(i.identifier, i.name, i.description) for i in prop.enum_items] == [tuple(c) for c in o.choices]
    elif o.kind in ("int", "float", "bool", "str", "dir"):
        assert prop.default == pytest.approx(o.ui_default) if o.kind == "float" else prop.default == o.ui_default
    if o.kind in ("int", "float"):
        assert prop.soft_min == pytest.approx(o.soft_min) and prop.soft_max == pytest.approx(o.soft_max), o.name


def test_operator_properties_are_the_spec_and_do_not_clamp():
    props = _props(bpy.ops.delight.run.get_rna_type())
    assert set(props) == set(OPERATOR)
    for key, name in OPERATOR.items():
        prop, o = props[key], OPTIONS[name]
        _check_words_and_defaults(prop, o)
        if o.kind == "float":  # any value reaches the run's check
            assert prop.hard_min == -math.inf and prop.hard_max == math.inf, key
        if o.kind == "int":
            assert prop.hard_min <= -(2**31) and prop.hard_max >= 2**31 - 1, key


def test_panel_properties_are_the_spec_with_its_hard_range():
    props = _props(DelightSettings.bl_rna)
    for key, prop in props.items():
        name = {"target": "object_name"}.get(key, OPERATOR.get(key, key))
        o = OPTIONS[name]
        if prop.type == "POINTER":  # the mesh and the collection are picked, not typed
            assert prop.name == o.label and prop.description == o.help, key
            continue
        _check_words_and_defaults(prop, o)
        if o.kind in ("int", "float"):
            assert prop.hard_min == o.min, key
            assert prop.hard_max == (o.max if o.max is not None else (math.inf if o.kind == "float" else 2**31 - 1))
    # Everything the panel hands over is an operator property of the same setting.
    s = bpy.context.scene.delight
    assert set(operator_settings(s)) == set(OPERATOR)
    s.texture_size = 3  # typed into the field: held at the range's end
    assert s.texture_size == 8


@pytest.mark.parametrize("kw, args, message", BAD)
def test_operator_and_command_line_refuse_a_bad_value_in_the_same_words(tmp_path, capsys, kw, args, message):
    build_scene(str(tmp_path))
    before = scene_state()
    out = tmp_path / "out"
    with pytest.raises(RuntimeError) as info:
        bpy.ops.delight.run(**{"method": "project", "texture_size": 16, "out_dir": str(out), **kw})
    assert str(info.value).strip() == f"Error: Delight: {message}"
    assert scene_state() == before and not out.exists()

    capsys.readouterr()
    status = cli.main([str(tmp_path / "scene.blend"), *args, "--out", str(out)])
    assert status == 1
    assert capsys.readouterr().err == f"error: {message}\n"
    assert not out.exists()
