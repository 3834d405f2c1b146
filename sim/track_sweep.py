"""Parameter sweeps of `sdvl track-table`: tracker parameters set on top of every configuration
(`--set KEY=VALUE`, a variant per value when several are given), over tracker seeds and the
world seeds of synthetic presets, and the summary that compares the variants seed by seed.
A single run says little (a small change to the tracker moves single seeds by 2-3x either way):
the summary gives each variant's mean ATE, its ATE per seed, and on how many seeds it beat the
first variant."""

from __future__ import annotations

import itertools
import tomllib
from dataclasses import dataclass

import numpy as np

from sdvl.errors import InputError


@dataclass(frozen=True)
class Variant:
    """Tracker parameters set on top of a configuration, and their label."""

    parameters: tuple[tuple[str, object], ...] = ()

    @property
    def label(self) -> str:
        """'key=value,key=value', or 'as configured'."""
        return ",".join(f"{k}={str(v).lower() if isinstance(v, bool) else v}"
                        for k, v in self.parameters) or "as configured"


def parse_value(text: str) -> object:
    """A parameter value as TOML reads it (true, 3, 0.5, "orb"), else the text itself."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def variants(settings: list[str]) -> list[Variant]:
    """The variants of `--set KEY=V1[,V2...]` options: one per combination of values, in the
    order given (the first is the reference of the comparison)."""
    keys, choices = [], []
    for item in settings:
        key, eq, values = item.partition("=")
        if not eq or not key.strip() or not values.strip():
            raise InputError(f"--set needs KEY=VALUE[,VALUE...], got '{item}'")
        keys.append(key.strip())
        choices.append([parse_value(v.strip()) for v in values.split(",")])
    if len(set(keys)) < len(keys):
        raise InputError("--set: each parameter once (list its values with commas)")
    return [Variant(tuple(zip(keys, combo, strict=True)))
            for combo in itertools.product(*choices)]


def summary(rows: list[dict]) -> list[dict]:
    """Per sequence, configuration and variant: ATE mean and per seed, frames tracked and the
    most map segments over the runs, and on how many seeds the variant's ATE beat the first
    variant's (same sequence, world seed, configuration and tracker seed)."""
    done = [r for r in rows if "error" not in r]
    groups: dict[tuple, list[dict]] = {}
    for r in done:
        groups.setdefault((r["sequence"], r["config"], r["variant"]), []).append(r)
    first = {}
    for (seq, config, _), runs in groups.items():
        first.setdefault((seq, config), runs)
    out = []
    for (seq, config, variant), runs in groups.items():
        ate = [r["ate_rmse_m"] for r in runs]
        reference = {(r["world_seed"], r["seed"]): r["ate_rmse_m"] for r in first[(seq, config)]}
        pairs = [(a, reference.get((r["world_seed"], r["seed"]))) for r, a in zip(runs, ate,
                                                                                 strict=True)]
        pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
        known = [a for a in ate if a is not None]
        out.append({"sequence": seq, "config": config, "variant": variant, "runs": len(runs),
                    "ate_mean_m": float(np.mean(known)) if known else None, "ate_m": ate,
                    "tracked": sum(r["tracked"] for r in runs),
                    "frames": sum(r["frames"] for r in runs),
                    "segments_max": max(r["segments"] for r in runs),
                    "better": sum(a < b for a, b in pairs), "compared": len(pairs)})
    return out


def format_summary(s: dict, first_variant: str) -> str:
    """One text line of a summary."""
    ate = "/".join("n/a" if a is None else f"{a:.4g}" for a in s["ate_m"])
    mean = "n/a" if s["ate_mean_m"] is None else f"{s['ate_mean_m']:.4f}"
    line = (f"{s['sequence']:<26} {s['config']:<14} {s['variant']:<28} ATE mean {mean} m over "
            f"{s['runs']} ({ate}); tracked {s['tracked']}/{s['frames']}, segments <= "
            f"{s['segments_max']}")
    if s["variant"] != first_variant:
        line += f"; better than {first_variant} on {s['better']} of {s['compared']}"
    return line
