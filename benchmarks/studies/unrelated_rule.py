"""When is a reference "of another scene"? Verified-match counts per matching rung on every true DEV
pair and on pairs of images from different DEV scenes, and the errors of the fill's give-up rule.

    .venv/bin/python benchmarks/studies/unrelated_rule.py [--seeds 0,1,2,3,4,5] [--negatives 2]
        [--rungs sift,loose] [--kinds true,unrelated] [--pairs A:B] [--save FILE | --load FILE ...]

Positives: the 23 DEV pairs of ``../shared/data/pairs``, each with the evaluation's stroke holes
(:func:`geofill.evaluation.pairs.pair_mask`, as ``geofill eval`` cuts them) of every seed.
Negatives: each DEV pair's target (its seed-0 hole) with the references of the next ``--negatives``
pairs (in name order) that show another scene. Each is matched as the fill's match stage does (the
working views of :func:`geofill.prepare.prepare_views`) with every rung in ``--rungs`` forced to
run (nothing counts as verified, no give-up, no time budget). Printed: per case the verified /
tentative matches per rung; then the rule the ladder applies (:func:`geofill.match.ladder.
another_scene` before each rung after :data:`~geofill.match.ladder.EARLY_RUNGS`, with the default
configuration): the true pairs it drops, the unrelated pairs it lets climb, and the time it takes
to give up on an unrelated reference (the rungs it ran). ``--save`` keeps the counts as JSON;
``--load`` re-evaluates the rule on saved counts without matching again (``--pairs``
and ``--kinds`` split the measurement into parts that can run at once).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

from geofill import FillConfig
from geofill.evaluation.pairs import load_pair, pair_mask
from geofill.match import match_pair
from geofill.match.ladder import EARLY_RUNGS, RungReport, another_scene
from geofill.prepare import prepare_views

#: Words of a pair's name that name its scene: two pairs sharing one show the same scene (the ICL
#: living room is slambook's; both KITTI pairs and both Lund pairs are counted as one scene each).
SCENES = (
    "apple", "eth3d", "fox", "kitti", "facade", "tower", "middlebury", "berlin", "lund",
    "livingroom", "tum", "youtube", "cyprus",
)  # fmt: skip


def scene(pair_id: str) -> str:
    found = [s for s in SCENES if re.search(rf"(^|_){s}(_|$)", pair_id)]
    if len(found) != 1:
        raise SystemExit(f"{pair_id}: no single scene among {SCENES}")
    return found[0]


def rung_reports(
    target: np.ndarray, hole: np.ndarray, source: np.ndarray, cfg: FillConfig, rungs: list[str]
) -> list[RungReport]:
    """Every rung in ``rungs`` forced to run on the pair, as the match stage sees it."""
    forced = replace(
        cfg.matching,
        max_rung=rungs[-1],
        min_verified=10**6,  # nothing verifies: every rung runs
        unrelated_max_verified=0,
        time_budget_s=86_400.0,
        learned="on" if "learned" in rungs else "off",
    )
    v = prepare_views(target, hole, source, cfg, None, None)
    m = match_pair(v.target_gray, v.source_gray, v.hole, forced, v.px_scale, (v.K_target.K, v.K_source.K))
    return list(m.rungs)


def measure(
    seeds: list[int], negatives: int, rungs: list[str], kinds: set[str], which: slice, save: Path | None
) -> list[dict]:
    """Every case of the DEV pairs ``which`` (each appended to ``save`` as a JSON line when done)."""
    cfg = FillConfig()
    pairs = [load_pair(p) for p in sorted(PAIRS.iterdir()) if p.is_dir() and p.name not in HELD_OUT]
    cases: list[dict] = []

    def done(case: dict) -> None:
        cases.append(case)
        if save is not None:
            with save.open("a") as f:
                f.write(json.dumps(case) + "\n")

    for i, pair in enumerate(pairs):
        if i not in range(len(pairs))[which]:
            continue
        for seed in seeds if "true" in kinds else []:
            reports = rung_reports(pair.target, pair_mask(pair, seed), pair.source, cfg, rungs)
            done({"kind": "true", "target": pair.id, "reference": pair.id, "seed": seed,
                  "rungs": [asdict(r) for r in reports]})  # fmt: skip
            print(f"{pair.id} seed {seed}: " + ", ".join(f"{r.rung} {r.n_verified}" for r in reports),
                  file=sys.stderr, flush=True)  # fmt: skip
        others = [p for p in pairs[i + 1 :] + pairs[:i] if scene(p.id) != scene(pair.id)][:negatives]
        for other in others if "unrelated" in kinds else []:
            reports = rung_reports(pair.target, pair_mask(pair, 0), other.source, cfg, rungs)
            done({"kind": "unrelated", "target": pair.id, "reference": other.id, "seed": 0,
                  "rungs": [asdict(r) for r in reports]})  # fmt: skip
    return cases


def verdict(reports: list[RungReport], cfg: FillConfig) -> tuple[bool, float]:
    """Whether the ladder gives the reference up before a rung it would climb to, and the seconds of
    the rungs it ran until then (all measured rungs when it does not)."""
    for k, r in enumerate(reports):
        if r.rung not in EARLY_RUNGS and another_scene(reports[:k], cfg.matching):
            return True, sum(x.time_s for x in reports[:k])
    # The check before the rung after the last one measured.
    return bool(another_scene(reports, cfg.matching)), sum(x.time_s for x in reports)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2,3,4,5")
    ap.add_argument("--negatives", type=int, default=2, help="unrelated references per DEV target")
    ap.add_argument("--rungs", default="sift,loose", help="rungs to run, in ladder order")
    ap.add_argument("--kinds", default="true,unrelated", help="which cases to measure")
    ap.add_argument("--pairs", default=":", help="which DEV pairs (a Python slice of the sorted list)")
    ap.add_argument("--save", type=Path, help="append each case's counts to this file (JSON lines)")
    ap.add_argument("--load", type=Path, nargs="+", help="evaluate the rule on files written by --save")
    args = ap.parse_args(argv)
    if args.load:
        cases = [json.loads(line) for path in args.load for line in path.read_text().splitlines()]
    else:
        seeds = [int(s) for s in args.seeds.split(",")]
        which = slice(*(int(x) if x else None for x in args.pairs.split(":")))
        kinds = set(args.kinds.split(","))
        cases = measure(seeds, args.negatives, args.rungs.split(","), kinds, which, args.save)
    cfg = FillConfig()
    rungs = [r["rung"] for r in cases[0]["rungs"]]
    limit = cfg.matching.unrelated_max_verified
    print(
        f"{sum(c['kind'] == 'true' for c in cases)} true pairs (DEV pair x hole seed), "
        f"{sum(c['kind'] == 'unrelated' for c in cases)} unrelated; verified / tentative matches per rung; "
        f"the rule: given up after {' and '.join(EARLY_RUNGS)} (before any later rung) when every rung so "
        f"far verified fewer than {limit} (matching.unrelated_max_verified)\n"
    )
    print("| kind | target | reference | seed | " + " | ".join(rungs) + " | given up |")
    print("| --- " * (5 + len(rungs)) + "|")
    lost, climb, give_up_s = [], [], []
    for c in cases:
        reports = [RungReport(**r) for r in c["rungs"]]
        dropped, seconds = verdict(reports, cfg)
        row = " | ".join(f"{r.n_verified} / {r.n_tentative}" for r in reports)
        mark = ("DROPPED" if dropped else "") if c["kind"] == "true" else ("yes" if dropped else "CLIMBS")
        print(f"| {c['kind']} | {c['target']} | {c['reference']} | {c['seed']} | {row} | {mark} |")
        if c["kind"] == "true" and dropped:
            lost.append(f"{c['target']} seed {c['seed']}")
        if c["kind"] == "unrelated":
            (give_up_s if dropped else climb).append(
                seconds if dropped else f"{c['target']} x {c['reference']}"
            )
    print()
    for k, rung in enumerate(rungs):
        for kind in ("true", "unrelated"):
            n = [c["rungs"][k]["n_verified"] for c in cases if c["kind"] == kind]
            print(f"{rung}, {kind}: verified {min(n)}-{max(n)} (median {statistics.median(n):g})")
    n_true = sum(c["kind"] == "true" for c in cases)
    print(f"\ntrue pairs dropped: {len(lost)} of {n_true}{': ' + ', '.join(lost) if lost else ''}")
    print(f"unrelated references not given up (they climb the costly rungs): {len(climb)} of "
          f"{len(climb) + len(give_up_s)}{': ' + ', '.join(climb) if climb else ''}")  # fmt: skip
    if give_up_s:
        print(f"time to give up on an unrelated reference (the rungs run before the verdict, this machine's "
              f"load): median {statistics.median(give_up_s):.2f} s, max {max(give_up_s):.2f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
