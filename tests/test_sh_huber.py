import numpy as np
import pytest

from core.geometry.sh import sh_basis, sh_degree
from core.geometry.transfer import sphere_directions
from core.solve.huber import huber, majorant, mm_weight
from core.solve.lighting import view_normal_equations, weighted_gram


def test_sh_basis_matches_closed_form():
    rng = np.random.default_rng(1)
    n = rng.standard_normal((50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    nu = sh_basis(n, np.float64)
    for (n1, n2, n3), row in zip(n, nu):
        expected = [n1, n2, n3, 1, n1 * n2, n1 * n3, n2 * n3, n1**2 - n2**2, 3 * n3**2 - 1]
        np.testing.assert_allclose(row, expected, rtol=1e-12, atol=1e-12)


def test_sh_basis_of_orders_3_and_4_are_spherical_harmonics_of_their_degrees():
    # Real SH are orthogonal over the sphere and of the degree sh_degree gives: a wrong term in any column
    # shows as an off-diagonal entry of the Gram matrix (quadrature on a Fibonacci lattice).
    d = sphere_directions(200_000)
    for order in (2, 3, 4):
        nu = sh_basis(d, np.float64, order)
        k = (order + 1) ** 2
        assert nu.shape == (len(d), k) and sh_basis(d[:5], np.float32, order).dtype == np.float32
        gram = nu.T @ nu / len(d)
        scale = np.sqrt(np.outer(np.diag(gram), np.diag(gram)))
        assert np.all(np.abs(gram - np.diag(np.diag(gram))) < 1e-3 * scale), order
        # Degree l: nu(-n) = (-1)^l nu(n).
        parity = (-1.0) ** sh_degree(k)
        np.testing.assert_allclose(sh_basis(-d[:100], np.float64, order), nu[:100] * parity, atol=1e-12)


def test_weighted_gram_sums_the_weighted_outer_products():
    rng = np.random.default_rng(2)
    nu = rng.standard_normal((7, 10))
    w = rng.random(7)
    M = weighted_gram(nu, w)
    np.testing.assert_allclose(M, sum(wp * np.outer(n, n) for wp, n in zip(w, nu)), rtol=1e-12)
    M32 = weighted_gram(nu.astype(np.float32), w)
    assert M32.dtype == np.float32
    np.testing.assert_allclose(M32, M, rtol=1e-5)
    # From nu's transpose with contiguous rows, and per view from one kept transpose (a slice of its columns).
    np.testing.assert_allclose(weighted_gram(nu, w, np.ascontiguousarray(nu.T)), M, rtol=1e-12)
    offsets = np.array([0, 3, 7])
    nu32 = nu.astype(np.float32)
    Ms, bs = view_normal_equations(nu32, offsets, w, w, np.float32, np.ascontiguousarray(nu32.T))
    for v in range(2):
        lo, hi = offsets[v], offsets[v + 1]
        np.testing.assert_allclose(Ms[v], weighted_gram(nu[lo:hi], w[lo:hi]), rtol=1e-5)
        np.testing.assert_allclose(bs[v], w[lo:hi] @ nu[lo:hi], rtol=1e-5)


def test_majorant_is_above_huber_and_touches_at_x0():
    delta = 1e-2
    x = np.linspace(-0.2, 0.2, 2001)
    for x0 in [0.0, 0.3 * delta, -delta, 1.5 * delta, -0.05, 0.17]:
        psi = majorant(x, x0, delta)
        assert np.all(psi >= huber(x, delta) - 1e-12), x0
        np.testing.assert_allclose(majorant(x0, x0, delta), huber(x0, delta), rtol=1e-12, atol=1e-15)
        # psi is the quadratic w x^2 / 2 + const with w = mm_weight(x0).
        curv = majorant(1.0, x0, delta) - majorant(0.0, x0, delta)
        np.testing.assert_allclose(curv, mm_weight(x0, delta) / 2, rtol=1e-12)


def test_huber_branches():
    d = 0.1
    np.testing.assert_allclose(huber(np.array([0.05, -0.5]), d), [0.05**2 / 0.2, 0.5 - 0.05])


def test_inplace_huber_matches_the_definition():
    from core.solve.huber import huber_inplace

    x = np.linspace(-0.01, 0.01, 1001)
    for dt in (np.float64, np.float32):
        np.testing.assert_allclose(huber_inplace(x.astype(dt), 1e-3), huber(x, 1e-3), rtol=1e-5, atol=1e-9)


def test_mm_weight_in_place_matches_the_definition():
    x = np.linspace(-0.01, 0.01, 1001).astype(np.float32)
    expected = mm_weight(x, 1e-3)
    buf = x.copy()
    assert mm_weight(buf, 1e-3, out=buf) is buf
    np.testing.assert_array_equal(buf, expected)


@pytest.mark.parametrize("order", [2, 3, 4])
def test_the_sh_basis_as_planes_holds_the_same_numbers(order):
    rng = np.random.default_rng(order)
    n = rng.normal(size=(5, 7, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    rows = sh_basis(n.astype(np.float32), order=order)
    planes = sh_basis(n.astype(np.float32), order=order, planes=True)
    assert planes.shape == rows.shape == (5, 7, (order + 1) ** 2) and planes.dtype == rows.dtype
    np.testing.assert_array_equal(planes, rows)
    assert planes[..., 4].flags.c_contiguous  # each function's values in a row of their own
