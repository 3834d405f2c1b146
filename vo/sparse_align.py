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
from vo.patch import inside, sample, to_level
from vo.pose_optimizer import MAD_TO_SIGMA, TUKEY_C
from vo.se3 import exp_se3, plane_jacobian, transform

HALF4 = 2
N4 = 16
# the Tukey scale is at least this (intensity levels): a start already at the optimum has
# residuals near zero, and a scale from them would weight out the sensor noise
MIN_SCALE = 1.0


@numba.njit(cache=True, nogil=True)
def reference_patches(image, level, px, xyz, fx, fy):
    """4x4 reference patches at `level` (`image` as for _patch_residuals) around level-0 pixels
    px (N, 2) of points xyz (N, 3) in the reference camera, their photometric Jacobians
    (N, 16, 6) and a validity mask."""
    flat, off, w, h = image
    n = px.shape[0]
    s = 2.0 ** level
    patches = np.zeros((n, N4))
    jac = np.zeros((n, N4, 6))
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
                    jac[i, k, j] = (gx * fx * Jp[0, j] + gy * fy * Jp[1, j]) / s
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


@numba.njit(cache=True, nogil=True)
def _patch_residuals(params, image, level, patches, valid, xyz, T_cur_ref):
    """Intensity residuals (current - reference, one row per patch visible at T_cur_ref) and
    the index of each row's patch; `image` = (flat pyramid, offset, width, height) of the
    current frame's level."""
    flat, off, w, h = image
    res = np.empty((patches.shape[0], N4))
    rows = np.empty(patches.shape[0], dtype=np.int64)
    n = 0
    for i in range(patches.shape[0]):
        if not valid[i]:
            continue
        ok, u, v = _patch_centre(params, T_cur_ref, xyz[i], level, w, h)
        if not ok:
            continue
        k = 0
        for r in range(-HALF4, HALF4):
            for c in range(-HALF4, HALF4):
                res[n, k] = sample(flat, off, w, u + c, v + r) - patches[i, k]
                k += 1
        rows[n] = i
        n += 1
    return res[:n], rows[:n]


@numba.njit(cache=True, nogil=True)
def tukey_scale(residuals):
    """The Tukey scale (cut-off) for these residuals: TUKEY_C robust sigmas (MAD), at least
    TUKEY_C * MIN_SCALE; inf (plain least squares) without residuals."""
    if residuals.shape[0] == 0:
        return np.inf
    return TUKEY_C * max(MAD_TO_SIGMA * np.median(np.abs(residuals)), MIN_SCALE)


@numba.njit(cache=True, nogil=True)
def _normal_equations(res, rows, jac, c):
    """H, b, mean Tukey cost (cut-off c; inf for squared residuals) and pixel count of the
    residuals `res` of patches `rows` (_patch_residuals). The sums are kept in scalars (in
    registers: the hot loop of the alignment), each in the order of the pixels."""
    b0 = b1 = b2 = b3 = b4 = b5 = 0.0
    h00 = h01 = h02 = h03 = h04 = h05 = h11 = h12 = h13 = h14 = h15 = 0.0
    h22 = h23 = h24 = h25 = h33 = h34 = h35 = h44 = h45 = h55 = 0.0
    cost = 0.0
    robust = np.isfinite(c)
    for j in range(rows.shape[0]):
        i = rows[j]
        for k in range(N4):
            e = res[j, k]
            weight = 1.0
            if robust:
                x = e / c
                if x * x >= 1.0:
                    cost += c * c / 6.0
                    continue
                weight = (1.0 - x * x) ** 2
                cost += c * c / 6.0 * (1.0 - (1.0 - x * x) ** 3)
            else:
                cost += e * e
            j0, j1, j2, j3, j4, j5 = jac[i, k, 0], jac[i, k, 1], jac[i, k, 2], jac[i, k, 3], \
                jac[i, k, 4], jac[i, k, 5]
            w0, w1, w2 = weight * j0, weight * j1, weight * j2
            w3, w4, w5 = weight * j3, weight * j4, weight * j5
            b0 += w0 * e
            b1 += w1 * e
            b2 += w2 * e
            b3 += w3 * e
            b4 += w4 * e
            b5 += w5 * e
            h00 += w0 * j0
            h01 += w0 * j1
            h02 += w0 * j2
            h03 += w0 * j3
            h04 += w0 * j4
            h05 += w0 * j5
            h11 += w1 * j1
            h12 += w1 * j2
            h13 += w1 * j3
            h14 += w1 * j4
            h15 += w1 * j5
            h22 += w2 * j2
            h23 += w2 * j3
            h24 += w2 * j4
            h25 += w2 * j5
            h33 += w3 * j3
            h34 += w3 * j4
            h35 += w3 * j5
            h44 += w4 * j4
            h45 += w4 * j5
            h55 += w5 * j5
    H = np.array([[h00, h01, h02, h03, h04, h05], [h01, h11, h12, h13, h14, h15],
                  [h02, h12, h22, h23, h24, h25], [h03, h13, h23, h33, h34, h35],
                  [h04, h14, h24, h34, h44, h45], [h05, h15, h25, h35, h45, h55]])
    count = rows.shape[0] * N4
    return H, np.array([b0, b1, b2, b3, b4, b5]), cost / max(count, 1), count


@numba.njit(cache=True, nogil=True)
def align_level(params, image, level, patches, jac, valid, xyz, T_cur_ref, iterations, robust):
    """Gauss-Newton at one level (`image` as for _patch_residuals; Tukey-weighted with
    `robust`, the scale from the residuals at T_cur_ref); returns the refined T_cur_ref and the
    pixel count used."""
    T = T_cur_ref.copy()
    res, rows = _patch_residuals(params, image, level, patches, valid, xyz, T)
    c = tukey_scale(res.ravel()) if robust else np.inf
    H, b, cost, count = _normal_equations(res, rows, jac, c)
    for _ in range(iterations):
        if count < 6 * N4:
            break
        xi = np.linalg.solve(H + 1e-9 * np.eye(6), b)
        T_new = T @ exp_se3(-xi)
        res, rows = _patch_residuals(params, image, level, patches, valid, xyz, T_new)
        H_new, b_new, cost_new, count_new = _normal_equations(res, rows, jac, c)
        if cost_new > cost or count_new < 6 * N4:
            break
        T, H, b, cost, count = T_new, H_new, b_new, cost_new, count_new
        if np.sqrt(xi @ xi) < 1e-10:
            break
    return T, count


def align(params: np.ndarray, ref_pyr, cur_pyr, px_ref: np.ndarray, xyz_ref: np.ndarray,
          T_cur_ref: np.ndarray, max_level: int, min_level: int, iterations: int,
          robust: bool = True, rotation_only: bool = False) -> np.ndarray:
    """T_cur_ref refined by aligning 4x4 patches around px_ref (level 0) of points xyz_ref (in
    the reference camera) from the reference pyramid to the current one, levels max..min;
    `robust` Tukey-weights the residuals (else plain least squares, as the thesis);
    `rotation_only` keeps the translation of T_cur_ref (from one without, the camera turns
    where the reference stood)."""
    T = np.ascontiguousarray(T_cur_ref, dtype=np.float64)
    fx, fy = float(params[1]), float(params[2])
    for level in range(max_level, min_level - 1, -1):
        patches, jac, valid = reference_patches(level_image(ref_pyr, level), level, px_ref,
                                                xyz_ref, fx, fy)
        if rotation_only:
            jac[:, :, :3] = 0.0  # no gradient along translation: the update only turns
        T, _ = align_level(params, level_image(cur_pyr, level), level, patches, jac, valid,
                           xyz_ref, T, iterations, robust)
    return T


@numba.njit(cache=True, nogil=True)
def _residual_ratio(params, image, level, patches, valid, xyz, T_cur_ref):
    """Zero-mean residual energy of the patches over their own zero-mean energy (per patch
    mean removed, so a brightness change costs nothing); inf when no patch is visible."""
    res, rows = _patch_residuals(params, image, level, patches, valid, xyz, T_cur_ref)
    err = 0.0
    energy = 0.0
    for j in range(rows.shape[0]):
        patch = patches[rows[j]]
        ref_mean = patch.mean()
        res_mean = res[j].mean()
        for k in range(N4):
            err += (res[j, k] - res_mean) ** 2
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
