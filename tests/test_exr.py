import os

import numpy as np
import OpenEXR
import pytest

import core.io.exr
from core.io.exr import compression_threads, exr_parts, read_exr, write_exr


def _rand(shape, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.standard_normal(shape) * 3).astype(np.float32)


@pytest.mark.parametrize("c, names", [(4, ["R", "G", "B", "A"]), (3, ["R", "G", "B"]), (1, ["Y"])])
def test_float_round_trip_is_exact(tmp_path, c, names):
    a = _rand((5, 7, c))
    a[0, 0, 0] = np.nan  # NaN and infinities survive a float file
    a[1, 2, -1] = np.inf
    p = tmp_path / "x.exr"
    write_exr(p, a)
    b, ch = read_exr(p)
    assert ch == names
    assert b.dtype == np.float32 and b.shape == a.shape
    np.testing.assert_array_equal(b, a)


def test_strided_and_integer_input(tmp_path):
    a = _rand((6, 8, 4), seed=7)
    view = a[::2, ::-1, 1:]  # non-contiguous: the binding would scramble it
    write_exr(tmp_path / "s.exr", view)
    np.testing.assert_array_equal(read_exr(tmp_path / "s.exr")[0], view)
    ints = np.arange(12).reshape(3, 4)
    write_exr(tmp_path / "i.exr", ints)
    np.testing.assert_array_equal(read_exr(tmp_path / "i.exr")[0][:, :, 0], ints)


def test_two_dimensional_array_is_written_as_y(tmp_path):
    a = _rand((4, 6))
    write_exr(tmp_path / "y.exr", a)
    b, ch = read_exr(tmp_path / "y.exr")
    assert ch == ["Y"] and b.shape == (4, 6, 1)
    np.testing.assert_array_equal(b[:, :, 0], a)


@pytest.mark.parametrize("c", [3, 4])
def test_half_round_trip_within_half_precision(tmp_path, c):
    a = _rand((6, 5, c), seed=1)
    p = tmp_path / "h.exr"
    write_exr(p, a, half=True)
    f = OpenEXR.File(str(p), separate_channels=True)
    assert all(ch.type() == OpenEXR.HALF for ch in f.parts[0].channels.values())
    assert f.header()["compression"] == OpenEXR.ZIP_COMPRESSION
    b, _ = read_exr(p)
    assert b.dtype == np.float32
    np.testing.assert_allclose(b, a, rtol=2**-11, atol=2**-24)
    assert not np.array_equal(b, a)  # it really was stored as half


def test_row_zero_is_the_top_row_in_the_file(tmp_path):
    a = np.zeros((3, 4, 3), np.float32)
    a[0, :, 0] = 1.0  # red top row
    p = tmp_path / "top.exr"
    write_exr(p, a)
    # read with OpenEXR directly: its row 0 is the first scanline of the data window (the top)
    f = OpenEXR.File(str(p), separate_channels=True)
    r = f.parts[0].channels["R"].pixels
    assert r[0].tolist() == [1.0] * 4 and not r[1:].any()


def test_custom_channel_names_and_order(tmp_path):
    a = _rand((3, 3, 5), seed=2)
    write_exr(tmp_path / "c.exr", a, channels=["Z", "A", "B", "G", "R"])
    b, ch = read_exr(tmp_path / "c.exr")
    assert ch == ["R", "G", "B", "A", "Z"]
    np.testing.assert_array_equal(b, a[:, :, [4, 3, 2, 1, 0]])


def test_write_rejects_bad_input_and_leaves_nothing(tmp_path):
    p = tmp_path / "bad.exr"
    with pytest.raises(ValueError, match="channel names"):
        write_exr(p, np.zeros((2, 2, 5), np.float32))
    with pytest.raises(ValueError, match="2 channel names for 3"):
        write_exr(p, np.zeros((2, 2, 3), np.float32), channels=["R", "G"])
    with pytest.raises(ValueError, match="unique"):
        write_exr(p, np.zeros((2, 2, 2), np.float32), channels=["R", "R"])
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        write_exr(p, np.zeros((2, 2, 3, 1), np.float32))
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_exr(tmp_path / "no" / "dir.exr", np.zeros((2, 2), np.float32))
    assert os.listdir(tmp_path) == []


def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    p = tmp_path / "keep.exr"
    old = _rand((3, 3, 3))
    write_exr(p, old)

    class FailingFile:  # writes half a file, then fails, like a full disk
        def __init__(self, *args):
            pass

        def write(self, target):
            with open(target, "wb") as fh:
                fh.write(b"v/1\x01partial")
            raise RuntimeError("disk full")

    monkeypatch.setattr(core.io.exr.OpenEXR, "File", FailingFile)
    with pytest.raises(OSError, match="keep.exr.*disk full"):
        write_exr(p, _rand((3, 3, 3), seed=9))
    monkeypatch.undo()
    assert sorted(os.listdir(tmp_path)) == ["keep.exr"]
    np.testing.assert_array_equal(read_exr(p)[0], old)


def test_multi_part_file(tmp_path):
    h, w = 4, 6
    depth = _rand((h, w), seed=3)
    rgb = _rand((h, w, 3), seed=4)
    nrm = _rand((h, w, 3), seed=5)
    parts = [
        OpenEXR.Part({"compression": OpenEXR.ZIP_COMPRESSION}, {"Layer.Depth.Z": depth}, "Layer.Depth"),
        # the binding ignores numpy strides: hand it contiguous planes
        OpenEXR.Part(
            {}, {f"Layer.Normal.{k}": np.ascontiguousarray(nrm[:, :, i]) for i, k in enumerate("XYZ")}, "Layer.Normal"
        ),
        OpenEXR.Part(
            {}, {f"Layer.Combined.{k}": rgb[:, :, i].astype(np.float16) for i, k in enumerate("RGB")}, "Layer.Combined"
        ),
    ]
    p = tmp_path / "multi.exr"
    OpenEXR.File(parts).write(str(p))

    a, ch = read_exr(p)  # default: first part with R, G, B
    assert ch == ["R", "G", "B"]
    np.testing.assert_array_equal(a, rgb.astype(np.float16).astype(np.float32))

    a, ch = read_exr(p, part="Layer.Normal")
    assert ch == ["X", "Y", "Z"]
    np.testing.assert_array_equal(a, nrm)

    a, ch = read_exr(p, part=0)
    assert ch == ["Z"]
    np.testing.assert_array_equal(a[:, :, 0], depth)

    assert exr_parts(p) == [
        ("Layer.Depth", ["Z"]),
        ("Layer.Normal", ["X", "Y", "Z"]),
        ("Layer.Combined", ["R", "G", "B"]),
    ]
    with pytest.raises(ValueError, match="no part named 'Nope'.*Layer.Normal"):
        read_exr(p, part="Nope")
    with pytest.raises(ValueError, match="part index 3 out of range"):
        read_exr(p, part=3)


def test_unreadable_files_name_the_path(tmp_path):
    missing = tmp_path / "missing.exr"
    with pytest.raises(FileNotFoundError, match="missing.exr"):
        read_exr(missing)
    text = tmp_path / "photo.exr"
    text.write_text("not an image")
    with pytest.raises(ValueError, match="not an OpenEXR file.*photo.exr"):
        read_exr(text)
    good = tmp_path / "good.exr"
    write_exr(good, _rand((16, 16, 4)))
    trunc = tmp_path / "trunc.exr"
    trunc.write_bytes(good.read_bytes()[:200])
    with pytest.raises(ValueError, match="trunc.exr"):
        read_exr(trunc)
    with pytest.raises(ValueError, match="not a file"):
        read_exr(tmp_path)


@pytest.mark.bpy
def test_blender_multilayer_exr_is_read(tmp_path):
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_homefile(use_empty=True)
    try:
        scene = bpy.context.scene
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = 1
        scene.render.resolution_x, scene.render.resolution_y = 8, 6
        scene.render.resolution_percentage = 100
        scene.render.film_transparent = True
        scene.view_layers[0].use_pass_normal = True
        # a sphere in the upper half of the frame: rows 0-2 see it, rows 3-5 do not
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.0, 0.8, 0.0))
        cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
        scene.collection.objects.link(cam)
        cam.location = (0.0, 0.0, 5.0)  # identity rotation: looks down -Z, +Y up
        scene.camera = cam
        # In 5.0 'OPEN_EXR_MULTILAYER' can only be reached through media_type.
        scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
        assert scene.render.image_settings.file_format == "OPEN_EXR_MULTILAYER"
        scene.render.filepath = str(tmp_path / "render.exr")
        bpy.ops.render.render(write_still=True)
    finally:
        bpy.ops.wm.read_homefile(use_empty=True)

    path = tmp_path / "render.exr"
    names = [name for name, _ in exr_parts(path)]
    assert len(names) > 1 and "ViewLayer.Normal" in names  # really multi-part

    rgba, ch = read_exr(path)
    assert ch == ["R", "G", "B", "A"]
    assert rgba.shape == (6, 8, 4) and rgba.dtype == np.float32
    alpha = rgba[:, :, 3]
    assert alpha[:2, 3:5].min() > 0.99  # the sphere, at the top
    assert alpha[4:].max() == 0.0  # transparent background, at the bottom

    nrm, ch = read_exr(path, part="ViewLayer.Normal")
    assert ch == ["X", "Y", "Z"]
    hit = alpha > 0.99
    np.testing.assert_allclose(np.linalg.norm(nrm[hit], axis=1), 1.0, atol=1e-3)
    assert nrm[0, 3:5, 1].min() > 0.3  # top row: world normals point up (+Y)


def test_compression_threads_write_the_same_bytes_and_are_set_back(tmp_path):
    rng = np.random.default_rng(4)
    image = (rng.random((300, 200, 4)) * 0.1 + np.linspace(0, 1, 200)[None, :, None]).astype(np.float32)
    before = OpenEXR.global_thread_count()
    write_exr(tmp_path / "one.exr", image)
    with compression_threads(2):
        assert OpenEXR.global_thread_count() == 2
        write_exr(tmp_path / "two.exr", image)
    assert OpenEXR.global_thread_count() == before
    assert (tmp_path / "one.exr").read_bytes() == (tmp_path / "two.exr").read_bytes()
    with pytest.raises(RuntimeError), compression_threads(2):  # set back whatever happens in the block
        raise RuntimeError("stop")
    assert OpenEXR.global_thread_count() == before
    with compression_threads(1):
        assert OpenEXR.global_thread_count() == 0  # one thread: the caller's
