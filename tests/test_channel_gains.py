"""The photos' channels brought to one mean, and that mean to one level, before the solve
(core.photo_levels.channel_gains), and divided out after."""

import numpy as np
import pytest
from test_detail import band_mesh, fine_albedo, inputs_of, lighting, render, ring_cameras

import core.pipeline as pipeline
from core.geometry.bake import bake_view
from core.photo_levels import CHANNEL_GAIN_MAX, channel_gains
from core.pipeline import Options, compute
from core.scene import SceneInputs, ViewInput


def test_channel_gains_bring_every_channel_to_the_mean_of_the_means():
    rng = np.random.default_rng(0)
    photos = [rng.uniform(0, 1, (6, 7, 3)).astype(np.float32) * [0.8, 0.3, 0.1] for _ in range(3)]
    masks = [rng.uniform(size=(6, 7)) < 0.6 for _ in range(3)]
    gains = channel_gains(photos, masks)
    pixels = np.concatenate([p[m] for p, m in zip(photos, masks)])
    means = pixels.mean(axis=0)
    np.testing.assert_allclose(means * gains, means.mean(), rtol=1e-5)
    # The unmasked pixels count for nothing.
    bright = [np.where(m[..., None], p, 100.0).astype(np.float32) for p, m in zip(photos, masks)]
    np.testing.assert_allclose(channel_gains(bright, masks), gains, rtol=1e-6)
    # A channel the photos hardly have is raised no more than CHANNEL_GAIN_MAX; an empty one is left as it is.
    faint = [p * [1.0, 1.0, 1e-4] for p in photos]
    assert channel_gains(faint, masks)[2] == pytest.approx(CHANNEL_GAIN_MAX)
    empty = [p * [1.0, 1.0, 0.0] for p in photos]
    g = channel_gains(empty, masks)
    assert g[2] == 1.0 and g[0] * means[0] == pytest.approx(g[1] * means[1], rel=1e-5)
    assert channel_gains([p[..., :1] for p in photos], masks).tolist() == [1.0]
    # With a level, every channel's mean is brought to it, and the cap still holds between the channels.
    np.testing.assert_allclose(means * channel_gains(photos, masks, 0.2), 0.2, rtol=1e-5)
    faint_level = (means * [1.0, 1.0, 1e-4]).mean()
    ratio = channel_gains(faint, masks, 0.2) / channel_gains(faint, masks)
    np.testing.assert_allclose(ratio, 0.2 / faint_level, rtol=1e-5)


@pytest.fixture(scope="module")
def warm_band():
    """The detail tests' band under their light, its albedo warm (blue a tenth of red), 10 photos of 240 x 180."""
    mesh = band_mesh()
    albedo = fine_albedo() * np.array([1.0, 0.4, 0.1], np.float32)
    cams = ring_cameras(240, 180)
    photos = [render(c, mesh, albedo, lighting()) for c in cams]
    return mesh, cams, photos, [bake_view(c, mesh) for c in cams]


def _balance(photos, masks):
    """Per-channel factors that change the photos' colour balance but not the mean of their channels' means."""
    means = np.mean(np.concatenate([p[m] for p, m in zip(photos, masks)]), axis=0)
    k = np.array([0.5, 2.0, 0.0])
    k[2] = (means.sum() - k[0] * means[0] - k[1] * means[1]) / means[2]
    return k.astype(np.float32)


def _computed(mesh, cams, photos, bakes):
    views = [ViewInput(name=f"c{i}", camera=c, photo=p, source="test") for i, (c, p) in enumerate(zip(cams, photos))]
    return compute(Options(texture_size=64), SceneInputs(object_name="band", mesh=mesh, views=views), bakes)


def _albedo(mesh, cams, photos, bakes):
    out = _computed(mesh, cams, photos, bakes)
    return out.albedo, out.seen


def test_the_albedo_does_not_depend_on_the_photos_colour_balance(warm_band, monkeypatch):
    mesh, cams, photos, bakes = warm_band
    k = _balance(photos, [b.mask for b in bakes])
    assert k[2] > 2  # blue raised, red halved

    def difference():
        a, seen_a = _albedo(mesh, cams, photos, bakes)
        b, seen_b = _albedo(mesh, cams, [p * k for p in photos], bakes)
        seen = seen_a & seen_b
        rel = (b[seen] / k - a[seen]) / np.maximum(a[seen], 1e-6)
        return np.sqrt(np.mean(rel**2, axis=0))

    # Measured: 4e-5 / 5e-5 / 5e-5 with the gains, 0.011 / 0.010 / 0.014 without.
    before = [p.copy() for p in photos]
    with_gains = difference()
    assert all(np.array_equal(p, q) for p, q in zip(photos, before))  # the caller's photos are not scaled in place
    monkeypatch.setattr(pipeline, "channel_gains", lambda photos, masks, level: np.ones(3, np.float32))
    without = difference()
    assert np.all(with_gains < 1e-3), with_gains
    assert np.all(without > 3e-3), without


def test_the_albedo_does_not_depend_on_the_photos_exposure(warm_band, monkeypatch):
    # Float photos come in any units (an EXR from a raw converter, an HDR merge): the albedo follows their scale
    # and nothing else, and the lighting written out is the same.
    mesh, cams, photos, bakes = warm_band

    def run(k):
        return _computed(mesh, cams, [p * np.float32(k) for p in photos], bakes)

    def differences():
        """The albedo's (relative RMS, divided by k) and the lighting's (relative to its largest coefficient)."""
        a = run(1.0)
        albedo, lighting = [], []
        for k in (0.01, 4.0):
            b = run(k)
            seen = a.seen & b.seen
            rel = (b.albedo[seen] / k - a.albedo[seen]) / np.maximum(a.albedo[seen], 1e-6)
            albedo.append(float(np.sqrt(np.mean(rel**2))))
            lighting.append(float(np.abs(b.sigma - a.sigma).max() / np.abs(a.sigma).max()))
        return albedo, lighting

    albedo, lighting = differences()
    plain = pipeline.channel_gains
    monkeypatch.setattr(pipeline, "channel_gains", lambda photos, masks, level: plain(photos, masks))
    albedo_without, _ = differences()
    # Measured (albedo at 0.01 and 4 times): 4e-5 / 0 at the level; 0.24 / 0.007 at the photos' own level.
    assert max(albedo) < 1e-3, albedo
    assert max(lighting) < 0.02, lighting  # a coefficient the pixels hardly fix moves within rounding
    assert min(albedo_without) > 3e-3, albedo_without


def test_the_full_resolution_photos_are_scaled_too():
    # The detail stage reads the full photos itself: they must take the gains the working ones took.
    mesh = band_mesh()
    albedo = fine_albedo() * np.array([1.0, 0.4, 0.1], np.float32)
    cams = ring_cameras(480, 360)
    photos = [render(c, mesh, albedo, lighting()) for c in cams]
    plain = inputs_of((mesh, albedo, None, cams, photos), lambda i: (photos[i].copy(), None))
    bakes = [bake_view(v.camera, mesh) for v in plain.views]
    k = _balance([v.photo for v in plain.views], [b.mask for b in bakes])
    tinted = inputs_of((mesh, albedo, None, cams, [p * k for p in photos]), lambda i: (photos[i] * k, None))
    a = compute(Options(texture_size=128, working_res_mp=0.02, detail="on"), plain, bakes)
    b = compute(Options(texture_size=128, working_res_mp=0.02, detail="on"), tinted, bakes)
    assert a.info["detail"] and b.info["detail"]
    seen = a.seen & b.seen
    rel = (b.albedo[seen] / k - a.albedo[seen]) / np.maximum(a.albedo[seen], 1e-6)
    assert np.all(np.sqrt(np.mean(rel**2, axis=0)) < 1e-3)


def test_a_nan_pixel_is_still_refused_by_name(warm_band):
    # Its channel's mean is NaN, so that channel keeps gain 1 and the problem's own check names the view.
    mesh, cams, photos, bakes = warm_band
    bad = [p.copy() for p in photos]
    r, c = np.argwhere(bakes[3].mask)[0]
    bad[3][r, c, 1] = np.nan
    with pytest.raises(ValueError, match=r"view 3 \(c3\): 1 pixels inside the mask are NaN or infinite"):
        _albedo(mesh, cams, bad, bakes)
    assert np.isnan(bad[3][r, c, 1]) and np.array_equal(bad[2], photos[2])
