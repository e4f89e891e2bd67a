"""Every failure is one line (core.errors), and ``python -m core solve`` prints no traceback without --debug."""

import errno
import io

import numpy as np
import pytest

import core.cli
from core.errors import Cancelled, DelightError, is_expected
from core.evaluate.synthetic import sphere_scene
from core.failures import failure_message, report_failure
from core.io.bundle import save_bundle


def test_failure_messages():
    assert failure_message(DelightError("no mesh")) == "no mesh"
    assert failure_message(ValueError("bad array")) == "bad array"
    assert failure_message(PermissionError(errno.EACCES, "Permission denied", "/x/out")) == "/x/out: permission denied"
    assert failure_message(OSError(errno.ENOSPC, "No space left on device")) == "the disk is full"
    assert failure_message(Cancelled("cancelled")) == "interrupted; nothing was written"
    assert (
        failure_message(Cancelled("interrupted after the new outputs were written to /o", written="/o"))
        == "interrupted after the new outputs were written to /o"
    )


def test_out_of_memory_names_the_settings_to_lower():
    exc = MemoryError()
    assert (
        failure_message(exc, "cli")
        == "out of memory: lower the working resolution (--working-res), the working total (--working-total) or the "
        "texture size (--texture-size)"
    )
    assert failure_message(exc, "panel") == (
        "out of memory: lower the Working resolution (MP), the Working total (MP) or the Texture size (px)"
    )
    assert "smaller bundle" in failure_message(exc, "core")
    with pytest.raises(MemoryError) as info:  # numpy's own kind says the same
        np.empty(2**62, dtype=np.uint8)
    assert failure_message(info.value, "cli") == failure_message(exc, "cli")


def test_an_unexpected_error_is_one_line_that_says_where_the_traceback_is():
    exc = KeyError("views")
    assert failure_message(exc, "cli") == "unexpected KeyError: 'views' (run with --debug for the traceback)"
    assert failure_message(exc, "panel") == "unexpected KeyError: 'views' (the traceback is in the system console)"
    assert failure_message(RuntimeError(), "cli") == "unexpected RuntimeError (run with --debug for the traceback)"
    assert not is_expected(exc) and is_expected(MemoryError()) and is_expected(OSError())


def _raise(exc):
    try:
        raise exc
    except BaseException as caught:  # with a traceback, as a real failure has
        return caught


def test_report_failure_prints_a_traceback_only_with_debug():
    out = io.StringIO()
    assert report_failure(_raise(RuntimeError("boom")), out) == 1
    assert out.getvalue() == "error: unexpected RuntimeError: boom (run with --debug for the traceback)\n"
    out = io.StringIO()
    assert report_failure(_raise(RuntimeError("boom")), out, debug=True) == 1
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("Traceback") and "_raise" in out.getvalue()
    assert lines[-1] == "error: unexpected RuntimeError: boom (run with --debug for the traceback)"
    out = io.StringIO()
    assert report_failure(_raise(KeyboardInterrupt()), out, debug=True) == 130
    assert out.getvalue() == "delight: interrupted; nothing was written\n"


@pytest.fixture
def bundle(tmp_path):
    path = tmp_path / "p.npz"
    save_bundle(path, sphere_scene(n_views=2, height=24, width=32, texture_size=16, seed=0).problem)
    return path


@pytest.mark.parametrize(
    "exc,line",
    [
        (MemoryError(), "error: out of memory: solve a smaller bundle (fewer or smaller photos, a smaller texture)"),
        (RuntimeError("boom"), "error: unexpected RuntimeError: boom (run with --debug for the traceback)"),
        (OSError(errno.ENOSPC, "No space left on device"), "error: the disk is full"),
    ],
)
def test_core_cli_failures_are_one_line(tmp_path, bundle, capsys, monkeypatch, exc, line):
    def fail(*args, **kwargs):  # the solver fails as it would on a machine that lacks the memory
        raise exc

    monkeypatch.setattr(core.cli, "solve", fail)
    argv = ["solve", str(bundle), "--out", str(tmp_path / "out"), "--max-iter", "2"]
    assert core.cli.main(argv) == 1
    err = capsys.readouterr().err.splitlines()
    assert [l for l in err if l.startswith("error:")] == [line] and err[-1] == line
    assert not any("Traceback" in l for l in err)
    assert not (tmp_path / "out").exists()

    assert core.cli.main([*argv, "--debug"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "in fail" in err and err.splitlines()[-1] == line
