"""Render the test scenes in blend_fixtures/ with Cycles, with ground truth.

Run with the venv's Python (Blender as the ``bpy`` module)::

    .venv/bin/python blend_fixtures/make_fixtures.py [--out DIR] [--only NAME ...]
        [--resolution W H] [--cameras N] [--samples S] [--texture-size N] [--view-gt] [--shading-views]

Each scene ``<name>`` gives, in ``<out>/<name>/``:

* ``scene.blend``: the target mesh (UV-mapped, no material) and one camera per photo, each photo set as its
  camera's background image (relative path ``//photos/...``); no lights, no world, no ground-truth material.
* ``photos/``: the rendered photos.
* ``albedo_gt.exr``: the ground-truth albedo in UV space (RGBA half float, linear Rec.709, row 0 = top = v 1;
  A = 1 where the texel centre lies inside a UV triangle, 0 in the padding). It is the very image the render's
  material sampled.
* ``scene.json``: everything used (mesh, texture, material, lighting, cameras with intrinsics/extrinsics,
  render settings, seeds, photo format, licences).

The functions are importable (``generate(name, out_dir, **overrides)``) so that tests can render a small
version. Nothing here is random without a fixed seed.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time

import bmesh
import bpy
import numpy as np
from mathutils import Matrix, Vector
from mathutils.bvhtree import BVHTree

HERE = os.path.dirname(os.path.abspath(__file__))
ASSETS = os.path.join(HERE, "assets")

# --------------------------------------------------------------------------------------------------------------
# Scene definitions
# --------------------------------------------------------------------------------------------------------------

HDRI_LICENCE = (
    "CC0, Greg Zaal / Poly Haven, bundled with Blender (datafiles/studiolights/world/license.txt): "
    "forest=ninomaru_teien, studio=studio_small_01, interior=hotel_room, sunrise=spruit_sunrise, "
    "courtyard=courtyard, city=portland_landing_pad, sunset=venice_sunset, night=moonless_golf (probably)"
)
PHOTO_LICENCES = {
    "chelsea.png": "CC0, photographer Stefan van der Walt (scikit-image data: skimage.data.chelsea)",
    "coffee.png": "CC0, photographer Rachel Michetti (scikit-image data: skimage.data.coffee)",
}

SCENES = {
    # (a) the paper's figure 1: Lambertian, piecewise-constant albedo, skydome-like environment light.
    "lambert_sky": dict(
        resolution=(320, 240),
        n_cameras=13,
        samples=48,
        texture_size=512,
        seed=1000,
        film_transparent=True,
        view_gt=True,
        albedo="regions",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["forest"], strength=1.0, rotation_deg=[0.0]),
        photo_format="EXR",
        user_mesh="fine",
    ),
    # (b) the paper's figure 2: photographic albedo, partly specular, one extended light with cast shadows.
    "photo_sun": dict(
        resolution=(480, 360),
        n_cameras=13,
        samples=48,
        texture_size=256,
        seed=2000,
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=4.5,
            sun_angle_deg=5.0,
            sun_elevation_deg=50.0,
            sun_azimuth_deg=-35.0,
            hdri=["studio"],
            strength=0.08,
            rotation_deg=[0.0],
        ),
        photo_format="PNG",
        user_mesh="fine",
    ),
    # (c) the paper's figure 5: (b)'s photos, but a smoothed, coarser target mesh with the same UV layout.
    "photo_sun_coarse": dict(base="photo_sun", user_mesh="coarse"),
    # (d) lighting that changes per view (the paper's per-view lighting), JPEG photos.
    "varying_light": dict(
        resolution=(480, 360),
        n_cameras=12,
        samples=48,
        texture_size=256,
        seed=4000,
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="hdri_per_view", hdri=["sunrise", "interior"], strength=[0.6, 0.45], rotation_step_deg=137.50776405
        ),
        photo_format="JPEG",
        user_mesh="fine",
    ),
    # The scenes below widen the set for choosing defaults by leave-one-scene-out: other meshes with concavities,
    # albedos, HDRIs (with a sun in the map or a sun lamp, or neither) and the faults of real captures. The EXR
    # and PNG ones are 256x192 (rendering noise compresses poorly), the JPEG ones 320x240.
    # (e) torus (hole, inner ring in its own shadow), flat patches, soft environment, EXR with transparent film.
    "torus_patches": dict(
        resolution=(256, 192),
        n_cameras=12,
        samples=32,
        texture_size=256,
        seed=5000,
        film_transparent=True,
        mesh="torus",
        albedo="patches",
        interpolation="Closest",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["courtyard"], strength=0.6, rotation_deg=[60.0]),
        photo_format="EXR",
        user_mesh="fine",
    ),
    # (f) open bowl (the rim shadows the inside), fine checker, partly specular, sun lamp: lit squares clip in 8 bit.
    "bowl_checker": dict(
        resolution=(256, 192),
        n_cameras=12,
        samples=32,
        texture_size=256,
        seed=6000,
        mesh="bowl",
        albedo="checker",
        interpolation="Linear",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=5.0,
            sun_angle_deg=3.0,
            sun_elevation_deg=55.0,
            sun_azimuth_deg=30.0,
            hdri=["city"],
            strength=0.3,
            rotation_deg=[0.0],
        ),
        photo_format="PNG",
        user_mesh="fine",
    ),
    # (g) a rock with dents (displaced icosphere), photographic albedo, low warm sun + sunset sky, JPEG q90.
    "rock_photo": dict(
        resolution=(320, 240),
        n_cameras=13,
        samples=32,
        texture_size=256,
        seed=7000,
        mesh="rock",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=4.0,
            sun_elevation_deg=25.0,
            sun_azimuth_deg=-60.0,
            hdri=["sunset"],
            strength=0.6,
            rotation_deg=[45.0],
        ),
        photo_format="JPEG",
        jpeg_quality=90,
        user_mesh="fine",
    ),
    # (h) (g)'s photos with a smoothed, 4x coarser user mesh (same UV islands).
    "rock_coarse": dict(base="rock_photo", user_mesh="coarse"),
    # (i) stairs (cast shadows of each step on the next), fine noise albedo, sun lamp + night sky, EXR.
    "stairs_noise": dict(
        resolution=(256, 192),
        n_cameras=12,
        samples=32,
        texture_size=256,
        seed=8000,
        film_transparent=True,
        mesh="stairs",
        albedo="noise",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun",
            sun_strength=3.0,
            sun_angle_deg=2.0,
            sun_elevation_deg=40.0,
            sun_azimuth_deg=125.0,
            hdri=["night"],
            strength=1.5,
            rotation_deg=[0.0],
        ),
        photo_format="EXR",
        user_mesh="fine",
    ),
    # (j) Suzanne under the studio HDRI, 8-bit PNG with per-photo exposure and white balance.
    "suzanne_exposure": dict(
        resolution=(256, 192),
        n_cameras=12,
        samples=32,
        texture_size=256,
        seed=9000,
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["studio"], strength=1.2, rotation_deg=[200.0]),
        photo_format="PNG",
        user_mesh="fine",
        capture=dict(exposure_ev=0.5, white_balance=0.10),
    ),
    # (k) torus, photographic albedo, lighting varying per photo: the sun lamp moves, the sky turns. EXR.
    "torus_varying_sun": dict(
        resolution=(256, 192),
        n_cameras=12,
        samples=32,
        texture_size=256,
        seed=10000,
        film_transparent=True,
        mesh="torus",
        albedo="photo:chelsea.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(
            kind="sun_per_view",
            sun_strength=3.0,
            sun_angle_deg=5.0,
            sun_elevation_deg=[30.0, 60.0],
            sun_azimuth_deg=0.0,
            sun_azimuth_step_deg=137.50776405,
            hdri=["sunrise"],
            strength=0.5,
            rotation_step_deg=97.0,
        ),
        photo_format="EXR",
        user_mesh="fine",
    ),
    # (l) bowl, photographic albedo, HDRI with the sun in the map, PNG; the user's cameras are ~1 px off.
    "bowl_jitter": dict(
        resolution=(256, 192),
        n_cameras=12,
        samples=32,
        texture_size=256,
        seed=11000,
        mesh="bowl",
        albedo="photo:coffee.png",
        interpolation="Linear",
        material="diffuse",
        lighting=dict(kind="hdri", hdri=["city"], strength=0.8, rotation_deg=[130.0]),
        photo_format="PNG",
        user_mesh="fine",
        capture=dict(jitter_px=1.0),
    ),
    # (m) a real capture: stairs, patches, partly specular, sun + courtyard; JPEG q85 with the background,
    # per-photo exposure and white balance, 8-bit clipping, cameras ~1 px off.
    "stairs_capture": dict(
        resolution=(320, 240),
        n_cameras=13,
        samples=32,
        texture_size=256,
        seed=12000,
        mesh="stairs",
        albedo="patches",
        interpolation="Closest",
        material="principled",
        lighting=dict(
            kind="sun",
            sun_strength=2.5,
            sun_angle_deg=3.0,
            sun_elevation_deg=50.0,
            sun_azimuth_deg=-140.0,
            hdri=["courtyard"],
            strength=0.3,
            rotation_deg=[300.0],
        ),
        photo_format="JPEG",
        jpeg_quality=85,
        user_mesh="fine",
        capture=dict(exposure_ev=0.5, white_balance=0.10, jitter_px=1.0),
    ),
}

# Piecewise-constant albedo of lambert_sky, linear Rec.709 (regions are defined on the surface, in 3D).
REGION_ALBEDO = {
    "face": (0.70, 0.52, 0.38),
    "cap": (0.18, 0.10, 0.05),
    "ears": (0.62, 0.28, 0.26),
    "eyes": (0.06, 0.12, 0.35),
    "plinth": (0.40, 0.42, 0.45),
}
PLINTH_ALBEDO_PHOTO = (0.35, 0.37, 0.40)
PHOTO_ALBEDO_SCALE = 0.85  # albedo = scale * srgb_to_linear(photo), so that albedo < 1
CAMERA_LENSES_MM = (35.0, 42.0, 50.0, 60.0)
SENSOR_WIDTH_MM = 36.0
MESH_OBJECT = "Subject"
UV_ANGLE_LIMIT_DEG = 55.0  # 66 (the default) gave folded, overlapping islands on this mesh
UV_ISLAND_MARGIN = 0.01
COARSE_SMOOTH = dict(factor=0.5, repeat=10)
COARSE_SMOOTH_ROCK = dict(factor=0.5, repeat=3)  # the rock has no plinth; more passes flatten its dents
# Generated albedos (linear Rec.709), for the meshes other than Suzanne.
PATCH_COUNT = 14  # Voronoi cells of seeded points in the object's bounding box
CHECKER = dict(cell_m=0.08, colours=((0.72, 0.68, 0.60), (0.10, 0.14, 0.24)))
NOISE = dict(base_per_m=5.0, octaves=3, gain=0.75, colours=((0.62, 0.48, 0.30), (0.20, 0.30, 0.22), (0.75, 0.74, 0.70)))

RENDER_COMMON = dict(
    engine="CYCLES",
    device="CPU",
    use_adaptive_sampling=False,
    use_denoising=False,
    max_bounces=6,
    diffuse_bounces=3,
    glossy_bounces=3,
    transmission_bounces=2,
    transparent_max_bounces=4,
    sample_clamp_direct=0.0,
    sample_clamp_indirect=3.0,
    caustics_reflective=False,
    caustics_refractive=False,
    blur_glossy=1.0,
    use_light_tree=False,
    pixel_filter_type="BLACKMAN_HARRIS",
    filter_width=1.5,
    view_transform="Standard",
    look="None",
    exposure=0.0,
    gamma=1.0,
    display_device="sRGB",
    dither_intensity=0.0,
)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def write_json(path, record):
    with open(path, "w") as f:
        json.dump(record, f, indent=1, default=_json_default)
        f.write("\n")


def log(*a):
    print("[make_fixtures]", *a, flush=True)


# --------------------------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------------------------


def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.maximum(c, 0.0031308) ** (1 / 2.4) - 0.055)


def hdri_path(name):
    return os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world", name + ".exr")


def write_exr_rgba(path, rgba, half=True):
    """Write (H, W, 4) as RGBA, or (H, W, 3) as RGB."""
    import OpenEXR

    arr = np.ascontiguousarray(rgba, dtype=np.float16 if half else np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGBA" if arr.shape[-1] == 4 else "RGB": arr}).write(path)


def read_exr(path):
    """Read an EXR (single part) as float32 (H, W, C), row 0 = top, channels in RGBA order."""
    import OpenEXR

    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGBA" in ch:
            return np.array(ch["RGBA"].pixels, dtype=np.float32)
        if "RGB" in ch:
            return np.array(ch["RGB"].pixels, dtype=np.float32)
        names = [c for c in "RGBA" if c in ch]
        return np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in names], axis=-1)


def load_png_linear(path):
    """An 8-bit sRGB photo as linear float (H, W, 3), row 0 = top."""
    img = bpy.data.images.load(path, check_existing=False)
    w, h = img.size
    px = np.empty(w * h * img.channels, dtype=np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, img.channels)[::-1, :, :3]  # Image.pixels row 0 is the bottom; code/255 for 8 bit
    bpy.data.images.remove(img)
    return srgb_to_linear(px)


def mesh_arrays(mesh):
    mesh.calc_loop_triangles()
    nt = len(mesh.loop_triangles)
    tri_loops = np.empty(nt * 3, dtype=np.int64)
    tri_verts = np.empty(nt * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("loops", tri_loops)
    mesh.loop_triangles.foreach_get("vertices", tri_verts)
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float64)
    mesh.vertices.foreach_get("co", co)
    uv = np.empty(len(mesh.loops) * 2, dtype=np.float64)
    mesh.uv_layers.active.data.foreach_get("uv", uv)
    ev = np.empty(len(mesh.edges) * 2, dtype=np.int64)
    mesh.edges.foreach_get("vertices", ev)
    return dict(
        co=co.reshape(-1, 3),
        uv=uv.reshape(-1, 2),
        tri_loops=tri_loops.reshape(-1, 3),
        tri_verts=tri_verts.reshape(-1, 3),
        edges=ev.reshape(-1, 2),
    )


def components(n_verts, edges):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_verts, n_verts))
    return connected_components(a, directed=False)[1]


# --------------------------------------------------------------------------------------------------------------
# Geometry: Suzanne (Catmull-Clark) on a plinth, one object, one non-overlapping UV map
# --------------------------------------------------------------------------------------------------------------


def _mesh_from_bmesh(name, bm):
    me = bpy.data.meshes.new(name)
    bm.to_mesh(me)
    bm.free()
    return me


def _apply_subsurf(me, levels, uv_smooth="NONE"):
    """Return a new mesh: ``me`` subdivided ``levels`` times (Catmull-Clark; fully creased edges stay sharp)."""
    obj = bpy.data.objects.new("_tmp_subsurf", me)
    bpy.context.scene.collection.objects.link(obj)
    mod = obj.modifiers.new("subsurf", "SUBSURF")
    mod.levels = mod.render_levels = levels
    mod.uv_smooth = uv_smooth
    mod.use_creases = True
    mod.quality = 3
    dg = bpy.context.evaluated_depsgraph_get()
    out = bpy.data.meshes.new_from_object(obj.evaluated_get(dg))
    bpy.data.objects.remove(obj)
    return out


def build_meshes():
    """Build the meshes. Returns (fine, mid, info).

    ``mid``: Suzanne subdivided once + a plinth, UV-unwrapped with Smart UV Project (~2.3k faces).
    ``fine``: ``mid`` subdivided once more with UV smoothing off, so its UV islands are exactly ``mid``'s
    (the render mesh and the user's mesh in the 'fine' scenes, ~9k faces).
    """
    # Suzanne, Catmull-Clark once.
    bm = bmesh.new()
    bmesh.ops.create_monkey(bm)
    base = _mesh_from_bmesh("suzanne_base", bm)
    head = _apply_subsurf(base, 1)
    bpy.data.meshes.remove(base)
    hco = np.array([v.co for v in head.vertices])
    zmin = hco[:, 2].min()

    # Plinth: a 32-sided prism under the chin, all edges creased so that subdivision keeps it sharp.
    bm = bmesh.new()
    bm.from_mesh(head)
    n_head_verts = len(bm.verts)
    r = 0.75
    depth = 0.30
    top = zmin - 0.06
    geom = bmesh.ops.create_cone(
        bm,
        cap_ends=True,
        cap_tris=False,
        segments=32,
        radius1=r,
        radius2=r,
        depth=depth,
        matrix=Matrix.Translation((0.0, -0.05, top - depth / 2)),
    )
    plinth_verts = set(geom["verts"])
    # Split the ngon caps into quads around a centre vertex (poke) so that subdivision is regular.
    caps = [f for f in bm.faces if len(f.verts) > 4 and all(v in plinth_verts for v in f.verts)]
    bmesh.ops.poke(bm, faces=caps)
    bm.verts.index_update()
    crease = bm.edges.layers.float.new("crease_edge")
    for e in bm.edges:
        if e.verts[0].index >= n_head_verts or e.verts[1].index >= n_head_verts:
            e[crease] = 1.0
    mid = _mesh_from_bmesh("mid", bm)
    bpy.data.meshes.remove(head)

    uv_params = smart_uv(mid)

    fine = _apply_subsurf(mid, 1, uv_smooth="NONE")
    fine.name = "fine"
    for me in (mid, fine):
        if "crease_edge" in me.attributes:
            me.attributes.remove(me.attributes["crease_edge"])
    info = dict(
        description="Suzanne (bmesh create_monkey, Catmull-Clark once) on a 32-sided prism plinth, joined; UV "
        "by Smart UV Project on that level; the fine mesh is that subdivided once more "
        "(Catmull-Clark, plinth fully creased, UV smoothing 'NONE', so the UV islands are identical)",
        smart_uv_project={k: (round(math.degrees(v), 3) if k == "angle_limit" else v) for k, v in uv_params.items()},
        plinth=dict(radius=r, depth=depth, top_z=top, centre_y=-0.05, segments=32),
    )
    return fine, mid, info


def smart_uv(me):
    """Smart UV Project on ``me`` in place, as the map ``UVMap``; returns the operator's parameters."""
    obj = bpy.data.objects.new("_tmp_uv", me)  # the operator needs the object in edit mode
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    uv_params = dict(
        angle_limit=math.radians(UV_ANGLE_LIMIT_DEG),
        island_margin=UV_ISLAND_MARGIN,
        area_weight=0.0,
        correct_aspect=True,
        scale_to_bounds=False,
    )
    bpy.ops.uv.smart_project(**uv_params)
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.data.objects.remove(obj)
    me.uv_layers.active.name = "UVMap"
    return uv_params


def make_coarse(mid, fine, smooth=COARSE_SMOOTH, keep_plinth=True):
    """The 'coarse' user mesh: ``mid`` (4x fewer faces than ``fine``) with its vertices smoothed.

    With ``keep_plinth`` the lowest connected component (Suzanne's plinth) is left as it is.
    """
    coarse = mid.copy()
    coarse.name = "coarse"
    bm = bmesh.new()
    bm.from_mesh(coarse)
    co = np.array([v.co for v in bm.verts])
    comp = components(len(bm.verts), np.array([[e.verts[0].index, e.verts[1].index] for e in bm.edges]))
    plinth_label = comp[np.argmin(co[:, 2])] if keep_plinth else -1
    verts = [v for v in bm.verts if comp[v.index] != plinth_label]
    for _ in range(smooth["repeat"]):
        bmesh.ops.smooth_vert(
            bm, verts=verts, factor=smooth["factor"], use_axis_x=True, use_axis_y=True, use_axis_z=True
        )
    bm.to_mesh(coarse)
    bm.free()
    # Distance of the coarse vertices to the fine surface.
    fbm = bmesh.new()
    fbm.from_mesh(fine)
    tree = BVHTree.FromBMesh(fbm)
    d = np.array([tree.find_nearest(v.co)[3] for v in coarse.vertices])
    fbm.free()
    return coarse, dict(mean=float(d.mean()), p95=float(np.percentile(d, 95)), max=float(d.max()))


def _revolve(name, profile, n_seg, closed, margin=0.01):
    """A surface of revolution about Z with two UV islands (the halves x >= 0 and x < 0 of the turn).

    ``profile``: (K, 2) points (r, z); ``closed``: the profile is a loop (torus), else its ends lie on the axis
    (r = 0: one pole vertex each) and the surface is closed by them. In each island u runs along the turn and v
    along the profile by arc length; island h covers v in [h/2 + margin, h/2 + 1/2 - margin].
    """
    profile = np.asarray(profile, dtype=np.float64)
    k_n = len(profile)
    seg = np.diff(np.vstack([profile, profile[:1]]) if closed else profile, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    tv = arc / arc[-1]  # k_n (+1 if closed) values in [0, 1]
    pole = profile[:, 0] <= 1e-9
    half = n_seg // 2
    bm = bmesh.new()
    ring = []
    for k, (r, z) in enumerate(profile):
        if pole[k]:
            v = bm.verts.new((0.0, 0.0, z))
            ring.append([v] * n_seg)
        else:
            ring.append(
                [
                    bm.verts.new((r * math.cos(2 * math.pi * j / n_seg), r * math.sin(2 * math.pi * j / n_seg), z))
                    for j in range(n_seg)
                ]
            )
    uv_of = {}
    for k in range(k_n if closed else k_n - 1):
        k2 = (k + 1) % k_n
        for j in range(n_seg):
            h, jl = divmod(j, half)
            corners = [
                (k, j, jl, tv[k]),
                (k, (j + 1) % n_seg, jl + 1, tv[k]),
                (k2, (j + 1) % n_seg, jl + 1, tv[k + 1]),
                (k2, j, jl, tv[k + 1]),
            ]
            verts, uvs = [], []
            for kk, jj, ul, t in corners:
                v = ring[kk][jj]
                if v in verts:
                    continue
                u = ul if not pole[kk] else jl + 0.5  # a pole's corner sits mid-segment
                verts.append(v)
                uvs.append((margin + (1 - 2 * margin) * u / half, 0.5 * h + margin + (0.5 - 2 * margin) * t))
            f = bm.faces.new(verts)
            uv_of[f] = uvs
    uv_layer = bm.loops.layers.uv.new("UVMap")
    for f, uvs in uv_of.items():
        for loop, uv in zip(f.loops, uvs):
            loop[uv_layer].uv = uv
    bmesh.ops.recalc_face_normals(bm, faces=bm.faces)
    return _mesh_from_bmesh(name, bm)


def _transform(me, matrix):
    me.transform(matrix)
    me.update()


def build_torus():
    big, small, n_seg, n_ring, tilt = 0.75, 0.3, 96, 36, 35.0
    a = 2 * math.pi * np.arange(n_ring) / n_ring
    me = _revolve("torus", np.stack([big + small * np.cos(a), small * np.sin(a)], axis=1), n_seg, closed=True)
    _transform(me, Matrix.Rotation(math.radians(tilt), 4, "X"))
    return (
        me,
        None,
        dict(
            description="torus (major radius %.2f m, minor %.2f m, %d x %d quads) tilted %.0f deg about X; UV: two "
            "islands (the halves of the turn), u along the turn, v around the tube" % (big, small, n_seg, n_ring, tilt),
            uv="parametric, two islands, margin 0.01",
        ),
    )


def build_bowl():
    """A thick-walled open bowl (quarter-ellipse walls, rounded rim), tilted towards -Y."""

    def arc_pts(f, a0, a1, step=0.035):
        ts = np.linspace(a0, a1, 400)
        p = np.array([f(t) for t in ts])
        d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        m = max(2, int(round(d[-1] / step)) + 1)
        return np.array([np.interp(np.linspace(0, d[-1], m), d, p[:, c]) for c in range(2)]).T

    outer_bottom = arc_pts(lambda t: (t, 0.0), 0.0, 0.30)
    outer = arc_pts(lambda t: (0.30 + 0.60 * math.sin(t), 0.65 * (1 - math.cos(t))), 0.0, math.pi / 2)
    rim = arc_pts(lambda t: (0.87 + 0.03 * math.cos(t), 0.65 + 0.03 * math.sin(t)), 0.0, math.pi, step=0.02)
    inner = arc_pts(lambda t: (0.27 + 0.57 * math.sin(t), 0.07 + 0.58 * (1 - math.cos(t))), math.pi / 2, 0.0)
    inner_bottom = arc_pts(lambda t: (t, 0.07), 0.27, 0.0)
    prof = np.vstack([outer_bottom, outer[1:], rim[1:], inner[1:], inner_bottom[1:]])
    tilt = 25.0
    me = _revolve("bowl", prof, 64, closed=False)
    _transform(me, Matrix.Rotation(math.radians(tilt), 4, "X") @ Matrix.Translation((0.0, 0.0, -0.33)))
    return (
        me,
        None,
        dict(
            description="open bowl: surface of revolution of a profile (outer bottom, quarter-ellipse outer wall to "
            "radius 0.9 m, rounded rim, inner wall, inner bottom; wall 0.03-0.07 m thick; %d profile "
            "points, 64 segments, poles at the two bottom centres), tilted %.0f deg about X so that it "
            "opens towards -Y; UV: two islands (the halves of the turn), u along the turn, v along the "
            "profile by arc length" % (len(prof), tilt),
            uv="parametric, two islands, margin 0.01",
        ),
    )


ROCK_SEED = 77


def build_rock():
    """A displaced icosphere with three dents; UV by Smart UV Project on the coarse level."""
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=4, radius=1.0)
    rng = np.random.default_rng(ROCK_SEED)
    d = np.array([v.co.normalized() for v in bm.verts])
    r = np.ones(len(d))
    for _ in range(6):
        f = rng.normal(size=3)
        f *= rng.uniform(1.5, 3.0) / np.linalg.norm(f)
        r += 0.07 * np.sin(d @ f + rng.uniform(0, 2 * math.pi))
    dents = rng.normal(size=(3, 3))
    dents /= np.linalg.norm(dents, axis=1, keepdims=True)
    for c in dents:
        ang = np.arccos(np.clip(d @ c, -1, 1))
        r -= 0.28 * np.exp(-((ang / 0.35) ** 2))
    for v, dv, rv in zip(bm.verts, d, r):
        v.co = Vector((0.8 * rv * dv[0], 0.8 * rv * dv[1], 0.6 * rv * dv[2]))
    mid = _mesh_from_bmesh("mid", bm)
    uv_params = smart_uv(mid)
    fine = _apply_subsurf(mid, 1, uv_smooth="NONE")
    fine.name = "fine"
    return (
        fine,
        mid,
        dict(
            description="rock: icosphere (bmesh subdivisions=4: 1280 triangles) displaced radially by 6 random "
            "sinusoids (amplitude 0.07) and 3 Gaussian dents (depth 0.28, width 0.35 rad), scaled (0.8, 0.8, 0.6) m, "
            "seed %d; UV by Smart UV Project on that level; the fine mesh is that subdivided once "
            "(Catmull-Clark, UV smoothing 'NONE', so the UV islands are identical)" % ROCK_SEED,
            smart_uv_project={
                k: (round(math.degrees(v), 3) if k == "angle_limit" else v) for k, v in uv_params.items()
            },
        ),
    )


def planar_islands(me, margin=0.01):
    """UV map ``UVMap``: one island per (planar) face, true to scale, shelf-packed into the unit square.

    (Smart UV Project packs this mesh's islands differently from run to run.) Each face is projected on its
    plane (u along its longest edge); islands go in rows by decreasing height, at the largest common scale that
    fits, ``margin`` apart.
    """
    co = np.array([v.co for v in me.vertices])
    flat = []
    for f in me.polygons:
        p = co[list(f.vertices)]
        edges = np.roll(p, -1, axis=0) - p
        a = edges[np.argmax(np.linalg.norm(edges, axis=1))]
        a /= np.linalg.norm(a)
        b = np.cross(np.array(f.normal), a)
        q = np.stack([p @ a, p @ b], axis=1)
        flat.append(q - q.min(axis=0))
    size = np.array([q.max(axis=0) for q in flat])
    order = sorted(range(len(flat)), key=lambda i: (-size[i, 1], i))

    def place(scale):
        x = y = row_h = 0.0
        out = {}
        for i in order:
            w, h = size[i] * scale
            if x + w + margin > 1.0:
                x, y, row_h = 0.0, y + row_h + margin, 0.0
            out[i] = (x + margin, y + margin)
            x += w + margin
            row_h = max(row_h, h)
        return out, y + row_h + 2 * margin <= 1.0 and all(size[i, 0] * scale + 2 * margin <= 1.0 for i in order)

    lo, hi = 0.0, 1.0 / size.max()
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if place(mid)[1] else (lo, mid)
    offsets, _ = place(lo)
    uv_layer = me.uv_layers.new(name="UVMap")
    for f in me.polygons:
        q = flat[f.index] * lo + np.array(offsets[f.index])
        for k, li in enumerate(f.loop_indices):
            uv_layer.data[li].uv = (q[k, 0], q[k, 1])
    return dict(method="one island per face, true to scale, shelf-packed", margin=margin, scale=lo)


def build_stairs():
    """Four steps: a stair profile in XZ extruded along Y, narrowing towards +Y; UV one island per face."""
    runs, rises, taper = (0.32, 0.34, 0.36, 0.38), (0.22, 0.24, 0.26, 0.28), 0.92
    prof = [(-0.7, 0.0), (0.7, 0.0), (0.7, 1.0)]
    x, z = 0.7, 1.0
    for run, rise in zip(runs[::-1], rises[::-1]):
        x -= run
        prof.append((x, z))
        z -= rise
        if z > 1e-9:
            prof.append((x, z))
    # Faces built one by one, outward (bmesh's extrude and normal recalculation order the loops differently from
    # run to run). The profile runs clockwise seen from -Y, so the near side's normal is -Y.
    bm = bmesh.new()
    near = [bm.verts.new((px, -0.5, pz - 0.5)) for px, pz in prof]
    far = [bm.verts.new((px * taper, 0.5, pz - 0.5)) for px, pz in prof]
    bm.faces.new(near)
    bm.faces.new(far[::-1])
    for i in range(len(prof)):
        j = (i + 1) % len(prof)
        bm.faces.new([near[j], near[i], far[i], far[j]])
    me = _mesh_from_bmesh("stairs", bm)
    uv = planar_islands(me)
    return (
        me,
        None,
        dict(
            description="stairs: 4 steps (runs %s m, rises %s m from the bottom), the stair profile in XZ extruded 1 m "
            "along Y, the far side (y = +0.5) scaled by %.2f in X; %d flat faces, the two sides concave "
            "ngons; UV: one island per face (planar_islands)" % (list(runs), list(rises), taper, len(me.polygons)),
            profile_xz=[list(p) for p in prof],
            uv=uv,
        ),
    )


def build_mesh(kind):
    """(render mesh, coarse level or None, info) for a mesh kind of SCENES."""
    if kind == "suzanne":
        return build_meshes()
    fine, mid, info = {"torus": build_torus, "bowl": build_bowl, "rock": build_rock, "stairs": build_stairs}[kind]()
    info["units"] = "metres, object near the origin, +Z up"
    return fine, mid, info


def finish_shading(me):
    me.shade_smooth()
    me.set_sharp_from_angle(angle=math.radians(60.0))


# --------------------------------------------------------------------------------------------------------------
# UV-space rasterisation and ground-truth albedo
# --------------------------------------------------------------------------------------------------------------


def rasterise_uv(mesh, n):
    """World position, triangle and coverage count of every texel centre of an n x n texture.

    Texel (r, c) has its centre at u = (c + 0.5) / n, v = 1 - (r + 0.5) / n (row 0 = top).
    """
    a = mesh_arrays(mesh)
    tuv = a["uv"][a["tri_loops"]]  # (T, 3, 2)
    tco = a["co"][a["tri_verts"]]  # (T, 3, 3)
    px = np.stack([tuv[..., 0] * n - 0.5, (1.0 - tuv[..., 1]) * n - 0.5], axis=-1)  # (col, row) coords
    pos = np.full((n, n, 3), np.nan)
    tri = np.full((n, n), -1, dtype=np.int64)
    count = np.zeros((n, n), dtype=np.int32)
    eps = 1e-9
    for t in range(len(px)):
        p = px[t]
        c0, c1 = int(math.ceil(p[:, 0].min())), int(math.floor(p[:, 0].max()))
        r0, r1 = int(math.ceil(p[:, 1].min())), int(math.floor(p[:, 1].max()))
        c0, r0 = max(c0, 0), max(r0, 0)
        c1, r1 = min(c1, n - 1), min(r1, n - 1)
        if c1 < c0 or r1 < r0:
            continue
        cc, rr = np.meshgrid(np.arange(c0, c1 + 1), np.arange(r0, r1 + 1))
        d1, d2 = p[1] - p[0], p[2] - p[0]
        det = d1[0] * d2[1] - d1[1] * d2[0]
        if abs(det) < 1e-14:
            continue
        qx, qy = cc - p[0, 0], rr - p[0, 1]
        b1 = (qx * d2[1] - qy * d2[0]) / det
        b2 = (d1[0] * qy - d1[1] * qx) / det
        b0 = 1.0 - b1 - b2
        inside = (b0 >= -eps) & (b1 >= -eps) & (b2 >= -eps)
        if not inside.any():
            continue
        rr, cc = rr[inside], cc[inside]
        w = np.stack([b0[inside], b1[inside], b2[inside]], axis=-1)
        pos[rr, cc] = w @ tco[t]
        tri[rr, cc] = t
        count[rr, cc] += 1
    return pos, tri, count, a


def part_labels(a):
    """Per-triangle part: 0 head, 1 eyes, 2 plinth (from connected components of the mesh)."""
    comp = components(len(a["co"]), a["edges"])
    labels = np.unique(comp)
    zmean = np.array([a["co"][comp == l, 2].mean() for l in labels])
    size = np.array([(comp == l).sum() for l in labels])
    plinth = labels[np.argmin(zmean)]
    head = labels[np.argmax(np.where(labels == plinth, -1, size))]
    vpart = np.where(comp == plinth, 2, np.where(comp == head, 0, 1))
    return vpart[a["tri_verts"][:, 0]]


def fill_padding(img, inside):
    """Fill texels outside every UV triangle with the value of the nearest inside texel."""
    from scipy.ndimage import distance_transform_edt

    idx = distance_transform_edt(~inside, return_distances=False, return_indices=True)
    return img[idx[0], idx[1]]


def _fbm(p, lo, base, octaves, gain, seed):
    """Value noise in 3D: seeded random lattices, cubic-spline interpolated, octaves at doubling frequencies."""
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(seed)
    out = np.zeros(len(p))
    for o in range(octaves):
        freq = base * 2**o
        q = (p - lo) * freq + 2.0
        lattice = rng.standard_normal(tuple(int(math.ceil(e)) + 4 for e in q.max(axis=0)))
        out += gain**o * map_coordinates(lattice, q.T, order=3, mode="nearest")
    return (out - out.mean()) / out.std()


def generated_albedo(kind, pos, co, seed):
    """Albedo (M, 3) at surface points ``pos`` (M, 3) for the meshes other than Suzanne; and its description.

    ``co``: the mesh's vertices (for the bounding box); ``seed``: the scene's.
    """
    lo, hi = co.min(axis=0), co.max(axis=0)
    if kind == "patches":
        rng = np.random.default_rng(seed + 1)
        sites = rng.uniform(lo, hi, (PATCH_COUNT, 3))
        colours = rng.uniform(0.05, 0.80, (PATCH_COUNT, 3))
        cell = np.argmin(((pos[:, None, :] - sites[None]) ** 2).sum(axis=2), axis=1)
        return colours[cell], dict(
            kind="piecewise constant: Voronoi cells of %d seeded sites in the mesh's bounding box (3D, object space), "
            "one uniform random colour in [0.05, 0.8]^3 each" % PATCH_COUNT,
            sites=sites.tolist(),
            colours=colours.tolist(),
        )
    if kind == "checker":
        c0, c1 = (np.array(c) for c in CHECKER["colours"])
        odd = (np.floor(pos / CHECKER["cell_m"]).astype(np.int64).sum(axis=1) % 2).astype(bool)
        return np.where(odd[:, None], c1, c0), dict(
            kind="3D checker (object space): parity of floor(x/s) + floor(y/s) + floor(z/s), s = {:.2f} m, two "
            "colours".format(CHECKER["cell_m"]),
            colours=[list(c) for c in CHECKER["colours"]],
        )
    if kind == "noise":
        c = [np.array(x) for x in NOISE["colours"]]
        f1 = _fbm(pos, lo, NOISE["base_per_m"], NOISE["octaves"], NOISE["gain"], seed + 1)
        f2 = _fbm(pos, lo, NOISE["base_per_m"], NOISE["octaves"], NOISE["gain"], seed + 2)
        a = np.clip(0.5 + 0.35 * f1, 0, 1)[:, None]
        b = np.clip(2.5 * (f2 - 0.8), 0, 1)[:, None]
        return ((1 - a) * c[0] + a * c[1]) * (1 - b) + b * c[2], dict(
            kind="fine procedural noise: two value-noise fields f1, f2 (3D, object space; %d octaves from %.1f "
            "lattice cells/m, each doubling, amplitude x %.2f; normalised to mean 0, sd 1); a = clip(0.5 + "
            "0.35 f1), b = clip(2.5 (f2 - 0.8)); albedo = mix(mix(c0, c1, a), c2, b)"
            % (NOISE["octaves"], NOISE["base_per_m"], NOISE["gain"]),
            colours=[list(x) for x in NOISE["colours"]],
        )
    if kind.startswith("photo:"):
        from scipy.ndimage import map_coordinates

        fname = kind.split(":", 1)[1]
        photo = load_png_linear(os.path.join(ASSETS, fname)) * PHOTO_ALBEDO_SCALE
        ph, pw = photo.shape[:2]
        d = pos - 0.5 * (lo + hi)
        s = np.abs(np.arctan2(d[:, 0], -d[:, 1])) / np.pi  # mirrored about the front: continuous all around
        t = np.arccos(np.clip(d[:, 2] / np.maximum(np.linalg.norm(d, axis=1), 1e-12), -1, 1)) / np.pi
        rgb = np.stack(
            [map_coordinates(photo[..., ch], [t * (ph - 1), s * (pw - 1)], order=1, mode="nearest") for ch in range(3)],
            axis=1,
        )
        return rgb, dict(
            kind="photograph, mirrored spherical projection about the bounding-box centre: s = |atan2(x-cx, "
            "-(y-cy))|/pi -> photo column s*(W-1), t = polar angle from +Z / pi -> photo row t*(H-1), "
            f"bilinear; albedo = {PHOTO_ALBEDO_SCALE:.2f} * srgb_to_linear(photo)",
            photo=fname,
            photo_licence=PHOTO_LICENCES[fname],
            photo_albedo_scale=PHOTO_ALBEDO_SCALE,
        )
    raise ValueError(kind)


def ground_truth_albedo(mesh, n, albedo_spec, mesh_kind="suzanne", seed=0):
    pos, tri, count, a = rasterise_uv(mesh, n)
    inside = tri >= 0
    overlap = int((count > 1).sum())
    if mesh_kind != "suzanne":
        rgb = np.zeros((n, n, 3))
        rgb[inside], info = generated_albedo(albedo_spec, pos[inside], a["co"], seed)
        return _finish_albedo(rgb, inside, overlap, info)
    tpart = part_labels(a)
    part = np.where(inside, tpart[np.maximum(tri, 0)], -1)
    rgb = np.zeros((n, n, 3))
    hco = a["co"][np.unique(a["tri_verts"][tpart != 2])]
    info = {}
    if albedo_spec == "regions":
        x, z = pos[..., 0], pos[..., 2]
        head = part == 0
        ears = head & (np.abs(x) > 0.98)
        cap = head & ~ears & (z > 0.30 + 0.12 * np.abs(x))
        face = head & ~ears & ~cap
        for name, m in (("face", face), ("cap", cap), ("ears", ears), ("eyes", part == 1), ("plinth", part == 2)):
            rgb[m] = REGION_ALBEDO[name]
        info = dict(
            kind="piecewise constant, regions defined on the surface in 3D (object space, metres): "
            "plinth = plinth component; eyes = Suzanne's two eye components; ears = head & |x| > 0.98; "
            "cap = head & not ears & z > 0.30 + 0.12|x|; face = rest of the head",
            regions={k: list(v) for k, v in REGION_ALBEDO.items()},
        )
    elif albedo_spec.startswith("photo:"):
        fname = albedo_spec.split(":", 1)[1]
        photo = load_png_linear(os.path.join(ASSETS, fname)) * PHOTO_ALBEDO_SCALE
        ph, pw = photo.shape[:2]
        lo, hi = hco.min(axis=0), hco.max(axis=0)
        cx, cy = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])
        m = part <= 1
        theta = np.arctan2(pos[..., 0] - cx, -(pos[..., 1] - cy))  # 0 at the front (-Y), +-pi at the back
        s = np.abs(theta) / np.pi  # mirrored: continuous all around
        t = (hi[2] - pos[..., 2]) / (hi[2] - lo[2])
        from scipy.ndimage import map_coordinates

        rows = np.clip(t[m], 0, 1) * (ph - 1)
        cols = np.clip(s[m], 0, 1) * (pw - 1)
        for ch in range(3):
            rgb[m, ch] = map_coordinates(photo[..., ch], [rows, cols], order=1, mode="nearest")
        rgb[part == 2] = PLINTH_ALBEDO_PHOTO
        info = dict(
            kind="photograph projected on the head (and eyes): mirrored cylindrical projection about the "
            "vertical axis through the head's bounding-box centre, s = |atan2(x-cx, -(y-cy))|/pi -> "
            "photo column s*(W-1) (front = left edge, back = right edge), t = (zmax - z)/(zmax - zmin) -> "
            f"photo row t*(H-1), bilinear; albedo = {PHOTO_ALBEDO_SCALE:.2f} * srgb_to_linear(photo); plinth uniform",
            photo=fname,
            photo_licence=PHOTO_LICENCES[fname],
            photo_albedo_scale=PHOTO_ALBEDO_SCALE,
            plinth=list(PLINTH_ALBEDO_PHOTO),
        )
    else:
        raise ValueError(albedo_spec)
    return _finish_albedo(rgb, inside, overlap, info)


def _finish_albedo(rgb, inside, overlap, info):
    rgb = fill_padding(rgb, inside)
    rgba = np.concatenate([rgb, inside[..., None].astype(np.float64)], axis=-1)
    if overlap:
        raise RuntimeError(f"UV islands overlap on {overlap} texels: the albedo texture would be ill-defined")
    info.update(inside_texels=int(inside.sum()), overlapping_texels=overlap)
    return rgba, info


# --------------------------------------------------------------------------------------------------------------
# Cameras, lighting, materials
# --------------------------------------------------------------------------------------------------------------


def look_at(eye, target, roll_deg=0.0):
    eye, target = Vector(eye), Vector(target)
    fwd = (target - eye).normalized()
    rot = fwd.to_track_quat("-Z", "Y").to_matrix().to_4x4()
    rot = rot @ Matrix.Rotation(math.radians(roll_deg), 4, "Z")
    return Matrix.Translation(eye) @ rot


def place_cameras(n, resolution, centre, radius, seed):
    """Two rings like a photogrammetry capture; lens cycles through CAMERA_LENSES_MM; seeded jitter."""
    rng = np.random.default_rng(seed)
    w, h = resolution
    n_low = int(math.ceil(n * 0.6))
    n_high = n - n_low
    cams = []
    for ring, (count, elev) in enumerate(((n_low, 12.0), (n_high, 42.0))):
        for k in range(count):
            az = 360.0 * k / count + (180.0 / count if ring else 0.0) + rng.uniform(-6, 6)
            el = elev + rng.uniform(-4, 4)
            lens = CAMERA_LENSES_MM[len(cams) % len(CAMERA_LENSES_MM)]
            half_v = math.atan(0.5 * SENSOR_WIDTH_MM * h / w / lens)
            dist = radius / math.sin(half_v) * rng.uniform(0.85, 1.0)
            a, e = math.radians(az), math.radians(el)
            eye = Vector(centre) + dist * Vector((math.sin(a) * math.cos(e), -math.cos(a) * math.cos(e), math.sin(e)))
            target = Vector(centre) + Vector(rng.uniform(-0.05, 0.05, 3) * radius)
            cams.append(
                dict(
                    azimuth_deg=az,
                    elevation_deg=el,
                    lens_mm=lens,
                    distance=dist,
                    matrix_world=look_at(eye, target, rng.uniform(-3, 3)),
                )
            )
    return cams


def camera_extrinsics(mw):
    """core.camera's R, t (world X -> R X + t; x right, y down, z forward) of a Blender camera-to-world matrix."""
    r_c2w = np.array(mw.to_3x3().normalized())
    r_cv = np.diag([1.0, -1.0, -1.0]) @ r_c2w.T
    return r_cv, -r_cv @ np.array(mw.translation)


def jitter_camera(mw, k_core, w, h, px, co, rng):
    """A camera about ``px`` pixels off ``mw``, as a real capture's calibration would be; and what was done.

    Small rotations about the camera's x and y axes (an image shift of ``px`` x U(0.6, 1) pixels in a random
    direction), a roll moving the image corners by up to 0.3 ``px``, and a shift of the camera centre by the
    distance that moves the object's centre by 0.3 ``px``. ``co``: the mesh's vertices, to measure the
    resulting displacement of their projections.
    """
    fx = k_core[0][0]
    ang = rng.uniform(0.0, 2 * math.pi)
    mag = px * rng.uniform(0.6, 1.0)
    rx, ry = mag * math.sin(ang) / fx, mag * math.cos(ang) / fx
    roll = rng.uniform(-0.3, 0.3) * px / (0.5 * math.hypot(w, h))
    depth = float(np.linalg.norm(co.mean(axis=0) - np.array(mw.translation)))
    t = rng.normal(size=3)
    t *= 0.3 * px * depth / fx / np.linalg.norm(t)
    user = (
        mw
        @ Matrix.Translation(Vector(t))
        @ Matrix.Rotation(rx, 4, "X")
        @ Matrix.Rotation(ry, 4, "Y")
        @ Matrix.Rotation(roll, 4, "Z")
    )
    k = np.array(k_core)
    xy = []
    for m in (mw, user):
        r, tt = camera_extrinsics(m)
        pc = co @ r.T + tt
        q = pc @ k.T
        xy.append(q[:, :2] / q[:, 2:])
    d = np.linalg.norm(xy[1] - xy[0], axis=1)
    return user, dict(
        rotation_x_rad=rx,
        rotation_y_rad=ry,
        roll_rad=roll,
        translation_camera_m=t.tolist(),
        note="user camera = render camera @ Translation(t) @ Rx @ Ry @ Rz (camera-local axes)",
        reprojection_px=dict(
            mean=float(d.mean()), max=float(d.max()), over="all mesh vertices, render camera vs user camera"
        ),
    )


def sun_direction(elevation_deg, azimuth_deg):
    """Unit vector towards the sun; azimuth 0 = towards -Y (the front), positive towards +X."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return Vector((math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)))


def camera_intrinsics(lens, w, h):
    """Blender (pixel centres at +0.5) and core (pixel centres at integers) intrinsics for sensor fit AUTO."""
    assert w >= h
    fx = lens / SENSOR_WIDTH_MM * w
    kb = [[fx, 0.0, w / 2.0], [0.0, fx, h / 2.0], [0.0, 0.0, 1.0]]
    kc = [[fx, 0.0, w / 2.0 - 0.5], [0.0, fx, h / 2.0 - 0.5], [0.0, 0.0, 1.0]]
    return kb, kc


def make_world(hdri, strength, rotation_deg):
    world = bpy.data.worlds.new("gt_world")
    nt = world.node_tree
    nt.nodes.clear()
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    bg = nt.nodes.new("ShaderNodeBackground")
    out = nt.nodes.new("ShaderNodeOutputWorld")
    env.image = bpy.data.images.load(hdri_path(hdri), check_existing=True)
    env.interpolation = "Linear"
    nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(rotation_deg))
    bg.inputs["Strength"].default_value = strength
    return world


def make_material(kind, gt_image, interpolation):
    mat = bpy.data.materials.new("gt_albedo")
    nt = mat.node_tree
    nt.nodes.clear()
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = gt_image
    tex.interpolation = interpolation
    tex.extension = "EXTEND"
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    aov = nt.nodes.new("ShaderNodeOutputAOV")  # the albedo each pixel sees, for the per-view ground truth
    aov.aov_name = VIEW_GT_AOV
    nt.links.new(tex.outputs["Color"], aov.inputs["Color"])
    if kind == "diffuse":
        bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Roughness"].default_value = 0.0
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Color"])
        desc = dict(shader="Diffuse BSDF (Lambert)", roughness=0.0)
    else:
        bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Roughness"].default_value = 0.4
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        desc = dict(
            shader="Principled BSDF",
            base_color="albedo texture",
            roughness=0.4,
            metallic=0.0,
            ior=bsdf.inputs["IOR"].default_value,
            specular_ior_level=bsdf.inputs["Specular IOR Level"].default_value,
            note="specular at the defaults; the diffuse lobe's colour is the albedo texture",
        )
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat, desc


# --------------------------------------------------------------------------------------------------------------
# Rendering one scene
# --------------------------------------------------------------------------------------------------------------

PHOTO_EXT = {"EXR": ".exr", "PNG": ".png", "JPEG": ".jpg"}
VIEW_GT_AOV = "albedo"


def _render_layers(scene, tmp):
    """Every pass of the last render, ``{"ViewLayer.<pass>.<channel>": (H, W) float32}``, row 0 at the top."""
    import OpenEXR

    ims = scene.render.image_settings
    saved = (ims.media_type, ims.file_format, ims.color_mode, ims.color_depth, ims.exr_codec)
    try:
        ims.media_type = "MULTI_LAYER_IMAGE"
        ims.color_depth = "32"
        ims.exr_codec = "ZIP"
        bpy.data.images["Render Result"].save_render(tmp, scene=scene)
    finally:
        ims.media_type = saved[0]
        ims.file_format, ims.color_mode, ims.color_depth, ims.exr_codec = saved[1:]
    out = {}
    with OpenEXR.File(tmp, separate_channels=True) as f:
        for part in f.parts:
            for key, ch in part.channels.items():
                out[key] = np.asarray(ch.pixels, dtype=np.float32)
    os.remove(tmp)
    return out


def _layer_rgb(layers, name, channels="RGB"):
    key = [k for k in layers if k.endswith("." + name + ".R")][0][:-2]
    return np.stack([layers[f"{key}.{c}"] for c in channels], axis=-1)


def save_view_gt(scene, path):
    """Write the last render's albedo AOV as RGBA half EXR (RGB premultiplied by A = the object's coverage)."""
    rgba = _layer_rgb(_render_layers(scene, path + ".multilayer.exr"), VIEW_GT_AOV, "RGBA")
    write_exr_rgba(path, rgba)  # (a fresh file: no metadata)
    return rgba


#: Cycles passes that give each photo's diffuse shading (``shading_views``).
SHADING_PASSES = ("diffuse_direct", "diffuse_indirect", "diffuse_color")


def save_shading_view(scene, path):
    """Write the last render's diffuse shading, diffuse colour and combined image (linear RGB) as .npz."""
    layers = _render_layers(scene, path + ".multilayer.exr")
    np.savez_compressed(
        path,
        diffuse_shading=_layer_rgb(layers, "Diffuse Direct") + _layer_rgb(layers, "Diffuse Indirect"),
        diffuse_colour=_layer_rgb(layers, "Diffuse Color"),
        combined=_layer_rgb(layers, "Combined"),
    )


def configure_render(scene, spec):
    rc = RENDER_COMMON
    scene.render.engine = rc["engine"]
    cy = scene.cycles
    cy.device = rc["device"]
    cy.samples = spec["samples"]
    for k in (
        "use_adaptive_sampling",
        "use_denoising",
        "max_bounces",
        "diffuse_bounces",
        "glossy_bounces",
        "transmission_bounces",
        "transparent_max_bounces",
        "sample_clamp_direct",
        "sample_clamp_indirect",
        "caustics_reflective",
        "caustics_refractive",
        "blur_glossy",
        "pixel_filter_type",
        "filter_width",
        "use_light_tree",
    ):
        setattr(cy, k, rc[k])
    cy.use_animated_seed = False
    scene.render.resolution_x, scene.render.resolution_y = spec["resolution"]
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    scene.render.film_transparent = spec.get("film_transparent", False)
    for p in SHADING_PASSES:
        setattr(scene.view_layers[0], "use_pass_" + p, bool(spec.get("shading_views")))
    scene.render.dither_intensity = rc["dither_intensity"]
    scene.render.use_persistent_data = True
    # No date/time/host metadata in the files, so that a re-run gives byte-identical photos.
    for prop in scene.render.bl_rna.properties:
        if prop.identifier.startswith("use_stamp"):
            setattr(scene.render, prop.identifier, False)
    scene.display_settings.display_device = rc["display_device"]
    vs = scene.view_settings
    vs.view_transform, vs.look, vs.exposure, vs.gamma = rc["view_transform"], rc["look"], rc["exposure"], rc["gamma"]
    vs.use_curve_mapping = False
    ims = scene.render.image_settings
    ims.media_type = "IMAGE"
    fmt = spec["photo_format"]
    if fmt == "EXR":
        ims.file_format = "OPEN_EXR"
        ims.color_mode = "RGBA" if scene.render.film_transparent else "RGB"
        ims.color_depth = "16"
        ims.exr_codec = "ZIP"
        photo = dict(
            format="OpenEXR", channels=ims.color_mode, depth="half", codec="ZIP", colour="scene-linear Rec.709"
        )
        if scene.render.film_transparent:
            photo["alpha"] = (
                "film transparent: the background is A = 0 (the world still lights the object); RGB is "
                "premultiplied by A, as usual in EXR; A is the object's pixel coverage"
            )
    elif fmt == "PNG":
        ims.file_format = "PNG"
        ims.color_mode = "RGB"
        ims.color_depth = "8"
        ims.compression = 90
        photo = dict(
            format="PNG",
            channels="RGB",
            depth=8,
            colour="sRGB-encoded linear radiance (view transform Standard, look None, exposure 0, no dither)",
        )
    elif fmt == "JPEG":
        ims.file_format = "JPEG"
        ims.color_mode = "RGB"
        ims.quality = spec.get("jpeg_quality", 95)
        photo = dict(
            format="JPEG",
            channels="RGB",
            quality=ims.quality,
            colour="sRGB-encoded linear radiance (view transform Standard, look None, exposure 0, no dither)",
        )
    else:
        raise ValueError(fmt)
    return photo


def develop_info(spec, photo_info):
    """scene.json's photo record for a scene with capture faults (see develop())."""
    cap = spec["capture"]
    info = dict(photo_info)
    if spec["photo_format"] != "EXR":
        info["colour"] = (
            "sRGB-encoded linear radiance x the photo's gains, clipped to [0, 1]: code = round(255 x "
            "srgb_oetf(clip(gain_rgb x radiance, 0, 1))), IEC 61966-2-1 piecewise curve, no dither"
        )
    else:
        info["colour"] = "scene-linear Rec.709 radiance x the photo's gains (RGB; A untouched)"
    info["developed"] = (
        "Cycles renders float EXR (scene linear); make_fixtures.develop() multiplies it per photo by gain_rgb = "
        "2^exposure_ev x white_balance (cameras[i].capture) and encodes it (8 bit: Blender's image writer, from "
        "byte pixels; EXR: half float)"
    )
    info["faults"] = dict(
        exposure_ev="uniform in [-{:g}, {:g}] per photo".format(cap.get("exposure_ev", 0), cap.get("exposure_ev", 0)),
        white_balance="per channel, 1 + uniform in [-{:g}, {:g}] per photo".format(
            cap.get("white_balance", 0), cap.get("white_balance", 0)
        ),
        camera_jitter_px=cap.get("jitter_px", 0),
        camera_jitter=(
            "the cameras in scene.blend (cameras[i].matrix_world, K/R/t) are about jitter_px pixels off the "
            "ones that rendered (cameras[i].render_camera); see cameras[i].jitter"
        )
        if cap.get("jitter_px")
        else None,
        rng="numpy default_rng(seed_base + 7919), drawn per photo in order: exposure, white balance (3), jitter",
    )
    return info


def develop(float_path, out_path, spec, capture, rng):
    """Make the user's photo from a float render, with this photo's faults; return them (for scene.json)."""
    lin = read_exr(float_path)
    ev = float(rng.uniform(-1.0, 1.0) * capture.get("exposure_ev", 0.0))
    wb = 1.0 + rng.uniform(-1.0, 1.0, 3) * capture.get("white_balance", 0.0)
    gain = 2.0**ev * wb
    rgb = lin[..., :3] * gain
    if spec["photo_format"] == "EXR":
        write_exr_rgba(out_path, np.concatenate([rgb, lin[..., 3:]], axis=-1))
        clipped = 0.0
    else:
        code = np.round(255.0 * linear_to_srgb(np.clip(rgb, 0.0, 1.0)))
        h, w = code.shape[:2]
        img = bpy.data.images.new("_develop", w, h, alpha=False, float_buffer=False)
        px = np.ones((h, w, 4), dtype=np.float32)
        px[..., :3] = code[::-1] / 255.0  # Image.pixels row 0 is the bottom
        img.pixels.foreach_set(px.ravel())
        img.filepath_raw = out_path
        img.file_format = spec["photo_format"]
        if spec["photo_format"] == "JPEG":
            img.save(quality=spec.get("jpeg_quality", 95))
        else:
            img.save()
        bpy.data.images.remove(img)
        strip_metadata(out_path)
        clipped = float((rgb.max(axis=-1) > 1.0).mean())
    return dict(exposure_ev=ev, white_balance=wb.tolist(), gain_rgb=gain.tolist(), clipped_pixel_fraction=clipped)


def strip_metadata(path):
    """Drop the text metadata Blender and Cycles write (dates, render times), so that re-runs are byte-identical.

    The pixels are untouched: EXR is rewritten from its own half-float channels, PNG loses its tEXt/zTXt/iTXt/tIME
    chunks and JPEG its COM segments.
    """
    import struct
    import zlib

    ext = os.path.splitext(path)[1].lower()
    if ext == ".exr":
        import OpenEXR

        with OpenEXR.File(path) as f:
            ch = f.channels()
            name = "RGBA" if "RGBA" in ch else "RGB"
            arr = np.array(ch[name].pixels)
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {name: arr}).write(path)
        return
    with open(path, "rb") as f:
        data = f.read()
    out = bytearray()
    if ext == ".png":
        out += data[:8]
        i = 8
        while i < len(data):
            (n,) = struct.unpack(">I", data[i : i + 4])
            kind = data[i + 4 : i + 8]
            chunk = data[i : i + 12 + n]
            assert struct.unpack(">I", chunk[-4:])[0] == zlib.crc32(chunk[4:-4]) & 0xFFFFFFFF
            if kind not in (b"tEXt", b"zTXt", b"iTXt", b"tIME"):
                out += chunk
            i += 12 + n
    elif ext in (".jpg", ".jpeg"):
        assert data[:2] == b"\xff\xd8"
        out += data[:2]
        i = 2
        while True:
            assert data[i] == 0xFF
            marker = data[i + 1]
            if marker == 0xDA:  # start of scan: the rest is image data
                out += data[i:]
                break
            (n,) = struct.unpack(">H", data[i + 2 : i + 4])
            if marker != 0xFE:  # COM
                out += data[i : i + 2 + n]
            i += 2 + n
    else:
        raise ValueError(path)
    with open(path, "wb") as f:
        f.write(bytes(out))


def resolved_spec(name, **overrides):
    spec = dict(SCENES[name])
    if "base" in spec:
        base = dict(SCENES[spec["base"]])
        base.update({k: v for k, v in spec.items() if k != "base"})
        base["base"] = spec["base"]
        spec = base
    for k, v in overrides.items():
        if v is not None:
            spec[k] = tuple(v) if k == "resolution" else v
    return spec


def generate(
    name,
    out_dir,
    resolution=None,
    n_cameras=None,
    samples=None,
    texture_size=None,
    view_gt=None,
    reuse_base=True,
    shading_views=None,
):
    """Render scene ``name`` into ``out_dir/name``; return its scene.json dictionary.

    The keyword arguments override the scene's defaults in SCENES (None keeps them). ``view_gt`` also writes
    per-photo ground-truth albedo images in ``gt_views/``; ``shading_views`` each photo's diffuse shading,
    diffuse colour and combined image from Cycles' passes in ``shading_views/`` (for bench/shading_ceiling.py).
    """
    spec = resolved_spec(
        name,
        resolution=resolution,
        n_cameras=n_cameras,
        samples=samples,
        texture_size=texture_size,
        view_gt=view_gt,
        shading_views=shading_views,
    )
    if "base" in spec:
        return _generate_derived(name, spec, out_dir, reuse_base)
    t_start = time.time()
    scene_dir = os.path.join(out_dir, name)
    photo_dir = os.path.join(scene_dir, "photos")
    if os.path.isdir(scene_dir):
        shutil.rmtree(scene_dir)
    os.makedirs(photo_dir)

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    mesh_kind = spec.get("mesh", "suzanne")
    fine, mid, mesh_info = build_mesh(mesh_kind)
    finish_shading(fine)

    # Ground truth texture, then the material that samples that very file.
    n = spec["texture_size"]
    rgba, albedo_info = ground_truth_albedo(fine, n, spec["albedo"], mesh_kind, spec["seed"])
    gt_path = os.path.join(scene_dir, "albedo_gt.exr")
    write_exr_rgba(gt_path, rgba)
    gt_img = bpy.data.images.load(gt_path)
    gt_img.colorspace_settings.name = "Linear Rec.709"
    gt_img.alpha_mode = "CHANNEL_PACKED"
    mat, mat_info = make_material(spec["material"], gt_img, spec["interpolation"])

    obj = bpy.data.objects.new(MESH_OBJECT, fine)
    scene.collection.objects.link(obj)
    fine.materials.append(mat)

    # Cameras around the object's bounding sphere.
    co = np.array([v.co for v in fine.vertices])
    lo, hi = co.min(axis=0), co.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = float(np.linalg.norm(co - centre, axis=1).max())
    w, h = spec["resolution"]
    cam_coll = bpy.data.collections.new("Cameras")
    scene.collection.children.link(cam_coll)
    cams = place_cameras(spec["n_cameras"], spec["resolution"], centre, radius, spec["seed"])
    photo_info = configure_render(scene, spec)
    ext = PHOTO_EXT[spec["photo_format"]]
    capture = spec.get("capture")
    if capture:
        # Rendered as float, then "developed" here with the per-photo faults (see develop()).
        photo_info = develop_info(spec, photo_info)
        ims = scene.render.image_settings
        ims.file_format, ims.color_depth, ims.exr_codec = "OPEN_EXR", "32", "ZIP"
        ims.color_mode = "RGBA" if scene.render.film_transparent else "RGB"
        capture_rng = np.random.default_rng(spec["seed"] + 7919)
    view_gt = bool(spec.get("view_gt"))
    if view_gt:
        aov = scene.view_layers[0].aovs.add()
        aov.name, aov.type = VIEW_GT_AOV, "COLOR"
        os.makedirs(os.path.join(scene_dir, "gt_views"))
    if spec.get("shading_views"):
        os.makedirs(os.path.join(scene_dir, "shading_views"))

    # Lighting.
    L = spec["lighting"]
    light_info = dict(L)
    light_info["hdri_mapping"] = (
        "World: Environment Texture (equirectangular, Linear) of "
        "<blender>/datafiles/studiolights/world/<hdri>.exr, its vector = Mapping node (type "
        "Point, rotation (0, 0, rotation_z_deg)) of the Generated texture coordinate, "
        "into a Background node of the given strength"
    )
    sun = None
    if L["kind"] in ("sun", "sun_per_view"):
        ld = bpy.data.lights.new("sun", "SUN")
        ld.energy = L["sun_strength"]
        ld.angle = math.radians(L["sun_angle_deg"])
        ld.use_shadow = True
        sun = bpy.data.objects.new("sun", ld)
        scene.collection.objects.link(sun)
        if L["kind"] == "sun":
            to_sun = sun_direction(L["sun_elevation_deg"], L["sun_azimuth_deg"])
            sun.matrix_world = look_at(to_sun, (0, 0, 0))
            light_info["direction_to_sun"] = list(to_sun)
        light_info["note"] = (
            "sun strength in W/m^2 (irradiance), angle = angular diameter; azimuth 0 = towards -Y "
            "(the face), positive towards +X"
        )
    worlds = {}

    cam_records = []
    render_times = []
    for i, c in enumerate(cams):
        cname = f"cam_{i:02d}"
        cd = bpy.data.cameras.new(cname)
        cd.lens = c["lens_mm"]
        cd.sensor_width = SENSOR_WIDTH_MM
        cd.sensor_fit = "AUTO"
        cd.clip_start, cd.clip_end = 0.05, 100.0
        cobj = bpy.data.objects.new(cname, cd)
        cam_coll.objects.link(cobj)
        cobj.matrix_world = c["matrix_world"]
        scene.camera = cobj

        view_light = {}
        if L["kind"] == "hdri_per_view":
            hk = i % len(L["hdri"])
            hname = L["hdri"][hk]
            strength = L["strength"][hk]
            rot = (i * L["rotation_step_deg"]) % 360.0
        elif L["kind"] == "sun_per_view":
            hname, strength = L["hdri"][0], L["strength"]
            rot = (i * L["rotation_step_deg"]) % 360.0
            el = L["sun_elevation_deg"][i % len(L["sun_elevation_deg"])]
            az = (L["sun_azimuth_deg"] + i * L["sun_azimuth_step_deg"]) % 360.0
            to_sun = sun_direction(el, az)
            sun.matrix_world = look_at(to_sun, (0, 0, 0))
            view_light = dict(sun_elevation_deg=el, sun_azimuth_deg=az, direction_to_sun=list(to_sun))
        else:
            hname, strength, rot = L["hdri"][0], L["strength"], L["rotation_deg"][0]
        key = (hname, strength, rot)
        if key not in worlds:
            worlds[key] = make_world(hname, strength, rot)
        scene.world = worlds[key]
        seed = spec["seed"] + i
        scene.cycles.seed = seed

        photo_name = cname + ext
        scene.render.filepath = os.path.join(photo_dir, photo_name if not capture else cname + ".float.exr")
        t0 = time.time()
        bpy.ops.render.render(write_still=True)
        if capture:
            faults = develop(scene.render.filepath, os.path.join(photo_dir, photo_name), spec, capture, capture_rng)
            os.remove(scene.render.filepath)
        else:
            strip_metadata(scene.render.filepath)
        render_times.append(time.time() - t0)
        log(f"{name}: {cname} rendered in {render_times[-1]:.1f} s")
        if view_gt:
            save_view_gt(scene, os.path.join(scene_dir, "gt_views", cname + ".exr"))
        if spec.get("shading_views"):
            save_shading_view(scene, os.path.join(scene_dir, "shading_views", cname + ".npz"))

        kb, kc = camera_intrinsics(c["lens_mm"], w, h)
        extra = {}
        if capture:
            extra["capture"] = faults
            if capture.get("jitter_px"):
                # The user's camera (the one saved in scene.blend) is about a pixel off the one that rendered.
                render_mw = cobj.matrix_world.copy()
                cobj.matrix_world, jit = jitter_camera(render_mw, kc, w, h, capture["jitter_px"], co, capture_rng)
                r_rv, t_rv = camera_extrinsics(render_mw)
                extra["render_camera"] = dict(
                    matrix_world=np.array(render_mw, dtype=np.float64).tolist(),
                    R_core=r_rv.tolist(),
                    t_core=t_rv.tolist(),
                )
                extra["jitter"] = jit
        mw = cobj.matrix_world
        cpos = np.array(mw.translation)
        r_cv, t_cv = camera_extrinsics(mw)
        cam_records.append(
            dict(
                name=cname,
                photo="photos/" + photo_name,
                lens_mm=c["lens_mm"],
                sensor_width_mm=SENSOR_WIDTH_MM,
                sensor_fit="AUTO",
                shift=[0.0, 0.0],
                width=w,
                height=h,
                matrix_world=np.array(mw, dtype=np.float64).tolist(),
                location=cpos.tolist(),
                K_blender=kb,
                K_core=kc,
                R_core=r_cv.tolist(),
                t_core=t_cv.tolist(),
                azimuth_deg=c["azimuth_deg"],
                elevation_deg=c["elevation_deg"],
                distance=c["distance"],
                seed=seed,
                lighting=dict(hdri=hname, strength=strength, rotation_z_deg=rot, **view_light),
                albedo_view=("gt_views/" + cname + ".exr") if view_gt else None,
                **extra,
            )
        )

    # ---- The user's file: mesh + cameras + photos; strip the ground truth and the lights. ----
    if sun is not None:
        bpy.data.objects.remove(sun)
        bpy.data.lights.remove(ld)
    scene.world = None
    if view_gt:
        scene.view_layers[0].aovs.remove(aov)
    for wd in list(bpy.data.worlds):
        bpy.data.worlds.remove(wd)
    fine.materials.clear()
    bpy.data.materials.remove(mat)
    for img in list(bpy.data.images):
        bpy.data.images.remove(img)
    user_mesh = fine
    if mid is not None:
        bpy.data.meshes.remove(mid)
    mesh_record = _mesh_record(user_mesh, mesh_info, "fine")
    _attach_photos(scene, {c["name"]: c["photo"] for c in cam_records}, scene_dir)
    blend_path = os.path.join(scene_dir, "scene.blend")
    _save_blend(blend_path)

    record = dict(
        name=name,
        description=_DESCRIPTIONS[name],
        blender_version=bpy.app.version_string,
        files=dict(
            blend="scene.blend",
            albedo_gt="albedo_gt.exr",
            photos="photos/",
            gt_views="gt_views/" if view_gt else None,
            shading_views="shading_views/" if spec.get("shading_views") else None,
        ),
        mesh=mesh_record,
        albedo_gt=dict(
            file="albedo_gt.exr",
            size=[n, n],
            channels="RGBA",
            dtype="half",
            colour="linear Rec.709 (scene linear), not colour managed",
            rows="row 0 = top = v 1; texel (r, c) centre at u = (c+0.5)/N, v = 1-(r+0.5)/N",
            alpha="1 where the texel centre is inside a UV triangle, 0 in the padding",
            padding="texels outside every UV triangle hold the nearest inside texel's value",
            sampled_with=dict(
                interpolation=spec["interpolation"],
                extension="EXTEND",
                alpha_mode="CHANNEL_PACKED",
                colorspace="Linear Rec.709",
            ),
            **albedo_info,
        ),
        material=mat_info,
        lighting=light_info,
        lighting_licence=HDRI_LICENCE,
        render=dict(
            RENDER_COMMON,
            samples=spec["samples"],
            film_transparent=scene.render.film_transparent,
            seed_base=spec["seed"],
            seed_rule="view i uses seed seed_base + i",
            resolution=list(spec["resolution"]),
            cycles_version=bpy.app.version_string,
            use_persistent_data=True,
        ),
        photo=photo_info,
        gt_views=(
            dict(
                folder="gt_views/",
                channels="RGBA",
                dtype="half",
                meaning="per photo, the albedo texture as Cycles sampled it (an AOV of the texture colour, same "
                "samples and pixel filter as the photo); RGB is premultiplied by A; A = fraction of the "
                "pixel's samples that hit the mesh, so albedo = RGB / A where A > 0",
            )
            if view_gt
            else None
        ),
        cameras=cam_records,
        camera_convention=(
            "matrix_world: Blender camera-to-world (camera looks down -Z, +Y up). K_blender: pixel "
            "centres at (c+0.5, r+0.5). K_core/R_core/t_core: core.geometry.camera convention (x right, y "
            "down, z forward; pixel (r, c) centre at (c, r); world X -> R X + t)."
        ),
        licences=dict(hdri=HDRI_LICENCE, photos=PHOTO_LICENCES),
    )
    write_json(os.path.join(scene_dir, "scene.json"), record)
    log(f"{name}: done in {time.time() - t_start:.1f} s (renders {sum(render_times):.1f} s)")
    record["_render_seconds"] = render_times
    return record


def _generate_derived(name, spec, out_dir, reuse_base):
    """photo_sun_coarse: the base scene's photos and cameras, a smoothed coarser user mesh."""
    base = spec["base"]
    base_dir = os.path.join(out_dir, base)
    base_json = os.path.join(base_dir, "scene.json")
    want = {k: spec[k] for k in ("resolution", "n_cameras", "samples", "texture_size")}
    ok = False
    if reuse_base and os.path.exists(base_json):
        with open(base_json) as f:
            b = json.load(f)
        ok = (
            tuple(b["render"]["resolution"]) == tuple(want["resolution"])
            and len(b["cameras"]) == want["n_cameras"]
            and b["render"]["samples"] == want["samples"]
            and b["albedo_gt"]["size"][0] == want["texture_size"]
            and (bool(b["files"].get("shading_views")) or not spec.get("shading_views"))
        )
    if not ok:
        generate(
            base,
            out_dir,
            resolution=want["resolution"],
            n_cameras=want["n_cameras"],
            samples=want["samples"],
            texture_size=want["texture_size"],
            shading_views=spec.get("shading_views"),
        )
    with open(base_json) as f:
        b = json.load(f)
    scene_dir = os.path.join(out_dir, name)
    if os.path.isdir(scene_dir):
        shutil.rmtree(scene_dir)
    os.makedirs(scene_dir)
    shutil.copyfile(os.path.join(base_dir, "albedo_gt.exr"), os.path.join(scene_dir, "albedo_gt.exr"))

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    mesh_kind = spec.get("mesh", "suzanne")
    fine, mid, mesh_info = build_mesh(mesh_kind)
    smooth = COARSE_SMOOTH if mesh_kind == "suzanne" else COARSE_SMOOTH_ROCK
    coarse, dist = make_coarse(mid, fine, smooth, keep_plinth=mesh_kind == "suzanne")
    finish_shading(coarse)
    bpy.data.meshes.remove(fine)
    bpy.data.meshes.remove(mid)
    obj = bpy.data.objects.new(MESH_OBJECT, coarse)
    scene.collection.objects.link(obj)
    cam_coll = bpy.data.collections.new("Cameras")
    scene.collection.children.link(cam_coll)
    configure_render(scene, spec)
    for c in b["cameras"]:
        cd = bpy.data.cameras.new(c["name"])
        cd.lens, cd.sensor_width, cd.sensor_fit = c["lens_mm"], c["sensor_width_mm"], c["sensor_fit"]
        cd.clip_start, cd.clip_end = 0.05, 100.0
        cobj = bpy.data.objects.new(c["name"], cd)
        cam_coll.objects.link(cobj)
        cobj.matrix_world = Matrix(c["matrix_world"])
    scene.camera = bpy.data.objects[b["cameras"][0]["name"]]
    photos = {c["name"]: "../" + base + "/" + c["photo"] for c in b["cameras"]}
    _attach_photos(scene, photos, scene_dir)
    _save_blend(os.path.join(scene_dir, "scene.blend"))

    mesh_info = dict(mesh_info)
    mesh_info["description"] += (
        "; COARSE: the user's mesh is the Smart-UV level (4x fewer faces than the render mesh) with the %s "
        "vertices smoothed (bmesh smooth_vert factor %.2f, %d times%s). Same UV islands as the render mesh, so "
        "albedo_gt.exr applies unchanged"
        % (
            "head" if mesh_kind == "suzanne" else "mesh's",
            smooth["factor"],
            smooth["repeat"],
            "; the plinth untouched" if mesh_kind == "suzanne" else "",
        )
    )
    record = dict(b)
    record.update(
        name=name,
        description=_DESCRIPTIONS[name],
        base_scene=base,
        files=dict(
            blend="scene.blend",
            albedo_gt="albedo_gt.exr (a copy of the base scene's)",
            photos=f"../{base}/photos/ (shared with the base scene, referenced by relative path)",
            shading_views=f"../{base}/shading_views/" if b["files"].get("shading_views") else None,
        ),
        mesh=dict(
            _mesh_record(coarse, mesh_info, "coarse"),
            coarse_smoothing=smooth,
            distance_to_render_mesh=dist,
            render_mesh=b["mesh"],
        ),
    )
    record["cameras"] = [
        dict(
            c,
            photo="../" + base + "/" + c["photo"],
            albedo_view=("../" + base + "/" + c["albedo_view"]) if c.get("albedo_view") else None,
        )
        for c in b["cameras"]
    ]
    write_json(os.path.join(scene_dir, "scene.json"), record)
    log(f"{name}: done (coarse mesh, distance to the render mesh mean {dist['mean']:.4f}, max {dist['max']:.4f})")
    return record


_DESCRIPTIONS = {
    "lambert_sky": "Lambertian, piecewise-constant albedo (5 regions), soft environment light (HDRI 'forest'), "
    "EXR photos (the paper's fig. 1 scenario)",
    "photo_sun": "Photographic albedo, Principled BSDF roughness 0.4 (partly specular), one sun (5 deg) with cast "
    "shadows plus a weak world (HDRI 'studio'), 8-bit sRGB PNG photos (the paper's fig. 2 scenario)",
    "photo_sun_coarse": "photo_sun's photos and cameras, but the user's mesh is smoothed and coarser, with the same "
    "UV layout (the paper's fig. 5 scenario)",
    "varying_light": "Photographic albedo, Lambertian, lighting changes per view (HDRIs 'sunrise' and 'interior' "
    "alternating, rotated by the golden angle per view), JPEG q95 photos",
    "torus_patches": "Tilted torus (its inner ring shades itself), 14 flat Voronoi patches, Lambertian, HDRI "
    "'courtyard' (no sun), EXR photos with transparent film",
    "bowl_checker": "Open bowl (the rim shadows the inside), fine 3D checker (8 cm), Principled roughness 0.4, sun "
    "lamp + weak HDRI 'city', 8-bit PNG: the lit light squares clip",
    "rock_photo": "Rock (displaced icosphere with three dents), photographic albedo (coffee), Lambertian, low sun "
    "lamp + HDRI 'sunset', JPEG q90 with the sky as background",
    "rock_coarse": "rock_photo's photos and cameras, but the user's mesh is the smoothed coarse level (4x fewer "
    "faces), same UV layout",
    "stairs_noise": "Stairs (each step shadows the next), fine procedural noise albedo, Lambertian, sun lamp + "
    "HDRI 'night', EXR photos with transparent film",
    "suzanne_exposure": "Suzanne, photographic albedo (chelsea), Lambertian, HDRI 'studio' (no sun), 8-bit PNG with "
    "per-photo exposure (+-0.5 EV) and white balance (+-10 % per channel)",
    "torus_varying_sun": "Torus, photographic albedo (chelsea), Lambertian, lighting varying per photo: a sun lamp "
    "moving (golden-angle azimuth steps, elevation 30/60 deg) and HDRI 'sunrise' turning, EXR",
    "bowl_jitter": "Bowl, photographic albedo (coffee), Lambertian, HDRI 'city' (a sun in the map), 8-bit PNG; "
    "the cameras in scene.blend are about a pixel off the ones that rendered",
    "stairs_capture": "A real capture's faults together: stairs, flat patches, Principled roughness 0.4, sun lamp + "
    "HDRI 'courtyard', JPEG q85 with the background, per-photo exposure and white balance, 8-bit "
    "clipping, cameras about a pixel off",
}


def _mesh_record(me, info, which):
    return dict(
        info,
        object=MESH_OBJECT,
        mesh=me.name,
        which=which,
        vertices=len(me.vertices),
        faces=len(me.polygons),
        triangles=len(me.loop_triangles) or None,
        uv_map=me.uv_layers.active.name,
        shading="smooth, sharp edges from angle 60 deg",
        units=info.get("units", "metres, object at the origin, +Z up, Suzanne faces -Y"),
    )


def _attach_photos(scene, rel_photos, scene_dir):
    """Each camera's photo as its background image; ``rel_photos``: camera name -> path relative to
    ``scene_dir`` (by name: names sorted as strings put cam_100 before cam_11)."""
    for name, rel in rel_photos.items():
        cobj = scene.objects[name]
        path = os.path.normpath(os.path.join(scene_dir, rel))
        img = bpy.data.images.load(path, check_existing=False)
        img.name = os.path.basename(rel)
        if rel.endswith(".exr"):
            img.colorspace_settings.name = "Linear Rec.709"
        else:
            img.colorspace_settings.name = "sRGB"
        cobj.data.show_background_images = True
        bg = cobj.data.background_images.new()
        bg.image = img
        bg.alpha = 1.0
        bg.frame_method = "STRETCH"


def _save_blend(path):
    bpy.ops.wm.save_as_mainfile(filepath=path, compress=True, relative_remap=True)
    for img in bpy.data.images:
        if img.filepath and not img.filepath.startswith("//"):
            img.filepath = bpy.path.relpath(img.filepath)
    bpy.ops.wm.save_mainfile(filepath=path, compress=True)
    # Blender keeps a backup; drop it.
    if os.path.exists(path + "1"):
        os.remove(path + "1")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=HERE, help="output folder (default: blend_fixtures/)")
    p.add_argument("--only", nargs="*", choices=list(SCENES), help="scenes to make (default: all)")
    p.add_argument("--resolution", nargs=2, type=int, metavar=("W", "H"))
    p.add_argument("--cameras", type=int)
    p.add_argument("--samples", type=int)
    p.add_argument("--texture-size", type=int)
    p.add_argument(
        "--view-gt",
        action="store_true",
        default=None,
        help="also write per-photo ground-truth albedo images (default: lambert_sky only)",
    )
    p.add_argument(
        "--shading-views",
        action="store_true",
        default=None,
        help="also write each photo's diffuse shading from Cycles' passes (shading_views/; bench/shading_ceiling.py)",
    )
    a = p.parse_args(argv)
    names = a.only or list(SCENES)
    for name in names:
        generate(
            name,
            a.out,
            resolution=a.resolution,
            n_cameras=a.cameras,
            samples=a.samples,
            texture_size=a.texture_size,
            view_gt=a.view_gt,
            reuse_base=True,
            shading_views=a.shading_views,
        )


if __name__ == "__main__":
    main(sys.argv[1:])
