"""`sdvl check-autopilot`: would a flight on our vision work with this autopilot as it is set?

Connects as the service does (--link, or the config's mavlink.link), waits for the autopilot's
heartbeat, reads every parameter it has (no assumed firmware version), listens to the port and
asks for the streams the service needs, times TIMESYNC, looks for a GPS, has the autopilot run
its pre-arm checks and measures the service's capture-to-send latency on this machine (with
--config; or takes --latency-ms). It prints one verdict line, then each problem with what to
set and why. `--apply` writes the values it recommends (PARAM_SET, read back) and says which
need a reboot; `--reboot` then reboots the autopilot (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN) and
checks again.

Exit codes: 0 OK (a flight would work; warnings say how it would work better), 1 NOT READY
(something would stop arming, the use of vision or a safe flight), 2 bad arguments or config,
3 no autopilot answered on the link.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import logging
import sys
import time

from daemon.ardupilot_params import ardupilot_findings
from daemon.autopilot_params import CheckContext, Finding, Severity, needs_reboot
from daemon.autopilot_probe import NoAutopilotError, Probe, Session
from daemon.config import OUTPUTS, Config, load_config
from daemon.latency import ardupilot_delay_ms, measure_capture_to_send, px4_delay_ms
from daemon.link_url import FORMS, parse_link_url
from daemon.probe_findings import probe_findings
from daemon.px4_params import px4_findings
from sdvl.errors import InputError

EXIT_OK, EXIT_NOT_READY, EXIT_NO_AUTOPILOT = 0, 1, 3
REBOOT_SILENCE_S = 1.5  # no heartbeat for this long: the autopilot went down
REBOOT_WAIT_S = 60.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl check-autopilot`."""
    parser.add_argument("--link", default=None,
                        help=f"autopilot link URL ({FORMS}); default: the config's")
    parser.add_argument("--config", default=None,
                        help="service config: link, output, fusion, origin and the camera the "
                             "latency is measured on")
    parser.add_argument("--output", choices=OUTPUTS, default=None,
                        help="vision message the service sends (default: the config's, else "
                             "odometry)")
    parser.add_argument("--latency-ms", type=float, default=None,
                        help="the service's capture-to-send latency, if known (the 'latency' "
                             "of its status line); default: measured with --config's camera")
    parser.add_argument("--measure-s", type=float, default=8.0,
                        help="seconds the service runs to measure its latency (default 8; 0: "
                             "do not measure)")
    parser.add_argument("--timeout", type=float, default=10.0,
                        help="seconds to wait for the autopilot's heartbeat (default 10)")
    parser.add_argument("--params-timeout", type=float, default=60.0,
                        help="seconds for reading every parameter (default 60)")
    parser.add_argument("--apply", action="store_true",
                        help="set the recommended values on the autopilot and read them back")
    parser.add_argument("--reboot", action="store_true",
                        help="with --apply: reboot the autopilot afterwards and check again")


def context(args: argparse.Namespace, cfg: Config | None) -> CheckContext:
    """The service's settings the checks judge against (the defaults without --config)."""
    cfg = cfg or Config()
    fusion = cfg.fusion.enabled
    return CheckContext(
        output=args.output or cfg.mavlink.output, fusion=fusion,
        vision_rate_hz=min(cfg.camera.fps, cfg.mavlink.max_rate_hz),
        good_std_m=cfg.fusion.quality_good_std_m if fusion else cfg.mavlink.position_std_m,
        origin_enabled=cfg.origin.enabled if args.config else None)


def capture_to_send(args: argparse.Namespace, cfg: Config | None) -> tuple[list[float], str]:
    """The service's capture-to-send latencies (s) and where they come from; [] unknown."""
    if args.latency_ms is not None:
        return [args.latency_ms / 1e3], "given with --latency-ms"
    if cfg is None or args.measure_s <= 0:
        return [], ""
    print(f"measuring the service's capture-to-send latency on camera '{cfg.camera.source}' "
          f"for {args.measure_s:g} s (the first run compiles the tracker)...", file=sys.stderr)
    samples = measure_capture_to_send(cfg, args.measure_s)
    if not samples:
        print("no frames came from the camera: latency not measured", file=sys.stderr)
    return samples, f"{len(samples)} frames of camera '{cfg.camera.source}' on this machine"


def judge(probe: Probe, ctx: CheckContext, latency: tuple[list[float], str]) -> list[Finding]:
    """Every finding, errors first."""
    samples, source = latency
    gps = None if probe.gps_fix_type is None else probe.gps_fix_type > 0
    ctx = dataclasses.replace(ctx, gps_present=gps)
    if samples:
        delay = ardupilot_delay_ms if probe.flavour == "ardupilot" else px4_delay_ms
        ms, basis = delay(samples, probe.rtt_s, source)
        ctx = dataclasses.replace(ctx, delay_ms=ms, delay_basis=basis)
    rules = ardupilot_findings if probe.flavour == "ardupilot" else px4_findings
    findings = [*rules(probe.params, ctx), *probe_findings(probe, ctx)]
    if not probe.params_complete:
        findings.append(Finding(Severity.NOTE, "parameters", None, f"only {len(probe.params)} "
                                "parameters arrived: those not read count as absent",
                                is_param=False))
    return sorted(findings, key=lambda f: f.severity)


def verdict(probe: Probe, findings: list[Finding]) -> tuple[str, int]:
    """The first line of the report and the exit code."""
    where = f"{probe.flavour}, system {probe.system_id} on {probe.link}"
    errors = sum(f.severity == Severity.ERROR for f in findings)
    warnings = sum(f.severity == Severity.WARNING for f in findings)
    if errors:
        return (f"NOT READY: {errors} problem{'s' * (errors > 1)} would stop a flight on vision "
                f"({where})", EXIT_NOT_READY)
    if warnings:
        return (f"OK, {warnings} warning{'s' * (warnings > 1)}: a flight on vision would work "
                f"({where})", EXIT_OK)
    return f"OK: a flight on vision would work ({where})", EXIT_OK


def report(probe: Probe, findings: list[Finding]) -> int:
    """Print the verdict, the findings and what --apply would write; the exit code."""
    line, code = verdict(probe, findings)
    print(line)
    for finding in findings:
        print(finding)
    settable = [f for f in findings if _applicable(f, probe)]
    if settable:
        print(f"`sdvl check-autopilot --apply` sets {', '.join(f.name for f in settable)}")
    return code


def _applicable(finding: Finding, probe: Probe) -> bool:
    return (finding.set_to is not None and finding.is_param and finding.name in probe.params
            and finding.severity != Severity.NOTE)


async def apply(session: Session, probe: Probe, findings: list[Finding]) -> list[str]:
    """Write each recommended value and read it back; the names that need a reboot."""
    changed = []
    for f in (f for f in findings if _applicable(f, probe)):
        held = await session.params.set(f.name, f.set_to)
        if held is None:
            print(f"set {f.name} = {f.set_to:g}: no answer from the autopilot")
            continue
        ok = "" if abs(held - f.set_to) < 1e-6 else f" (refused: it holds {held:g})"
        print(f"set {f.name} = {f.set_to:g}, read back {held:g}{ok}")
        changed += [f.name] if not ok and needs_reboot(probe.flavour, f.name) else []
    for f in findings:
        if f.severity != Severity.NOTE and not f.is_param:
            print(f"not set by --apply: {f.name}: {f.message}")
    return changed


async def check(url: str, ctx: CheckContext, latency: tuple[list[float], str],
                args: argparse.Namespace) -> int:
    """Probe, report, apply, reboot and check again; the exit code."""
    async with Session(url) as session:
        await session.wait_autopilot(args.timeout)
        probe = await session.probe(args.params_timeout)
        findings = judge(probe, ctx, latency)
        code = report(probe, findings)
        changed = await apply(session, probe, findings) if args.apply else []
        if not changed:
            return code
        if not args.reboot:
            print(f"reboot the autopilot for {', '.join(changed)} to take effect (or run "
                  "again with --apply --reboot), then run sdvl check-autopilot again")
            return code
        if not await _reboot(session):
            return code
    print("after the reboot:")
    async with Session(url) as session:
        await session.wait_autopilot(REBOOT_WAIT_S)
        probe = await session.probe(args.params_timeout)
        return report(probe, judge(probe, ctx, latency))


async def _reboot(session: Session) -> bool:
    """Reboot and wait until its heartbeat stops; False when it refused."""
    if not await session.reboot(3.0):
        print("the autopilot refused to reboot (is it armed?): reboot it by hand")
        return False
    print("rebooting the autopilot...")
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        if time.monotonic() - session.watch.last_heartbeat > REBOOT_SILENCE_S:
            break
        await asyncio.sleep(0.1)
    return True


def run(args: argparse.Namespace) -> int:
    """Entry point of `sdvl check-autopilot`."""
    cfg = load_config(args.config) if args.config else None
    url = args.link or (cfg.mavlink.link if cfg else None)
    if url is None:
        raise InputError("give --link URL or --config FILE")
    if args.reboot and not args.apply:
        raise InputError("--reboot goes with --apply")
    parse_link_url(url)
    latency = capture_to_send(args, cfg)
    link_log = logging.getLogger("sdvl.link")
    level = link_log.level
    link_log.setLevel(logging.ERROR)  # retries are summed up in one line when nothing answers
    try:
        return asyncio.run(check(url, context(args, cfg), latency, args))
    except NoAutopilotError as exc:
        print(f"sdvl check-autopilot: {exc}", file=sys.stderr)
        return EXIT_NO_AUTOPILOT
    finally:
        link_log.setLevel(level)
