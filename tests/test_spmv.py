import numpy as np
import pytest
import scipy.sparse as sp

from core.solve import spmv
from core.solve.spmv import PairNormal, matvec_into, scatter_add


def _matrix():
    A = sp.random(300, 200, density=0.05, random_state=1, format="csr", dtype=np.float32)
    return A, np.random.default_rng(0).standard_normal(200).astype(np.float32)


def test_matvec_into_writes_the_product_into_the_buffer():
    A, x = _matrix()
    out = np.full(300, np.nan, np.float32)
    for _ in range(2):  # overwritten each call, not added to
        assert matvec_into(A, x, out) is out
        np.testing.assert_allclose(out, A @ x, rtol=1e-5, atol=1e-6)


def test_matvec_into_falls_back_to_the_product_for_other_dtypes():
    A, x = _matrix()
    out = np.full(300, np.nan, np.float32)
    matvec_into(A, x.astype(np.float64), out)
    np.testing.assert_allclose(out, A @ x.astype(np.float64), rtol=1e-5, atol=1e-6)
    out64 = np.empty(200)
    matvec_into(A.T.tocsr(), np.ones(300, np.float32), out64)
    np.testing.assert_allclose(out64, A.T @ np.ones(300, np.float32), rtol=1e-5)


@pytest.mark.parametrize("block", [None, 7])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_scatter_add_sums_in_order_as_a_sparse_product(monkeypatch, block, dtype):
    # Columns taken in blocks (7: many, the last one short). Each entry's terms are summed in their order, as a
    # loop does and as scipy's CSR product over the same entries does: the same bits.
    if block is not None:
        monkeypatch.setattr(spmv, "_SCATTER_BLOCK", block)
    rng = np.random.default_rng(3)
    index = rng.integers(0, 40, 500)
    x = (rng.standard_normal(500) * 10.0 ** rng.integers(-3, 4, 500)).astype(dtype)
    looped = np.zeros(41, dtype)
    for i, v in zip(index, x):
        looped[i] += v
    out = np.zeros(41, dtype)
    assert scatter_add(index, x, out) is out
    np.testing.assert_array_equal(out, looped)
    S = sp.csr_matrix((np.ones(500, dtype), (index, np.arange(500))), shape=(41, 500))
    np.testing.assert_array_equal(out, S @ x)
    assert out[40] == 0  # an index that no entry has
    # Added to what out holds.
    np.testing.assert_array_equal(
        scatter_add(index, np.ones(500, dtype), np.full(41, 2, dtype)), 2 + np.bincount(index, minlength=41)
    )


@pytest.mark.parametrize("block", [None, 7])
def test_pair_normal_is_the_weighted_normal_matrix_off_its_diagonal(monkeypatch, block):
    # Rows c1 x_a + c2 x_b, one of them twice (two rows between the same unknowns are summed). The entries are
    # gathered in blocks; 7 makes many, and a last one that is short.
    if block is not None:
        monkeypatch.setattr(spmv, "_TAKE_BLOCK", block)
    rng = np.random.default_rng(2)
    a = rng.integers(0, 50, 120)
    b = (a + rng.integers(1, 49, 120)) % 50
    a, b = np.append(a, a[0]), np.append(b, b[0])
    rows = np.repeat(np.arange(a.size), 2)
    coef = rng.uniform(-2, 2, 2 * a.size).astype(np.float32)
    B = sp.csr_matrix((coef, (rows, np.stack([a, b], 1).ravel())), shape=(a.size, 50))
    BT = B.T.tocsr()
    pair = PairNormal.of(B, BT)
    s = rng.uniform(0.1, 3, a.size).astype(np.float32)
    x = rng.standard_normal(50).astype(np.float32)
    L = (B.T @ sp.diags(s) @ B).toarray()
    np.fill_diagonal(L, 0)
    values = pair.values(s, np.empty(pair.edge.size, np.float32))
    out = np.full(50, np.nan, np.float32)
    assert pair.matvec_into(values, x, out) is out
    np.testing.assert_allclose(out, L @ x, rtol=1e-4, atol=1e-4)


def test_pair_normal_refuses_rows_of_another_width():
    B = sp.csr_matrix(np.array([[1.0, -1.0, 0.0], [1.0, -0.5, -0.5]], np.float32))
    assert PairNormal.of(B, B.T.tocsr()) is None
    assert PairNormal.of(sp.csr_matrix((0, 3), dtype=np.float32), sp.csr_matrix((3, 0), dtype=np.float32)) is None
