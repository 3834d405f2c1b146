"""Point matching between a reference keyframe and another frame (thesis 6.5).

`match_direct` refines a predicted position with an affine-warped patch (tracking, 6.7.2);
`match_epipolar` searches FAST corners of several levels along the epipolar segment of the 95%
inverse-depth interval, scores them by ZMSSD and refines the best one (mapping, 6.6.2-6.6.3).
"""

from __future__ import annotations

import numba
import numpy as np

from calib.camera import project_point, unproject_pixel
from vo.frame import corner_normalised
from vo.orb import NONE, UNKNOWN, VALID, hamming
from vo.patch import (
    BORDER_PATCH,
    HALF,
    PATCH_AREA,
    align2d,
    from_level,
    inside,
    to_level,
    warp_patch,
    zmssd,
)
from vo.se3 import transform

MIN_RHO = 1e-10


@numba.njit(cache=True, nogil=True)
def affine_cur_ref(params, T_cur_ref, f_ref, depth, u_ref, v_ref, ref_level):
    """2x2 affine map from reference level-0 pixel offsets to current ones, for a fronto-parallel
    patch at `depth` along bearing f_ref. NaN entries when the patch cannot be projected."""
    A = np.full((2, 2), np.nan)
    step = (HALF + 1) * 2.0 ** ref_level
    xr, yr, zr = f_ref[0] * depth, f_ref[1] * depth, f_ref[2] * depth
    X, Y, Z = transform(T_cur_ref, xr, yr, zr)
    u0, v0 = project_point(params, X, Y, Z)
    for k in range(2):
        du = step if k == 0 else 0.0
        dv = step if k == 1 else 0.0
        bx, by, bz = unproject_pixel(params, u_ref + du, v_ref + dv)
        s = zr / bz
        X, Y, Z = transform(T_cur_ref, bx * s, by * s, bz * s)
        u1, v1 = project_point(params, X, Y, Z)
        A[0, k] = (u1 - u0) / step
        A[1, k] = (v1 - v0) / step
    return A


@numba.njit(cache=True, nogil=True)
def inverse2(A):
    """The inverse of a non-singular 2x2 matrix as LAPACK computes it (getrf with partial
    pivoting, then getri), so it equals np.linalg.inv(A) to the bit without that call's
    overhead (a match computes one per point)."""
    a00, a01, a10, a11 = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    swap = abs(a10) > abs(a00)
    if swap:
        a00, a01, a10, a11 = a10, a11, a00, a01
    lower = a10 * (1.0 / a00)
    i00 = 1.0 / a00
    i11 = 1.0 / (a11 - lower * a01)
    i01 = (a01 * i00) * -i11
    out = np.empty((2, 2))
    c0, c1 = (1, 0) if swap else (0, 1)
    out[0, c0] = i00 - i01 * lower
    out[0, c1] = i01
    out[1, c0] = 0.0 - i11 * lower
    out[1, c1] = i11
    return out


@numba.njit(cache=True, nogil=True)
def search_level(A, max_level):
    """Pyramid level where the warped patch is closest to its reference size."""
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    level = 0
    while det > 3.0 and level < max_level:
        det *= 0.25
        level += 1
    return level


@numba.njit(cache=True, nogil=True)
def triangulate_depth(T_cur_ref, f_ref, f_cur):
    """Depth along f_ref (reference frame) of the point closest to both rays; <= 0 if none."""
    R = np.ascontiguousarray(T_cur_ref[:3, :3])  # contiguous operands for BLAS
    t = np.ascontiguousarray(T_cur_ref[:3, 3])
    a = R @ f_ref
    # minimise |d_ref * a + t - d_cur * f_cur|
    aa = a @ a
    ab = -(a @ f_cur)
    bb = f_cur @ f_cur
    det = aa * bb - ab * ab
    if det < 1e-12:
        return -1.0
    ra = -(a @ t)
    rb = f_cur @ t
    return (bb * ra - ab * rb) / det


@numba.njit(cache=True, nogil=True)
def inverse_depth_sigma(T_cur_ref, f_ref, depth, px_angle):
    """Std of the inverse depth caused by a `px_angle` error in the current observation."""
    R_t = np.ascontiguousarray(T_cur_ref[:3, :3].T)  # contiguous operands for BLAS
    t = -(R_t @ np.ascontiguousarray(T_cur_ref[:3, 3]))  # current camera centre in the ref
    tn = np.sqrt(t @ t)
    if tn < 1e-12:
        return 1e10
    a = f_ref * depth - t
    an = np.sqrt(a @ a)
    alpha = np.arccos(min(1.0, max(-1.0, (f_ref @ t) / tn)))
    beta = np.arccos(min(1.0, max(-1.0, -(a @ t) / (tn * an))))
    gamma = np.pi - alpha - (beta + px_angle)
    if gamma <= 1e-9:
        return 1e10
    d_plus = tn * np.sin(beta + px_angle) / np.sin(gamma)
    tau = d_plus - depth
    return 0.5 * (1.0 / max(1e-7, depth - tau) - 1.0 / (depth + tau))


@numba.njit(cache=True, nogil=True)
def match_direct(params, layout, ref_flat, ref_obs, depth, T_cur_ref, cur_flat, u, v, max_level,
                 iterations):
    """Refine the predicted level-0 pixel (u, v) of a point in the current frame.

    `layout` is the (offsets, widths, heights) of both pyramids (one camera), `ref_obs` the
    reference observation (level-0 u, v, level, bearing f) of the point at `depth` along f.
    Returns (u, v, level, ok) with (u, v) at level 0.
    """
    off, w, h = layout
    ref_u, ref_v, ref_level, f_ref = ref_obs
    A = affine_cur_ref(params, T_cur_ref, f_ref, depth, ref_u, ref_v, ref_level)
    if np.isnan(A[0, 0]) or np.isnan(A[1, 1]):
        return u, v, 0, False
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    if abs(det) < 1e-6:
        return u, v, 0, False
    level = search_level(A, max_level)
    A_ref_cur = inverse2(A)
    patch = np.empty((BORDER_PATCH, BORDER_PATCH))
    if not warp_patch(ref_flat, off[ref_level], w[ref_level], h[ref_level], A_ref_cur, ref_u,
                      ref_v, ref_level, level, patch):
        return u, v, level, False
    ul, vl, ok = align2d(cur_flat, off[level], w[level], h[level], patch, to_level(u, level),
                         to_level(v, level), iterations)
    return from_level(ul, level), from_level(vl, level), level, ok


@numba.njit(cache=True, nogil=True)
def _segment_distance(px, py, ax, ay, bx, by):
    """Distance from (px, py) to the segment a-b."""
    dx = bx - ax
    dy = by - ay
    L2 = dx * dx + dy * dy
    s = 0.0 if L2 < 1e-20 else ((px - ax) * dx + (py - ay) * dy) / L2
    s = min(1.0, max(0.0, s))
    ex = ax + s * dx - px
    ey = ay + s * dy - py
    return np.sqrt(ex * ex + ey * ey)


@numba.njit(cache=True, nogil=True)
def match_epipolar(params, layout, ref_flat, ref_obs, rho, sigma, T_cur_ref, cur_flat, corners,
                   search, orb):
    """Search a point with inverse depth rho +- 2 sigma along its epipolar segment in the
    current frame, among its FAST corners. Returns (u, v, level, ok) at level 0.

    `layout` is the (offsets, widths, heights) of both pyramids, `ref_obs` the reference
    observation (level-0 u, v, level, bearing f), `corners` the current frame's FAST corners
    (x, y per level, normalised xn, yn, row_start: vo.frame.Corners.tables), `search` the
    (min_level, max_level, margin_px, threshold, iterations) of the search: corners of levels
    min_level..max_level within margin_px (scaled by the level) of the segment.

    Candidates are scored by ZMSSD of the affine-warped patch (below `threshold` per pixel),
    or, when orb[0] (the maximum distance) >= 0, by the Hamming distance of ORB descriptors
    (vo.orb.query: the point's per-level descriptors, the frame's corner descriptors; missing
    ones are marked as needed and the search fails as pending)."""
    off, widths, heights = layout
    ref_u, ref_v, ref_level, f_ref = ref_obs
    cx, cy, _, _, c_row_start = corners
    min_level, max_level, margin_px, threshold, iterations = search
    if not (rho > 0.0 and sigma > 0.0 and np.isfinite(rho + sigma)):
        return 0.0, 0.0, 0, False
    rho_far = max(rho - 2.0 * sigma, MIN_RHO)
    rho_near = rho + 2.0 * sigma
    # sample the segment to bound it in distorted pixels; endpoints in the normalised plane
    n_samples = 9
    limit = 4.0 * (widths[0] + heights[0])
    umin, umax, vmin, vmax = 1e18, -1e18, 1e18, -1e18
    ax = ay = bx = by = 0.0
    for k in range(n_samples):
        a = k / (n_samples - 1)
        r = rho_near * (1.0 - a) + rho_far * a
        X, Y, Z = transform(T_cur_ref, f_ref[0] / r, f_ref[1] / r, f_ref[2] / r)
        if 1e-6 * (abs(X) + abs(Y) + Z + 1e-30) >= Z or Z <= 0.0:
            return 0.0, 0.0, 0, False
        if k == 0:
            ax, ay = X / Z, Y / Z
        bx, by = X / Z, Y / Z
        u, v = project_point(params, X, Y, Z)
        if not (abs(u) < limit and abs(v) < limit):  # NaN, or beyond the distortion model
            return 0.0, 0.0, 0, False
        umin, umax = min(umin, u), max(umax, u)
        vmin, vmax = min(vmin, v), max(vmax, v)
    A = affine_cur_ref(params, T_cur_ref, f_ref, 1.0 / rho, ref_u, ref_v, ref_level)
    if np.isnan(A[0, 0]) or np.isnan(A[1, 1]):
        return 0.0, 0.0, 0, False
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    if abs(det) < 1e-6:
        return 0.0, 0.0, 0, False
    A_ref_cur = inverse2(A)
    use_orb = orb[0] >= 0
    # ORB: corners of level l are compared with the point's descriptor at the reference
    # level that shows the same scale
    level_shift = int(np.round(0.5 * np.log2(abs(det))))
    pending = orb[7][0]
    # the warped reference patch of each level searched, kept for the refinement
    patches = np.empty((max_level + 1, BORDER_PATCH, BORDER_PATCH))
    warped = np.zeros(max_level + 1, dtype=np.bool_)
    best = orb[0] + 1.0 if use_orb else threshold * PATCH_AREA
    best_x = best_y = 0.0
    best_level = -1
    focal = params[1]
    for level in range(min_level, max_level + 1):
        rl = level - level_shift
        if use_orb:
            if rl < 0 or rl >= orb[1].shape[0] or orb[2][rl] == NONE:
                continue
            if orb[2][rl] == UNKNOWN:
                orb[3][rl] = True
                orb[7][0] += 1
        else:
            warped[level] = warp_patch(ref_flat, off[ref_level], widths[ref_level],
                                       heights[ref_level], A_ref_cur, ref_u, ref_v, ref_level,
                                       level, patches[level])
            if not warped[level]:
                continue
        s = 2.0 ** level
        m = margin_px * s
        tol = m / focal
        w = widths[level]
        h = heights[level]
        r0 = int(min(max(to_level(vmin - m, level), 0.0), h - 1.0))
        r1 = int(min(max(to_level(vmax + m, level) + 1.0, 0.0), h - 1.0))
        lo_u = to_level(umin - m, level)
        hi_u = to_level(umax + m, level)
        for row in range(r0, r1 + 1):
            for i in range(c_row_start[level, row], c_row_start[level, row + 1]):
                x = cx[i]
                if x < lo_u or x > hi_u:
                    continue
                y = cy[i]
                if not inside(x, y, w, h, HALF + 1):
                    continue
                xn, yn = corner_normalised(params, corners, i, level)
                if _segment_distance(xn, yn, ax, ay, bx, by) > tol:
                    continue
                if not use_orb:
                    score = zmssd(patches[level], cur_flat, off[level], w, int(x), int(y))
                elif orb[5][i] == UNKNOWN:
                    orb[6][i] = True
                    orb[7][0] += 1
                    continue
                elif orb[5][i] == VALID and orb[2][rl] == VALID:
                    score = float(hamming(orb[1][rl], orb[4][i]))
                else:
                    continue
                if score < best:
                    best = score
                    best_x, best_y, best_level = x, y, level
    if best_level < 0 or orb[7][0] > pending:
        return 0.0, 0.0, 0, False
    lv = best_level
    u0, v0 = from_level(best_x, lv), from_level(best_y, lv)
    if not (warped[lv] or warp_patch(ref_flat, off[ref_level], widths[ref_level],
                                     heights[ref_level], A_ref_cur, ref_u, ref_v, ref_level, lv,
                                     patches[lv])):
        return u0, v0, lv, use_orb  # a descriptor match whose patch cannot be refined
    ul, vl, ok = align2d(cur_flat, off[lv], widths[lv], heights[lv], patches[lv], best_x, best_y,
                         iterations)
    if ok and (ul - best_x) ** 2 + (vl - best_y) ** 2 <= 4.0:
        u0, v0 = from_level(ul, lv), from_level(vl, lv)
    if lv > 0 and (warped[0] or warp_patch(ref_flat, off[ref_level], widths[ref_level],
                                           heights[ref_level], A_ref_cur, ref_u, ref_v,
                                           ref_level, 0, patches[0])):
        # a last sub-pixel step at full resolution
        uf, vf, ok = align2d(cur_flat, off[0], widths[0], heights[0], patches[0], u0, v0,
                             iterations)
        if ok and (uf - u0) ** 2 + (vf - v0) ** 2 < 4.0:
            u0, v0 = uf, vf
    return u0, v0, lv, True
