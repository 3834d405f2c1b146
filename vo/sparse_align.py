"""Sparse direct image alignment (thesis 6.7.1): the pose of the new frame relative to the last
one, from 4x4 patches around the last frame's matched points, inverse-compositional
Gauss-Newton on SE(3), coarse to fine.

The thesis minimises the plain sum of squared intensity residuals (6.10). Here each pixel's
residual is Tukey-weighted (as the pose refinement of 6.7.3 is), with a scale fixed per level
from the residuals where the level starts: a few patches that no longer look like their
reference (a point placed at a wrong depth, a patch across an occluding edge) otherwise pull
the least-squares optimum, for a camera looking down along its tilt-versus-sideways-move
ambiguity (RESULTS.md: tracker-align-robust)."""

from __future__ import annotations

import numba
import numpy as np

from calib.camera import project_point
from vo.normal_equations import solve_spd
from vo.patch import inside, sample, to_level
from vo.pose_optimizer import MAD_TO_SIGMA, TUKEY_C
from vo.se3 import compose, exp_se3, plane_jacobian, transform

HALF4 = 2
N4 = 16
# the Tukey scale is at least this (intensity levels): a start already at the optimum has
# residuals near zero, and a scale from them would weight out the sensor noise
MIN_SCALE = 1.0
# the sums of the hot loops may be reordered (vector lanes): they differ from a sum in pixel
# order only in rounding
REORDER = {"reassoc"}


@numba.njit(cache=True, nogil=True)
def reference_patches(image, level, px, xyz, fx, fy):
    """4x4 reference patches (N, 16) at `level` (`image` = (flat pyramid, offset, width,
    height) of the level) around level-0 pixels px (N, 2) of points xyz (N, 3) in the
    reference camera, their photometric Jacobians (6, N * 16: per twist component, pixel by
    pixel, patch after patch) and a validity mask."""
    flat, off, w, h = image
    n = px.shape[0]
    s = 2.0 ** level
    patches = np.zeros((n, N4))
    jac = np.zeros((6, n * N4))
    valid = np.zeros(n, dtype=np.bool_)
    Jp = np.zeros((2, 6))
    for i in range(n):
        u = to_level(px[i, 0], level)
        v = to_level(px[i, 1], level)
        if not inside(u, v, w, h, HALF4 + 2):
            continue
        valid[i] = True
        plane_jacobian(xyz[i, 0], xyz[i, 1], xyz[i, 2], Jp)
        k = 0
        for r in range(-HALF4, HALF4):
            for c in range(-HALF4, HALF4):
                x = u + c
                y = v + r
                patches[i, k] = sample(flat, off, w, x, y)
                gx = 0.5 * (sample(flat, off, w, x + 1.0, y) - sample(flat, off, w, x - 1.0, y))
                gy = 0.5 * (sample(flat, off, w, x, y + 1.0) - sample(flat, off, w, x, y - 1.0))
                for j in range(6):
                    jac[j, i * N4 + k] = (gx * fx * Jp[0, j] + gy * fy * Jp[1, j]) / s
                k += 1
    return patches, jac, valid


@numba.njit(cache=True, nogil=True)
def _patch_centre(params, T_cur_ref, p_ref, level, w, h):
    """(visible, u, v): where a reference point's patch lands on a pyramid level of the
    current frame, with room for the whole patch."""
    X, Y, Z = transform(T_cur_ref, p_ref[0], p_ref[1], p_ref[2])
    u, v = project_point(params, X, Y, Z)
    if np.isnan(u):
        return False, 0.0, 0.0
    u = to_level(u, level)
    v = to_level(v, level)
    return inside(u, v, w, h, HALF4 + 1), u, v


@numba.njit(cache=True, nogil=True, fastmath=REORDER)
def _patch_residuals(params, image, level, patches, valid, xyz, T_cur_ref, res, seen):
    """Fill res (N * 16) with the intensity residuals (current - reference) of the patches
    visible at T_cur_ref, and seen with 1 for their pixels (0 and 0 for the others);
    returns how many pixels are seen. A patch's pixels are one pixel apart, so one set of
    bilinear weights serves all 16 (as `sample` computes them for its first pixel)."""
    flat, off, w, h = image
    n_seen = 0
    for i in range(patches.shape[0]):
        ok = False
        u = v = 0.0
        if valid[i]:
            ok, u, v = _patch_centre(params, T_cur_ref, xyz[i], level, w, h)
        if not ok:
            res[i * N4:(i + 1) * N4] = 0.0
            seen[i * N4:(i + 1) * N4] = 0.0
            continue
        x0, y0 = u - HALF4, v - HALF4
        ix, iy = np.floor(x0), np.floor(y0)
        ax, ay = x0 - ix, y0 - iy
        w00, w01 = (1.0 - ax) * (1.0 - ay), ax * (1.0 - ay)
        w10, w11 = (1.0 - ax) * ay, ax * ay
        base = off + int(iy) * w + int(ix)
        for r in range(2 * HALF4):
            b = base + r * w
            for c in range(2 * HALF4):
                k = r * 2 * HALF4 + c
                value = (w00 * flat[b + c] + w01 * flat[b + c + 1] + w10 * flat[b + c + w]
                         + w11 * flat[b + c + w + 1])
                res[i * N4 + k] = value - patches[i, k]
                seen[i * N4 + k] = 1.0
        n_seen += N4
    return n_seen


@numba.njit(cache=True, nogil=True)
def tukey_scale(residuals):
    """The Tukey scale (cut-off) for these residuals: TUKEY_C robust sigmas (MAD), at least
    TUKEY_C * MIN_SCALE; inf (plain least squares) without residuals."""
    if residuals.shape[0] == 0:
        return np.inf
    return TUKEY_C * max(MAD_TO_SIGMA * np.median(np.abs(residuals)), MIN_SCALE)


@numba.njit(cache=True, nogil=True, fastmath=REORDER)
def _normal_equations(res, seen, jac, c, wj):
    """H, b and the summed Tukey cost (cut-off c; inf for squared residuals) of the seen
    residuals (_patch_residuals) with Jacobians jac (6, P); wj (6, P) is scratch. Each sum
    runs over all pixels (weight 0 where unseen or beyond the cut-off) in loops the compiler
    spreads over vector lanes: the alignment's hot loop."""
    n = res.shape[0]
    cost = 0.0
    weight = wj[0]  # the weights first, then each row times its Jacobian row in its place
    if np.isfinite(c):
        k6 = c * c / 6.0
        for p in range(n):
            x2 = (res[p] / c) ** 2
            inlier = x2 < 1.0
            t = 1.0 - x2
            weight[p] = seen[p] * (t * t if inlier else 0.0)
            cost += seen[p] * (k6 * (1.0 - t * t * t) if inlier else k6)
    else:
        for p in range(n):
            cost += seen[p] * res[p] * res[p]
            weight[p] = seen[p]
    for a in range(5, -1, -1):
        row = wj[a]
        for p in range(n):
            row[p] = weight[p] * jac[a, p]
    H = np.empty((6, 6))
    b = np.empty(6)
    for a in range(6):
        acc = 0.0
        for p in range(n):
            acc += wj[a, p] * res[p]
        b[a] = acc
        for q in range(a, 6):
            acc = 0.0
            for p in range(n):
                acc += wj[a, p] * jac[q, p]
            H[a, q] = acc
            H[q, a] = acc
    return H, b, cost


@numba.njit(cache=True, nogil=True)
def align_level(params, image, level, patches, jac, valid, xyz, T_cur_ref, iterations, robust):
    """Gauss-Newton at one level (`image` as for reference_patches; Tukey-weighted with
    `robust`, the scale from the residuals at T_cur_ref); returns the refined T_cur_ref and the
    pixel count used."""
    T = T_cur_ref.copy()
    n = patches.shape[0] * N4
    res, seen, res_new = np.empty(n), np.empty(n), np.empty(n)
    wj = np.empty((6, n))
    count = _patch_residuals(params, image, level, patches, valid, xyz, T, res, seen)
    c = tukey_scale(res[seen > 0.0]) if robust else np.inf
    H, b, cost = _normal_equations(res, seen, jac, c, wj)
    for _ in range(iterations):
        if count < 6 * N4:
            break
        det, xi = solve_spd(H + 1e-9 * np.eye(6), b)
        if det == 0.0:
            break
        T_new = compose(T, exp_se3(-xi))
        count_new = _patch_residuals(params, image, level, patches, valid, xyz, T_new, res_new,
                                     seen)
        H_new, b_new, cost_new = _normal_equations(res_new, seen, jac, c, wj)
        if cost_new / max(count_new, 1) > cost / max(count, 1) or count_new < 6 * N4:
            break
        T, H, b, cost, count = T_new, H_new, b_new, cost_new, count_new
        if np.sqrt(xi @ xi) < 1e-10:
            break
    return T, count


@numba.njit(cache=True, nogil=True)
def _align_levels(params, ref, cur, px_ref, xyz_ref, T_cur_ref, levels, iterations, robust,
                  rotation_only):
    """align's levels max..min in one call: `ref`, `cur` = (flat, offsets, widths, heights)
    of the pyramids, `levels` = (max, min)."""
    T = T_cur_ref.copy()
    fx, fy = params[1], params[2]
    for level in range(levels[0], levels[1] - 1, -1):
        patches, jac, valid = reference_patches(
            (ref[0], ref[1][level], ref[2][level], ref[3][level]), level, px_ref, xyz_ref, fx, fy)
        if rotation_only:
            jac[:3] = 0.0  # no gradient along translation: the update only turns
        T, _ = align_level(params, (cur[0], cur[1][level], cur[2][level], cur[3][level]), level,
                           patches, jac, valid, xyz_ref, T, iterations, robust)
    return T


def align(params: np.ndarray, ref_pyr, cur_pyr, px_ref: np.ndarray, xyz_ref: np.ndarray,
          T_cur_ref: np.ndarray, max_level: int, min_level: int, iterations: int,
          robust: bool = True, rotation_only: bool = False) -> np.ndarray:
    """T_cur_ref refined by aligning 4x4 patches around px_ref (level 0) of points xyz_ref (in
    the reference camera) from the reference pyramid to the current one, levels max..min;
    `robust` Tukey-weights the residuals (else plain least squares, as the thesis);
    `rotation_only` keeps the translation of T_cur_ref (from one without, the camera turns
    where the reference stood)."""
    return _align_levels(params, (ref_pyr.flat, *ref_pyr.layout), (cur_pyr.flat, *cur_pyr.layout),
                         np.ascontiguousarray(px_ref, dtype=np.float64),
                         np.ascontiguousarray(xyz_ref, dtype=np.float64),
                         np.ascontiguousarray(T_cur_ref, dtype=np.float64),
                         (max_level, min_level), iterations, robust, rotation_only)


@numba.njit(cache=True, nogil=True)
def _residual_ratio(params, image, level, patches, valid, xyz, T_cur_ref):
    """Zero-mean residual energy of the patches over their own zero-mean energy (per patch
    mean removed, so a brightness change costs nothing); inf when no patch is visible."""
    n = patches.shape[0]
    res, seen = np.empty(n * N4), np.empty(n * N4)
    _patch_residuals(params, image, level, patches, valid, xyz, T_cur_ref, res, seen)
    err = 0.0
    energy = 0.0
    for i in range(n):
        if seen[i * N4] == 0.0:
            continue
        patch = patches[i]
        own = res[i * N4:(i + 1) * N4]
        ref_mean = patch.mean()
        res_mean = own.mean()
        for k in range(N4):
            err += (own[k] - res_mean) ** 2
            energy += (patch[k] - ref_mean) ** 2
    return err / energy if energy > 0.0 else np.inf


def residual_ratio(params: np.ndarray, ref_pyr, cur_pyr, px_ref: np.ndarray,
                   xyz_ref: np.ndarray, T_cur_ref: np.ndarray, level: int) -> float:
    """How badly the reference patches fit the current image at T_cur_ref (at `level`): 0 for
    a perfect fit, about 1 against a blank image, about 2 against unrelated texture."""
    patches, _, valid = reference_patches(level_image(ref_pyr, level), level, px_ref, xyz_ref,
                                          float(params[1]), float(params[2]))
    return _residual_ratio(params, level_image(cur_pyr, level), level, patches, valid, xyz_ref,
                           np.ascontiguousarray(T_cur_ref, dtype=np.float64))


def level_image(pyr, level: int) -> tuple:
    """(flat pyramid, offset, width, height) of one level of a vo.frame.Pyramid."""
    return pyr.flat, pyr.offsets[level], pyr.widths[level], pyr.heights[level]
