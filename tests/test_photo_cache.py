"""The full-resolution photos' temporary copies (core.io.photo_cache)."""

import os
import shutil

import numpy as np
import pytest

from core.errors import DelightError
from core.io import photo_cache
from core.io.photo_cache import PREFIX, PhotoCache
from core.io.photos import CodedPhoto, _area_matrix, downscale, photo_pixels, photo_scaled, srgb_to_linear


def test_copies_read_back_as_half_floats_and_go_with_the_folders_they_made(tmp_path):
    out = tmp_path / "new" / "out"  # neither exists yet
    cache = PhotoCache(out)
    photo = np.random.default_rng(0).uniform(0, 4, size=(30, 40, 3)).astype(np.float32)
    photo[0, 0] = 1e6  # beyond half floats: clipped, not infinite
    clipped = photo[..., 0] > 3.5
    load = cache.put(photo, clipped)
    load_plain = cache.put(photo[:10])
    (folder,) = [f for f in os.listdir(out) if f.startswith(PREFIX)]
    back, back_clipped = load()
    assert back.dtype == np.float32 and back.shape == photo.shape
    np.testing.assert_allclose(back[1:], photo[1:], rtol=1e-3)
    assert back[0, 0, 0] == 65504.0
    np.testing.assert_array_equal(back_clipped, clipped)
    assert load_plain()[1] is None
    assert load() is not None  # read anew on each call
    cache.close()
    assert not (tmp_path / "new").exists()  # the cache made both folders and removes them
    cache.close()  # twice is fine
    with pytest.raises(OSError):
        load()


def test_an_8bit_photo_is_kept_as_its_codes_and_reads_back_the_same_colours(tmp_path):
    rng = np.random.default_rng(1)
    tables = np.zeros((3, 256, 3), np.float32)
    for k in range(3):  # a curve per channel and a matrix that mixes them: no channel's colour is its own alone
        tables[k] = np.outer(srgb_to_linear(np.arange(256) / 255.0), [0.8 if j == k else 0.1 for j in range(3)])
    codes = rng.integers(0, 256, (40, 30, 3)).astype(np.uint8)
    clipped = np.any(codes >= 250, axis=2)
    cache = PhotoCache(tmp_path)
    load = cache.put(CodedPhoto(codes, tables), clipped)
    back, back_clipped = load()
    assert isinstance(back, CodedPhoto) and back.gains is None
    np.testing.assert_array_equal(back.codes, codes)
    colours = back.colours()
    np.testing.assert_array_equal(
        colours, tables[0][codes[..., 0]] + tables[1][codes[..., 1]] + tables[2][codes[..., 2]]
    )
    np.testing.assert_array_equal(back_clipped, clipped)
    # Gains apply as the colours are read, the same numbers as the colours times the gains; a few pixels alike.
    gains = np.array([1.5, 0.5, 0.9], np.float32)
    np.testing.assert_array_equal(photo_scaled(back, gains).colours(), colours * gains)
    index = np.array([0, 7, 29, 30, 299])
    np.testing.assert_array_equal(
        photo_pixels(back.scaled(gains), slice(3, 13), index), (colours * gains)[3:13].reshape(-1, 3)[index]
    )
    # A byte a channel on the disk: half of a half-float copy.
    (folder,) = [f for f in os.listdir(tmp_path) if f.startswith(PREFIX)]
    assert os.path.getsize(tmp_path / folder / "0.npy") < codes.size + 200
    with pytest.raises(ValueError, match="without gains"):
        cache.put(back.scaled(gains))
    cache.close()
    assert not os.listdir(tmp_path)


def test_a_grey_photos_code_stands_for_all_three_channels():
    tables = np.zeros((3, 256, 3), np.float32)
    for k in range(3):
        tables[k][:, k] = np.linspace(0, 1 + k, 256)
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16, 1)
    colours = CodedPhoto(codes, tables).colours()
    np.testing.assert_array_equal(colours, np.stack([tables[k][codes[..., 0], k] for k in range(3)], axis=2))


def test_a_photo_is_downscaled_in_blocks_of_rows_as_in_one_product_and_its_codes_as_its_colours():
    rng = np.random.default_rng(4)
    tables = np.zeros((3, 256, 3), np.float32)
    for k in range(3):
        tables[k][:, k] = srgb_to_linear(np.arange(256) / 255.0)
    codes = rng.integers(0, 256, (97, 61, 3)).astype(np.uint8)
    colours = CodedPhoto(codes, tables).colours()
    small, (sx, sy) = downscale(colours, 0.0005)
    h2, w2 = small.shape[:2]
    assert h2 * w2 <= 500 and h2 > 8 and (sx, sy) == (w2 / 61, h2 / 97)  # more than one block of rows
    # The definition: the area matrices applied to the whole photo at once.
    ay, ax = _area_matrix(97, h2), _area_matrix(61, w2)
    rows = (ay @ colours.reshape(97, -1)).reshape(h2, 61, 3)
    whole = (ax @ rows.transpose(1, 0, 2).reshape(61, -1)).reshape(w2, h2, 3).transpose(1, 0, 2)
    np.testing.assert_array_equal(small, whole)
    np.testing.assert_array_equal(downscale(CodedPhoto(codes, tables), 0.0005)[0], small)
    np.testing.assert_array_equal(downscale(CodedPhoto(codes, tables), 1.0)[0], colours)  # fits: its colours


def test_an_existing_output_folder_and_its_files_stay(tmp_path):
    (tmp_path / "keep.txt").write_text("mine")
    cache = PhotoCache(tmp_path)
    cache.put(np.zeros((4, 4, 3), np.float32))
    del cache  # collected: the copies go all the same
    assert sorted(os.listdir(tmp_path)) == ["keep.txt"]


def test_too_little_room_is_one_clear_error(tmp_path, monkeypatch):
    cache = PhotoCache(tmp_path)
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(photo_cache.shutil, "disk_usage", lambda _: usage._replace(free=1000))
    with pytest.raises(DelightError, match="too little room .* turn off Full-resolution detail"):
        cache.put(np.zeros((100, 100, 3), np.float32))
    cache.close()
    assert os.listdir(tmp_path) == []


def test_an_output_folder_that_is_a_file_is_refused_before_anything_is_written(tmp_path):
    (tmp_path / "out").write_text("a file")
    with pytest.raises(DelightError, match="is a file"):
        PhotoCache(tmp_path / "out" / "deeper").put(np.zeros((2, 2, 3), np.float32))


def test_a_killed_runs_copies_are_removed_by_the_next_run_and_no_others(tmp_path):
    import socket
    import subprocess
    import sys
    import time

    # A real run killed with its copies on disk: it cannot clean up.
    code = (
        "import os, signal, sys, numpy as np; sys.path.insert(0, sys.argv[2]);"
        "from core.io.photo_cache import PhotoCache;"
        "c = PhotoCache(sys.argv[1]); c.put(np.ones((8, 8, 3), np.float32));"
        "os.kill(os.getpid(), signal.SIGKILL)"
    )
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    subprocess.run([sys.executable, "-c", code, str(tmp_path), root], check=False, timeout=60)
    (killed,) = [f for f in os.listdir(tmp_path) if f.startswith(PREFIX)]
    # Others: a live run's, another machine's, a recent one without an owner, and a user's file of that name.
    for name, owner in (("live", f"{socket.gethostname()} {os.getpid()}"), ("other", "elsewhere 1")):
        (tmp_path / f"{PREFIX}{name}").mkdir()
        (tmp_path / f"{PREFIX}{name}" / "owner").write_text(owner)
    (tmp_path / f"{PREFIX}recent").mkdir()
    (tmp_path / f"{PREFIX}old").mkdir()
    old = time.time() - 2 * 3600
    os.utime(tmp_path / f"{PREFIX}old", (old, old))
    (tmp_path / f"{PREFIX}file").write_text("not ours to judge")
    cache = PhotoCache(tmp_path)
    cache.put(np.zeros((4, 4, 3), np.float32))
    cache.close()
    left = sorted(os.listdir(tmp_path))
    assert killed not in left and f"{PREFIX}old" not in left
    assert left == sorted(f"{PREFIX}{n}" for n in ("live", "other", "recent", "file"))
