"""imaging.core.prefetch: a hint that reaches the machine code and changes no result."""

import numba
import numpy as np

from imaging.core.prefetch import prefetch


@numba.njit
def _row_sums_prefetching(rows):
    out = np.zeros(rows.shape[0])
    for p in range(rows.shape[0]):
        if p + 1 < rows.shape[0]:
            for j in range(0, rows.shape[1], 8):
                prefetch(rows, p + 1, j)
        out[p] = rows[p].sum()
    return out


def test_prefetching_changes_no_result_and_is_emitted():
    rows = np.random.default_rng(0).standard_normal((5, 37))
    np.testing.assert_allclose(_row_sums_prefetching(rows), rows.sum(axis=1), rtol=1e-12)
    asm = _row_sums_prefetching.inspect_asm(_row_sums_prefetching.signatures[0])
    assert "prefetch" in asm
