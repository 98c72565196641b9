"""All references against the best single reference, over several hole seeds, on the DEV
multi-reference sets: the robust form of the multi-view targets (one seed's holes can favour
either side by a dB).

    .venv/bin/python benchmarks/quality/multiview_seeds.py [--seeds 0,1,2] [--set KEY=VALUE ...]
        [--variant NAME:KEY=VALUE[;KEY=VALUE...] ...] [--keep DIR]

Per seed: ``geofill eval --references primary,each,all --methods geofill`` (the default
configuration with ``--set``), then each ``--variant`` with ``--references all`` only (a variant
that touches single-reference fills needs its own run without ``--variant``). Per set and seed the
best single reference is the highest hole PSNR among the primary and each other reference alone.
Printed: per set, the means over the seeds; per seed, the means; and the targets' two figures, all
references minus the best single reference on the mean, and on how many sets the all-reference
fill is at least as good as the best single reference (seed means).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW, add_sweep_arguments, eval_scores, sweep_variants


def run_eval(out: Path, seed: int, references: str, overrides: list[str]) -> dict[str, dict[str, float]]:
    """``geofill eval`` on the DEV multi-reference sets: {set: {method: hole PSNR}}."""
    args = [
        "--pairs",
        str(MULTIVIEW),
        "--methods",
        "geofill",
        "--references",
        references,
        "--seed",
        str(seed),
    ]
    for kv in overrides:
        args += ["--set", kv]
    got = eval_scores(out, args)
    return {pair: {m: v["psnr_hole"] for m, v in methods.items()} for pair, methods in got.items()}


def summarise(
    singles: dict[int, dict[str, dict[str, float]]], alls: dict[str, dict[int, dict[str, float]]]
) -> list[str]:
    """Markdown: per set and per seed, the primary, the best single and each all-reference row."""
    names = list(alls)
    sets = sorted({s for per_seed in singles.values() for s in per_seed})
    seeds = sorted(singles)

    def best(seed: int, name: str) -> float:
        return max(v for m, v in singles[seed][name].items() if m == "geofill" or m.startswith("geofill[ref"))

    def all_of(variant: str, seed: int, name: str) -> float:
        return alls[variant][seed][name]

    head = "| set | primary | best single | " + " | ".join(names) + " |"
    lines = [f"#### Means over seeds {', '.join(map(str, seeds))} (hole PSNR, dB)", "", head]
    lines.append("| --- " * (3 + len(names)) + "|")
    per_set: dict[str, dict[str, float]] = {}
    for name in sets:
        row = {
            "primary": statistics.mean(singles[s][name]["geofill"] for s in seeds),
            "best single": statistics.mean(best(s, name) for s in seeds),
        }
        row.update({v: statistics.mean(all_of(v, s, name) for s in seeds) for v in names})
        per_set[name] = row
        lines.append(f"| {name} | " + " | ".join(f"{x:.2f}" for x in row.values()) + " |")
    means = {k: statistics.mean(r[k] for r in per_set.values()) for k in next(iter(per_set.values()))}
    lines.append("| **mean** | " + " | ".join(f"**{x:.2f}**" for x in means.values()) + " |")
    lines += ["", "#### Per seed (mean over the sets; sets with all references >= the best single)", ""]
    lines += ["| seed | primary | best single | " + " | ".join(names) + " |"]
    lines.append("| --- " * (3 + len(names)) + "|")
    for s in seeds:
        b = [best(s, n) for n in sets]
        primary = statistics.mean(singles[s][n]["geofill"] for n in sets)
        cells = [f"{primary:.2f}", f"{statistics.mean(b):.2f}"]
        for v in names:
            a = [all_of(v, s, n) for n in sets]
            wins = sum(x >= y for x, y in zip(a, b, strict=True))
            cells.append(f"{statistics.mean(a):.2f} ({wins}/{len(sets)})")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines.append("")
    for v in names:
        gain = means[v] - means["best single"]
        wins = sum(per_set[n][v] >= per_set[n]["best single"] for n in sets)
        lines.append(
            f"- {v}: {gain:+.2f} dB over the best single reference (seed means), at least as good on "
            f"{wins}/{len(sets)} sets"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sweep_arguments(ap, "an all-reference row with these settings on top of --set (repeatable)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="settings of every run")
    args = ap.parse_args(argv)
    if not MULTIVIEW.is_dir():
        print(f"skipped: {MULTIVIEW} not found")
        return 0
    seeds = [int(s) for s in args.seeds.split(",")]
    variants = sweep_variants(args.variant)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        singles: dict[int, dict[str, dict[str, float]]] = {}
        alls: dict[str, dict[int, dict[str, float]]] = {"all references": {}}
        for seed in seeds:
            scores = run_eval(root / f"default_s{seed}", seed, "primary,each,all", args.set)
            singles[seed] = scores
            alls["all references"][seed] = {n: m["geofill[all]"] for n, m in scores.items()}
            for name, settings in variants:
                got = run_eval(root / f"{name}_s{seed}", seed, "all", args.set + settings)
                alls.setdefault(name, {})[seed] = {n: m["geofill[all]"] for n, m in got.items()}
            print(f"seed {seed} done", file=sys.stderr, flush=True)
    print("\n".join(summarise(singles, alls)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
