"""The bpy-free middle of a run: problem -> solve -> fuse, on the scene as arrays.

The Blender layer reads the scene and bakes it (:mod:`core.scene`, :mod:`core.geometry.bake`), calls
:func:`compute`, and writes the results. :func:`compute` never touches bpy, so it can run in a worker thread.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .geometry.raycast import Triangles
from .geometry.texels import texture_layout
from .masks import masked
from .memory import peak_mb
from .options import OPTIONS, Options
from .parallel import blas_on_one_thread, joined, start, thread_map
from .photo_levels import PHOTO_LEVEL, channel_gains, with_gains
from .plan import (
    DEFAULTS,
    DETAIL_MIN_COLOUR_TEXTURE,
    FLAT_ALBEDO_PIXELS,
    flat_albedo,
    light_size,
    runs_detail,
    schedule,
    solve_parts,
    spans_without_detail,
    wants_detail,
)
from .progress import check_cancel, piecewise, shares, stage_progress, sub_progress
from .scene import SceneInputs
from .solve.albedo_weight import colour_measures
from .solve.params import SolverParams
from .solve.problem import Problem, row_blocks
from .solve.pyramid import seen_onto
from .solve.stages import LIGHTING_SHARE, albedo_stage, lighting_stage, solve
from .texture import fill_scaled_up, fuse_views, outline_only, sample_texture

# Options, stage_progress and check_cancel live in core.options and core.progress; they are importable from
# here too.
__all__ = [
    "DEFAULTS",
    "METHODS",
    "Options",
    "Computed",
    "compute",
    "peak_mb",
    "LIGHTING_PIXELS",
    "stage_progress",
    "check_cancel",
]

METHODS = OPTIONS["method"].values


@dataclass
class Computed:
    """The results as arrays (output of :func:`compute`)."""

    albedo: np.ndarray  # (N, N, C) filled texture, row 0 at the top
    seen: np.ndarray  # (N, N) bool
    views: list  # per view (H, W, C) reflectance
    sigma: np.ndarray | None  # (m, C, 9) lighting (10 with the sun term: info["sun"]), None for "project"
    energy: list
    iterations: int
    info: dict = field(default_factory=dict)

    @property
    def sun_direction(self):
        """The direction towards the sun when the lighting has the sun's term (``info["sun"]``), else None."""
        sun = self.info.get("sun") or {}
        return sun.get("direction") if sun.get("used") else None


def _layout(mesh, n):
    return texture_layout(mesh.tri_uv, mesh.tri_pos, mesh.tri_vert, n)


#: The lighting stage's layout is the mesh's UV map rasterised at this size (the default texture's), then
#: coarsened to the stage's own (SolverParams.light_size), whatever the texture's size. A UV island is about a
#: texel wider than its triangles at every size, so coarsened from the texture's own layout, the stage's texels
#: at the islands' borders came and went with the texture size, and the lighting, the colour texture and the
#: albedo's weight with them (photo_sun's weight 32 at a 256² texture, 16.5 at 1024²; docs/measurements.md).
LIGHT_LAYOUT_SIZE = 1024


def _layouts(mesh, n, light_n):
    """The texture's layout, and the lighting stage's where it coarsens the texture and that is not the same
    (not for a lighting stage of LIGHT_LAYOUT_SIZE or more, which keeps the texture's)."""
    coarsens = 0 < light_n < min(n, LIGHT_LAYOUT_SIZE)
    light = _layout(mesh, LIGHT_LAYOUT_SIZE) if coarsens and n != LIGHT_LAYOUT_SIZE else None
    return _layout(mesh, n), light


def _unclipped(mask, clipped):
    """The mask without the clipped pixels, unless that leaves nothing (or nothing is known)."""
    if clipped is None:
        return mask
    keep = mask & ~clipped
    return keep if keep.any() else mask


#: With the detail stage, the most pixels on the mesh (all photos together) the lighting stage is solved on: a
#: lighting of 9 numbers per channel on a texture of at most 128^2 needs no more, and the solve's time and memory
#: grow with its pixels.
LIGHTING_PIXELS = 8_000_000


def _thinned(masks, budget):
    """The masks keeping every k-th pixel of every k-th row, k the least that leaves about ``budget`` pixels."""
    total = sum(int(np.count_nonzero(m)) for m in masks)
    if total <= budget:
        return masks
    k = int(np.ceil(np.sqrt(total / budget)))
    out = []
    for m in masks:
        t = np.zeros_like(m)
        t[::k, ::k] = m[::k, ::k]
        out.append(t if t.any() else m)
    return out


def _lighting_only(result, texture):
    """The two-stage solve's lighting stage as the run's result, before the detail stage: its albedo as solved
    in ``result.solved`` (the fuse scales it up to the full texture, :func:`core.texture.fill.fill_scaled_up`),
    ``result.texture`` None.

    The detail stage makes the albedo again from the full photos, so the working resolution's albedo stage
    would only give it a prior and a fallback: the lighting stage's albedo, scaled up, serves as well (measured
    on the fixtures) and saves the albedo stage's time and memory. The problem's masks are thinned to
    :data:`LIGHTING_PIXELS` (:func:`_thinned`) by the caller.
    """
    result.solved, result.texture, result.seen = (result.texture, result.seen), None, None
    result.info["lighting_only"] = True
    result.info["colour_texture"] = texture
    return result


#: The sun search's settings (core.geometry.sun.find_sun): 200 candidates on 128² shadow maps, at most 20 000
#: pairs of pixels; 1-4 s on the fixtures, within 1-7 degrees where the sun casts shadows (docs/measurements.md).
SUN_SEARCH = {"n_directions": 200, "max_pairs": 20000, "resolution": 128}


def _transfer(bakes, masks, cells, sun, threads=None) -> list:
    """Per view, the transfer of its masked pixels (:func:`core.geometry.transfer.transfer_rows`), as
    consecutive row blocks of one array (:func:`core.solve.problem.row_blocks`), which the solver uses uncopied.
    """
    from .geometry.transfer import transfer_rows

    k = (9 if cells is None else cells.occ.shape[1]) + (sun is not None)
    transfer = row_blocks([int(np.count_nonzero(m)) for m in masks], k)

    def fill(v):
        b, m = bakes[v], masks[v]
        transfer_rows(
            masked(b.normal, m),
            masked(b.uv, m),
            cells,
            sun,
            None if sun is None else masked(b.position, m),
            out=transfer[v],
        )

    thread_map(fill, range(len(masks)), threads)
    return transfer


def _occlusion(occluders, bakes, opt, progress):
    """The occlusion transfer on its UV grid (:func:`core.geometry.transfer.occlusion_grid`), and its seconds."""
    from .geometry.transfer import occlusion_grid

    progress(0.0, "occlusion")
    t = time.perf_counter()
    cells = occlusion_grid(
        occluders,
        [b.uv for b in bakes],
        [b.mask for b in bakes],
        [b.normal for b in bakes],
        [b.position for b in bakes],
        [b.view_weight for b in bakes],
        threads=opt.threads,
    )
    return cells, time.perf_counter() - t


def _lighting_choice(problem, opt, progress):
    """``(lam, variation, lighting)``: the options', with "auto" (None for lambda) decided from the photos.

    ``variation`` is :func:`core.solve.lambda_choice.lighting_variation` where measured, else None.
    """
    from .solve.lambda_choice import LIGHT_LAMBDA, auto_lambda, describe_lambda
    from .solve.lighting import choose_lighting

    lam, variation, lighting = opt.lam, None, opt.lighting
    if lam is None or lighting == "auto":
        auto, variation = auto_lambda(problem)
        if lam is None:
            # With two stages the lighting stage wants a strong TV whatever the light does.
            lam = LIGHT_LAMBDA if opt.albedo_lam is not None else auto
            progress(0.0, describe_lambda(lam, variation, auto=True))
        if lighting == "auto":
            lighting = choose_lighting(variation)
    return lam, variation, lighting


def _find_sun(photos, masks, occluders, bakes, lighting, opt, progress):
    """The sun, found from the photos (option ``sun``), whose term becomes the transfer's last column.

    Returns the :class:`core.geometry.sun.SunLight` (None when not used) and a summary for the report. A light
    that moves between the photos (``lighting`` ``per_view``) gets no sun; under the other models the sun is one
    world light (:class:`core.solve.lighting.Coupling`, ``shared_lighting_step``).
    """
    from .geometry.sun import SunLight, SunNotFound, find_sun

    if lighting == "per_view":
        progress(0.0, "sun shadows: off, the light changes between the photos")
        return None, {"used": False, "reason": "the light changes between the photos"}
    progress(0.0, "finding the sun")
    t0 = time.perf_counter()
    try:
        found = find_sun(
            photos,
            masks,
            [b.position for b in bakes],
            [b.normal for b in bakes],
            occluders,
            threads=opt.threads,
            **SUN_SEARCH,
        )
    except SunNotFound as e:  # too few pixels to tell where it is: solve without it, and say so
        progress(0.0, f"sun shadows: off, {e}")
        return None, {"used": False, "reason": str(e)}
    sun = SunLight(found.direction, occluders)
    info = {
        "used": True,
        "direction": [float(x) for x in found.direction],
        "correlation": found.score,
        "seconds": time.perf_counter() - t0,
    }
    progress(0.0, f"sun towards ({', '.join(f'{x:.2f}' for x in found.direction)}), found in {info['seconds']:.0f} s")
    return sun, info


def _detail(inputs, bakes, masks, sigma, albedo, inside, cells, sun, occluders, opt, progress, cancel, stages):
    """The detail stage (:func:`core.texture.detail.detail_albedo`) on every view at its own resolution.

    ``occluders``: the mesh as shared vertices, if the shadows made it (None: the stage makes it).
    """
    from .texture.detail import agreement, detail_albedo, shading_floors, view_shadings

    report = stage_progress(progress, "detail", stages)
    report(0.0, "lighting at the working resolution")
    normals, uvs, positions = [b.normal for b in bakes], [b.uv for b in bakes], [b.position for b in bakes]
    photos = [v.photo for v in inputs.views]
    shades = view_shadings(sigma, normals, uvs, masks, cells, sun, positions, opt.threads)
    floor = shading_floors(shades, photos, masks)
    weights = [b.view_weight for b in bakes]
    clipped = None if opt.mask_clipped else [v.clipped for v in inputs.views]
    agree = agreement(photos, masks, uvs, shades, weights, floor, clipped, opt.threads)
    del shades
    views = inputs.views

    def load(i):
        v = views[i]
        return v.full.load() if v.full is not None else (v.photo, v.clipped)

    cameras = [v.full.camera if v.full is not None else v.camera for v in views]
    return detail_albedo(
        inputs.mesh,
        cameras,
        load,
        sigma,
        albedo,
        inside,
        floor,
        weights=agree,
        cells=cells,
        sun=sun,
        use_clipped=bool(opt.mask_clipped),
        progress=report,
        cancel=cancel,
        outlines=bool(opt.fill_outlines),
        threads=opt.threads,
        shared=occluders,
    )


@blas_on_one_thread()
def compute(
    options: Options,
    inputs: SceneInputs,
    bakes: list,
    times: dict | None = None,
    progress=None,
    cancel=None,
    peaks: dict | None = None,
    stages: dict | None = None,
) -> Computed:
    """Build the problem, solve and fuse (pure arrays; safe in a worker thread).

    ``times`` (if given) receives the seconds spent in "solve", "fuse" and "detail"; ``peaks`` the process's
    peak memory (:func:`peak_mb`) at the end of each, and of "occlusion" (part of the solve). ``stages`` is the
    progress bar's spans (:func:`schedule`, by default of ``options`` and ``inputs``). The detail stage
    (:mod:`core.texture.detail`) runs when :func:`uses_detail` and some view has its photo at full resolution
    (``ViewInput.full``); it replaces the albedo, and the texture method's per-view maps are sampled from it.
    With it, a two-stage texture solve stops after its lighting stage (:func:`_lighting_stage`).

    Raises
    ------
    Cancelled
        ``cancel()`` returned True.
    ValueError
        From the core, for inconsistent arrays.
    """
    opt = options
    times = {} if times is None else times
    peaks = {} if peaks is None else peaks
    occlusion_s = None
    n = int(opt.texture_size)
    masks = [b.mask for b in bakes]
    gains = None
    if opt.method != "project":
        gains = channel_gains([v.photo for v in inputs.views], masks, PHOTO_LEVEL)
        inputs = with_gains(inputs, gains)
    photos = [v.photo for v in inputs.views]
    solve_masks = masks
    if opt.mask_clipped and opt.method != "project":
        solve_masks = [_unclipped(m, v.clipped) for m, v in zip(masks, inputs.views)]
    uvs = [b.uv for b in bakes]
    weights = [b.view_weight for b in bakes]
    detail = runs_detail(opt, inputs)
    # With the detail stage a two-stage texture solve stops after its lighting stage, on fewer pixels.
    lighting_only = detail and opt.method == "texture" and opt.albedo_lam is not None
    light_masks = _thinned(solve_masks, LIGHTING_PIXELS) if lighting_only else solve_masks
    stages = schedule(opt, inputs) if stages is None else stages
    solve_progress = stage_progress(progress, "solve", stages)
    parts = shares(solve_parts(opt, inputs))

    t = time.perf_counter()
    solve_progress(0.0, "building the problem")
    # The layout (one core) is made while the occlusion, the lighting's choice and the sun search use the others.
    # A run that fails or is cancelled before that waits for it: no thread outlives the run.
    light_n = light_size(opt) if opt.method == "texture" else 0
    with joined(start(_layouts, inputs.mesh, n, light_n, threads=opt.threads)) as layout_job:
        correspondences = None
        if opt.method == "image":
            from .geometry.correspondences import find_correspondences

            correspondences = find_correspondences(
                [v.camera for v in inputs.views], [b.position for b in bakes], solve_masks, [b.normal for b in bakes]
            )
            check_cancel(cancel)
        cells = sun = sun_info = None
        # The shadow casters as shared vertices: each cast projects a vertex once, not once per triangle.
        occluders = None
        if opt.method != "project" and (opt.occlusion or opt.sun):
            occluders = Triangles.of(inputs.mesh.tri_pos, inputs.mesh.tri_vert)
        if opt.occlusion and opt.method != "project":
            cells, occlusion_s = _occlusion(occluders, bakes, opt, sub_progress(solve_progress, *parts["occlusion"]))
            peaks["occlusion"] = peak_mb()
            check_cancel(cancel)
        problem = Problem(
            images=photos,
            masks=light_masks,
            normals=[b.normal for b in bakes],
            correspondences=correspondences,
            uv=uvs,
            view_weight=weights,
            names=[v.name for v in inputs.views],
            clipped=[v.clipped for v in inputs.views],
        )
        result = None
        lam, variation, lighting = opt.lam, None, opt.lighting
        if opt.method != "project":
            problem_progress = sub_progress(solve_progress, *parts["problem"])
            lam, variation, lighting = _lighting_choice(problem, opt, problem_progress)
            if opt.sun:
                # On every pixel, not the lighting stage's thinned ones: the search compares neighbouring pixels.
                sun, sun_info = _find_sun(photos, solve_masks, occluders, bakes, lighting, opt, problem_progress)
                check_cancel(cancel)
        layout, light_layout = layout_job.result()
    check_cancel(cancel)
    if opt.method == "texture":
        problem = problem.on_layout(layout)
        problem.light_texture = light_layout  # (on_layout's copy)
    if opt.method != "project":
        if cells is not None or sun is not None:
            problem = replace(problem, transfer=_transfer(bakes, light_masks, cells, sun, opt.threads))
        params = SolverParams(
            **dict(
                opt.solver or {},
                domain=opt.method,
                lam=float(lam),
                mu=float(opt.mu),
                max_iter=int(opt.max_iter),
                albedo_lam=opt.albedo_lam,
                albedo_adapt=bool(opt.albedo_adapt),
                lighting=lighting,
                threads=opt.threads,
            )
        )
        (first, lit), (_, last) = parts["lighting"], parts["albedo"]

        def flat_problem(texture):
            """The problem on at most FLAT_ALBEDO_PIXELS for a flat albedo's stage (None: the problem as it is)."""
            if not flat_albedo(texture):
                return None
            masks = _thinned(solve_masks, FLAT_ALBEDO_PIXELS)
            if masks is light_masks:
                return None
            transfer = None if cells is None and sun is None else _transfer(bakes, masks, cells, sun, opt.threads)
            return replace(problem, masks=masks, transfer=transfer)

        if lighting_only:
            t_light = time.perf_counter()
            light_problem, lit_result = lighting_stage(
                problem, params, sub_progress(solve_progress, first, last), cancel
            )
            measures = colour_measures(light_problem, lit_result.sigma)
            texture = measures[0]
            if wants_detail(opt, texture):
                result = _lighting_only(lit_result, texture)
            else:
                # A flat albedo: the albedo stage at the working resolution in place of the detail stage.
                detail = lighting_only = False
                stages, span = spans_without_detail(opt, inputs, stages)
                albedo_progress = sub_progress(progress, *span, "solve")
                albedo_progress(
                    0.0,
                    f"detail stage: off, the albedo is flat (colour texture {texture:.3f}, detail from "
                    f"{DETAIL_MIN_COLOUR_TEXTURE:g}); the albedo at the working resolution",
                )
                result = albedo_stage(
                    flat_problem(texture) or problem,
                    light_problem,
                    lit_result,
                    params,
                    sub_progress(albedo_progress, 0.0, 1.0, "albedo"),
                    cancel,
                    views=False,
                    scale_up=False,
                    started=t_light,
                    measures=measures,
                )
            light_problem = lit_result = None
        else:
            # The two-stage solve's own shares of its bar redrawn to the parts'.
            points = [(0.0, first), (LIGHTING_SHARE, lit), (1.0, last)] if opt.albedo_lam is not None else None
            solve_report = piecewise(solve_progress, points) if points else sub_progress(solve_progress, first, last)
            # The texture's per-view maps are sampled from the filled albedo below, not the solve's; a texture
            # solved smaller is filled there, then scaled up (below).
            on_texels = opt.method == "texture"
            result = solve(
                problem,
                params,
                progress=solve_report,
                cancel=cancel,
                views=not on_texels,
                scale_up=not on_texels,
                albedo_problem=flat_problem if on_texels else None,
            )
    times["solve"], peaks["solve"] = time.perf_counter() - t, peak_mb()
    check_cancel(cancel)

    t = time.perf_counter()
    fuse_progress = stage_progress(progress, "fuse", stages)
    fuse_progress(0.0, "texture")
    outline = None
    if opt.method == "texture":
        # Filled at the size it was solved at, where its texels hold the data; then scaled up.
        texture, solved_seen = result.solved if result.solved is not None else (result.texture, result.seen)
        solved_seen = np.asarray(solved_seen, dtype=bool)
        known = solved_seen
        if opt.fill_outlines:
            outline = outline_only(uvs, masks, weights, solved_seen, used=solve_masks)
            known = solved_seen & ~outline
        albedo = fill_scaled_up(texture, known if known.any() else solved_seen, layout.inside, 4, opt.threads)
        seen = None  # the detail stage's
        if not lighting_only:
            seen = solved_seen if result.solved is None else seen_onto(solved_seen, layout.inside)
    else:
        # Image domain: fuse the per-view reflectance; project: the photos themselves.
        maps = result.views if result is not None else problem.images
        fused = fuse_views(maps, problem.masks, uvs, n, view_weight=weights, inside=layout.inside, margin=4)
        albedo, seen = fused[..., :-1], fused[..., -1] > 0
        views = list(maps)
    times["fuse"], peaks["fuse"] = time.perf_counter() - t, peak_mb()
    fuse_progress(1.0, "done")
    check_cancel(cancel)

    if detail:
        # Let the solve's arrays go that the stage does not need: it is to hold the texture and one photo.
        problem = None
        result.texture = None
        t = time.perf_counter()
        albedo, seen = _detail(
            inputs,
            bakes,
            solve_masks,
            result.sigma,
            albedo,
            layout.inside,
            cells,
            sun,
            occluders,
            opt,
            progress,
            cancel,
            stages,
        )
        times["detail"], peaks["detail"] = time.perf_counter() - t, peak_mb()
        check_cancel(cancel)
    if gains is not None:
        albedo = albedo / gains
    if opt.method == "texture":
        views = thread_map(lambda v: sample_texture(albedo, uvs[v], masks[v]), range(len(uvs)), opt.threads)
    elif gains is not None:
        views = [v / gains for v in views]
    return Computed(
        albedo=np.asarray(albedo, dtype=np.float32),
        seen=seen,
        views=views,
        sigma=None if result is None else np.asarray(result.sigma),
        energy=[] if result is None else [float(e) for e in result.energy],
        iterations=0 if result is None else int(result.iterations),
        info={}
        if result is None
        else dict(
            result.info,
            lam=lam,
            lighting_variation=variation,
            albedo_lam=result.info.get("albedo_lam", opt.albedo_lam),
            lighting_mode=lighting,
            occlusion=bool(opt.occlusion),
            occlusion_seconds=occlusion_s,
            detail=detail,
            outline_texels=0 if outline is None else int(outline.sum()),
            channel_gains=None if gains is None else [float(g) for g in gains],
            **({} if sun_info is None else {"sun": sun_info}),
        ),
    )
