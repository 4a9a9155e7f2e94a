"""The self-calibration's constrained least squares as a bordered sparse system.

Normal equations with the gauge as exact constraints (Lagrange multipliers):

    [ D^T D   G^T ] [x]   [D^T b]
    [ G       0   ] [l] = [  0  ]

Almost every unknown (the stage's residual field F and the plate's mark errors A) touches a
handful of rows, but a few (O, R, the placements' misalignments, the closed loop's extra
columns) touch every row of a placement, and the gauge rows span every site. Factored as one
matrix, those dense rows and columns defeat the fill-reducing ordering. Here the sparse block
is factored alone and the dense columns and gauge rows are a border of a few dozen,
eliminated through their Schur complement (Golub and Van Loan, Matrix Computations, section
4.5, block LU of a bordered matrix): at N = 101, 0.73 s where SuperLU on the whole matrix
takes 15.6 s in the same run (bench_results/grid.md). The solution is the same to rounding.
"""
from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

# A column is dense when it holds more than this many times the median column's entries
# (F and A hold 3-6; O, R and the misalignments one per reading of a placement).
DENSE_FACTOR = 10
MIN_DENSE_ENTRIES = 32
# Relative residual of a probe solve above which the bordered factor is not trusted.
PROBE_TOLERANCE = 1e-8
# The symmetric pattern's minimum-degree ordering: 4-5x less fill than SuperLU's default
# (COLAMD) on the whole system, 1.6x on the sparse block.
ORDERING = 'MMD_AT_PLUS_A'


def dense_columns(design: sparse.spmatrix) -> np.ndarray:
    """Indices of the columns of ``design`` (rows, columns) that touch many rows."""
    counts = np.diff(sparse.csc_matrix(design).indptr)
    limit = max(MIN_DENSE_ENTRIES, DENSE_FACTOR * float(np.median(counts)))
    return np.flatnonzero(counts > limit)


def kkt_matrix(design: sparse.csr_matrix, gauge: sparse.csr_matrix) -> sparse.csc_matrix:
    """The KKT matrix above, (columns + gauge rows) square."""
    return sparse.bmat([[design.T @ design, gauge.T], [gauge, None]], format='csc')


class BorderedFactor:
    """Solves the KKT system ``kkt`` in its own layout, (size,) or (size, k) right-hand
    sides, x then the multipliers, with the unknowns ``border`` (indices) eliminated
    through their Schur complement and the rest factored by SuperLU.

    Raises ``RuntimeError`` (as SuperLU does) when the sparse block or the border's Schur
    complement is singular; :func:`factor_kkt` then factors the whole matrix instead."""

    def __init__(self, kkt: sparse.csc_matrix, border: np.ndarray, ordering: str):
        self.shape = kkt.shape
        self._border = border
        self._sparse = np.setdiff1d(np.arange(kkt.shape[0]), border)
        rows = kkt[self._sparse]
        inner = rows[:, self._sparse].tocsc()
        coupling = rows[:, border].toarray()                        # (sparse, border)
        corner = kkt[border][:, border].toarray()                   # (border, border)
        # The sparse block is D^T D on F and A: symmetric positive definite, so no pivoting
        # is needed and the symmetric ordering is kept.
        self._inner = splu(inner, permc_spec=ordering, diag_pivot_thresh=0.0,
                           options={'SymmetricMode': True})
        self._spread = self._inner.solve(coupling)                 # inner^-1 coupling
        schur = corner - coupling.T @ self._spread
        if not (np.all(np.isfinite(self._spread)) and np.all(np.isfinite(schur))):
            raise RuntimeError('the sparse block is singular')
        self._coupling = coupling
        self._schur = np.linalg.inv(schur) if schur.size else schur
        if not np.all(np.isfinite(self._schur)):
            raise RuntimeError('the border is singular')

    def solve(self, right: np.ndarray) -> np.ndarray:
        right = np.asarray(right, dtype=float)
        inner = self._inner.solve(np.ascontiguousarray(right[self._sparse]))
        border = self._schur @ (right[self._border] - self._coupling.T @ inner)
        out = np.empty_like(right)
        out[self._sparse] = inner - self._spread @ border
        out[self._border] = border
        return out


def factor_whole_kkt(design: sparse.csr_matrix, gauge: sparse.csr_matrix,
                     ordering: str = ORDERING):
    """SuperLU on the whole KKT matrix (the route before the border)."""
    return splu(kkt_matrix(design, gauge), permc_spec=ordering)


def factor_kkt(design: sparse.csr_matrix, gauge: sparse.csr_matrix, ordering: str = ORDERING):
    """A factor of the KKT matrix with a ``solve`` and a ``shape``: bordered (the dense
    columns of ``design`` and the gauge rows) when the sparse block is regular (the
    self-calibration's case), else SuperLU on the whole matrix."""
    kkt = kkt_matrix(design, gauge)
    border = np.concatenate([dense_columns(design), design.shape[1] + np.arange(gauge.shape[0])])
    try:
        factor = BorderedFactor(kkt, border, ordering)
    except RuntimeError:
        return splu(kkt, permc_spec=ordering)
    # A nearly singular sparse block factors without complaint and solves badly: checked on
    # one right-hand side (a solve and a product, against the factorisation's cost).
    probe = np.random.default_rng(0).standard_normal(kkt.shape[0])
    error = np.linalg.norm(kkt @ factor.solve(probe) - probe)
    if not error <= PROBE_TOLERANCE * np.linalg.norm(probe):
        return splu(kkt, permc_spec=ordering)
    return factor
