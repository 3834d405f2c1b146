"""How wrong each relocalisation was, against the ground truth: the jump from the last pose before
the loss to the relocalised pose compared with the true motion between them, and the orientation
error of both in their map (a wrong relocalisation adds error the map did not have; one that
returns to the map where it drifted less can lower it)."""

from __future__ import annotations

import numpy as np

from sim.metrics import interpolate, umeyama
from sim.trajectory import Trajectory


def relocalisation_errors(groundtruth: Trajectory, estimate: Trajectory, segment: np.ndarray,
                          relocalised: np.ndarray) -> list[dict]:
    """Per relocalised pose j (index into estimate) with i, the last pose of its map before it:
    its time; `jump_rot_err_deg` and `jump_pos_err_m`, the error of the motion from i to j
    (position in the map's scale, a Sim(3) fit of its poses up to i); `rot_err_deg` and
    `rot_err_before_deg`, the orientation errors of j and i after the rotation that best aligns
    the map's orientations up to i. Poses outside the ground truth, or without three earlier
    poses in their map (`segment` of each pose), are left out."""
    gt, covered = interpolate(groundtruth, estimate.t)
    where = np.cumsum(covered) - 1  # row of each covered pose in gt
    E, G = estimate.matrices(), gt.matrices()
    out = []
    for j in relocalised:
        before = np.flatnonzero(covered[:j] & (segment[:j] == segment[j]))
        if not covered[j] or len(before) < 3:
            continue
        i = before[-1]
        _, _, s = umeyama(estimate.positions[before], gt.positions[where[before]], True)
        rel_est = np.linalg.inv(E[i]) @ E[j]
        rel_gt = np.linalg.inv(G[where[i]]) @ G[where[j]]
        g_rot, e_rot = gt.rotations, estimate.rotations
        align = (g_rot[where[before]] * e_rot[before].inv()).mean()  # chordal L2 best fit
        err = (g_rot[where[[j, i]]].inv() * align * e_rot[[j, i]]).magnitude()
        jump = (g_rot[where[i]].inv() * g_rot[where[j]]).inv() * e_rot[i].inv() * e_rot[j]
        out.append({"t": float(estimate.t[j]),
                    "jump_rot_err_deg": float(np.degrees(jump.magnitude())),
                    "jump_pos_err_m": float(np.linalg.norm(s * rel_est[:3, 3] - rel_gt[:3, 3])),
                    "rot_err_deg": float(np.degrees(err[0])),
                    "rot_err_before_deg": float(np.degrees(err[1]))})
    return out


def add_relocalisations(report: dict, groundtruth: Trajectory | None,
                        estimate: Trajectory | None, segment: np.ndarray,
                        relocalised: np.ndarray) -> None:
    """Put into a `sdvl track` report how many poses were relocalised and, with ground truth,
    each one's errors (relocalisation_errors), the largest jump error and the most orientation
    error a relocalisation added to its map's."""
    report["relocalisations"] = len(relocalised)
    events = []
    if groundtruth is not None and estimate is not None and len(relocalised):
        events = relocalisation_errors(groundtruth, estimate, segment, relocalised)
    report["relocalisation_errors"] = events
    report["reloc_max_jump_rot_err_deg"] = max((e["jump_rot_err_deg"] for e in events),
                                               default=None)
    report["reloc_max_added_rot_err_deg"] = max(
        (e["rot_err_deg"] - e["rot_err_before_deg"] for e in events), default=None)


def format_relocalisations(report: dict) -> list[str]:
    """The report's line about relocalisations (none when there were none)."""
    n = report.get("relocalisations", 0)
    if not n:
        return []
    line = f"relocalised {n} times"
    if report["reloc_max_jump_rot_err_deg"] is not None:
        line += (f"; the largest errors: {report['reloc_max_jump_rot_err_deg']:.1f} deg in the "
                 f"jump from the pose before the loss, "
                 f"{report['reloc_max_added_rot_err_deg']:+.1f} deg of orientation error")
    return [line]
