"""What a solve takes and what it gives: :class:`SolverParams` and :class:`Result`.

The parameters' defaults were chosen by albedo error against the ground truth of many rendered scenes, not by
energy (``docs/measurements.md``); :meth:`SolverParams.check` says what is out of range.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["SolverParams", "Result"]


@dataclass
class SolverParams:
    """Parameters of a solve (:func:`core.solve.stages.solve`, :func:`core.solve.solver.solve_joint`).

    Attributes
    ----------
    domain : {"texture", "image"}
        Where the reflectance lives: on the texels of the UV map, or in one map
        per view as in the paper.
    lam, mu : float
        Weights of the TV and of the multi-view consistency term (image domain).
    delta : float
        Huber parameter.
    max_iter, min_iter : int
        Bounds on the outer iterations (the stopping test is skipped before
        ``min_iter``, so a warm start cannot stop the loop at once).
    tol : float
        Stop when the relative energy change falls below it.
    cg_iter : int or None
        CG iterations per rho-step; None: 10 with the multigrid
        preconditioner, 30 with Jacobi.
    preconditioner : {"auto", "multigrid", "jacobi"}
        Of the rho-step's CG (:mod:`core.solve.multigrid`). "auto" is multigrid in
        the image domain, where the correspondences make the step stiff, and
        Jacobi in the texture domain, where a better solved step did not cut
        the outer iterations (docs/measurements.md).
    gauss_newton : bool
        Add a joint Gauss-Newton step on rho and sigma to each iteration
        (:func:`core.solve.gauss_newton.gauss_newton_step`); about 3x the cost of an iteration.
    data_model : {"nearest", "splat", "interpolate"}
        Texture domain: how a pixel sees the texels (:mod:`core.solve.discretization`); "nearest" is
        the splat where the photos have too few pixels per texel
        (:func:`core.solve.discretization.data_model_for`).
    precision : {"float32", "float64"}
        Working precision of rho and the CG.
    levels, coarse_iter : int
        Both domains: solve first on up to ``levels - 1`` coarser copies (every
        other pixel each, and half the texture in the texture domain; see
        :func:`core.solve.pyramid.coarsen`), ``coarse_iter`` iterations at most on
        each, and start each level from the one below (rho sampled
        bilinearly from it, sigma as it is).
    threads : int or None
        Threads the solve uses (the sparse products and NumPy's large array
        operations release the GIL): the colour channels are solved at once,
        up to this many in threads. None: every core, one thread per channel.
        The result does not depend on the number.
    extrapolate : float
        After each iteration, try ``rho + extrapolate * (rho - rho_before)``
        and keep it if it lowers the energy (0 never tries): MM creeps along
        a steady direction, and this follows it further at the cost of one
        energy evaluation.
    max_texels_per_pixel : float
        Texture domain: when the texture has more seen texels than this many
        per photo pixel on the mesh, solve on a texture halved until it has
        not, and sample the result bilinearly back up (0 never does).
    lighting : {"per_view", "shared", "coupled", "fixed"}
        The sigma-step's model (:mod:`core.solve.lighting`): 9 free SH
        coefficients per view and channel (the paper); one world lighting
        shared by all views, times a gain per view and channel (exposure and
        white balance); per view, held to such a shared lighting by a
        quadratic prior of weight ``coupling``; or no sigma-step (the
        lighting given).
    coupling : float
        Weight of the prior of ``lighting="coupled"``, in units of the data
        term (:class:`core.solve.lighting.Coupling`).
    albedo_lam : float or None
        None: one stage, as the paper. A number: two stages
        (:func:`core.solve.stages.solve_two_stage`): the lighting is
        estimated with ``lam``, then the albedo solved again with that
        lighting fixed and this TV weight. ``lam``'s default is the one-stage
        solve's; where :mod:`core.pipeline` picks it for two stages it is
        :data:`core.solve.lambda_choice.LIGHT_LAMBDA`.
    albedo_adapt : bool
        Two stages, texture domain: ``albedo_lam`` scaled by how much fine colour texture the photos show and
        how sparse its changes are (:func:`core.solve.albedo_weight.adapted_albedo_lam`); False: as given.
    light_size : int
        Two stages: the largest texture the lighting stage solves on (0: the
        problem's own).
    light_pixels : float
        Two stages, texture domain: while the lighting stage's texture has more than this many photo pixels on
        the mesh per texel, it keeps every other pixel of every other row (:func:`core.solve.pyramid.coarsen`);
        0 keeps them all.
    light_balance : float
        Two stages, texture domain: the lighting stage weighs each pixel by its view weight times
        ``(m / W) ** light_balance``, W the view weight of all the pixels on its texel and m the median of W
        over the texels (within 1/4 to 4 times; :func:`core.solve.stages.balanced_for_lighting`), so that the
        surface the photos see only at a glancing angle (mostly facing away from the cameras) counts for more
        in the lighting than its few pixels would make it; 0: each pixel by its view weight alone.
    light_extrapolate : float
        Two stages: ``extrapolate`` in the lighting stage. Its MM alternates the albedo and the lighting and runs
        to its iteration caps, where a longer step along the albedo's direction pays; the albedo stage (a convex
        problem under a fixed lighting) keeps ``extrapolate`` (docs/measurements.md).
    light_data_model : {"nearest", "splat", "interpolate"}
        Two stages, texture domain: the lighting stage's data model (see
        ``data_model``); "nearest" gives each pixel one observation, of its
        nearest texel, a quarter of the splats' work.
    light_edges : float
        Two stages, texture domain: when > 0, the lighting stage is run again
        with its TV rows weighted down across the albedo edges it found
        (:func:`core.solve.edges.reweighted_lighting`; this is the edge scale
        relative to the median of the albedo's chromaticity); 0 skips it.
    light_edge_passes : int
        How many times at most that run is made, each with the edges of the albedo the one before found
        (reweighted L1 in passes): the albedo of each pass shows the changes of colour more sharply. The passes
        stop at one that settles quickly (:data:`core.solve.stages.EDGE_PASS_SETTLED`; docs/measurements.md).
    light_tilts, light_tilt_iter : int
        Two stages, texture domain: after the lighting stage's first run, each channel is restarted from its
        shading tilted along the albedo-lighting ambiguity in ``1 + 2 * light_tilts`` ways, each iterated
        ``light_tilt_iter`` times, and the lowest energy is kept (:func:`core.solve.ambiguity.tilt_search`);
        0 tilts skips it.
    light_tilt_rounds : tuple of (int, int)
        Under one light (not ``lighting="per_view"``), before the lowest energy is kept, the search's ends are
        narrowed in rounds: in each ``(keep, iterations)``, the ``keep`` ends of lowest energy are iterated
        ``iterations`` more times, so that a tilted start is judged nearer its own minimum; () skips it. An
        end stops early where its energy has stopped falling (``tol``), and no end is iterated more than
        ``max_iter`` times in all.
    light_tilt_entropy : float
        Under one light, of the last round's ends within :data:`core.solve.ambiguity.ENTROPY_WINDOW` of the
        lowest energy (and no higher than the search's start), the one whose albedo has the least entropy
        (:func:`core.solve.ambiguity.albedo_entropy`, its log smoothed by this width) is kept: their energies are
        often within a per cent, where the albedo's fewer distinct values pick the better end more often than
        the energy does (docs/measurements.md). 0 keeps the lowest energy.
    albedo_edges : float
        Texture domain, lighting fixed (:func:`core.solve.stages.solve_albedo`,
        the albedo stage): when > 0, each TV row is weighted by
        :func:`core.solve.edges.edge_weights` of the albedo's start (the photos
        divided by the shading) with this edge scale, so TV smooths what is left
        of the shading inside regions of one colour and spares the changes of
        colour; 0: plain TV.
    albedo_debias : float
        Texture domain, the albedo stage: at a TV weight of at least this, the albedo is solved once more from
        its result, each TV row weighted by :func:`core.solve.edges.edge_weights` of that result's colour and
        brightness (the edge scale ``albedo_edges``): a strong TV lowers the height of every change it keeps,
        and the regions so freed take their level from the photos (docs/measurements.md). 0, or
        ``albedo_edges`` 0: never.
    """

    domain: str = "texture"
    lam: float = 5.0
    mu: float = 10.0
    delta: float = 1e-3
    max_iter: int = 50
    min_iter: int = 5
    tol: float = 1e-4
    cg_iter: int | None = None
    normalise_correspondences: bool = True
    threads: int | None = None
    gauss_newton: bool = False
    data_model: str = "nearest"
    precision: str = "float32"
    levels: int = 4
    coarse_iter: int = 100
    max_texels_per_pixel: float = 2.0
    extrapolate: float = 1.0
    preconditioner: str = "auto"
    lighting: str = "per_view"
    coupling: float = 10.0
    albedo_lam: float | None = None
    albedo_adapt: bool = True
    light_size: int = 128
    light_pixels: float = 64.0
    light_balance: float = 0.5
    light_edges: float = 0.003
    light_edge_passes: int = 8
    light_tilts: int = 6
    light_tilt_iter: int = 5
    light_tilt_rounds: tuple = ((4, 15), (2, 30))
    light_tilt_entropy: float = 0.1
    light_data_model: str = "nearest"
    light_extrapolate: float = 2.0
    albedo_edges: float = 0.002
    albedo_debias: float = 40.0

    def resolved(self) -> SolverParams:
        """These parameters with "auto" and None replaced by what they stand for."""
        pre = self.preconditioner
        if pre == "auto":
            pre = "multigrid" if self.domain == "image" else "jacobi"
        cg = self.cg_iter if self.cg_iter is not None else (10 if pre == "multigrid" else 30)
        return replace(self, preconditioner=pre, cg_iter=cg)

    def check(self):
        if self.domain not in ("texture", "image"):
            raise ValueError(f"solver: domain must be 'texture' or 'image', got {self.domain!r}")
        if self.preconditioner not in ("auto", "jacobi", "multigrid"):
            raise ValueError(
                f"solver: preconditioner must be 'auto', 'jacobi' or 'multigrid', got {self.preconditioner!r}"
            )
        for name in ("data_model", "light_data_model"):
            if getattr(self, name) not in ("interpolate", "splat", "nearest"):
                raise ValueError(
                    f"solver: {name} must be 'interpolate', 'splat' or 'nearest', got {getattr(self, name)!r}"
                )
        for name in (
            "lam",
            "mu",
            "delta",
            "coupling",
            "extrapolate",
            "light_extrapolate",
            "max_texels_per_pixel",
            "light_edges",
            "albedo_edges",
            "albedo_debias",
            "light_pixels",
            "light_balance",
            "light_tilt_entropy",
        ):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"solver: {name} must be finite and >= 0, got {v}")
        for name in (
            "max_iter",
            "min_iter",
            "levels",
            "coarse_iter",
            "light_size",
            "light_edge_passes",
            "light_tilts",
            "light_tilt_iter",
            "cg_iter",
            "threads",
        ):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer))):
                raise ValueError(f"solver: {name} must be a whole number, got {v!r}")
        if self.delta <= 0:
            raise ValueError("solver: delta must be > 0")
        if self.max_iter < 1 or (self.cg_iter is not None and self.cg_iter < 1):
            raise ValueError("solver: max_iter and cg_iter must be >= 1")
        if self.levels < 1 or self.coarse_iter < 1:
            raise ValueError("solver: levels and coarse_iter must be >= 1")
        if self.lighting not in ("per_view", "shared", "coupled", "fixed"):
            raise ValueError(
                f"solver: lighting must be 'per_view', 'shared', 'coupled' or 'fixed', got {self.lighting!r}"
            )
        if self.albedo_lam is not None and (not np.isfinite(self.albedo_lam) or self.albedo_lam < 0):
            raise ValueError(f"solver: albedo_lam must be None or finite and >= 0, got {self.albedo_lam}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"solver: threads must be None or >= 1, got {self.threads}")
        if self.light_size < 0:
            raise ValueError(f"solver: light_size must be >= 0, got {self.light_size}")
        if self.light_edge_passes < 1:
            raise ValueError(f"solver: light_edge_passes must be >= 1, got {self.light_edge_passes}")
        if self.light_tilts < 0 or self.light_tilt_iter < 1:
            raise ValueError(
                f"solver: light_tilts must be >= 0 and light_tilt_iter >= 1, got {self.light_tilts}, "
                f"{self.light_tilt_iter}"
            )
        if not all(
            isinstance(r, (tuple, list))
            and len(r) == 2
            and all(isinstance(x, (int, np.integer)) for x in r)
            and r[0] >= 1
            and r[1] >= 0
            for r in self.light_tilt_rounds
        ):
            raise ValueError(
                f"solver: light_tilt_rounds must be pairs (keep >= 1, iterations >= 0), got {self.light_tilt_rounds}"
            )


@dataclass
class Result:
    """Output of a solve (:func:`core.solve.stages.solve`, :func:`core.solve.solver.solve_joint`).

    Attributes
    ----------
    sigma : (m, C, 9) array
        Lighting per view and channel.
    views : list of (H, W, C) float32 arrays, or None
        Reflectance seen through each view, NaN outside its mask (None from :func:`solve` with ``views``
        False, texture domain).
    energy : list of float
        Energy at the finest level, before iteration 1 (at the warm start
        when there are coarse levels) and after each iteration (before the
        final rescaling); coarse levels are in ``info``.
    iterations : int
        Outer iterations done at the finest level.
    texture : (N, N, C) float32 array or None
        Texture domain: the albedo texture, NaN on texels no pixel saw (None when solved smaller and not
        scaled up: ``scale_up`` False).
    seen : (N, N) bool array or None
        Texture domain: texels with data.
    solved : tuple or None
        Texture domain, when the texture was solved smaller (``info["solved_size"]``) than N:
        the ``(texture, seen)`` it was solved as. Fill and fuse there (:func:`core.texture.fill.fill_scaled_up`):
        the larger texture's texels between the solved ones carry no data of their own.
    """

    sigma: np.ndarray
    views: list | None
    energy: list
    iterations: int
    texture: np.ndarray | None = None
    seen: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    solved: tuple | None = None
