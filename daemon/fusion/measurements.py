"""Measurement updates of the navigation filter, each gated by its innovation's chi-square.

A gated-out measurement changes nothing. Range and baro readings that keep failing the gate
(new terrain under the vehicle, a baro step) re-reference their offset state instead.
"""

from __future__ import annotations

import numpy as np

from daemon.fusion.state import (
    ANCHOR,
    BARO,
    BIAS,
    DIM,
    GROUND,
    LOG_SCALE,
    POS,
    THETA,
    TIME_OFFSET,
    VEL,
    VO_TILT,
    NavFilter,
    matrix_to_rotvec,
    rotvec_to_matrix,
    skew,
)


def gated_update(f: NavFilter, z: np.ndarray, h: np.ndarray, H: np.ndarray, R: np.ndarray,
                 gate: float, frozen: np.ndarray | None = None) -> bool:
    """One EKF update with measurement z, prediction h, Jacobian H and noise R; False (and no
    change) when the innovation fails the chi-square gate or the result is not finite.
    `frozen` = a (states x measurement rows) mask of gains to zero: those rows must not change
    those states (a Schmidt update; the Joseph form keeps the covariance right)."""
    S = H @ f.P @ H.T + R
    y = z - h
    try:
        d2 = float(y @ np.linalg.solve(S, y))
    except np.linalg.LinAlgError:
        return False
    if not np.isfinite(d2) or d2 > gate:
        return False
    K = f.P @ H.T @ np.linalg.inv(S)
    if frozen is not None:
        K[frozen] = 0.0
    I_KH = np.eye(DIM) - K @ H
    x = f.x + K @ y
    P = I_KH @ f.P @ I_KH.T + K @ R @ K.T  # Joseph form: right for any gain
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
        return False
    f.x, f.P = x, 0.5 * (P + P.T)
    return True


def fold_alignment(f: NavFilter) -> None:
    """Move the estimated small rotation theta into the nominal alignment R_nom."""
    f.R_nom = rotvec_to_matrix(f.x[THETA]) @ f.R_nom
    f.x[THETA] = 0.0


def _position_rows(f: NavFilter, p_w: np.ndarray, R_n_b: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z, h, H, u) of the tracker's camera position, rotated into N axes (tracker units); u is
    the camera's offset from the anchor in metres."""
    x = f.x
    s_inv = float(np.exp(-x[LOG_SCALE]))
    camera, J = f.camera(R_n_b)
    u = camera - x[ANCHOR]
    h = s_inv * u
    H = s_inv * J
    H[:, ANCHOR] = -s_inv * np.eye(3)
    H[:, LOG_SCALE] = -h
    H[:, THETA] = s_inv * skew(u)
    return f.R_nom @ (np.asarray(p_w, float) - f.p_w0), h, H, u


def _alignment_rows(f: NavFilter, R_n_b_autopilot: np.ndarray, R_w_b: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(z, h, H) of the autopilot's attitude against the tracker's: a direct look at R_N_w,
    less the tracker's own tilt error."""
    H = np.zeros((3, DIM))
    H[:, THETA] = np.eye(3)
    H[:2, VO_TILT] = -np.eye(2)
    return (matrix_to_rotvec(R_n_b_autopilot @ R_w_b.T @ f.R_nom.T),
            f.x[THETA] - np.append(f.x[VO_TILT], 0.0), H)


def tilt_coupling(cov_n: np.ndarray) -> np.ndarray:
    """The tracker's position error per radian of its tilt error (3x2, tracker units, N axes):
    its covariance's regression of position on rotation about north and east."""
    try:
        return cov_n[:3, 3:5] @ np.linalg.pinv(cov_n[3:5, 3:5], rcond=1e-9)
    except np.linalg.LinAlgError:
        return np.zeros((3, 2))


def _without_motion(rows: int, climbing: bool) -> np.ndarray:
    """The gains a tracker update must not use without an IMU. Then nothing independent of the
    map knows the horizontal motion (a constant-velocity model only echoes the map), so the map
    cannot say where its anchor is or what its scale is: only the vertical row, against the
    barometer or rangefinder, may move the anchor's height, and the scale in a climb. Nor
    the clocks' offset: the map's own motion cannot time it against itself."""
    mask = np.zeros((DIM, rows), dtype=bool)
    mask[LOG_SCALE, [i for i in range(rows) if not (i == 2 and climbing)]] = True
    mask[TIME_OFFSET, :] = True
    return mask


def vo_position_floor(f: NavFilter) -> float:
    """The least variance of a tracker position (map units^2): vo_position_std_m at the
    filter's scale."""
    return (f.cfg.vo_position_std_m * float(np.exp(-f.x[LOG_SCALE]))) ** 2


def update_vo(f: NavFilter, p_w: np.ndarray, cov_w: np.ndarray, R_n_b: np.ndarray,
              inflation: float, scale_from_motion: bool = True,
              attitude: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
              horizontal_inflation: float = 1.0) -> bool:
    """The tracker's camera position (its world frame and units); `cov_w` is its 6x6 pose
    covariance (position, rotation; tracker world), times `inflation`.

    With `attitude` = (the autopilot's R_n_b, the tracker's R_w_b, the autopilot's attitude
    noise in N, rad^2) position and attitude are one 6-dof update: the tracker's position errors
    over a flat scene are mostly its tilt errors times the height, and its covariance says so
    (position-rotation correlation near 1), so the autopilot's attitude corrects them.

    Without an IMU, `scale_from_motion` is False: horizontal motion says nothing about the scale
    then (only a constant-velocity guess would), so the horizontal rows do not update the scale
    (a Schmidt "consider" update: the scale's uncertainty still counts in their innovation).
    `horizontal_inflation` further inflates the north and east rows (variance factor)."""
    rotate = np.kron(np.eye(2), f.R_nom)
    cov_n = rotate @ cov_w @ rotate.T
    coupling = tilt_coupling(cov_n)
    z, h, H, u = _position_rows(f, p_w, R_n_b)
    h = h + coupling @ f.x[VO_TILT]
    H[:, VO_TILT] = coupling
    if attitude is not None:
        z_a, h_a, H_a = _alignment_rows(f, attitude[0], attitude[1])
        z, h, H = np.concatenate([z, z_a]), np.concatenate([h, h_a]), np.vstack([H, H_a])
    R = inflation * (cov_n + np.diag([vo_position_floor(f)] * 3 + [0.0] * 3))
    stretch = np.diag([np.sqrt(horizontal_inflation)] * 2 + [1.0] * 4)
    R = stretch @ R @ stretch
    gate = f.cfg.gate_chi2_3dof
    if attitude is None:
        R = R[:3, :3]
    else:
        R[3:, 3:] += attitude[2]
        R[:3, 3:] *= -1.0  # z_a carries minus the tracker's rotation error
        R[3:, :3] *= -1.0
        gate = f.cfg.gate_chi2_6dof
    frozen = np.zeros((DIM, len(z)), dtype=bool)
    if not scale_from_motion:
        frozen |= _without_motion(len(z), abs(u[2]) >= 1.0)
    if np.sqrt(f.P[LOG_SCALE, LOG_SCALE]) > f.cfg.nav_scale_std:
        frozen[np.r_[POS, VEL, BIAS]] = True  # the map teaches its scale, not the motion
    disagreement = (z[:3] - h[:3]) * f.scale  # metres, N axes
    ok = gated_update(f, z, h, H, R, gate, frozen)
    fold_alignment(f)
    f.rejections["vo"] = 0 if ok else f.rejections["vo"] + 1
    run = [] if ok else [*f.vo_disagreement, (float(f.t), disagreement)]
    f.vo_disagreement = run[-f.cfg.reset_after_rejections:]  # the run a re-alignment looks at
    return ok


def _scalar_update(f: NavFilter, which: str, z: float, index: int, std: float) -> bool:
    """z = x[index] - p_z (+ noise): the shared form of the range and baro models."""
    if not (f.has_ground if which == "range" else f.has_baro):
        f.reference(which, z, std)
        return True
    H = np.zeros((1, DIM))
    H[0, index] = 1.0
    H[0, 2] = -1.0
    h = np.array([f.x[index] - f.x[2]])
    ok = gated_update(f, np.array([z]), h, H, np.array([[std**2]]), f.cfg.gate_chi2_1dof)
    f.rejections[which] = 0 if ok else f.rejections[which] + 1
    if f.rejections[which] >= f.cfg.reset_after_rejections:
        f.reference(which, z, std)
    return ok


def update_range(f: NavFilter, distance: float, R_n_b: np.ndarray) -> bool:
    """Downward rangefinder: vertical distance to the ground = ground level - p_z."""
    cos_tilt = float(R_n_b[2, 2])
    if cos_tilt < np.cos(np.radians(f.cfg.range_max_tilt_deg)):
        return False
    std = (f.cfg.range_std_m + f.cfg.range_std_fraction * distance) * cos_tilt
    return _scalar_update(f, "range", distance * cos_tilt, GROUND, std)


def update_scene(f: NavFilter, log_height_units: float, lever_down: float,
                 spread_fraction: float) -> bool:
    """ln of the camera's height above the ground in map units (scene.py) = ln of its height
    above the rangefinder's ground level in metres - ln(scale); the ground the map sees differs
    from the rangefinder's by the terrain relief: the spread of the matched points' heights
    (`spread_fraction` of the height), at least terrain_relief_m."""
    cfg = f.cfg
    height = float(f.x[GROUND] - f.x[2] - lever_down)
    if not height > cfg.range_std_m:
        return False
    relief = max(cfg.terrain_relief_m, spread_fraction * height)
    std = float(np.hypot(relief, cfg.scene_height_std_fraction * height)) / height
    H = np.zeros((1, DIM))
    H[0, LOG_SCALE] = -1.0
    H[0, GROUND] = 1.0 / height
    H[0, 2] = -1.0 / height
    h = np.array([np.log(height) - f.x[LOG_SCALE]])
    return gated_update(f, np.array([log_height_units]), h, H, np.array([[std**2]]),
                        cfg.gate_chi2_1dof)


def update_baro(f: NavFilter, altitude: float) -> bool:
    """Barometric altitude = baro offset - p_z."""
    return _scalar_update(f, "baro", altitude, BARO, f.cfg.baro_std_m)



def update_rest(f: NavFilter, axes: int = 3) -> bool:
    """The vehicle stands still (rest.py): zero velocity along its first `axes` N axes (2:
    north and east, a vehicle on its gear that may be lifting)."""
    H = np.zeros((axes, DIM))
    H[:, VEL.start:VEL.start + axes] = np.eye(axes)
    R = np.eye(axes) * f.cfg.rest_velocity_std**2
    gate = f.cfg.gate_chi2_3dof if axes == 3 else f.cfg.gate_chi2_2dof
    return gated_update(f, np.zeros(axes), f.x[VEL][:axes].copy(), H, R, gate)


def update_from_start(f: NavFilter, p_w: np.ndarray, R_n_b: np.ndarray, log_scale: float,
                      scale_std: float) -> bool:
    """The camera where the map puts it at a new scale (ln, std), measured from where its
    segment started: the displacement since then at that scale, as uncertain as the scale,
    the alignment and the map's drift make it, plus the start's own uncertainty. Before a
    rescale the IMU carries (the map is then hung from the vehicle): the map saw what dead
    reckoning on an unknown scale did not, a take-off's sideways drift of 0.35 m that stayed
    in the position for the whole flight (closed loop, no rangefinder, seed 0)."""
    if f.segment_start is None:
        return False
    camera0, cov0, p_w0 = f.segment_start
    moved = float(np.exp(log_scale)) * (f.R_nom @ (np.asarray(p_w, float) - p_w0))
    turn = skew(moved)  # the alignment's error turns the displacement
    R = (cov0 + np.outer(moved, moved) * scale_std**2 + turn @ f.P[THETA, THETA] @ turn.T
         + np.eye(3) * (f.cfg.vo_position_std_m**2
                        + f.cfg.vo_drift_m_per_sqrt_m**2 * float(np.linalg.norm(moved))))
    camera, J = f.camera(R_n_b)
    return gated_update(f, camera0 + moved, camera, J, R, f.cfg.gate_chi2_3dof)
