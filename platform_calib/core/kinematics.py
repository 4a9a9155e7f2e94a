"""Kinematics of the 3-PRR platform: the inverse in closed form on the assembly's branch,
the forward by Newton, and the Jacobians of the pose against the feeds and the 18
parameters (the error model dP = J_A^-1 J_B de of the source, eq. (14), derived here from
the loop closure ``|C_i - B_i|^2 = L_i^2``). SI units: m, rad."""
from __future__ import annotations

import numpy as np

from calib_core.errors import InvalidInputError
from platform_calib.core.geometry import PlatformGeometry
from platform_calib.errors import WorkspaceError


def rotation(theta: np.ndarray) -> np.ndarray:
    """(n, 2, 2) rotation matrices."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _poses(poses) -> np.ndarray:
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    if poses.shape[1] != 3 or not np.all(np.isfinite(poses)):
        raise InvalidInputError('poses must be finite (x m, y m, theta rad) rows')
    return poses


def _feeds(feeds) -> np.ndarray:
    feeds = np.atleast_2d(np.asarray(feeds, dtype=float))
    if feeds.shape[1] != 3 or not np.all(np.isfinite(feeds)):
        raise InvalidInputError('feeds must be finite rows of three (m)')
    return feeds


def joint_positions(geometry: PlatformGeometry, poses) -> np.ndarray:
    """C_i in the base frame for each pose, (n, 3, 2) m."""
    poses = _poses(poses)
    turned = np.einsum('nab,ib->nia', rotation(poses[:, 2]), geometry.joints)
    return poses[:, None, :2] + turned


def feed_directions(geometry: PlatformGeometry) -> np.ndarray:
    """e_i, (3, 2)."""
    return np.column_stack([np.cos(geometry.alpha), np.sin(geometry.alpha)])


def slide_positions(geometry: PlatformGeometry, feeds) -> np.ndarray:
    """B_i = A_i + rho_i e_i, (n, 3, 2) m."""
    return geometry.base + _feeds(feeds)[:, :, None] * feed_directions(geometry)


def check_stroke(geometry: PlatformGeometry, feeds) -> np.ndarray:
    """``feeds`` (n, 3), refused if any lies outside the stroke."""
    feeds = _feeds(feeds)
    low, high = geometry.stroke
    outside = (feeds < low) | (feeds > high)
    if outside.any():
        k, i = np.argwhere(outside)[0]
        raise WorkspaceError(f'feed {i + 1} = {feeds[k, i] * 1e3:.3f} mm is outside the stroke '
                             f'{low * 1e3:g}..{high * 1e3:g} mm ({int(outside.sum())} feed(s) '
                             'out in all)')
    return feeds


def inverse(geometry: PlatformGeometry, poses, check: bool = True) -> np.ndarray:
    """Feeds (n, 3) m that put the platform at ``poses``: rho_i = k_i + s_i sqrt(L_i^2 -
    q_i^2) with k_i and q_i the components of C_i - A_i along and across the feed, s_i the
    assembly's branch.

    Raises
    ------
    WorkspaceError
        A chain cannot close (the pose lies beyond its link), or (with ``check``) a feed
        outside the stroke."""
    c = joint_positions(geometry, poses)
    e = feed_directions(geometry)
    d = c - geometry.base
    along = np.einsum('nia,ia->ni', d, e)
    across = d[..., 0] * e[:, 1] - d[..., 1] * e[:, 0]
    room = geometry.length ** 2 - across ** 2
    if np.any(room < 0):
        k, i = np.argwhere(room < 0)[0]
        raise WorkspaceError(f'pose {k}: chain {i + 1} cannot reach it (its joint lies '
                             f'{abs(across[k, i]) * 1e3:.3f} mm across the feed, the link is '
                             f'{geometry.length[i] * 1e3:.3f} mm)')
    feeds = along + geometry.branch * np.sqrt(room)
    return check_stroke(geometry, feeds) if check else feeds


def closure(geometry: PlatformGeometry, poses, feeds) -> np.ndarray:
    """|C_i - B_i| - L_i (n, 3) m: zero where pose and feeds agree."""
    d = joint_positions(geometry, poses) - slide_positions(geometry, feeds)
    return np.linalg.norm(d, axis=-1) - geometry.length


def _branch_of(geometry: PlatformGeometry, poses, feeds) -> np.ndarray:
    """The branch each chain is on: the sign of rho_i - k_i, (n, 3)."""
    d = joint_positions(geometry, poses) - geometry.base
    along = np.einsum('nia,ia->ni', d, feed_directions(geometry))
    return np.sign(_feeds(feeds) - along)


def pose_jacobians(geometry: PlatformGeometry, poses, feeds):
    """Derivatives of the loop closure g_i = |C_i - B_i|^2 - L_i^2 at (poses, feeds):
    dg/dP (n, 3, 3), dg/drho (n, 3) (diagonal) and dg/de (n, 3, 18)."""
    poses, feeds = _poses(poses), _feeds(feeds)
    n = len(poses)
    r = rotation(poses[:, 2])
    e = feed_directions(geometry)
    d = joint_positions(geometry, poses) - slide_positions(geometry, feeds)   # (n, 3, 2)
    turned = np.einsum('nab,ib->nia', r, geometry.joints)
    perpendicular = np.stack([-turned[..., 1], turned[..., 0]], -1)          # J R p'
    g_pose = 2 * np.stack([d[..., 0], d[..., 1], np.sum(d * perpendicular, -1)], -1)
    g_feed = -2 * np.sum(d * e, -1)
    normal = np.column_stack([-np.sin(geometry.alpha), np.cos(geometry.alpha)])
    g_par = np.zeros((n, 3, 18))
    for i in range(3):
        col = 6 * i
        g_par[:, i, col] = -2 * d[:, i, 0]
        g_par[:, i, col + 1] = -2 * d[:, i, 1]
        g_par[:, i, col + 2] = -2 * feeds[:, i] * (d[:, i] @ normal[i])
        g_par[:, i, col + 3] = -2 * geometry.length[i]
        g_par[:, i, col + 4] = 2 * np.sum(d[:, i] * r[:, :, 0], -1)
        g_par[:, i, col + 5] = 2 * np.sum(d[:, i] * r[:, :, 1], -1)
    return g_pose, g_feed, g_par


def forward(geometry: PlatformGeometry, feeds, start=None, tolerance: float = 1e-14,
            iterations: int = 50, strict: bool = True) -> np.ndarray:
    """Poses (n, 3) for ``feeds`` (n, 3) m by Newton on the loop closure, from ``start``
    (default P = 0), checked to lie on the assembly's branch. With ``strict`` False, rows
    that fail are NaN instead (an optimiser's candidates).

    Raises
    ------
    WorkspaceError
        Newton did not converge (no pose closes the chains, or a singular pose), or the
        pose found is on another branch (another assembly)."""
    feeds = _feeds(feeds)
    poses = np.zeros((len(feeds), 3)) if start is None else _poses(start).copy()
    if len(poses) != len(feeds):
        poses = np.repeat(poses[:1], len(feeds), axis=0)
    for _ in range(iterations):
        d = joint_positions(geometry, poses) - slide_positions(geometry, feeds)
        g = np.sum(d * d, -1) - geometry.length ** 2
        if np.all(np.abs(g) < tolerance * geometry.length.max()):
            break
        g_pose = pose_jacobians(geometry, poses, feeds)[0]
        singular = np.abs(np.linalg.det(g_pose)) < 1e-300
        if singular.any() and strict:
            raise WorkspaceError('the forward kinematics met a singular pose')
        g_pose[singular] = np.eye(3)
        poses = poses - np.linalg.solve(g_pose, g[..., None])[..., 0]
        poses[singular] = np.nan
    residual = np.abs(closure(geometry, poses, feeds))
    if not strict:
        failed = ~np.all(np.isfinite(residual) & (residual <= 1e-9), axis=1)
        failed |= np.any(_branch_of(geometry, np.nan_to_num(poses), feeds) != geometry.branch,
                         axis=1)
        poses[failed] = np.nan
        return poses
    if not np.all(np.isfinite(residual)) or residual.max() > 1e-9:
        raise WorkspaceError(f'no pose closes the chains for these feeds (closure '
                             f'{np.nanmax(residual):.3g} m after {iterations} Newton steps)')
    flipped = _branch_of(geometry, poses, feeds) != geometry.branch
    if flipped.any():
        k, i = np.argwhere(flipped)[0]
        raise WorkspaceError(f'feeds {k}: chain {i + 1} closes only on the other branch '
                             '(another assembly mode)')
    return poses


def parameter_jacobian(geometry: PlatformGeometry, poses, feeds) -> np.ndarray:
    """dP/de (n, 3, 18): how the pose reached with fixed feeds moves with each parameter
    (the source's J_A^-1 J_B)."""
    g_pose, _, g_par = pose_jacobians(geometry, poses, feeds)
    return -np.linalg.solve(g_pose, g_par)


def feed_jacobian(geometry: PlatformGeometry, poses, feeds) -> np.ndarray:
    """dP/drho (n, 3, 3)."""
    g_pose, g_feed, _ = pose_jacobians(geometry, poses, feeds)
    return -np.linalg.solve(g_pose, g_feed[:, :, None] * np.eye(3))
