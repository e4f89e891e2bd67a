"""The one options spec (core.options): the command lines are built from it and refuse bad values in its words.

The bpy side (operator and panel properties, the operator's refusals) is in tests/bpy/test_option_properties.py.
"""

import dataclasses
import io
import math

import pytest

from blender_addon.cli import CLI_FIELDS, options_from_args
from blender_addon.cli import build_parser as addon_parser
from core import pipeline
from core.cli import build_parser as core_parser
from core.cli import main as core_main
from core.errors import Cancelled, DelightError
from core.failures import report_failure
from core.options import OPTIONS, RUN_FIELDS, SOLVER_FIELDS, SPEC, Options, check, requirement
from core.progress import STAGES, ProgressPrinter, check_cancel, stage_progress
from core.solve.lambda_choice import LIGHT_LAMBDA
from core.solve.params import SolverParams

#: Bad values and the one message every front end gives for them.
BAD = [
    ("texture_size", 3, "texture size must be an integer between 8 and 16384, got 3"),
    ("texture_size", 16385, "texture size must be an integer between 8 and 16384, got 16385"),
    ("lam", -1.0, "lambda must be a number of at least 0 or auto, got -1"),
    ("lam", math.inf, "lambda must be a finite number, got inf"),
    ("lam", math.nan, "lambda must be a finite number, got nan"),
    ("working_res_mp", 0.0, "working resolution (MP) must be a number greater than 0, got 0"),
    ("max_iter", 0, "iterations must be an integer of at least 1, got 0"),
    ("mu", -0.5, "mu must be a number of at least 0, got -0.5"),
    ("method", "magic", "method must be one of texture, image, project, got 'magic'"),
    ("threads", 0, "threads must be an integer between 1 and 4096 or auto, got 0"),
]


def test_solver_defaults_come_from_solver_params():
    p = SolverParams()
    for name in ("mu", "max_iter", "delta", "data_model", "gauss_newton"):
        assert OPTIONS[name].default == getattr(p, name), name
    # Auto; the UI starts at the lighting stage's weight, which the default two stages take.
    assert OPTIONS["lam"].default is None and OPTIONS["lam"].ui_default == LIGHT_LAMBDA
    assert pipeline.DEFAULTS == p


def test_every_setting_has_words_and_a_sane_range():
    assert len({o.name for o in SPEC}) == len(SPEC)
    for o in SPEC:
        assert o.label and o.help and o.label[0].isupper(), o.name
        if o.kind in ("int", "float"):
            lo = -math.inf if o.min is None else o.min
            hi = math.inf if o.max is None else o.max
            if o.soft_min is not None:
                assert lo <= o.soft_min < o.soft_max <= hi, o.name
            if o.default is not None:
                check(o.name, o.default)
        if o.kind == "choice":
            assert o.default in o.values


def test_options_is_built_from_the_spec():
    assert pipeline.Options is Options
    fields = dataclasses.fields(Options)
    assert tuple(f.name for f in fields) == RUN_FIELDS + ("solver",)  # solver: expert SolverParams fields
    assert {f.name: f.default for f in fields[:-1]} == {n: OPTIONS[n].default for n in RUN_FIELDS}
    assert pipeline.METHODS == ("texture", "image", "project")
    Options().validate()
    with pytest.raises(DelightError, match="texture size must be"):
        Options(texture_size=3).validate()
    assert "working_res_mp : float" in Options.__doc__ and "Working resolution (MP)" in Options.__doc__


@pytest.mark.parametrize("name, value, message", BAD)
def test_check_refuses_with_one_wording(name, value, message):
    with pytest.raises(DelightError) as info:
        check(name, value)
    assert str(info.value) == message


@pytest.mark.parametrize(
    "name, value",
    [
        ("texture_size", 8),
        ("texture_size", 16384),
        ("lam", 0.0),
        ("lam", None),
        ("working_res_mp", 1e-4),
        ("max_iter", 1),
        ("delta", 1e-9),
        ("method", "project"),
        ("object_name", None),
    ],
)
def test_check_accepts_the_edges(name, value):
    assert check(name, value) is value


def test_check_refuses_non_numbers_and_fractional_integers():
    with pytest.raises(DelightError, match="texture size must be an integer between 8 and 16384, got 64.5"):
        check("texture_size", 64.5)
    with pytest.raises(DelightError, match="got 'x'"):
        check("mu", "x")
    with pytest.raises(DelightError, match="got True"):
        check("max_iter", True)
    with pytest.raises(DelightError, match="Huber delta must be a number greater than 0, got 0"):
        check("delta", 0.0)
    assert requirement(OPTIONS["data_model"]) == "one of nearest, splat, interpolate"


def _parser_actions(parser, names):
    actions = {}
    for a in parser._actions:  # the first for a dest: the spec's (an old flag's alias comes after)
        actions.setdefault(a.dest, a)
    return {n: actions[n] for n in names}


@pytest.mark.parametrize("which", ["addon", "core"])
def test_the_command_lines_take_their_defaults_choices_and_help_from_the_spec(which):
    if which == "addon":
        parser, names = addon_parser(with_blend=True), CLI_FIELDS
    else:
        parser, names = core_parser()._subparsers._group_actions[0].choices["solve"], SOLVER_FIELDS
    for name, action in _parser_actions(parser, names).items():
        o = OPTIONS[name]
        # A setting on by default also has its --no- form.
        assert action.option_strings == [o.flag] + ([f"--no-{o.flag[2:]}"] if o.kind == "bool" and o.default else []), (
            name
        )
        assert action.default == o.default, name
        assert action.help.startswith(o.help), name
        if o.kind == "choice":
            assert tuple(action.choices) == o.values
        if o.kind in ("int", "float"):
            assert action.type("7") == 7 and isinstance(action.type("7"), int if o.kind == "int" else float)


def test_addon_command_line_defaults_are_the_options_defaults():
    args = addon_parser(with_blend=True).parse_args(["scene.blend"])
    # (blender_addon.core is core under a second name, so compare the values)
    assert dataclasses.asdict(options_from_args(args)) == dataclasses.asdict(Options())
    args = addon_parser(with_blend=True).parse_args(
        [
            "scene.blend",
            "--lambda",
            "auto",
            "--texture-size",
            "3",
            "--working-res",
            "0.5",
            "--cameras",
            "a",
            "b",
            "--save",
        ]
    )
    opts = options_from_args(args)
    assert opts.lam is None and opts.texture_size == 3 and opts.working_res_mp == 0.5
    assert opts.camera_names == ["a", "b"] and opts.save_blend


def test_the_old_no_detail_flag_still_turns_the_detail_stage_off():
    parser = addon_parser(with_blend=True)
    assert options_from_args(parser.parse_args(["scene.blend", "--no-detail"])).detail == "off"
    assert options_from_args(parser.parse_args(["scene.blend", "--detail", "on"])).detail == "on"
    assert "--no-detail" not in parser.format_help()


@pytest.mark.parametrize("name, value, message", [b for b in BAD if b[0] in SOLVER_FIELDS])
def test_core_command_line_refuses_bad_values_in_the_same_words(tmp_path, capsys, name, value, message):
    flag = OPTIONS[name].flag
    status = core_main(["solve", str(tmp_path / "none.npz"), "--out", str(tmp_path / "out"), flag, f"{value:g}"])
    assert status == 1
    assert capsys.readouterr().err == f"error: {message}\n"
    assert not (tmp_path / "out").exists()


def test_a_word_for_a_number_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        core_parser().parse_args(["solve", "b.npz", "--out", "o", "--lambda", "soft"])
    assert info.value.code == 2
    assert "lambda must be a number of at least 0 or auto, got 'soft'" in capsys.readouterr().err


def test_progress_stages_cover_the_bar_in_order():
    spans = list(STAGES.values())
    assert spans[0][0] == 0.0 and spans[-1][1] == 1.0
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
    seen = []
    report = stage_progress(lambda f, m: seen.append((f, m)), "solve")
    report(0.5, "iteration 3")
    report(2.0)
    assert seen == [(pytest.approx(0.6), "solve: iteration 3"), (pytest.approx(0.9), "solve")]
    stage_progress(None, "bake")(0.5, "nothing happens")


def test_check_cancel():
    check_cancel(None)
    check_cancel(lambda: False)
    with pytest.raises(Cancelled):
        check_cancel(lambda: True)


def test_progress_printer_prints_on_a_new_message_or_a_step():
    out = io.StringIO()
    p = ProgressPrinter(out, step=0.05)
    p(0.0, "bake: a")
    p(0.01, "bake: a")  # same message, small move: quiet
    p(0.06, "bake: a")
    p(0.061, "bake: b")
    assert out.getvalue().splitlines() == [
        "delight:   0.0% bake: a",
        "delight:   6.0% bake: a",
        "delight:   6.1% bake: b",
    ]


def test_report_failure_lines_and_statuses():
    out = io.StringIO()
    assert report_failure(DelightError("no mesh"), out) == 1
    assert report_failure(ValueError("bad array"), out) == 1
    assert report_failure(Cancelled("cancelled"), out) == 130
    assert report_failure(KeyboardInterrupt(), out) == 130
    assert (
        out.getvalue().splitlines()
        == ["error: no mesh", "error: bad array"] + ["delight: interrupted; nothing was written"] * 2
    )
