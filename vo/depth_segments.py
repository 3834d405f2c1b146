"""Where a map point's match may lie given its depth uncertainty: the segment of its epipolar
line that its inverse-depth interval projects to in a frame, and a match's distance from it.
A bad frame is held when enough of its matches lie on theirs (vo.map_matching, hold_frames)."""

from __future__ import annotations

import numba
import numpy as np

from vo.se3 import compose, inv_se3, transform


@numba.njit(cache=True, nogil=True)
def _distance_to_segment(px, py, ax, ay, bx, by):
    """Distance of the point p from the segment a-b (plane coordinates)."""
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    s = 0.0
    if length2 > 0.0:
        s = min(max(((px - ax) * dx + (py - ay) * dy) / length2, 0.0), 1.0)
    ex, ey = px - (ax + s * dx), py - (ay + s * dy)
    return np.sqrt(ex * ex + ey * ey)


@numba.njit(cache=True, nogil=True)
def segment_distances(T_c_w, kf_T_c_w, host, f, rho, half_width, obs):
    """Per match, the distance (normalised image plane, frame at T_c_w) of its observation obs
    from the segment that its point's inverse-depth interval rho +- half_width projects to
    (out to the vanishing point of its ray when rho - half_width <= 0); inf where an end of
    it lies behind the camera."""
    n = host.shape[0]
    out = np.full(n, np.inf)
    T_slot = np.empty((kf_T_c_w.shape[0], 4, 4))  # T_c_w times each slot's inverse, on use
    have = np.zeros(kf_T_c_w.shape[0], dtype=np.bool_)
    for i in range(n):
        if not have[host[i]]:
            T_slot[host[i]] = compose(T_c_w, inv_se3(kf_T_c_w[host[i]]))
            have[host[i]] = True
        T = T_slot[host[i]]
        # transform gives R f + t; the point at inverse depth r on the ray is R f + r t
        X, Y, Z = transform(T, f[i, 0], f[i, 1], f[i, 2])
        tx, ty, tz = T[0, 3], T[1, 3], T[2, 3]
        near = rho[i] + half_width[i] - 1.0
        far = max(rho[i] - half_width[i], 0.0) - 1.0
        X1, Y1, Z1 = X + near * tx, Y + near * ty, Z + near * tz
        X2, Y2, Z2 = X + far * tx, Y + far * ty, Z + far * tz
        if Z1 <= 1e-9 or Z2 <= 1e-9:
            continue
        out[i] = _distance_to_segment(obs[i, 0], obs[i, 1], X1 / Z1, Y1 / Z1, X2 / Z2, Y2 / Z2)
    return out
