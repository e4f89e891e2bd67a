import numpy as np
import scipy.sparse as sp

from core.solve.spmv import matvec_into


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
