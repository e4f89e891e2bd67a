import numpy as np
import pytest

from core.evaluate.synthetic import sphere_scene
from core.solve.discretization import texture_domain
from core.solve.edges import edge_weights
from core.solve.lighting import shading_error
from core.solve.solver import SolverParams, solve


def test_edge_weights_free_the_changes_of_colour_and_hold_those_of_brightness():
    scene = sphere_scene(n_views=4, height=60, width=80, texture_size=32, n_cells=6, seed=1)
    d = texture_domain(scene.problem)
    col = d.texel_index % 32
    # Three bands: a colour, the same colour in shadow (40 % as bright), another hue.
    rho = np.where(
        (col < 11)[:, None], [0.5, 0.3, 0.2], np.where((col < 22)[:, None], [0.2, 0.12, 0.08], [0.2, 0.3, 0.5])
    )
    w = edge_weights(d, rho, 0.003)
    band = np.digitize(col, [11, 22])
    ends = [np.asarray(m.argmax(axis=1)).ravel() for m in (d.B > 0, d.B < 0)]  # each row's two texels
    lo, hi = np.minimum(band[ends[0]], band[ends[1]]), np.maximum(band[ends[0]], band[ends[1]])
    shadow, hue = (lo == 0) & (hi == 1), (lo == 1) & (hi == 2)
    assert shadow.sum() > 10 and hue.sum() > 10
    assert np.all((w > 0) & (w <= 1))
    assert np.all(w[lo == hi] > 0.99)  # flat
    assert np.all(w[shadow] > 0.99)  # brightness alone: held by TV
    assert np.all(w[hue] < 0.05)  # a new hue: freed
    # Relative to the albedo's scale: the same weights for the albedo at any scale.
    np.testing.assert_allclose(edge_weights(d, 3.0 * rho, 0.003), w, rtol=1e-5)


def test_the_lighting_stage_with_its_edges_freed_finds_a_better_lighting():
    # Six flat cells under one light: the strong TV of the lighting stage trades shading for lower cell edges.
    scene = sphere_scene(n_views=8, height=90, width=120, texture_size=64, n_cells=6, seed=1, noise=0.002)
    d = texture_domain(scene.problem)
    base = dict(lam=5.0, albedo_lam=0.3, lighting="coupled", light_size=64)
    plain = solve(scene.problem, SolverParams(**base, light_edges=0.0))
    edges = solve(scene.problem, SolverParams(**base))  # the default, light_edges=0.003
    assert plain.info["lighting_stage"]["edges"] is None
    assert edges.info["lighting_stage"]["edges"]["iterations"] >= 1
    assert edges.texture.shape == (64, 64, 3) and np.isfinite(edges.texture[edges.seen]).all()
    err_plain = shading_error(d, plain.sigma, scene.sigma).mean()
    err_edges = shading_error(d, edges.sigma, scene.sigma).mean()
    # Measured 0.137 and 0.092.
    assert err_edges < 0.85 * err_plain


def test_light_edges_must_be_finite_and_not_negative():
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="light_edges"):
            SolverParams(light_edges=bad).check()
