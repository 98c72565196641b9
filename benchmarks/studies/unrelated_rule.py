"""When is a reference "of another scene"? Verified-match counts per matching rung on every true DEV
pair and on pairs of images from different DEV scenes, and the errors of the give-up rule.

    .venv/bin/python benchmarks/studies/unrelated_rule.py [--seeds 0,1,2,3,4,5] [--negatives 2]
        [--rungs sift,loose] [--threshold N]

Positives: the 23 DEV pairs of ``../shared/data/pairs``, each with the evaluation's stroke holes
(:func:`geofill.evaluation.pairs.pair_mask`, as ``geofill eval`` cuts them) of every seed.
Negatives: each DEV pair's target (its seed-0 hole) with the references of the next ``--negatives``
pairs (in name order) that show another scene. Each is matched as the fill's match stage does (the
working views of :func:`geofill.prepare.prepare_views`), every rung in ``--rungs`` forced to run
(nothing counts as verified, no give-up, no time budget). Printed: per case the verified matches
per rung; then the rule the fill applies (``matching.unrelated_max_verified``: given up when
fewer than N matches verified on every rung before ``asift``), for the configured N or
``--threshold``: the true pairs it drops, the unrelated pairs it lets climb, and the time it takes
to give up on an unrelated reference (the rungs it runs).
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import PAIRS

from geofill import FillConfig
from geofill.evaluation.pairs import load_pair, pair_mask
from geofill.match import match_pair
from geofill.match.ladder import RUNGS
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


def counts(
    target: np.ndarray, hole: np.ndarray, source: np.ndarray, cfg: FillConfig, rungs: list[str]
) -> tuple[dict[str, int], dict[str, float]]:
    """Verified matches and seconds per rung, every rung in ``rungs`` forced to run."""
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
    return {r.rung: r.n_verified for r in m.rungs}, {r.rung: r.time_s for r in m.rungs}


def dropped(n: dict[str, int], early: list[str], threshold: int) -> bool:
    """The rule: given up when every early rung verified fewer than ``threshold`` matches."""
    return max(n[r] for r in early) < threshold


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2,3,4,5")
    ap.add_argument("--negatives", type=int, default=2, help="unrelated references per DEV target")
    ap.add_argument("--rungs", default="sift,loose", help="rungs to count, in ladder order")
    ap.add_argument("--threshold", type=int, help="N of the rule (default: the configured one)")
    args = ap.parse_args(argv)
    cfg = FillConfig()
    rungs = args.rungs.split(",")
    early = [r for r in rungs if RUNGS.index(r) < RUNGS.index("asift")]
    threshold = args.threshold if args.threshold is not None else cfg.matching.unrelated_max_verified
    pairs = [load_pair(p) for p in sorted(PAIRS.iterdir()) if p.is_dir()]
    seeds = [int(s) for s in args.seeds.split(",")]
    print(f"{len(pairs)} DEV pairs x seeds {args.seeds}; rungs {', '.join(rungs)}; the rule looks at "
          f"{', '.join(early)}: given up below {threshold} verified matches\n")  # fmt: skip
    print("| kind | target | reference | seed | " + " | ".join(rungs) + " | given up |")
    print("| --- " * (5 + len(rungs)) + "|")
    pos, neg, give_up_s = [], [], []
    for i, pair in enumerate(pairs):
        for seed in seeds:
            hole = pair_mask(pair, seed)
            n, _ = counts(pair.target, hole, pair.source, cfg, rungs)
            pos.append((pair.id, seed, n))
            row = " | ".join(str(n[r]) for r in rungs)
            lost = "DROPPED" if dropped(n, early, threshold) else ""
            print(f"| true | {pair.id} | same | {seed} | {row} | {lost} |", flush=True)
        others = [p for p in pairs[i + 1 :] + pairs[:i] if scene(p.id) != scene(pair.id)][: args.negatives]
        for other in others:
            hole = pair_mask(pair, 0)
            n, t = counts(pair.target, hole, other.source, cfg, rungs)
            neg.append((pair.id, other.id, n))
            give_up_s.append(sum(t[r] for r in early))
            row = " | ".join(str(n[r]) for r in rungs)
            given_up = "yes" if dropped(n, early, threshold) else "CLIMBS"
            print(f"| unrelated | {pair.id} | {other.id} | 0 | {row} | {given_up} |", flush=True)
    print()
    for r in rungs:
        p = [n[r] for *_, n in pos]
        q = [n[r] for *_, n in neg]
        print(f"{r}: true pairs verify {min(p)}-{max(p)} (median {statistics.median(p):g}), "
              f"unrelated {min(q)}-{max(q)} (median {statistics.median(q):g})")  # fmt: skip
    lost = [f"{pid} seed {s}" for pid, s, n in pos if dropped(n, early, threshold)]
    climb = [f"{a} x {b}" for a, b, n in neg if not dropped(n, early, threshold)]
    best_true = min(max(n[r] for r in early) for *_, n in pos)
    worst_unrelated = max(max(n[r] for r in early) for *_, n in neg)
    print(f"rule (max over {', '.join(early)} < {threshold}): {len(lost)} of {len(pos)} true pairs dropped"
          f"{': ' + ', '.join(lost) if lost else ''}; {len(climb)} of {len(neg)} unrelated pairs climb"
          f"{': ' + ', '.join(climb) if climb else ''}")  # fmt: skip
    print(f"separating thresholds: {worst_unrelated + 1}-{best_true} (unrelated at most {worst_unrelated}, "
          f"true pairs at least {best_true})")  # fmt: skip
    print(f"time to give up on an unrelated reference ({' + '.join(early)}): median "
          f"{statistics.median(give_up_s):.2f} s, max {max(give_up_s):.2f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
