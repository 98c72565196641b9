"""Object removal over several seeds, the default against settings: hole PSNR and leak of the
all-reference fill, per protocol (a static object; strangers in the references), so a change is
judged on both kinds of removal and on more than one seed's cases (one seed can swing a set by dB).

    .venv/bin/python benchmarks/quality/removal_seeds.py [--seeds 0,1,2] [--protocol static|strangers ...]
        [--variant NAME:KEY=VALUE[;KEY=VALUE...] ...] [--keep DIR]

Per protocol and seed: ``geofill eval --protocol P --references all --methods geofill`` with the
default configuration, then with each ``--variant``'s settings. The sets are those of the
``removal_static`` and ``removal_strangers`` results without the synthetic strangers sets: the
three multi-reference sets with GT poses and three rendered view sets (static), the seven DEV
multi-reference sets (strangers). Printed: per protocol, per seed and their mean, the mean hole
PSNR (dB) / leak over the sets, then the per-set means over the seeds.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW, STATIC_PAIRS, add_sweep_arguments, eval_scores, sweep_variants

SETS = {"static": STATIC_PAIRS, "strangers": [str(MULTIVIEW)]}


def run(out: Path, protocol: str, seed: int, settings: list[str]) -> dict[str, tuple[float, float]]:
    """{set: (hole PSNR, leak)} of the all-reference fill."""
    args = ["--protocol", protocol, "--references", "all", "--methods", "geofill", "--seed", str(seed)]
    for name in SETS[protocol]:
        args += ["--pairs", name]
    for kv in settings:
        args += ["--set", kv]
    got = eval_scores(out, args, ("psnr_hole", "leak"))
    return {s: (m["geofill[all]"]["psnr_hole"], m["geofill[all]"].get("leak", 0.0)) for s, m in got.items()}


def table(protocol: str, runs: dict[str, dict[int, dict[str, tuple[float, float]]]]) -> list[str]:
    """Markdown: per seed and mean, then per set, ``PSNR / leak`` for each configuration."""
    names = list(runs)
    seeds = sorted(next(iter(runs.values())))
    sets = sorted(next(iter(runs.values()))[seeds[0]])

    def cell(values: list[tuple[float, float]]) -> str:
        return f"{statistics.mean(v[0] for v in values):.2f} / {statistics.mean(v[1] for v in values):.3f}"

    head = "| {} | " + " | ".join(names) + " |"
    rule = "| --- " * (1 + len(names)) + "|"
    lines = [f"#### {protocol}: hole PSNR (dB) / leak, mean over the sets", "", head.format("seed"), rule]
    for s in seeds:
        lines.append(f"| {s} | " + " | ".join(cell(list(runs[n][s].values())) for n in names) + " |")
    every = {n: [v for s in seeds for v in runs[n][s].values()] for n in names}
    lines.append("| **mean** | " + " | ".join(f"**{cell(every[n])}**" for n in names) + " |")
    lines += [
        "",
        f"#### {protocol}: per set, mean over seeds {', '.join(map(str, seeds))}",
        "",
        head.format("set"),
        rule,
    ]
    for name in sets:
        lines.append(
            f"| {name} | " + " | ".join(cell([runs[n][s][name] for s in seeds]) for n in names) + " |"
        )
    return lines + [""]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sweep_arguments(ap, "a column with these settings (repeatable)")
    ap.add_argument("--protocol", action="append", choices=sorted(SETS), help="(repeatable; default both)")
    args = ap.parse_args(argv)
    if not MULTIVIEW.is_dir():
        print(f"skipped: {MULTIVIEW} not found")
        return 0
    seeds = [int(s) for s in args.seeds.split(",")]
    configs = [("default", []), *sweep_variants(args.variant)]
    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for protocol in args.protocol or sorted(SETS):
            runs: dict[str, dict[int, dict[str, tuple[float, float]]]] = {}
            for seed in seeds:
                for name, settings in configs:
                    runs.setdefault(name, {})[seed] = run(
                        root / f"{protocol}_{name}_s{seed}", protocol, seed, settings
                    )
                print(f"{protocol} seed {seed} done", file=sys.stderr, flush=True)
            lines += table(protocol, runs)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
