"""lighting.exr in real Blender: Cycles reads it in the directions we wrote, it relights a diffuse surface to the
estimated shading, and on lambert_sky it matches the fixture's true world in its low orders."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import (  # noqa: E402
    ROOT,
    add_camera,
    add_uv_sphere,
    needs_fixture_blend,
    new_material,
    render_cycles,
    set_render,
)
from mathutils import Vector  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.geometry.sh import DIFFUSE, sh_basis  # noqa: E402
from blender_addon.core.io.envmap import add_sun, envmap_image, equirect_uv, project_envmap, radiance_sh  # noqa: E402
from blender_addon.core.io.exr import read_exr, write_exr  # noqa: E402

pytestmark = pytest.mark.bpy


def use_as_world(scene, path, interpolation="Linear"):
    """The world as the README tells users to set it: an Environment Texture of the file, default vector, strength 1."""
    world = bpy.data.worlds.new("env")
    if world.node_tree is None:
        world.use_nodes = True
    nt = world.node_tree
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(str(path))
    env.interpolation = interpolation
    nt.links.new(env.outputs["Color"], nt.nodes["Background"].inputs["Color"])
    scene.world = world


def test_cycles_reads_the_image_where_equirect_uv_says(tmp_path):
    # Each pixel holds its own (u, v): a camera looking along d sees the (u, v) Cycles reads for d.
    w, h = 256, 128
    img = np.ones((h, w, 3), np.float32)
    img[..., 0] = (np.arange(w) + 0.5) / w
    img[..., 1] = (1 - (np.arange(h) + 0.5) / h)[:, None]
    write_exr(tmp_path / "uv.exr", img)
    scene = set_render(5, 5)
    use_as_world(scene, tmp_path / "uv.exr")
    scene.world.cycles.sampling_method = "NONE"  # nothing to light: no importance map to build per render
    scene.camera = cam = add_camera("probe", (0, 0, 0), lens=5000.0)  # a 0.4 degree field of view
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", 1, False
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = "BOX", 0.01
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(tmp_path / "probe.exr")
    for d in [(1, 0, 0), (0, 1, 0), (0, -1, 0), (-0.8, 0.5, 0.2), (0.3, 0.4, 0.8), (0.6, -0.7, -0.35)]:
        d = Vector(d).normalized()
        cam.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()
        bpy.ops.render.render(write_still=True)
        seen = read_exr(tmp_path / "probe.exr")[0][2, 2]
        np.testing.assert_allclose(seen[:3], [*equirect_uv(np.array(d)), 1.0], atol=2e-3, err_msg=str(d))


def test_a_diffuse_white_sphere_lit_by_the_image_renders_the_shading(tmp_path):
    # A lighting with a clear direction (towards +X, -Y, +Z), positive everywhere so nothing is clamped.
    sigma = np.array(
        [
            [0.25, -0.2, 0.3, 1.0, 0.05, -0.08, 0.04, 0.06, 0.03],
            [0.2, -0.25, 0.25, 0.9, -0.04, 0.05, 0.02, -0.03, 0.05],
            [0.15, -0.1, 0.35, 0.8, 0.02, 0.03, -0.05, 0.04, -0.02],
        ]
    )
    img = envmap_image(radiance_sh(sigma))
    assert img.min() > 0
    write_exr(tmp_path / "lighting.exr", img)
    scene = set_render(48, 48)
    use_as_world(scene, tmp_path / "lighting.exr")
    sphere = add_uv_sphere(segments=64, rings=32)
    mat = new_material("white")
    nt = mat.node_tree
    nt.nodes.clear()
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    sphere.data.materials.append(mat)
    cam = add_camera("cam", (2.5, -5.0, 1.5), lens=70.0)
    r = render_cycles(scene, cam, str(tmp_path), passes=("normal",), samples=32)
    on = r["rgba"][..., 3] > 0.999
    n = r["normal"][on][:, :3].astype(np.float64)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    got = r["rgba"][on][:, :3]
    want = sh_basis(n, np.float64) @ sigma.T
    # Measured at 64 samples: the means agree to 0.1 %, per pixel 1 % RMS (render noise). Read half a turn
    # wrong, the same lighting is 40 % off.
    np.testing.assert_allclose(got.mean(axis=0), want.mean(axis=0), rtol=0.02)
    assert np.all(np.sqrt(((got - want) ** 2).mean(axis=0)) < 0.04 * want.mean(axis=0))
    turned = sh_basis(n * [-1, -1, 1], np.float64) @ sigma.T
    assert np.all(np.sqrt(((got - turned) ** 2).mean(axis=0)) > 0.2 * want.mean(axis=0))


def shading_error(estimate, truth, normals):
    """Per channel, the relative RMS difference of two radiances' shading over ``normals``, scale fitted."""
    basis = sh_basis(normals, np.float64)
    lobe = radiance_sh(np.ones(9)) ** -1  # shading from radiance: A_l / pi
    se, st = basis @ (estimate * lobe).T, basis @ (truth * lobe).T
    k = (se * st).sum(axis=0) / (se * se).sum(axis=0)
    return np.sqrt(((k * se - st) ** 2).sum(axis=0) / (st**2).sum(axis=0))


@needs_fixture_blend
def test_the_written_sky_matches_lambert_skys_world(tmp_path):
    fixture = os.path.join(ROOT, "blend_fixtures", "lambert_sky")
    with open(os.path.join(fixture, "scene.json")) as fh:
        record = json.load(fh)
    assert record["lighting"]["hdri"] == ["forest"] and record["lighting"]["rotation_deg"] == [0.0]
    bpy.ops.wm.open_mainfile(filepath=os.path.join(fixture, "scene.blend"))
    # Reduced so that the run takes seconds (photos at 0.02 MP, 20 iterations); the lighting stage is as default.
    options = pipeline.Options(
        object_name=record["mesh"]["object"], texture_size=128, working_res_mp=0.02, max_iter=20, out_dir=str(tmp_path)
    )
    rep = pipeline.run(bpy.context.scene, options)
    assert os.path.join(str(tmp_path), "lighting.exr") in rep.files
    sky = read_exr(tmp_path / "lighting.exr")[0]
    estimate = project_envmap(sky)
    light = json.loads((tmp_path / "lighting.json").read_text())
    # The image is the sky of radiance_sh, clamped at 0, plus the sun's disc; little of it is clamped: projected
    # back it is within 0.06 of radiance_sh (0.055 since light_balance, whose lighting is nearer the truth's and
    # sharper, below; 0.05 before).
    sun = light["world"]["sun"]
    radiance = np.asarray(light["world"]["radiance_sh"])
    want = add_sun(envmap_image(radiance), sun["direction"], sun["strength"])
    np.testing.assert_allclose(sky[..., :3], want, rtol=1e-5, atol=1e-5)
    disc = project_envmap(add_sun(np.zeros_like(sky[..., :3]), sun["direction"], sun["strength"]))
    np.testing.assert_allclose(estimate, radiance + disc, atol=0.06)

    # The truth: the fixture's world, Blender's forest HDRI laid out as Blender reads it (no rotation).
    hdri = os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world", "forest.exr")
    img = read_exr(hdri)[0][..., :3]
    truth = project_envmap(img)
    # Normals over the sphere down to 11 degrees below the horizon (the cameras are 8 to 45 degrees up and see
    # little of what faces down). Measured: 0.087 / 0.090 / 0.095 (0.13 / 0.15 / 0.14 before light_balance;
    # 0.17 / 0.20 / 0.17 without the sun term, which here takes the HDRI's bright patch). Ambient light only:
    # 0.46 / 0.43 / 0.43; the truth read half a turn or mirrored: 0.58 to 0.75.
    normals = np.random.default_rng(0).standard_normal((20000, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals[normals[:, 2] > -0.2]
    err = shading_error(estimate, truth, normals)
    ambient = shading_error(radiance_sh(np.tile(DIFFUSE, (3, 1))), truth, normals)
    turned = shading_error(project_envmap(np.roll(img, img.shape[1] // 2, axis=1)), truth, normals)
    assert np.all(err < 0.3), err
    assert np.all(err < 0.6 * ambient) and np.all(err < 0.5 * turned), (err, ambient, turned)
