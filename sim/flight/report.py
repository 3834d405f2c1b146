"""The report of a closed-loop flight: one verdict line a user can act on, then the figures
behind it, then `sdvl replay`'s expert figures. `flight_report` is a JSON-ready dict (KEYS);
`format_flight` prints it.

The limits are issue 27's acceptance for a first vision flight: a LOITER that holds within
0.3 m over 30 s, GUIDED corners within 0.3 m, no height step over 0.1 m, no failsafe, the
autopilot using our estimate within 5 s of take-off.
"""

from __future__ import annotations

from dataclasses import asdict

from sim.flight.runner import Outcome
from sim.flight.scores import FlightScores
from sim.replay.recording import stats_ms
from sim.replay.report import format_report

HOLD_LIMIT_M = 0.3
CORNER_LIMIT_M = 0.3
HEIGHT_STEP_LIMIT_M = 0.1
HEIGHT_HOLD_LIMIT_M = 0.3  # a hold's or a corner's height off by more is said in the verdict
EXTNAV_LIMIT_S = 5.0
# the barometer reads high under the rotors' wash (sim/autopilot/barometer.py); AP_Baro
# subtracts BARO1_THST_SCALE Pa per unit throttle when it is set
BARO_ADVICE = (" -> it flies on its barometer (EK3_SRC1_POSZ 1), which prop wash moves in "
               "flight: fit BARO1_THST_SCALE from a hover log")
DELAY_TOLERANCE_MS = 10.0  # a VISO_DELAY_MS this close to the measured latency is right
# what a user changes when a step fails with the autopilot's words (first match)
ADVICE = (
    ("VisOdom: not healthy", "no vision message reached the autopilot before arming: the "
     "service must publish while on the ground (its log says why it does not)"),
    ("requires position", "the autopilot has no position from our estimate: run sdvl "
     "check-autopilot (VISO_TYPE, EK3_SRC1_POSXY 6)"),
    ("Need Position Estimate", "the autopilot has no position from our estimate: run sdvl "
     "check-autopilot"),
    ("no vision", "no vision messages on the link: check the service's log and the link URL"),
    ("no position", "the autopilot does not use our estimate: run sdvl check-autopilot and "
     "check its EKF messages"),
    ("EKF", "the autopilot's EKF rejected our estimate (EKF variance): compare our "
     "covariance with VISO_POS_M_NSE and check VISO_DELAY_MS"),
)

KEYS = {
    "verdict": "one line: READY / NOT READY and what to change",
    "ready_loiter": "LOITER held within the limit with no failsafe or height step",
    "ready_guided": "ready_loiter and every GUIDED corner within the limit",
    "mission": "mission name", "world": "the synthetic preset flown over", "seed": "world seed",
    "without": "sensors the autopilot did not stream to us",
    "mode": "'lockstep' (virtual clock) or 'realtime' (wall clock, real service)",
    "steps": "each step: what, outcome, start and end (s since boot), detail",
    "steps_done": "steps that ended as asked",
    "failed_step": "the step the mission ended at (None: none failed)",
    "armed": "the autopilot armed when asked",
    "takeoff_s": "lift-off time in truth (height up 0.1 m), s since boot",
    "extnav_s": "the autopilot started using our estimate, s since boot",
    "extnav_after_takeoff_s": "extnav_s - takeoff_s (negative: before lift-off)",
    "holds": "each hold: mode, seconds, drift_xy_m and drift_z_m (truth)",
    "hold_drift_m": "the largest horizontal drift over a LOITER hold (truth), m",
    "corners": "each goto: target (north, east, up from home), error_xy_m and error_z_m "
               "(truth)",
    "corner_error_max_m": "the largest horizontal corner error (truth), m (None: a corner not "
                          "reached)",
    "corner_height_error_max_m": "the largest vertical corner error (truth), m",
    "height_wander_m": "the largest vertical hold drift or corner error (truth), m",
    "autopilot_height_error_m": "airborne, the largest error of the autopilot's own height "
                                "from the arming point (truth), m",
    "our_height_error_m": "airborne, the largest error of the height we sent, from the arming "
                          "point (truth), m",
    "height_steps": "the autopilot's height resets: t, step_m, why",
    "height_step_max_m": "the largest height reset, m",
    "failsafes": "the autopilot's failsafe messages",
    "latency_ms_p50": "capture-to-arrival at the autopilot, median, ms",
    "latency_ms_p95": "capture-to-arrival at the autopilot, p95, ms",
    "suggested_viso_delay_ms": "VISO_DELAY_MS for this latency (ArduPilot's jitter correction "
                               "takes the fastest message of each 100: daemon/latency.py)",
    "viso_delay_ms": "the autopilot's VISO_DELAY_MS in the flight",
    "expert": "sdvl replay's report of the messages the autopilot received "
              "(sim/replay/report.py KEYS)",
}


def loiter_drift(s: FlightScores) -> float | None:
    drifts = [h.drift_xy_m for h in s.holds if h.mode == "LOITER"]
    return max(drifts) if drifts else None


def corner_max(s: FlightScores, key: str = "error_xy_m") -> float | None:
    """The largest corner error (horizontal by default); None when a corner was not reached."""
    errors = [getattr(c, key) for c in s.corners]
    return None if not errors or None in errors else max(errors)


def height_drift(s: FlightScores) -> float:
    """The largest height error of a hold or a corner, in truth."""
    return max([h.drift_z_m for h in s.holds] + [c.error_z_m or 0.0 for c in s.corners],
               default=0.0)


def _height_note(s: FlightScores) -> str:
    """Said when the height wandered: whose height estimate was off (the autopilot flies its
    own, from the barometer with EK3_SRC1_POSZ 1)."""
    drift = height_drift(s)
    if drift <= HEIGHT_HOLD_LIMIT_M:
        return ""
    ap, ours = s.heights.autopilot_m, s.heights.ours_m
    advice = (BARO_ADVICE if ap is not None and ap > HEIGHT_HOLD_LIMIT_M else "")
    return (f"; its height wandered {drift:.2f} m: the autopilot's own height was off by "
            f"{_num(ap, '.2f')} m in flight, ours by {_num(ours, '.2f')} m{advice}")


def _advice(detail: str) -> str:
    return next((advice for words, advice in ADVICE if words in detail), "")


def _delay_note(s: FlightScores) -> str:
    if s.suggested_delay_ms is None:
        return ""
    want = round(s.suggested_delay_ms)
    if s.viso_delay_ms is not None and abs(s.viso_delay_ms - want) <= DELAY_TOLERANCE_MS:
        return f"; VISO_DELAY_MS {s.viso_delay_ms:g} fits the {want} ms measured"
    return f"; set VISO_DELAY_MS {want} (it is {s.viso_delay_ms})"


def verdict(s: FlightScores) -> tuple[str, bool, bool]:
    """(the line, ready for LOITER, ready for GUIDED)."""
    drift, corners = loiter_drift(s), corner_max(s)
    worst_step = max((h.step_m for h in s.height_steps), default=0.0)
    late = s.extnav_after_takeoff_s
    problems = []
    if s.failed is not None:
        f = s.failed
        advice = _advice(f.detail)
        problems.append(f"step {f.step.index} ({f.step.describe()}) {f.outcome.value}: "
                        f"{f.detail}" + (f" -> {advice}" if advice else ""))
    if s.failsafes:
        problems.append(f"failsafe: {s.failsafes[0]}")
    if worst_step > HEIGHT_STEP_LIMIT_M:
        problems.append(f"the autopilot's height stepped {worst_step:.2f} m")
    if late is not None and late > EXTNAV_LIMIT_S:
        problems.append(f"the autopilot used our estimate only {late:.1f} s after take-off")
    loiter = not problems and drift is not None and drift <= HOLD_LIMIT_M
    if not problems and drift is not None and not loiter:
        problems.append(f"LOITER drifted {drift:.2f} m (limit {HOLD_LIMIT_M} m)")
    notes = _height_note(s) + _delay_note(s)
    if problems:
        return "NOT READY: " + "; ".join(problems) + notes, False, False
    if drift is None:
        return "NOT JUDGED: the mission has no LOITER hold" + notes, False, False
    guided = corners is not None and corners <= CORNER_LIMIT_M
    if not guided and s.corners:
        text = (f"READY for LOITER (drift {drift:.2f} m), not for GUIDED: a corner "
                + ("not reached" if corners is None else f"{corners:.2f} m off"))
    elif s.corners:
        text = (f"READY for LOITER and GUIDED: LOITER drift {drift:.2f} m, corners within "
                f"{corners:.2f} m")
    else:
        text = f"READY for LOITER: drift {drift:.2f} m"
    return text + notes, True, guided and bool(s.corners)


def flight_report(run: object, s: FlightScores) -> dict:
    """The report dict (KEYS) of a FlightRun and its scores."""
    line, loiter, guided = verdict(s)
    latency = stats_ms([v / 1e3 for v in s.latency_ms])
    report = {
        "verdict": line, "ready_loiter": loiter, "ready_guided": guided,
        "mission": run.mission.name, "world": run.mission.world, "seed": run.seed,
        "without": list(run.without), "mode": "realtime" if run.realtime else "lockstep",
        "steps": [{"step": r.step.describe(), "outcome": r.outcome.value, "start_s": r.started,
                   "end_s": r.ended, "detail": r.detail} for r in run.steps],
        "steps_done": s.steps_done,
        "failed_step": None if s.failed is None else s.failed.step.describe(),
        "armed": s.armed, "takeoff_s": s.takeoff_s, "extnav_s": s.extnav_s,
        "extnav_after_takeoff_s": s.extnav_after_takeoff_s,
        "holds": [asdict(h) for h in s.holds], "hold_drift_m": loiter_drift(s),
        "corners": [asdict(c) for c in s.corners], "corner_error_max_m": corner_max(s),
        "corner_height_error_max_m": corner_max(s, "error_z_m"),
        "height_wander_m": height_drift(s),
        "autopilot_height_error_m": s.heights.autopilot_m, "our_height_error_m": s.heights.ours_m,
        "height_steps": [asdict(h) for h in s.height_steps],
        "height_step_max_m": max((h.step_m for h in s.height_steps), default=0.0),
        "failsafes": s.failsafes,
        "latency_ms_p50": latency["median"], "latency_ms_p95": latency["p95"],
        "suggested_viso_delay_ms": s.suggested_delay_ms, "viso_delay_ms": s.viso_delay_ms,
        "expert": s.expert,
    }
    return {key: report[key] for key in KEYS}


def _num(value: float | None, fmt: str, unit: str = "") -> str:
    return "n/a" if value is None else format(value, fmt) + unit


def format_flight(r: dict, total_steps: int) -> str:
    """Human-readable lines: the verdict first."""
    lines = [f"verdict    {r['verdict']}",
             f"mission    {r['mission']} over the {r['world']} world (seed {r['seed']}, "
             f"{r['mode']}" + (f", without {', '.join(r['without'])}" if r["without"] else "")
             + f"): {r['steps_done']} of {total_steps} steps done"]
    lines += [f"           step {i}: {s['step']} {s['outcome']} at {s['end_s']:.1f} s: "
              f"{s['detail']}" for i, s in enumerate(r["steps"], 1)
              if s["outcome"] not in (Outcome.DONE.value, Outcome.RUNNING.value)]
    extnav = r["extnav_after_takeoff_s"]
    lines.append("extnav     " + ("the autopilot never used our estimate" if r["extnav_s"] is None
                                  else f"the autopilot used our estimate from {r['extnav_s']:.1f}"
                                  " s" + ("" if extnav is None else
                                          f", {abs(extnav):.1f} s "
                                          f"{'after' if extnav > 0 else 'before'} lift-off")))
    for h in r["holds"]:
        lines.append(f"hold       {h['mode']} {h['seconds']:.0f} s: drift {h['drift_xy_m']:.2f} m "
                     f"horizontal, {h['drift_z_m']:.2f} m vertical (truth)")
    if r["corners"]:
        xy = " ".join(_num(c["error_xy_m"], ".2f") for c in r["corners"])
        z = " ".join(_num(c["error_z_m"], ".2f") for c in r["corners"])
        lines.append(f"corners    off by {xy} m horizontally, {z} m vertically (truth, from the "
                     "arming point)")
    lines.append(f"height     in flight the autopilot's own height was off by up to "
                 f"{_num(r['autopilot_height_error_m'], '.2f')} m, ours by "
                 f"{_num(r['our_height_error_m'], '.2f')} m (truth)")
    steps = r["height_steps"]
    lines.append(f"resets     {len(steps)} of the autopilot's height, largest "
                 f"{r['height_step_max_m']:.2f} m"
                 + "".join(f"; {h['step_m']:.2f} m at {h['t']:.1f} s ({h['why']})"
                           for h in steps[:3]))
    lines.append("failsafes  " + ("; ".join(r["failsafes"]) if r["failsafes"] else "none"))
    lines.append(f"latency    capture-to-arrival p50 {_num(r['latency_ms_p50'], '.0f')} / p95 "
                 f"{_num(r['latency_ms_p95'], '.0f')} ms; suggested VISO_DELAY_MS "
                 f"{_num(r['suggested_viso_delay_ms'], '.0f')} (the autopilot has "
                 f"{_num(r['viso_delay_ms'], 'g')})")
    lines.append("expert     what the autopilot received, as sdvl replay scores it:")
    lines += ["  " + line for line in format_report(r["expert"]).splitlines()]
    return "\n".join(lines)


