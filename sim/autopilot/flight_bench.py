"""`python -m sim.autopilot.flight_bench`: what the flying simulated ArduCopter costs and how it
flies the default mission with a near-perfect companion (truth plus 1 cm / 2 cm/s noise at
30 Hz), on a virtual clock: GUIDED takeoff to 3 m, LOITER, a 2 m GUIDED square, LAND.

Prints the CPU per simulated second, the CPU time per call of each stage (median, p95), and the
flight's figures: true height after takeoff, LOITER drift (horizontal, vertical), corner errors
(in truth, where the compass's heading error turns the autopilot's frame, and in the EKF's
frame), touchdown speed.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from collections.abc import Callable

import numpy as np

from sim.autopilot import configured_options
from sim.autopilot.dynamics import Dynamics
from sim.autopilot.ground_station import GroundStation, TruthCompanion
from sim.autopilot.virtual import VirtualLink

GUIDED, LOITER, LAND = 4, 5, 9
SQUARE = ((2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0))


def timed(store: list[float], function: Callable) -> Callable:
    """`function` recording each call's CPU time (s) in `store`."""
    def wrapper(*args: object, **kwargs: object) -> object:
        start = time.thread_time()
        try:
            return function(*args, **kwargs)
        finally:
            store.append(time.thread_time() - start)
    return wrapper


def instrument(link: VirtualLink) -> dict[str, list[float]]:
    """Time the model's stages per call (a benchmark's own wrappers)."""
    stages: dict[str, list[float]] = defaultdict(list)
    model = link.model
    model._predict = timed(stages["20 ms step, EKF and modes"], model._predict)
    model.flying._run_loops = timed(stages["400 Hz loops, per call"],
                                    model.flying._run_loops)
    model.ekf.step = timed(stages["EKF3 stand-in"], model.ekf.step)
    model.flying.after_estimator = timed(stages["flight modes"], model.flying.after_estimator)
    return stages


def fly_mission(link: VirtualLink, gcs: GroundStation, companion: TruthCompanion,
                loiter_s: float) -> dict[str, float]:
    """The default mission; its truth figures (m, m/s)."""
    vehicle = link.model.vehicle
    companion.fly(2.0)
    gcs.mode(GUIDED)
    gcs.arm()
    gcs.takeoff(3.0)
    companion.fly(10.0)
    out = {"takeoff height": float(vehicle.body.contact_z - vehicle.body.position[2])}
    gcs.mode(LOITER)
    companion.fly(2.0)
    start = vehicle.body.position.copy()
    drift = height_drift = 0.0
    for _ in range(int(loiter_s)):
        companion.fly(1.0)
        drift = max(drift, float(np.linalg.norm(vehicle.body.position[:2] - start[:2])))
        height_drift = max(height_drift, abs(float(vehicle.body.position[2] - start[2])))
    out["loiter drift max"] = drift
    out["  its height's drift max"] = height_drift  # the barometer's prop wash settling in
    gcs.mode(GUIDED)
    errors, estimated = [], []
    for north, east in SQUARE:
        gcs.goto(north, east, -3.0)
        companion.fly(8.0)
        errors.append(float(np.hypot(*(vehicle.body.position[:2] - (north, east)))))
        estimate = link.model.ekf.filter.position[:2]
        estimated.append(float(np.hypot(*(estimate - (north, east)))))
    out["square corner error max"] = max(errors)  # truth: with the compass's frame turn
    out["  same, in the EKF's frame"] = max(estimated)
    gcs.mode(LAND)
    companion.fly(15.0)
    out["touchdown speed"] = vehicle.body.touchdown_speeds[0] if vehicle.body.touchdown_speeds \
        else float("nan")
    out["disarmed"] = float(not link.model.armed)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.autopilot.flight_bench",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="sensors' and companion's seed")
    parser.add_argument("--loiter-s", type=float, default=30.0, help="LOITER hold, seconds")
    args = parser.parse_args(argv)
    link = VirtualLink(configured_options(requested={}, dynamics=Dynamics(seed=args.seed)))
    stages = instrument(link)
    start_cpu, start_sim = time.process_time(), link.now
    figures = fly_mission(link, GroundStation(link), TruthCompanion(link, seed=args.seed),
                          args.loiter_s)
    cpu, simulated = time.process_time() - start_cpu, link.now - start_sim
    print(f"simulated {simulated:.1f} s in {cpu:.2f} s CPU: "
          f"{cpu / simulated:.3f} s CPU per simulated second (seed {args.seed})")
    print(f"{'stage, CPU ms per call':28s} {'calls':>7s} {'median':>8s} {'p95':>8s}")
    for name, values in stages.items():
        ms = np.array(values) * 1000.0
        print(f"{name:28s} {len(ms):7d} {np.median(ms):8.3f} {np.percentile(ms, 95):8.3f}")
    for name, value in figures.items():
        print(f"{name:28s} {value:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
