"""Per-pixel ray casting of a quad scene: exact perspective (any calib.camera model: the rays
are the camera's own unprojected pixel centres), depth test, and trilinear mip-mapped texture
sampling whose level follows each pixel's footprint on the surface, so far textures do not
shimmer.

Each quad is only tested on the pixels inside the bounding box of its near-clipped outline,
so the cost is about the image area times the overdraw, not pixels times quads.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from calib.camera import CameraModel
from sim.synth.scene import QuadList, Scene

NEAR = 0.02  # m: nearer surfaces are clipped
MIN_COS = 0.02  # grazing-angle limit of the footprint estimate


@functools.lru_cache(maxsize=8)
def camera_rays(camera: CameraModel) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Per camera, cached: unit rays (H, W, 3) through pixel centres, each pixel's angular size
    (H, W) rad, and the normalised-plane extent of every column and row (min/max of x/z and y/z:
    (2, W) and (2, H)) used to bound which pixels a quad can cover."""
    w, h = camera.width, camera.height
    u, v = np.meshgrid(np.arange(w + 1, dtype=np.float64), np.arange(h + 1, dtype=np.float64))
    rays = camera.unproject(np.column_stack([u.ravel(), v.ravel()])).reshape(h + 1, w + 1, 3)
    du = np.arccos(np.clip(np.sum(rays[:-1, 1:] * rays[:-1, :-1], -1), -1, 1))
    dv = np.arccos(np.clip(np.sum(rays[1:, :-1] * rays[:-1, :-1], -1), -1, 1))
    centre = np.ascontiguousarray(rays[:-1, :-1])
    if np.any(centre[..., 2] <= 0):
        raise ValueError("the renderer needs every pixel ray in front of the camera (< 180 deg)")
    xn, yn = centre[..., 0] / centre[..., 2], centre[..., 1] / centre[..., 2]
    cols = np.stack([xn.min(axis=0), xn.max(axis=0)])
    rows = np.stack([yn.min(axis=1), yn.max(axis=1)])
    # float32 halves the memory the kernels stream through; 1e-7 rad is far below a pixel
    return (centre.astype(np.float32), np.maximum(du, dv).astype(np.float32), (cols, rows))


def _clip_near(points: np.ndarray) -> np.ndarray:
    """The polygon (N, 3) camera-frame points clipped to z >= NEAR (Sutherland-Hodgman)."""
    out = []
    n = len(points)
    for i in range(n):
        a, b = points[i], points[(i + 1) % n]
        if a[2] >= NEAR:
            out.append(a)
        if (a[2] >= NEAR) != (b[2] >= NEAR):
            s = (NEAR - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out).reshape(-1, 3)


def _pixel_span(lo: np.ndarray, hi: np.ndarray, low_edge: np.ndarray,
                high_edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last column (or row) whose normalised-plane extent overlaps [lo, hi]; the
    extents are made monotonic (conservatively) so a binary search finds them."""
    high_edge = np.maximum.accumulate(high_edge)
    low_edge = np.minimum.accumulate(low_edge[::-1])[::-1]
    first = np.searchsorted(high_edge, lo, "left")
    last = np.searchsorted(low_edge, hi, "right") - 1
    return first, last


def quad_bounds(quads: QuadList, R_w_c: np.ndarray, c_w: np.ndarray,
                cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(Q, 4) pixel box [col0, col1, row0, row1] (inclusive) each quad may cover; col0 = -1
    when it cannot be seen."""
    g = quads.geometry
    o, u, v = g[:, None, 0:3], g[:, None, 3:6], g[:, None, 6:9]
    s = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)[None]
    eu, ev = g[:, None, 9:10], g[:, None, 10:11]
    corners = o + u * eu * s[..., :1] + v * ev * s[..., 1:]  # (Q, 4, 3)
    cam = (corners - c_w) @ R_w_c
    lo = np.full((len(quads), 2), np.inf)
    hi = np.full((len(quads), 2), -np.inf)
    front = np.all(cam[..., 2] >= NEAR, axis=1)
    xy = cam[front, :, :2] / cam[front, :, 2:]
    lo[front], hi[front] = xy.min(axis=1), xy.max(axis=1)
    for q in np.flatnonzero(~front & np.any(cam[..., 2] >= NEAR, axis=1)):
        poly = _clip_near(cam[q])
        lo[q], hi[q] = (poly[:, :2] / poly[:, 2:]).min(axis=0), (poly[:, :2] / poly[:, 2:]).max(0)
    c0, c1 = _pixel_span(lo[:, 0], hi[:, 0], cols[0], cols[1])
    r0, r1 = _pixel_span(lo[:, 1], hi[:, 1], rows[0], rows[1])
    out = np.column_stack([c0, c1, r0, r1]).astype(np.int64)
    seen = np.isfinite(lo[:, 0]) & (c0 <= c1) & (r0 <= r1)
    out[~seen] = -1
    return out


@numba.njit(cache=True, nogil=True)
def ray_quad(geom, q, ox, oy, oz, dx, dy, dz):
    """(t, a, b, |cos|) where the ray o + t d meets quad q at edge coordinates (a, b) metres;
    t = -1 if it misses."""
    ux, uy, uz = geom[q, 3], geom[q, 4], geom[q, 5]
    vx, vy, vz = geom[q, 6], geom[q, 7], geom[q, 8]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    denom = nx * dx + ny * dy + nz * dz
    if abs(denom) < 1e-12:
        return -1.0, 0.0, 0.0, 0.0
    rx, ry, rz = geom[q, 0] - ox, geom[q, 1] - oy, geom[q, 2] - oz
    t = (nx * rx + ny * ry + nz * rz) / denom
    if t <= 0.0:
        return -1.0, 0.0, 0.0, 0.0
    px, py, pz = t * dx - rx, t * dy - ry, t * dz - rz
    a = px * ux + py * uy + pz * uz
    b = px * vx + py * vy + pz * vz
    if a < 0.0 or b < 0.0 or a > geom[q, 9] or b > geom[q, 10]:
        return -1.0, 0.0, 0.0, 0.0
    return t, a, b, abs(denom)


@numba.njit(cache=True, nogil=True)
def _bilinear(pixels, offset, w, h, x, y):
    """Bilinear sample of one mip level at texel-centre coordinates, wrapping."""
    fx, fy = math.floor(x), math.floor(y)
    ax, ay = x - fx, y - fy
    x0, y0 = int(fx) & (w - 1), int(fy) & (h - 1)  # power-of-two sides: wrap by masking
    x1, y1 = (x0 + 1) & (w - 1), (y0 + 1) & (h - 1)
    r0, r1 = offset + y0 * w, offset + y1 * w
    top = pixels[r0 + x0] * (1.0 - ax) + pixels[r0 + x1] * ax
    bottom = pixels[r1 + x0] * (1.0 - ax) + pixels[r1 + x1] * ax
    return top * (1.0 - ay) + bottom * ay


@numba.njit(cache=True, nogil=True)
def sample_texture(pixels, levels, n_levels, tex, x, y, lod):
    """Mip-mapped sample of texture `tex` at level-0 texel coordinates (x, y), level `lod`:
    bilinear on the nearest level, blended with the next one around half-way between them."""
    top = n_levels[tex] - 1
    lod = min(max(lod, 0.0), float(top))
    lv = min(int(lod), top - 1) if top > 0 else 0
    # blend the two levels only in the middle half of the interval ("brilinear"): half the taps
    frac = min(max(2.0 * (lod - lv) - 0.5, 0.0), 1.0) if top > 0 else 0.0
    value = 0.0
    for k in range(2):
        weight = 1.0 - frac if k == 0 else frac
        if weight <= 0.0:
            continue
        scale = 1.0 / (1 << (lv + k))
        off, w, h = levels[tex, lv + k, 0], levels[tex, lv + k, 1], levels[tex, lv + k, 2]
        value += weight * _bilinear(pixels, off, w, h, x * scale - 0.5, y * scale - 0.5)
    return value


@numba.njit(cache=True, nogil=True)
def overlay_terms(overlay):
    """What every pixel's `overlay_sample` needs of overlay = (base id, overlay id, scale,
    angle, weight), computed once a frame: (scale, cos, sin, log2 scale, weight, base
    weight); the trigonometry per pixel was a third of a frame's shading."""
    k, w = overlay[2], overlay[4]
    return (k, math.cos(overlay[3]), math.sin(overlay[3]), math.log2(k) if k > 0.0 else 0.0,
            w, math.sqrt(1.0 - w * w))


@numba.njit(cache=True, nogil=True)
def overlay_sample(pixels, levels, n_levels, tex, terms, value, u, v, lod):
    """`value` of the base texture at texel (u, v) blended with overlay texture `tex`, sampled
    on a grid scaled and turned by `terms` (overlay_terms). Two tilings whose lattices never
    (nearly) coincide make a pattern that does not repeat at flight scale although each texture
    does."""
    k, ca, sa, log2k, w, base_w = terms
    over = sample_texture(pixels, levels, n_levels, tex, k * (ca * u - sa * v),
                          k * (sa * u + ca * v), lod + log2k)
    return 128.0 + base_w * (value - 128.0) + w * (over - 128.0)  # the contrast of one texture


@numba.njit(cache=True, nogil=True)
def nearest_quads(rays, R, c, geom, bounds):
    """Depth along the optical axis (inf where nothing is hit) and the index of the nearest
    quad (-1) of every pixel; each quad is tested only inside its pixel box."""
    h, w = rays.shape[0], rays.shape[1]
    depth = np.full((h, w), np.inf, np.float32)
    hit = np.full((h, w), -1, np.int32)
    for q in range(geom.shape[0]):
        if bounds[q, 0] < 0:
            continue
        for r in range(bounds[q, 2], bounds[q, 3] + 1):
            for col in range(bounds[q, 0], bounds[q, 1] + 1):
                x, y, z = rays[r, col, 0], rays[r, col, 1], rays[r, col, 2]
                dx = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
                dy = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
                dz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z
                t = ray_quad(geom, q, c[0], c[1], c[2], dx, dy, dz)[0]
                if t * z < NEAR or t * z >= depth[r, col]:
                    continue
                depth[r, col] = t * z
                hit[r, col] = q
    return depth, hit


@numba.njit(cache=True, nogil=True)
def shade(rays, pixel_angle, R, c, geom, tex, gain, hit, pixels, levels, n_levels, look):
    """Grey image (float32, 0..255 before effects): each pixel's quad, sampled at the mip level
    of the pixel's footprint on it. `look` = (background grey, detail (3), overlay (5)): where a
    texture is magnified (closer than one texel per pixel) the detail texture (id, frequency
    factor, amplitude; amplitude 0 = none) adds finer structure, fading in over one mip level;
    quads with the overlay's base texture get a second texture on top (see `overlay_sample`)."""
    background, detail, overlay = look[0], look[1:4], look[4:9]
    terms, base_tex, over_tex = overlay_terms(overlay), int(overlay[0]), int(overlay[1])
    fine_lod = math.log2(detail[1]) if detail[1] > 0.0 else 0.0
    h, w = rays.shape[0], rays.shape[1]
    image = np.full((h, w), background, np.float32)
    for r in range(h):
        for col in range(w):
            q = hit[r, col]
            if q < 0:
                continue
            x, y, z = rays[r, col, 0], rays[r, col, 1], rays[r, col, 2]
            dx = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
            dy = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
            dz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z
            t, a, b, cos = ray_quad(geom, q, c[0], c[1], c[2], dx, dy, dz)
            texel = geom[q, 11]
            footprint = t * pixel_angle[r, col] / max(cos, MIN_COS)
            lod = math.log2(max(footprint / texel, 1e-9))
            u = a / texel + geom[q, 12]
            v = b / texel + geom[q, 13]
            value = sample_texture(pixels, levels, n_levels, tex[q], u, v, lod)
            if tex[q] == base_tex:
                value = overlay_sample(pixels, levels, n_levels, over_tex, terms, value, u, v,
                                       lod)
            if lod < 0.0 and detail[2] > 0.0:
                k = detail[1]
                fine = sample_texture(pixels, levels, n_levels, int(detail[0]), u * k, v * k,
                                      lod + fine_lod)
                value += min(-lod, 1.0) * detail[2] * (fine - 128.0)
            image[r, col] = gain[q] * value
    return image


@numba.njit(cache=True, nogil=True)
def cast_ray(geom, ox, oy, oz, dx, dy, dz):
    """Distance along the unit ray to the nearest quad, inf if none (rangefinders)."""
    best = np.inf
    for q in range(geom.shape[0]):
        t = ray_quad(geom, q, ox, oy, oz, dx, dy, dz)[0]
        if 0.0 < t < best:
            best = t
    return best


@dataclass
class Surfaces:
    """What a camera sees at one instant, without effects: grey image (float32 0..255), depth
    along the optical axis (float32 m, inf where empty), the index of the quad each pixel
    sees (-1: none) in `quads`, the scene's quads at that time."""

    image: np.ndarray
    depth: np.ndarray
    hit: np.ndarray
    quads: QuadList


def render_surfaces(scene: Scene, camera: CameraModel, T_w_c: np.ndarray,
                    t: float = 0.0) -> Surfaces:
    """The Surfaces of `scene` at time `t` from camera pose T_w_c (4x4)."""
    rays, pixel_angle, (cols, rows) = camera_rays(camera)
    quads = scene.quads_at(t)
    R = np.ascontiguousarray(T_w_c[:3, :3], dtype=np.float64)
    c = np.ascontiguousarray(T_w_c[:3, 3], dtype=np.float64)
    bounds = quad_bounds(quads, R, c, cols, rows)
    depth, hit = nearest_quads(rays, R, c, quads.geometry, bounds)
    atlas = scene.atlas
    look = np.array([float(scene.background), *(scene.detail or (0.0, 1.0, 0.0)),
                     *(scene.overlay or (-1.0, 0.0, 1.0, 0.0, 0.0))], dtype=np.float64)
    image = shade(rays, pixel_angle, R, c, quads.geometry, quads.texture, quads.gain, hit,
                  atlas.pixels, atlas.levels, atlas.n_levels, look)
    return Surfaces(image, depth, hit, quads)


def render(scene: Scene, camera: CameraModel, T_w_c: np.ndarray,
           t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Image (float32 grey, no effects) and depth map (float32 m, inf where empty) of `scene`
    at time `t` from camera pose T_w_c (4x4)."""
    surfaces = render_surfaces(scene, camera, T_w_c, t)
    return surfaces.image, surfaces.depth
