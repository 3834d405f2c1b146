"""Pixel-level kernels on flat pyramids: bilinear sampling, affine-warped 8x8 patches, ZMSSD and
inverse-compositional 2-D alignment (Baker & Matthews) with an intensity offset."""

from __future__ import annotations

import numba
import numpy as np

PATCH = 8
HALF = PATCH // 2
BORDER_PATCH = PATCH + 2  # one pixel of border all round, for gradients
PATCH_AREA = PATCH * PATCH


@numba.njit(cache=True, nogil=True)
def to_level(x, level):
    """Level-0 pixel coordinate -> coordinate at `level` (pyrDown pixel centres)."""
    s = 2.0 ** level
    return (x + 0.5) / s - 0.5


@numba.njit(cache=True, nogil=True)
def from_level(x, level):
    """Coordinate at `level` -> level-0 pixel coordinate."""
    s = 2.0 ** level
    return (x + 0.5) * s - 0.5


@numba.njit(cache=True, nogil=True)
def sample(flat, off, w, x, y):
    """Bilinear intensity at (x, y) of the level stored at `off` with row width `w` (no checks)."""
    ix = int(np.floor(x))
    iy = int(np.floor(y))
    ax = x - ix
    ay = y - iy
    b = off + iy * w + ix
    return ((1.0 - ax) * (1.0 - ay) * flat[b] + ax * (1.0 - ay) * flat[b + 1]
            + (1.0 - ax) * ay * flat[b + w] + ax * ay * flat[b + w + 1])


@numba.njit(cache=True, nogil=True)
def inside(x, y, w, h, border):
    """True when a `border`-pixel window around (x, y) can be sampled bilinearly."""
    return x >= border and y >= border and x < w - 1 - border and y < h - 1 - border


@numba.njit(cache=True, nogil=True)
def warp_patch(flat, off, w, h, A_ref_cur, u_ref, v_ref, ref_level, search_level, out):
    """Fill `out` (10x10) with the reference image seen through the affine warp A_ref_cur.

    Patch pixels are steps of 2**search_level level-0 pixels in the current image, mapped into
    the reference keyframe around its level-0 pixel (u_ref, v_ref) and sampled at `ref_level`
    (its `off`, `w`, `h`). False when the warped patch leaves the reference image.
    """
    step = 2.0 ** search_level
    inv_ref = 1.0 / 2.0 ** ref_level
    half = BORDER_PATCH // 2
    cx = to_level(u_ref, ref_level)
    cy = to_level(v_ref, ref_level)
    for r in range(BORDER_PATCH):
        for c in range(BORDER_PATCH):
            dx = (c - half) * step
            dy = (r - half) * step
            x = (A_ref_cur[0, 0] * dx + A_ref_cur[0, 1] * dy) * inv_ref + cx
            y = (A_ref_cur[1, 0] * dx + A_ref_cur[1, 1] * dy) * inv_ref + cy
            if not inside(x, y, w, h, 0):
                return False
            out[r, c] = sample(flat, off, w, x, y)
    return True


@numba.njit(cache=True, nogil=True)
def zmssd(ref_border, flat, off, w, x, y):
    """Zero-mean SSD between the 8x8 interior of `ref_border` and the image patch centred at
    integer pixel (x, y) (caller checks bounds)."""
    sa = 0.0
    sb = 0.0
    saa = 0.0
    sbb = 0.0
    sab = 0.0
    for r in range(PATCH):
        base = off + (y - HALF + r) * w + (x - HALF)
        for c in range(PATCH):
            a = ref_border[r + 1, c + 1]
            b = float(flat[base + c])
            sa += a
            sb += b
            saa += a * a
            sbb += b * b
            sab += a * b
    n = float(PATCH_AREA)
    return (saa - 2.0 * sab + sbb) - (sa * sa - 2.0 * sa * sb + sb * sb) / n


@numba.njit(cache=True, nogil=True)
def align2d(flat, off, w, h, ref_border, u, v, iterations):
    """Sub-pixel position of the reference patch near (u, v) at one level: inverse-compositional
    Gauss-Newton on translation plus an intensity offset. Returns (u, v, converged)."""
    n = PATCH_AREA
    gx = np.empty(n)
    gy = np.empty(n)
    ref = np.empty(n)
    H = np.zeros((3, 3))
    k = 0
    for r in range(1, PATCH + 1):
        for c in range(1, PATCH + 1):
            gx[k] = 0.5 * (ref_border[r, c + 1] - ref_border[r, c - 1])
            gy[k] = 0.5 * (ref_border[r + 1, c] - ref_border[r - 1, c])
            ref[k] = ref_border[r, c]
            J = (gx[k], gy[k], 1.0)
            for i in range(3):
                for j in range(3):
                    H[i, j] += J[i] * J[j]
            k += 1
    if abs(np.linalg.det(H)) < 1e-9:
        return u, v, False
    Hinv = np.linalg.inv(H)
    offset = 0.0
    for _ in range(iterations):
        if not inside(u, v, w, h, HALF + 1):
            return u, v, False
        b0 = 0.0
        b1 = 0.0
        b2 = 0.0
        k = 0
        for r in range(PATCH):
            for c in range(PATCH):
                res = sample(flat, off, w, u + c - HALF, v + r - HALF) - ref[k] + offset
                b0 -= gx[k] * res
                b1 -= gy[k] * res
                b2 -= res
                k += 1
        du = Hinv[0, 0] * b0 + Hinv[0, 1] * b1 + Hinv[0, 2] * b2
        dv = Hinv[1, 0] * b0 + Hinv[1, 1] * b1 + Hinv[1, 2] * b2
        offset += Hinv[2, 0] * b0 + Hinv[2, 1] * b1 + Hinv[2, 2] * b2
        u += du
        v += dv
        if du * du + dv * dv < 0.03 * 0.03:
            return u, v, True
    return u, v, False
