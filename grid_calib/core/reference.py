"""The reference solver: the source's own route (route A of SEEDS_CDE.md section 002),
used to cross-check the global solver in ``selfcal``.

The plate errors A are eliminated instead of estimated. For mark (i, j):

- symmetry (initial and rotated): ``V_1 - rot(V_0) = G(-j, i) - rot(G(i, j)) + E_s`` with
  ``rot(a) = (-a_y, a_x)``, the 90-degree turn;
- transitivity (initial and shifted): ``V_2 - V_0 = G(i + 1, j) - G(i, j) + E_t``;

E_s and E_t are what is left of the placements' misalignments after the difference: a
rigid motion each (two shifts and an angle). The unknowns are F at every site, O, R and
these six; the six zero moments of F close the gauge. The system is solved by LSQR with
the constraints as extra rows: another formulation and another linear-algebra route than
the global solver's, so that agreement between the two means something.

``literal_transitivity`` takes the transitivity equations as the source prints them
(``U_0y`` in the x line; ``F_y(m+1) + F_y(m)`` and ``+U_0x`` in the y line): kept only to
show that they cannot be satisfied.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import lsqr

from grid_calib.core.model import Grid, stage_error
from grid_calib.core.selfcal import Placement, check_placements
from grid_calib.errors import PlacementError


@dataclass(frozen=True)
class ReferenceSolution:
    """Stage error of one region from the difference equations (SI units)."""

    non_orthogonality: float      # O, rad
    scale_difference: float       # R, 1
    sites: np.ndarray             # (s, 2) site indices, grid.sites order
    stage_error: np.ndarray       # G, (s, 2) m
    residual_rms: float           # RMS of the difference equations' residuals, m
    iterations: int               # LSQR iterations


def solve_by_differences(grid: Grid, placements: list[Placement],
                         literal_transitivity: bool = False) -> ReferenceSolution:
    """Solve one region by the symmetry and transitivity equations.

    Raises
    ------
    PlacementError
        A placement missing or doubled, marks missing or measured twice, bad values, or an
        LSQR that did not converge.
    """
    by_name = check_placements(grid, placements)
    sites = grid.sites
    site_index = {tuple(s): k for k, s in enumerate(sites)}
    half_size = grid.half * grid.pitch
    n_sites = len(sites)
    o_col, e0 = 2 * n_sites, 2 * n_sites + 2
    columns = e0 + 6
    deviation = {name: dict(zip(map(tuple, np.asarray(p.marks, dtype=int)), p.deviation))
                 for name, p in by_name.items()}
    rows, cols, values, rhs = [], [], [], []

    def g_terms(site, component, sign):
        """The coefficients of ``sign * G_component(site)`` in units of half_size."""
        s = site_index[site]
        x, y = site[0] / grid.half, site[1] / grid.half
        o, r = (y, x) if component == 0 else (x, -y)
        return [(2 * s + component, sign), (o_col, sign * o), (o_col + 1, sign * r)]

    def add(entries, value):
        for c, v in entries:
            rows.append(len(rhs))
            cols.append(c)
            values.append(v)
        rhs.append(value / half_size)

    for (i, j) in map(tuple, grid.marks):
        x, y = i / grid.half, j / grid.half
        v0, v1, v2 = (deviation[n][(i, j)] for n in ('initial', 'rotated', 'shifted'))
        turned, here, next_site = (-j, i), (i, j), (i + 1, j)
        # Symmetry: x: G_x(turned) + G_y(here); y: G_y(turned) - G_x(here). E_s is a rigid
        # motion of the turned site (-j, i): (a - phi i, b - phi j).
        add(g_terms(turned, 0, 1.0) + g_terms(here, 1, 1.0) + [(e0, 1.0), (e0 + 2, -x)],
            v1[0] + v0[1])
        add(g_terms(turned, 1, 1.0) + g_terms(here, 0, -1.0) + [(e0 + 1, 1.0), (e0 + 2, -y)],
            v1[1] - v0[0])
        # Transitivity: E_t is (c - phi y, d + phi x) at the mark's first site.
        if literal_transitivity:
            add(g_terms(next_site, 0, 1.0) + g_terms(here, 0, -1.0)
                + [(e0 + 3, 1.0), (e0 + 5, -y)], v2[0] - v0[1])
            add(g_terms(next_site, 1, 1.0) + g_terms(here, 1, 1.0)
                + [(e0 + 4, 1.0), (e0 + 5, x)], v2[1] + v0[0])
        else:
            add(g_terms(next_site, 0, 1.0) + g_terms(here, 0, -1.0)
                + [(e0 + 3, 1.0), (e0 + 5, -y)], v2[0] - v0[0])
            add(g_terms(next_site, 1, 1.0) + g_terms(here, 1, -1.0)
                + [(e0 + 4, 1.0), (e0 + 5, x)], v2[1] - v0[1])
    equations = len(rhs)
    # The six zero moments of F, as rows the solution must meet (weighted to dominate).
    scaled = sites / grid.half
    weight = 1e3
    for component in (0, 1):
        for moment in (np.ones(n_sites), scaled[:, 0], scaled[:, 1]):
            add([(2 * s + component, weight * moment[s]) for s in range(n_sites)], 0.0)
    design = sparse.csr_matrix((values, (rows, cols)), shape=(len(rhs), columns))
    b = np.asarray(rhs)
    solution, stop, iterations = lsqr(design, b, atol=1e-16, btol=1e-16, conlim=1e12,
                                      iter_lim=20 * columns)[:3]
    if stop in (3, 7) or not np.all(np.isfinite(solution)):
        raise PlacementError(f'the difference equations did not converge (LSQR stop {stop} '
                             f'after {iterations} iterations)')
    residual = (design @ solution - b)[:equations] * half_size
    o_value, r_value = solution[o_col], solution[o_col + 1]
    field = solution[:2 * n_sites].reshape(n_sites, 2) * half_size
    g = stage_error(sites * grid.pitch, o_value, r_value, field)
    return ReferenceSolution(float(o_value), float(r_value), sites, g,
                             float(np.sqrt(np.mean(residual ** 2))), int(iterations))
