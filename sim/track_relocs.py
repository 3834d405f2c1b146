"""How far each relocalisation put the camera from where it was: the pose of a relocalised frame
against the ground truth, relative to the last pose before the loss (a wrong relocalisation is a
jump the ground truth does not make; drift before the loss does not count)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sim.metrics import interpolate, umeyama
from sim.trajectory import Trajectory


def relocalisation_errors(groundtruth: Trajectory, estimate: Trajectory, segment: np.ndarray,
                          relocalised: np.ndarray) -> list[dict]:
    """Per relocalised pose (index into estimate, `relocalised`): its frame time, the rotation
    error (degrees) and position error (m, in the scale of its map fitted by Sim(3) to the
    ground truth over the map's poses before it) of the motion from the map's last pose before
    it to it. Poses outside the ground truth, or without three earlier poses in their map
    (`segment` of each pose), are left out."""
    gt, covered = interpolate(groundtruth, estimate.t)
    where = np.cumsum(covered) - 1  # row of each covered pose in gt
    out = []
    for j in relocalised:
        before = np.flatnonzero(covered[:j] & (segment[:j] == segment[j]))
        if not covered[j] or len(before) < 3:
            continue
        i = before[-1]
        _, _, s = umeyama(estimate.positions[before], gt.positions[where[before]], True)
        E, G = estimate.matrices(), gt.matrices()
        rel_est = np.linalg.inv(E[i]) @ E[j]
        rel_gt = np.linalg.inv(G[where[i]]) @ G[where[j]]
        rot = Rotation.from_matrix(rel_gt[:3, :3].T @ rel_est[:3, :3]).magnitude()
        out.append({"t": float(estimate.t[j]), "rot_err_deg": float(np.degrees(rot)),
                    "pos_err_m": float(np.linalg.norm(s * rel_est[:3, 3] - rel_gt[:3, 3]))})
    return out


def add_relocalisations(report: dict, groundtruth: Trajectory | None,
                        estimate: Trajectory | None, segment: np.ndarray,
                        relocalised: np.ndarray) -> None:
    """Put into a `sdvl track` report how many poses were relocalised and, with ground truth,
    each one's errors (relocalisation_errors) and the largest of them."""
    report["relocalisations"] = len(relocalised)
    events = []
    if groundtruth is not None and estimate is not None and len(relocalised):
        events = relocalisation_errors(groundtruth, estimate, segment, relocalised)
    report["relocalisation_errors"] = events
    report["reloc_max_rot_err_deg"] = max((e["rot_err_deg"] for e in events), default=None)
    report["reloc_max_pos_err_m"] = max((e["pos_err_m"] for e in events), default=None)


def format_relocalisations(report: dict) -> list[str]:
    """The report's line about relocalisations (none when there were none)."""
    n = report.get("relocalisations", 0)
    if not n:
        return []
    line = f"relocalised {n} times"
    if report["reloc_max_rot_err_deg"] is not None:
        line += (f"; largest jump error {report['reloc_max_rot_err_deg']:.2f} deg, "
                 f"{report['reloc_max_pos_err_m']:.3f} m (from the pose before the loss)")
    return [line]
