"""One focal for all references vs. one per pair, on the multi-reference sets with a true K.

    .venv/bin/python benchmarks/studies/shared_focal.py [--sets ../shared/data/multiview]

Every set's images come from one camera. Per set: the target focal's error (% of the true one)
of the per-pair estimate of each reference (the focal stage alone), and of the estimate from all
pairs together (``intrinsics.shared_camera``), with the evaluation's stroke hole (seed 0).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

from geofill.config import FillConfig
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.pipeline import ReferenceArtifacts, prepare_fill, run_reference, shared_focal

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, MULTIVIEW


def _error_pct(art: ReferenceArtifacts, f_true: float) -> float:
    """Target focal error (%), in input pixels."""
    K = art.focal.K_target
    return 100.0 * abs(K.fx * art.views.target_shape[1] / K.width / f_true - 1.0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default=str(MULTIVIEW))
    args = ap.parse_args(argv)
    cfg = FillConfig()
    per_pair_all, shared_all = [], []
    print(f"{'set':<32s} {'per pair (each reference), % error':<40s} {'median':>7s} {'shared':>7s}  status")
    for pair in load_pairs([args.sets], exclude=HELD_OUT):
        K = pair.meta.get("K_target")
        if K is None or len(pair.sources) < 2:
            continue
        f_true = float(np.sqrt(K[0][0] * K[1][1]))
        hole = pair_mask(pair, 0)
        ctx = prepare_fill(pair.target, hole, pair.sources, cfg)
        refs = [ReferenceArtifacts(i + 1, s) for i, s in enumerate(pair.sources)]
        matched = [run_reference(ctx, r, until="match") for r in refs]
        alone = [run_reference(ctx, r, until="focal") for r in matched]
        joint = shared_focal(matched, cfg)
        errs = [_error_pct(a, f_true) for a in alone if a.focal is not None]
        shared = next(r for r in joint if r.focal is not None)
        e_shared = _error_pct(shared, f_true)
        per_pair_all += errs
        shared_all.append(e_shared)
        cells = " ".join(f"{e:6.1f}" for e in errs)
        print(
            f"{pair.id:<32s} {cells:<40s} {statistics.median(errs):7.1f} {e_shared:7.1f}  "
            f"{shared.focal.status} {shared.focal.reason}",
            flush=True,
        )
    print(
        f"median over pairs: per pair {statistics.median(per_pair_all):.1f} %, "
        f"shared (one per set) {statistics.median(shared_all):.1f} %"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
