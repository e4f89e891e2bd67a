"""N-gons across a UV seam on a real mesh: the texels follow Blender's loop triangles.

On the lambert_sky fixture, 40 pairs of faces on either side of a UV seam are joined into n-gons. Their
loops keep their UVs, so each n-gon has corners in two UV islands, and some of its loop triangles span the
gap between them in UV. The run on that mesh must give the albedo of its triangulated copy (a mesh whose
faces are those loop triangles), warn about the stretched faces, and leave the texels of the other faces as
the run on the original mesh has them.
"""

from __future__ import annotations

import os
import re
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
import bmesh  # noqa: E402  (only exists once bpy is imported)
from bpy_extras.mesh_utils import mesh_linked_uv_islands  # noqa: E402
from conftest import ROOT, needs_fixture_blend  # noqa: E402
from scipy.ndimage import binary_dilation  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.evaluate.metrics import scaled_rmse  # noqa: E402
from blender_addon.core.geometry.texels import STRETCH_FACTOR, texture_layout, uv_stretched  # noqa: E402
from blender_addon.core.io.exr import read_exr  # noqa: E402

pytestmark = [pytest.mark.bpy, needs_fixture_blend]

FIXTURE = os.path.join(ROOT, "blend_fixtures", "lambert_sky")
OBJECT, UV_MAP = "Subject", "UVMap"
N_NGONS, TEX, ITERATIONS = 40, 128, 10
CAMERAS = [f"cam_{i:02d}" for i in range(0, 13, 2)]  # every other camera, for time


def loop_triangles(mesh):
    """Vertex indices ``(T, 3)``, loop indices ``(T, 3)`` and polygon index ``(T,)`` of the loop triangles."""
    mesh.calc_loop_triangles()
    t = len(mesh.loop_triangles)
    vert, loop, poly = np.empty(3 * t, np.int32), np.empty(3 * t, np.int32), np.empty(t, np.int32)
    mesh.loop_triangles.foreach_get("vertices", vert)
    mesh.loop_triangles.foreach_get("loops", loop)
    mesh.loop_triangles.foreach_get("polygon_index", poly)
    return vert.reshape(t, 3), loop.reshape(t, 3), poly


def corner_array(collection, attr, width, n):
    out = np.empty(n * width, np.float64)
    collection.foreach_get(attr, out)
    return out.reshape(n, width)


def triangle_arrays(mesh):
    """UV ``(T, 3, 2)``, object-space positions ``(T, 3, 3)``, vertices ``(T, 3)`` and polygon ``(T,)``."""
    vert, loop, poly = loop_triangles(mesh)
    uv = corner_array(mesh.uv_layers[UV_MAP].data, "uv", 2, len(mesh.loops))
    co = corner_array(mesh.vertices, "co", 3, len(mesh.vertices))
    return uv[loop], co[vert], vert, poly


def uv_islands(mesh):
    """UV island index of each face ``(F,)``."""
    island = np.empty(len(mesh.polygons), np.int64)
    for i, faces in enumerate(mesh_linked_uv_islands(mesh)):
        island[faces] = i
    return island


def corner_normals(mesh):
    """Corner normals of the loop triangles ``(T, 3, 3)``: what the run shades with."""
    _, loop, _ = loop_triangles(mesh)
    return corner_array(mesh.corner_normals, "vector", 3, len(mesh.loops))[loop]


def join_across_seams(mesh, count, seed=0):
    """A copy of ``mesh`` where ``count`` pairs of faces in two UV islands are joined into n-gons.

    Returns the new mesh and the joined faces' indices in ``mesh`` as ``(count, 2)``.
    """
    island = uv_islands(mesh)
    bm = bmesh.new()
    bm.from_mesh(mesh)
    bm.edges.ensure_lookup_table()
    seams = [
        e for e in bm.edges if len(e.link_faces) == 2 and island[e.link_faces[0].index] != island[e.link_faces[1].index]
    ]
    chosen, pairs, used = [], [], set()
    for k in np.random.default_rng(seed).permutation(len(seams)):
        faces = sorted(f.index for f in seams[k].link_faces)
        if used.isdisjoint(faces):  # each face in one n-gon, so each n-gon joins exactly two faces
            used.update(faces)
            chosen.append(seams[k])
            pairs.append(faces)
        if len(chosen) == count:
            break
    # Dissolving the shared edge keeps the other loops, with their UVs, in the joined face.
    bmesh.ops.dissolve_edges(bm, edges=chosen, use_verts=False, use_face_split=False)
    joined = mesh.copy()
    joined.name = mesh.name + "_ngons"
    bm.to_mesh(joined)
    bm.free()
    return joined, np.array(pairs)


def triangulated_copy(mesh):
    """A mesh whose faces are ``mesh``'s loop triangles: the same vertices, corner UVs and shading.

    A non-planar n-gon is shaded with its own corner normals, not its triangles' (as Cycles does), so the
    copy carries them as custom normals; smooth flags, sharp edges and materials are copied too.
    """
    vert, loop, poly = loop_triangles(mesh)
    uv = corner_array(mesh.uv_layers[UV_MAP].data, "uv", 2, len(mesh.loops))
    normal = corner_array(mesh.corner_normals, "vector", 3, len(mesh.loops))
    co = corner_array(mesh.vertices, "co", 3, len(mesh.vertices))
    smooth = np.empty(len(mesh.polygons), bool)
    mesh.polygons.foreach_get("use_smooth", smooth)
    edges = corner_array(mesh.edges, "vertices", 2, len(mesh.edges)).astype(np.int64)
    sharp = np.empty(len(mesh.edges), bool)
    mesh.edges.foreach_get("use_edge_sharp", sharp)
    sharp_keys = set((np.sort(edges[sharp], axis=1) @ [len(co), 1]).tolist())

    copy = bpy.data.meshes.new(mesh.name + "_triangulated")
    copy.from_pydata(co.tolist(), [], vert.tolist())  # face i's loops are loop triangle i's corners, in order
    for mat in mesh.materials:
        copy.materials.append(mat)
    copy.polygons.foreach_set("use_smooth", smooth[poly])
    copy_edges = corner_array(copy.edges, "vertices", 2, len(copy.edges)).astype(np.int64)
    keys = np.sort(copy_edges, axis=1) @ [len(co), 1]
    copy.edges.foreach_set("use_edge_sharp", np.isin(keys, list(sharp_keys)))
    copy.uv_layers.new(name=UV_MAP).data.foreach_set("uv", uv[loop].ravel())
    # Free custom normals (Blender 4.5+), stored as they are, not encoded in each corner's fan.
    custom = copy.attributes.new("custom_normal", "FLOAT_VECTOR", "CORNER")
    custom.data.foreach_set("vector", normal[loop].ravel())
    copy.update()
    return copy


def truth_at(size):
    """The fixture's albedo truth at ``size``: the mean of the truth texels around each texel centre.

    Returns RGB ``(size, size, 3)`` and the texels wholly inside the UV islands ``(size, size)``.
    """
    gt = read_exr(os.path.join(FIXTURE, "albedo_gt.exr"))[0].astype(np.float64)
    f = gt.shape[0] // size
    middle = slice(f // 2 - 1, f // 2 + 1) if f > 1 else slice(0, 1)
    gt = gt.reshape(size, f, size, f, 4)[:, middle, :, middle].mean(axis=(1, 3))
    return np.clip(gt[..., :3], 0, 1), gt[..., 3] > 0.999


def footprint(mesh, faces, size):
    """Texels of ``faces`` and of every face that shares a vertex with them, grown by two texels."""
    uv, pos, vert, poly = triangle_arrays(mesh)
    corners = np.zeros(len(mesh.vertices), bool)
    for f in faces:
        corners[list(mesh.polygons[int(f)].vertices)] = True
    near = corners[vert].any(axis=1)
    inside = texture_layout(uv[near], pos[near], vert[near], size).inside
    return binary_dilation(inside, iterations=2)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The run (texture method, a few iterations) on the original mesh, the n-gon mesh and its copy."""
    out = tmp_path_factory.mktemp("ngons")
    bpy.ops.wm.open_mainfile(filepath=os.path.join(FIXTURE, "scene.blend"))
    obj = bpy.data.objects[OBJECT]
    original = obj.data
    ngons, pairs = join_across_seams(original, N_NGONS)
    copy = triangulated_copy(ngons)
    r = SimpleNamespace(pairs=pairs, albedo={}, warnings={})
    r.ngon_triangles, r.copy_triangles = triangle_arrays(ngons), triangle_arrays(copy)
    r.ngon_normals, r.copy_normals = corner_normals(ngons), corner_normals(copy)
    r.ngon_sizes = np.array([len(p.vertices) for p in ngons.polygons])
    island = uv_islands(original)
    island_of = {  # (vertex, UV) of the joined faces' corners -> the face's UV island
        (v, tuple(original.uv_layers[UV_MAP].data[i].uv)): island[f]
        for f in pairs.ravel()
        for v, i in zip(original.polygons[int(f)].vertices, original.polygons[int(f)].loop_indices)
    }
    uv_data = ngons.uv_layers[UV_MAP].data
    r.ngon_islands = [
        [island_of.get((v, tuple(uv_data[i].uv))) for v, i in zip(p.vertices, p.loop_indices)]
        for p in ngons.polygons
        if len(p.vertices) > 4
    ]
    r.near = footprint(original, pairs.ravel(), TEX)
    for name, mesh in (("original", original), ("ngons", ngons), ("copy", copy)):
        obj.data = mesh
        # Without fill_outlines, to see the n-gons alone: it fills the texels seen only at the outline from their
        # neighbours, some of which are the n-gons'. With it, 93 of the 7478 texels away from the n-gons change
        # by more than 0.05 (37 without), and their error is 1.19x, 1.05x, 1.04x the original mesh's.
        options = pipeline.Options(
            object_name=OBJECT,
            camera_names=CAMERAS,
            texture_size=TEX,
            max_iter=ITERATIONS,
            out_dir=str(out / name),
            fill_outlines=False,
        )
        rep = pipeline.run(bpy.context.scene, options)
        r.albedo[name] = read_exr(rep.albedo_path)[0]
        r.warnings[name] = rep.warnings
    r.truth, r.inside = truth_at(TEX)
    return r


def seen(albedo):
    return albedo[..., 3] > 0


def accuracy(runs, name, where):
    """Scaled RMSE (R, G, B) of a run's albedo against the truth, over its seen texels ``where``."""
    a = runs.albedo[name]
    return scaled_rmse(a[..., :3], runs.truth, seen(a) & runs.inside & where)


def test_the_ngons_join_faces_of_two_uv_islands_and_keep_their_uvs(runs):
    assert runs.pairs.shape == (N_NGONS, 2) and len(np.unique(runs.pairs)) == 2 * N_NGONS
    assert np.count_nonzero(runs.ngon_sizes > 4) == N_NGONS  # quads joined across an edge: hexagons
    assert set(runs.ngon_sizes.tolist()) == {4, 6}
    for islands in runs.ngon_islands:
        # Every corner keeps the UV one of the two faces had there, and both faces keep some corners.
        assert None not in islands and len(set(islands)) == 2, islands
    uv, pos, vert, poly = runs.ngon_triangles
    stretched = uv_stretched(uv, pos)
    in_ngon = runs.ngon_sizes[poly] > 4
    assert not stretched[~in_ngon].any()
    # Nearly every n-gon has loop triangles that span the gap between its islands, stretched more than
    # STRETCH_FACTOR (the others join islands that lie close in UV).
    assert len(np.unique(poly[stretched])) >= 0.9 * N_NGONS
    # The copy's faces are exactly those loop triangles.
    cuv, cpos, cvert, _ = runs.copy_triangles
    np.testing.assert_array_equal(cvert, vert)
    np.testing.assert_array_equal(cuv, uv)
    np.testing.assert_array_equal(runs.copy_normals, runs.ngon_normals)


def test_ngons_give_the_albedo_of_their_triangulated_copy(runs):
    ngons, copy = runs.albedo["ngons"], runs.albedo["copy"]
    np.testing.assert_array_equal(seen(ngons), seen(copy))
    np.testing.assert_allclose(ngons, copy, rtol=0, atol=1e-6)
    everywhere = np.ones(ngons.shape[:2], bool)
    assert accuracy(runs, "ngons", everywhere).mean() <= accuracy(runs, "copy", everywhere).mean() + 1e-6


def test_ngons_leave_the_other_faces_texels_as_they_were(runs):
    # Away from the n-gons and their neighbours in UV, the texels keep their surface points and seam pairs,
    # so the albedo is the original mesh's, but for the small change of the lighting that all texels share.
    ngons, original = runs.albedo["ngons"], runs.albedo["original"]
    away = ~runs.near & seen(ngons) & seen(original)
    changed = np.abs(ngons[..., :3] - original[..., :3]).max(axis=2) > 0.05
    assert np.count_nonzero(changed & away) < 0.01 * np.count_nonzero(away)
    # Scored on the texels both runs see (pixels on an n-gon's stretched triangles also land on
    # texels that no camera sees otherwise).
    # The albedo stage's strong TV (lambda 20 inside regions of one colour) spreads the change of the lighting
    # and of the n-gons' texels over each such region: measured 1.18x, 1.09x, 1.10x (1.12x, 1.06x, 1.09x before
    # light_balance, which weighs the lighting stage's pixels by their texel's total, so that the n-gons'
    # stretched triangles, which change the texels' totals, move the lighting more; 1.1 held at lambda 1).
    ours, before = accuracy(runs, "ngons", away), accuracy(runs, "original", away)
    assert np.all(ours < 1.22 * before), (ours, before)


def test_the_uv_warning_counts_the_stretched_triangles(runs):
    uv, pos, _, _ = runs.ngon_triangles
    count = int(np.count_nonzero(uv_stretched(uv, pos)))
    for name in ("ngons", "copy"):
        found = [w for w in runs.warnings[name] if f"stretched more than {STRETCH_FACTOR:g}x in the UV map" in w]
        assert len(found) == 1 and re.match(rf"UV layout: {count} faces ", found[0]), runs.warnings[name]
    assert not [w for w in runs.warnings["original"] if "stretched" in w]
