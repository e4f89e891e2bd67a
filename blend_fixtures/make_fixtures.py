"""Render the test scenes in blend_fixtures/ with Cycles, with ground truth.

Run with the venv's Python (Blender as the ``bpy`` module)::

    .venv/bin/python blend_fixtures/make_fixtures.py [--out DIR] [--only NAME ...]
        [--resolution W H] [--cameras N] [--samples S] [--texture-size N]

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

import numpy as np

import bpy
import bmesh
from mathutils import Matrix, Vector
from mathutils.bvhtree import BVHTree

HERE = os.path.dirname(os.path.abspath(__file__))
ASSETS = os.path.join(HERE, "assets")

# --------------------------------------------------------------------------------------------------------------
# Scene definitions
# --------------------------------------------------------------------------------------------------------------

HDRI_LICENCE = ("CC0, Greg Zaal / Poly Haven, bundled with Blender (datafiles/studiolights/world/license.txt): "
                "forest=ninomaru_teien, studio=studio_small_01, interior=hotel_room, sunrise=spruit_sunrise")
PHOTO_LICENCES = {
    "chelsea.png": "CC0, photographer Stefan van der Walt (scikit-image data: skimage.data.chelsea)",
    "coffee.png": "CC0, photographer Rachel Michetti (scikit-image data: skimage.data.coffee)",
}

SCENES = {
    # (a) the paper's figure 1: Lambertian, piecewise-constant albedo, skydome-like environment light.
    "lambert_sky": dict(
        resolution=(320, 240), n_cameras=13, samples=48, texture_size=512, seed=1000, film_transparent=True,
        view_gt=True,
        albedo="regions", interpolation="Closest", material="diffuse",
        lighting=dict(kind="hdri", hdri=["forest"], strength=1.0, rotation_deg=[0.0]),
        photo_format="EXR", user_mesh="fine"),
    # (b) the paper's figure 2: photographic albedo, partly specular, one extended light with cast shadows.
    "photo_sun": dict(
        resolution=(480, 360), n_cameras=13, samples=48, texture_size=256, seed=2000,
        albedo="photo:chelsea.png", interpolation="Linear", material="principled",
        lighting=dict(kind="sun", sun_strength=4.5, sun_angle_deg=5.0, sun_elevation_deg=50.0,
                      sun_azimuth_deg=-35.0, hdri=["studio"], strength=0.08, rotation_deg=[0.0]),
        photo_format="PNG", user_mesh="fine"),
    # (c) the paper's figure 5: (b)'s photos, but a smoothed, coarser target mesh with the same UV layout.
    "photo_sun_coarse": dict(base="photo_sun", user_mesh="coarse"),
    # (d) lighting that changes per view (the paper's per-view lighting), JPEG photos.
    "varying_light": dict(
        resolution=(480, 360), n_cameras=12, samples=48, texture_size=256, seed=4000,
        albedo="photo:coffee.png", interpolation="Linear", material="diffuse",
        lighting=dict(kind="hdri_per_view", hdri=["sunrise", "interior"], strength=[0.6, 0.45],
                      rotation_step_deg=137.50776405),
        photo_format="JPEG", user_mesh="fine"),
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
PHOTO_ALBEDO_SCALE = 0.85          # albedo = scale * srgb_to_linear(photo), so that albedo < 1
CAMERA_LENSES_MM = (35.0, 42.0, 50.0, 60.0)
SENSOR_WIDTH_MM = 36.0
MESH_OBJECT = "Subject"
UV_ANGLE_LIMIT_DEG = 55.0   # 66 (the default) gave folded, overlapping islands on this mesh
UV_ISLAND_MARGIN = 0.01
COARSE_SMOOTH = dict(factor=0.5, repeat=10)

RENDER_COMMON = dict(
    engine="CYCLES", device="CPU", use_adaptive_sampling=False, use_denoising=False,
    max_bounces=6, diffuse_bounces=3, glossy_bounces=3, transmission_bounces=2, transparent_max_bounces=4,
    sample_clamp_direct=0.0, sample_clamp_indirect=3.0, caustics_reflective=False, caustics_refractive=False,
    blur_glossy=1.0, use_light_tree=False,
    pixel_filter_type="BLACKMAN_HARRIS", filter_width=1.5,
    view_transform="Standard", look="None", exposure=0.0, gamma=1.0, display_device="sRGB",
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


def hdri_path(name):
    return os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world", name + ".exr")


def write_exr_rgba(path, rgba, half=True):
    import OpenEXR
    arr = np.ascontiguousarray(rgba, dtype=np.float16 if half else np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGBA": arr}).write(path)


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
    px = px.reshape(h, w, img.channels)[::-1, :, :3]   # Image.pixels row 0 is the bottom; code/255 for 8 bit
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
    return dict(co=co.reshape(-1, 3), uv=uv.reshape(-1, 2), tri_loops=tri_loops.reshape(-1, 3),
                tri_verts=tri_verts.reshape(-1, 3), edges=ev.reshape(-1, 2))


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
    geom = bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=32, radius1=r, radius2=r,
                                 depth=depth, matrix=Matrix.Translation((0.0, -0.05, top - depth / 2)))
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

    # Smart UV Project (operator: needs the object in edit mode).
    obj = bpy.data.objects.new("_tmp_uv", mid)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    uv_params = dict(angle_limit=math.radians(UV_ANGLE_LIMIT_DEG), island_margin=UV_ISLAND_MARGIN, area_weight=0.0,
                     correct_aspect=True, scale_to_bounds=False)
    bpy.ops.uv.smart_project(**uv_params)
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.data.objects.remove(obj)
    mid.uv_layers.active.name = "UVMap"

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


def make_coarse(mid, fine):
    """The 'coarse' user mesh: ``mid`` (4x fewer faces than ``fine``) with the head's vertices smoothed."""
    coarse = mid.copy()
    coarse.name = "coarse"
    bm = bmesh.new()
    bm.from_mesh(coarse)
    co = np.array([v.co for v in bm.verts])
    comp = components(len(bm.verts), np.array([[e.verts[0].index, e.verts[1].index] for e in bm.edges]))
    plinth_label = comp[np.argmin(co[:, 2])]
    verts = [v for v in bm.verts if comp[v.index] != plinth_label]
    for _ in range(COARSE_SMOOTH["repeat"]):
        bmesh.ops.smooth_vert(bm, verts=verts, factor=COARSE_SMOOTH["factor"],
                              use_axis_x=True, use_axis_y=True, use_axis_z=True)
    bm.to_mesh(coarse)
    bm.free()
    # Distance of the coarse vertices to the fine surface.
    fbm = bmesh.new()
    fbm.from_mesh(fine)
    tree = BVHTree.FromBMesh(fbm)
    d = np.array([tree.find_nearest(v.co)[3] for v in coarse.vertices])
    fbm.free()
    return coarse, dict(mean=float(d.mean()), p95=float(np.percentile(d, 95)), max=float(d.max()))


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
    tuv = a["uv"][a["tri_loops"]]              # (T, 3, 2)
    tco = a["co"][a["tri_verts"]]              # (T, 3, 3)
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


def ground_truth_albedo(mesh, n, albedo_spec):
    pos, tri, count, a = rasterise_uv(mesh, n)
    inside = tri >= 0
    overlap = int((count > 1).sum())
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
        info = dict(kind="piecewise constant, regions defined on the surface in 3D (object space, metres): "
                         "plinth = plinth component; eyes = Suzanne's two eye components; ears = head & |x| > 0.98; "
                         "cap = head & not ears & z > 0.30 + 0.12|x|; face = rest of the head",
                    regions={k: list(v) for k, v in REGION_ALBEDO.items()})
    elif albedo_spec.startswith("photo:"):
        fname = albedo_spec.split(":", 1)[1]
        photo = load_png_linear(os.path.join(ASSETS, fname)) * PHOTO_ALBEDO_SCALE
        ph, pw = photo.shape[:2]
        lo, hi = hco.min(axis=0), hco.max(axis=0)
        cx, cy = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])
        m = part <= 1
        theta = np.arctan2(pos[..., 0] - cx, -(pos[..., 1] - cy))      # 0 at the front (-Y), +-pi at the back
        s = np.abs(theta) / np.pi                                       # mirrored: continuous all around
        t = (hi[2] - pos[..., 2]) / (hi[2] - lo[2])
        from scipy.ndimage import map_coordinates
        rows = np.clip(t[m], 0, 1) * (ph - 1)
        cols = np.clip(s[m], 0, 1) * (pw - 1)
        for ch in range(3):
            rgb[m, ch] = map_coordinates(photo[..., ch], [rows, cols], order=1, mode="nearest")
        rgb[part == 2] = PLINTH_ALBEDO_PHOTO
        info = dict(kind="photograph projected on the head (and eyes): mirrored cylindrical projection about the "
                         "vertical axis through the head's bounding-box centre, s = |atan2(x-cx, -(y-cy))|/pi -> "
                         "photo column s*(W-1) (front = left edge, back = right edge), t = (zmax - z)/(zmax - zmin) -> "
                         "photo row t*(H-1), bilinear; albedo = %.2f * srgb_to_linear(photo); plinth uniform"
                         % PHOTO_ALBEDO_SCALE,
                    photo=fname, photo_licence=PHOTO_LICENCES[fname], photo_albedo_scale=PHOTO_ALBEDO_SCALE,
                    plinth=list(PLINTH_ALBEDO_PHOTO))
    else:
        raise ValueError(albedo_spec)
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
            cams.append(dict(azimuth_deg=az, elevation_deg=el, lens_mm=lens, distance=dist,
                             matrix_world=look_at(eye, target, rng.uniform(-3, 3))))
    return cams


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
    aov = nt.nodes.new("ShaderNodeOutputAOV")      # the albedo each pixel sees, for the per-view ground truth
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
        desc = dict(shader="Principled BSDF", base_color="albedo texture", roughness=0.4, metallic=0.0,
                    ior=bsdf.inputs["IOR"].default_value, specular_ior_level=bsdf.inputs["Specular IOR Level"].default_value,
                    note="specular at the defaults; the diffuse lobe's colour is the albedo texture")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat, desc


# --------------------------------------------------------------------------------------------------------------
# Rendering one scene
# --------------------------------------------------------------------------------------------------------------

PHOTO_EXT = {"EXR": ".exr", "PNG": ".png", "JPEG": ".jpg"}
VIEW_GT_AOV = "albedo"


def save_view_gt(scene, path):
    """Write the last render's albedo AOV as RGBA half EXR (RGB premultiplied by A = the object's coverage)."""
    import OpenEXR
    ims = scene.render.image_settings
    saved = (ims.media_type, ims.file_format, ims.color_mode, ims.color_depth, ims.exr_codec)
    tmp = path + ".multilayer.exr"
    try:
        ims.media_type = "MULTI_LAYER_IMAGE"
        ims.color_depth = "32"
        ims.exr_codec = "ZIP"
        bpy.data.images["Render Result"].save_render(tmp, scene=scene)
    finally:
        ims.media_type = saved[0]
        ims.file_format, ims.color_mode, ims.color_depth, ims.exr_codec = saved[1:]
    with OpenEXR.File(tmp, separate_channels=True) as f:
        part = [p for p in f.parts if p.name().endswith("." + VIEW_GT_AOV)][0]
        pre = part.name()
        rgba = np.stack([np.asarray(part.channels[f"{pre}.{c}"].pixels, dtype=np.float32) for c in "RGBA"], axis=-1)
    os.remove(tmp)
    write_exr_rgba(path, rgba)          # (a fresh file: no metadata)
    return rgba


def configure_render(scene, spec):
    rc = RENDER_COMMON
    scene.render.engine = rc["engine"]
    cy = scene.cycles
    cy.device = rc["device"]
    cy.samples = spec["samples"]
    for k in ("use_adaptive_sampling", "use_denoising", "max_bounces", "diffuse_bounces", "glossy_bounces",
              "transmission_bounces", "transparent_max_bounces", "sample_clamp_direct", "sample_clamp_indirect",
              "caustics_reflective", "caustics_refractive", "blur_glossy",
              "pixel_filter_type", "filter_width", "use_light_tree"):
        setattr(cy, k, rc[k])
    cy.use_animated_seed = False
    scene.render.resolution_x, scene.render.resolution_y = spec["resolution"]
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    scene.render.film_transparent = spec.get("film_transparent", False)
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
        photo = dict(format="OpenEXR", channels=ims.color_mode, depth="half", codec="ZIP", colour="scene-linear Rec.709")
        if scene.render.film_transparent:
            photo["alpha"] = ("film transparent: the background is A = 0 (the world still lights the object); RGB is "
                              "premultiplied by A, as usual in EXR; A is the object's pixel coverage")
    elif fmt == "PNG":
        ims.file_format = "PNG"
        ims.color_mode = "RGB"
        ims.color_depth = "8"
        ims.compression = 90
        photo = dict(format="PNG", channels="RGB", depth=8,
                     colour="sRGB-encoded linear radiance (view transform Standard, look None, exposure 0, no dither)")
    elif fmt == "JPEG":
        ims.file_format = "JPEG"
        ims.color_mode = "RGB"
        ims.quality = 95
        photo = dict(format="JPEG", channels="RGB", quality=95,
                     colour="sRGB-encoded linear radiance (view transform Standard, look None, exposure 0, no dither)")
    else:
        raise ValueError(fmt)
    return photo


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
            (n,) = struct.unpack(">I", data[i:i + 4])
            kind = data[i + 4:i + 8]
            chunk = data[i:i + 12 + n]
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
            if marker == 0xDA:                      # start of scan: the rest is image data
                out += data[i:]
                break
            (n,) = struct.unpack(">H", data[i + 2:i + 4])
            if marker != 0xFE:                      # COM
                out += data[i:i + 2 + n]
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


def generate(name, out_dir, resolution=None, n_cameras=None, samples=None, texture_size=None, view_gt=None,
             reuse_base=True):
    """Render scene ``name`` into ``out_dir/name``; return its scene.json dictionary.

    The keyword arguments override the scene's defaults in SCENES (None keeps them). ``view_gt`` also writes
    per-photo ground-truth albedo images in ``gt_views/``.
    """
    spec = resolved_spec(name, resolution=resolution, n_cameras=n_cameras, samples=samples,
                         texture_size=texture_size, view_gt=view_gt)
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
    fine, mid, mesh_info = build_meshes()
    finish_shading(fine)

    # Ground truth texture, then the material that samples that very file.
    n = spec["texture_size"]
    rgba, albedo_info = ground_truth_albedo(fine, n, spec["albedo"])
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
    view_gt = bool(spec.get("view_gt"))
    if view_gt:
        aov = scene.view_layers[0].aovs.add()
        aov.name, aov.type = VIEW_GT_AOV, "COLOR"
        os.makedirs(os.path.join(scene_dir, "gt_views"))

    # Lighting.
    L = spec["lighting"]
    light_info = dict(L)
    light_info["hdri_mapping"] = ("World: Environment Texture (equirectangular, Linear) of "
                                  "<blender>/datafiles/studiolights/world/<hdri>.exr, its vector = Mapping node (type "
                                  "Point, rotation (0, 0, rotation_z_deg)) of the Generated texture coordinate, "
                                  "into a Background node of the given strength")
    sun = None
    if L["kind"] == "sun":
        ld = bpy.data.lights.new("sun", "SUN")
        ld.energy = L["sun_strength"]
        ld.angle = math.radians(L["sun_angle_deg"])
        ld.use_shadow = True
        sun = bpy.data.objects.new("sun", ld)
        scene.collection.objects.link(sun)
        el, az = math.radians(L["sun_elevation_deg"]), math.radians(L["sun_azimuth_deg"])
        to_sun = Vector((math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)))
        sun.matrix_world = look_at(to_sun, (0, 0, 0))
        light_info["direction_to_sun"] = list(to_sun)
        light_info["note"] = ("sun strength in W/m^2 (irradiance), angle = angular diameter; azimuth 0 = towards -Y "
                              "(the face), positive towards +X")
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

        if L["kind"] == "hdri_per_view":
            hk = i % len(L["hdri"])
            hname = L["hdri"][hk]
            strength = L["strength"][hk]
            rot = (i * L["rotation_step_deg"]) % 360.0
        else:
            hname, strength, rot = L["hdri"][0], L["strength"], L["rotation_deg"][0]
        key = (hname, strength, rot)
        if key not in worlds:
            worlds[key] = make_world(hname, strength, rot)
        scene.world = worlds[key]
        seed = spec["seed"] + i
        scene.cycles.seed = seed

        photo_name = cname + ext
        scene.render.filepath = os.path.join(photo_dir, photo_name)
        t0 = time.time()
        bpy.ops.render.render(write_still=True)
        strip_metadata(scene.render.filepath)
        render_times.append(time.time() - t0)
        log(f"{name}: {cname} rendered in {render_times[-1]:.1f} s")
        if view_gt:
            save_view_gt(scene, os.path.join(scene_dir, "gt_views", cname + ".exr"))

        mw = cobj.matrix_world
        r_c2w = np.array(mw.to_3x3().normalized())
        cpos = np.array(mw.translation)
        r_cv = np.diag([1.0, -1.0, -1.0]) @ r_c2w.T
        kb, kc = camera_intrinsics(c["lens_mm"], w, h)
        cam_records.append(dict(
            name=cname, photo="photos/" + photo_name, lens_mm=c["lens_mm"], sensor_width_mm=SENSOR_WIDTH_MM,
            sensor_fit="AUTO", shift=[0.0, 0.0], width=w, height=h,
            matrix_world=np.array(mw, dtype=np.float64).tolist(), location=cpos.tolist(),
            K_blender=kb, K_core=kc, R_core=r_cv.tolist(), t_core=(-r_cv @ cpos).tolist(),
            azimuth_deg=c["azimuth_deg"], elevation_deg=c["elevation_deg"], distance=c["distance"],
            seed=seed, lighting=dict(hdri=hname, strength=strength, rotation_z_deg=rot),
            albedo_view=("gt_views/" + cname + ".exr") if view_gt else None))

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
    bpy.data.meshes.remove(mid)
    mesh_record = _mesh_record(user_mesh, mesh_info, "fine")
    _attach_photos(scene, [c["photo"] for c in cam_records], scene_dir)
    blend_path = os.path.join(scene_dir, "scene.blend")
    _save_blend(blend_path)

    record = dict(
        name=name,
        description=_DESCRIPTIONS[name],
        blender_version=bpy.app.version_string,
        files=dict(blend="scene.blend", albedo_gt="albedo_gt.exr", photos="photos/",
                   gt_views="gt_views/" if view_gt else None),
        mesh=mesh_record,
        albedo_gt=dict(file="albedo_gt.exr", size=[n, n], channels="RGBA", dtype="half",
                       colour="linear Rec.709 (scene linear), not colour managed",
                       rows="row 0 = top = v 1; texel (r, c) centre at u = (c+0.5)/N, v = 1-(r+0.5)/N",
                       alpha="1 where the texel centre is inside a UV triangle, 0 in the padding",
                       padding="texels outside every UV triangle hold the nearest inside texel's value",
                       sampled_with=dict(interpolation=spec["interpolation"], extension="EXTEND",
                                         alpha_mode="CHANNEL_PACKED", colorspace="Linear Rec.709"),
                       **albedo_info),
        material=mat_info,
        lighting=light_info,
        lighting_licence=HDRI_LICENCE,
        render=dict(RENDER_COMMON, samples=spec["samples"], film_transparent=scene.render.film_transparent, seed_base=spec["seed"],
                    seed_rule="view i uses seed seed_base + i", resolution=list(spec["resolution"]),
                    cycles_version=bpy.app.version_string, use_persistent_data=True),
        photo=photo_info,
        gt_views=(dict(folder="gt_views/", channels="RGBA", dtype="half",
                       meaning="per photo, the albedo texture as Cycles sampled it (an AOV of the texture colour, same "
                               "samples and pixel filter as the photo); RGB is premultiplied by A; A = fraction of the "
                               "pixel's samples that hit the mesh, so albedo = RGB / A where A > 0")
                  if view_gt else None),
        cameras=cam_records,
        camera_convention=("matrix_world: Blender camera-to-world (camera looks down -Z, +Y up). K_blender: pixel "
                           "centres at (c+0.5, r+0.5). K_core/R_core/t_core: core.geometry.camera convention (x right, y "
                           "down, z forward; pixel (r, c) centre at (c, r); world X -> R X + t)."),
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
        ok = (tuple(b["render"]["resolution"]) == tuple(want["resolution"]) and len(b["cameras"]) == want["n_cameras"]
              and b["render"]["samples"] == want["samples"] and b["albedo_gt"]["size"][0] == want["texture_size"])
    if not ok:
        generate(base, out_dir, resolution=want["resolution"], n_cameras=want["n_cameras"], samples=want["samples"],
                 texture_size=want["texture_size"])
    with open(base_json) as f:
        b = json.load(f)
    scene_dir = os.path.join(out_dir, name)
    if os.path.isdir(scene_dir):
        shutil.rmtree(scene_dir)
    os.makedirs(scene_dir)
    shutil.copyfile(os.path.join(base_dir, "albedo_gt.exr"), os.path.join(scene_dir, "albedo_gt.exr"))

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    fine, mid, mesh_info = build_meshes()
    coarse, dist = make_coarse(mid, fine)
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
    photos = ["../" + base + "/" + c["photo"] for c in b["cameras"]]
    _attach_photos(scene, photos, scene_dir)
    _save_blend(os.path.join(scene_dir, "scene.blend"))

    mesh_info = dict(mesh_info)
    mesh_info["description"] += (
        "; COARSE: the user's mesh is the Smart-UV level (4x fewer faces than the render mesh) with the head "
        "vertices smoothed (bmesh smooth_vert factor %.2f, %d times; the plinth untouched). Same UV islands as the "
        "render mesh, so albedo_gt.exr applies unchanged" % (COARSE_SMOOTH["factor"], COARSE_SMOOTH["repeat"]))
    record = dict(b)
    record.update(
        name=name, description=_DESCRIPTIONS[name], base_scene=base,
        files=dict(blend="scene.blend", albedo_gt="albedo_gt.exr (a copy of the base scene's)",
                   photos="../%s/photos/ (shared with the base scene, referenced by relative path)" % base),
        mesh=dict(_mesh_record(coarse, mesh_info, "coarse"), coarse_smoothing=COARSE_SMOOTH,
                  distance_to_render_mesh=dist, render_mesh=b["mesh"]),
    )
    record["cameras"] = [dict(c, photo="../" + base + "/" + c["photo"],
                              albedo_view=("../" + base + "/" + c["albedo_view"]) if c.get("albedo_view") else None)
                         for c in b["cameras"]]
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
}


def _mesh_record(me, info, which):
    return dict(info, object=MESH_OBJECT, mesh=me.name, which=which, vertices=len(me.vertices),
                faces=len(me.polygons), triangles=len(me.loop_triangles) or None, uv_map=me.uv_layers.active.name,
                shading="smooth, sharp edges from angle 60 deg", units="metres, object at the origin, +Z up, "
                "Suzanne faces -Y")


def _attach_photos(scene, rel_photos, scene_dir):
    cams = sorted([o for o in scene.objects if o.type == "CAMERA"], key=lambda o: o.name)
    for cobj, rel in zip(cams, rel_photos):
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
    p.add_argument("--view-gt", action="store_true", default=None,
                   help="also write per-photo ground-truth albedo images (default: lambert_sky only)")
    a = p.parse_args(argv)
    names = a.only or list(SCENES)
    for name in names:
        generate(name, a.out, resolution=a.resolution, n_cameras=a.cameras, samples=a.samples,
                 texture_size=a.texture_size, view_gt=a.view_gt, reuse_base=True)


if __name__ == "__main__":
    main(sys.argv[1:])
