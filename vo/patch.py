"""Pixel-level kernels on flat pyramids: bilinear sampling, affine-warped 8x8 patches, ZMSSD and
inverse-compositional 2-D alignment (Baker & Matthews) with an intensity offset."""

from __future__ import annotations

import numba
import numpy as np

PATCH = 8
HALF = PATCH // 2
BORDER_PATCH = PATCH + 2  # one pixel of border all round, for gradients
PATCH_AREA = PATCH * PATCH
# sums over a patch's pixels may be reordered (vector lanes): they differ from a sum in pixel
# order only in rounding
REORDER = {"reassoc"}


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
    # an affine warp's patch lies within its four corners: check those, then sample all
    for r in (0, BORDER_PATCH - 1):
        for c in (0, BORDER_PATCH - 1):
            dx = (c - half) * step
            dy = (r - half) * step
            x = (A_ref_cur[0, 0] * dx + A_ref_cur[0, 1] * dy) * inv_ref + cx
            y = (A_ref_cur[1, 0] * dx + A_ref_cur[1, 1] * dy) * inv_ref + cy
            if not inside(x, y, w, h, 0):
                return False
    for r in range(BORDER_PATCH):
        for c in range(BORDER_PATCH):
            dx = (c - half) * step
            dy = (r - half) * step
            x = (A_ref_cur[0, 0] * dx + A_ref_cur[0, 1] * dy) * inv_ref + cx
            y = (A_ref_cur[1, 0] * dx + A_ref_cur[1, 1] * dy) * inv_ref + cy
            out[r, c] = sample(flat, off, w, x, y)
    return True


@numba.njit(cache=True, nogil=True, fastmath=REORDER)
def zmssd(ref_border, flat, off, w, x, y):
    """Zero-mean SSD between the 8x8 interior of `ref_border` and the image patch centred at
    integer pixel (x, y) (caller checks bounds); the sums in vector lanes (REORDER)."""
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


@numba.njit(cache=True, nogil=True, fastmath=REORDER)
def align2d(flat, off, w, h, ref_border, u, v, iterations):
    """Sub-pixel position of the reference patch near (u, v) at one level: inverse-compositional
    Gauss-Newton on translation plus an intensity offset. Returns (u, v, converged).

    The patch's pixels are one pixel apart, so one set of bilinear weights samples all of
    them (those `sample` computes for the first), and the sums over the pixels run in vector
    lanes (REORDER): this runs for every point matched."""
    n = PATCH_AREA
    buf = np.empty(4 * n)
    gx, gy, ref, res = buf[:n], buf[n:2 * n], buf[2 * n:3 * n], buf[3 * n:]
    for r in range(PATCH):
        for c in range(PATCH):
            k = r * PATCH + c
            gx[k] = 0.5 * (ref_border[r + 1, c + 2] - ref_border[r + 1, c])
            gy[k] = 0.5 * (ref_border[r + 2, c + 1] - ref_border[r, c + 1])
            ref[k] = ref_border[r + 1, c + 1]
    # normal matrix of J = (gx, gy, 1), symmetric, and its inverse by cofactors
    sxx = sxy = sx = syy = sy = 0.0
    for k in range(n):
        sxx += gx[k] * gx[k]
        sxy += gx[k] * gy[k]
        sx += gx[k]
        syy += gy[k] * gy[k]
        sy += gy[k]
    s1 = float(n)
    c00, c01, c02 = syy * s1 - sy * sy, sy * sx - sxy * s1, sxy * sy - syy * sx
    det = sxx * c00 + sxy * c01 + sx * c02
    if abs(det) < 1e-9:
        return u, v, False
    i00, i01, i02 = c00 / det, c01 / det, c02 / det
    i11, i12 = (sxx * s1 - sx * sx) / det, (sxy * sx - sxx * sy) / det
    i22 = (sxx * syy - sxy * sxy) / det
    offset = 0.0
    for _ in range(iterations):
        if not inside(u, v, w, h, HALF + 1):
            return u, v, False
        x0, y0 = u - HALF, v - HALF
        ix, iy = np.floor(x0), np.floor(y0)
        ax, ay = x0 - ix, y0 - iy
        w00, w01, w10, w11 = (1.0 - ax) * (1.0 - ay), ax * (1.0 - ay), (1.0 - ax) * ay, ax * ay
        base = off + int(iy) * w + int(ix)
        for r in range(PATCH):
            row = base + r * w
            for c in range(PATCH):
                b = row + c
                res[r * PATCH + c] = (w00 * flat[b] + w01 * flat[b + 1] + w10 * flat[b + w]
                                      + w11 * flat[b + w + 1]) - ref[r * PATCH + c] + offset
        b0 = b1 = b2 = 0.0
        for k in range(n):
            b0 -= gx[k] * res[k]
            b1 -= gy[k] * res[k]
            b2 -= res[k]
        du = i00 * b0 + i01 * b1 + i02 * b2
        dv = i01 * b0 + i11 * b1 + i12 * b2
        offset += i02 * b0 + i12 * b1 + i22 * b2
        u += du
        v += dv
        if du * du + dv * dv < 0.03 * 0.03:
            return u, v, True
    return u, v, False
