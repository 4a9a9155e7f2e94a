"""Stitching self-calibrated regions into one stage frame (SEEDS_CDE.md section 002,
step 8).

Each region's G is known up to what one region cannot show: a translation, a rotation
and an isotropic scale (a similarity; its O and R are its own). Neighbouring regions share
sites; at a shared site both regions must give the same G once each carries its own
similarity. Two ways to find the similarities:

- ``joint``: all regions in one least-squares fit of every overlap (the first region
  fixed; loops in the region graph average the noise out);
- ``chained``: region by region along a breadth-first path from the first region, each
  fitted to the one before it only (the source's pairwise route; errors add up along the
  chain).

The stitched G is then put in the travel's gauge: no translation, rotation or isotropic
scale over all the sites, undetermined without an external length like a single region's.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from grid_calib.core.model import without_similarity
from grid_calib.errors import PlacementError

METHODS = ('joint', 'chained')


@dataclass
class StitchedMap:
    """The stage error over the travel, one frame (SI units)."""

    pitch: float                  # m
    sites: np.ndarray             # (s, 2) site indices in the travel frame
    stage_error: np.ndarray       # G, (s, 2) m
    similarities: dict            # region -> (shift_x m, shift_y m, angle rad, scale 1)
    overlap_rms: float | None     # RMS disagreement of regions at shared sites, m
    method: str
    uncertainty: np.ndarray | None = None   # 1-sigma of G per site (s, 2) m, if propagated
    uncertainty_draws: int = 0              # noise draws behind it

    @property
    def site_positions(self) -> np.ndarray:
        return self.sites * self.pitch


def _similarity_rows(local: np.ndarray, size: float) -> np.ndarray:
    """(2k, 4): the (x, y) change of G at local positions (k, 2) m per unit of (shift_x,
    shift_y, angle, scale); angle and scale in units of 1 / size for conditioning."""
    x, y = local[:, 0] / size, local[:, 1] / size
    rows = np.zeros((2 * len(local), 4))
    rows[0::2, 0], rows[0::2, 2], rows[0::2, 3] = 1.0, -y, x
    rows[1::2, 1], rows[1::2, 2], rows[1::2, 3] = 1.0, x, y
    return rows


def _overlaps(regions: dict) -> dict:
    """(a, b) -> (rows in a, rows in b) of the sites both regions cover."""
    where = {}
    for r, (origin, result) in regions.items():
        for k, site in enumerate(map(tuple, result.sites + origin)):
            where.setdefault(site, []).append((r, k))
    pairs = {}
    for covering in where.values():
        for a, ka in covering:
            for b, kb in covering:
                if a < b:
                    pairs.setdefault((a, b), ([], []))
                    pairs[(a, b)][0].append(ka)
                    pairs[(a, b)][1].append(kb)
    return pairs


def _check_connected(regions: dict, pairs: dict) -> list:
    """Breadth-first order of the regions from the first; refuses regions that share no
    sites with the rest (they cannot be put in one frame)."""
    first = min(regions)
    order, parent, queue = [first], {first: None}, deque([first])
    while queue:
        a = queue.popleft()
        for b in sorted(regions):
            if b not in parent and ((a, b) in pairs or (b, a) in pairs):
                parent[b] = a
                order.append(b)
                queue.append(b)
    alone = sorted(set(regions) - set(parent))
    if alone:
        raise PlacementError(f'region(s) {alone} share no sites with region {first} and its '
                             'neighbours: regions must overlap by at least one row or column '
                             'of sites to be stitched')
    return [(r, parent[r]) for r in order]


def _similarities(regions: dict, pitch: float, method: str, errors: dict,
                  size: float) -> dict:
    """Each region's similarity (4, K) (shift_x, shift_y, angle and scale times ``size``)
    for K sets of the regions' G (``errors``: region -> (s, 2, K) m); linear in them."""
    pairs = _overlaps(regions)
    order = _check_connected(regions, pairs)
    first = order[0][0]
    unknown = [r for r, _ in order[1:]]
    column = {r: 4 * k for k, r in enumerate(unknown)}
    count = next(iter(errors.values())).shape[2]
    solution = {first: np.zeros((4, count))}

    def pair_rows(a, b, rows_a, rows_b):
        """Design blocks and right sides of 'G_a + S_a = G_b + S_b' at the shared sites."""
        da = _similarity_rows(regions[a][1].sites[rows_a] * pitch, size)
        db = _similarity_rows(regions[b][1].sites[rows_b] * pitch, size)
        rhs = (errors[b][rows_b] - errors[a][rows_a]).reshape(-1, count)
        return da, db, rhs

    if method == 'joint' and unknown:
        blocks, right = [], []
        for (a, b), (rows_a, rows_b) in pairs.items():
            da, db, rhs = pair_rows(a, b, rows_a, rows_b)
            block = np.zeros((len(rhs), 4 * len(unknown)))
            if a != first:
                block[:, column[a]:column[a] + 4] += da
            if b != first:
                block[:, column[b]:column[b] + 4] -= db
            blocks.append(block)
            right.append(rhs)
        design, rhs = np.vstack(blocks), np.vstack(right)
        x, _, rank, _ = np.linalg.lstsq(design, rhs, rcond=None)
        if rank < design.shape[1]:
            raise PlacementError('the overlaps between regions cannot fix every region\'s '
                                 'shift, rotation and scale (too few shared sites)')
        solution.update({r: x[column[r]:column[r] + 4] for r in unknown})
    else:
        for r, parent in order[1:]:
            a, b = sorted((r, parent))
            rows_a, rows_b = pairs[(a, b)]
            da, db, rhs = pair_rows(a, b, rows_a, rows_b)
            # da S_a - db S_b = rhs, with the parent's S already in the frame.
            if a == r:
                own, target = da, rhs + db @ solution[parent]
            else:
                own, target = db, da @ solution[parent] - rhs
            if np.linalg.matrix_rank(own) < 4:
                raise PlacementError(f'regions {parent} and {r} share too few sites to fix a '
                                     'shift, rotation and scale')
            solution[r] = np.linalg.lstsq(own, target, rcond=None)[0]
    return solution


def _combined(regions: dict, solution: dict, errors: dict, pitch: float, size: float):
    """Every region's G (``errors``, (s, 2, K)) with its similarity, averaged where regions
    share sites: the travel's sites (S, 2), the mean (S, 2, K) and the RMS disagreement at
    shared sites per set (K,), NaN without shared sites."""
    travel = {r: result.sites + origin for r, (origin, result) in regions.items()}
    sites, inverse = np.unique(np.vstack(list(travel.values())), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    count = next(iter(errors.values())).shape[2]
    total, covered = np.zeros((len(sites), 2, count)), np.zeros(len(sites))
    corrected, start = {}, 0
    for r, (origin, result) in regions.items():
        rows = inverse[start:start + len(result.sites)]
        start += len(result.sites)
        shift = (_similarity_rows(result.sites * pitch, size) @ solution[r]).reshape(-1, 2, count)
        corrected[r] = (rows, errors[r] + shift)
        np.add.at(total, rows, corrected[r][1])
        np.add.at(covered, rows, 1)
    mean = total / covered[:, None, None]
    shared = covered > 1
    squares, entries = np.zeros(count), 0
    for rows, values in corrected.values():
        keep = shared[rows]
        squares += np.sum((values[keep] - mean[rows[keep]]) ** 2, axis=(0, 1))
        entries += 2 * int(keep.sum())
    overlap = np.sqrt(squares / entries) if entries else np.full(count, np.nan)
    return sites, mean, overlap


def stitch(regions: dict, pitch: float, method: str = 'joint') -> StitchedMap:
    """Put self-calibrated regions into one frame.

    Parameters
    ----------
    regions : dict
        region -> (origin (2,) int site indices of the region's centre in the travel frame,
        a result with ``sites`` (s, 2) local site indices and ``stage_error`` (s, 2) m).
    pitch : float
        Site pitch, m.
    method : {'joint', 'chained'}

    Raises
    ------
    PlacementError
        Regions that do not overlap, or an overlap too small to fix a similarity.
    """
    if method not in METHODS:
        raise PlacementError(f'unknown stitching method {method!r}; use {METHODS}')
    regions = {r: (np.asarray(o, dtype=int), res) for r, (o, res) in regions.items()}
    size = max(np.abs(res.sites).max() for _, res in regions.values()) * pitch
    errors = {r: res.stage_error[:, :, None] for r, (_, res) in regions.items()}
    solution = _similarities(regions, pitch, method, errors, size)
    sites, mean, overlap = _combined(regions, solution, errors, pitch, size)
    gauge = without_similarity(sites * pitch, mean[:, :, 0])
    similarities = {r: (s[0, 0], s[1, 0], s[2, 0] / size, s[3, 0] / size)
                    for r, s in solution.items()}
    return StitchedMap(pitch, sites, gauge, similarities,
                       None if np.isnan(overlap[0]) else float(overlap[0]), method)


def stitched_draws(regions: dict, pitch: float, method: str, draws: dict) -> np.ndarray:
    """The stitched G's error (K, S, 2) m, in the travel's gauge and the sites' order of
    :func:`stitch`, for K draws of every region's G error (``draws``: region -> (K, s, 2)
    m, independent between regions): the regions' noise through the similarities they
    are stitched with, the averaging and the gauge. The stitching is linear in the regions'
    G, so these are draws of the stitched map's own error."""
    regions = {r: (np.asarray(o, dtype=int), res) for r, (o, res) in regions.items()}
    size = max(np.abs(res.sites).max() for _, res in regions.values()) * pitch
    errors = {r: np.transpose(draws[r], (1, 2, 0)) for r in regions}
    solution = _similarities(regions, pitch, method, errors, size)
    sites, mean, _ = _combined(regions, solution, errors, pitch, size)
    return np.stack([without_similarity(sites * pitch, mean[:, :, k])
                     for k in range(mean.shape[2])])
