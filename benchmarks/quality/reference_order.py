"""Does the order the references are listed in change the fill? Hole PSNR and output hash of the
all-reference fill for several orders of the same references.

    .venv/bin/python benchmarks/quality/reference_order.py [--sets NAME,...] [--seed 0] [--orders N]

Per multi-reference set of ``../shared/data/multiview`` (default: the Lund red car and the living
room): the evaluation's stroke hole (``geofill eval``'s, seed ``--seed``), filled by ``geofill.fill``
with the default configuration and the references in the given order, the reverse order and a
rotation (``--orders 3``; every permutation with ``--orders 0``). Printed per order: the hole PSNR
against the target, the first 12 hex digits of the output's SHA-256, and the time.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW

from geofill import FillConfig, fill
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import load_pair, pair_mask

DEFAULT_SETS = "dev_mv_opensfm_lund_redcar,dev_mv_slambook_livingroom"


def orders(n: int, how_many: int) -> list[tuple[int, ...]]:
    """The given order, its reverse, then rotations (0: every permutation)."""
    if how_many == 0:
        return list(itertools.permutations(range(n)))
    found = [tuple(range(n)), tuple(reversed(range(n)))]
    found += [tuple((i + r) % n for i in range(n)) for r in range(1, n)]
    return list(dict.fromkeys(found))[:how_many]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default=DEFAULT_SETS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--orders", type=int, default=3, help="how many orders (0: every permutation)")
    args = ap.parse_args(argv)
    print("| set | order | hole PSNR (dB) | output SHA-256 | time (s) |")
    print("| --- | --- | --- | --- | --- |")
    for name in args.sets.split(","):
        pair = load_pair(MULTIVIEW / name)
        hole = pair_mask(pair, args.seed)
        target = pair.target.copy()
        target[hole] = 0
        hashes = set()
        for order in orders(len(pair.sources), args.orders):
            t0 = time.perf_counter()
            res = fill(
                target,
                hole,
                [pair.sources[k] for k in order],
                FillConfig(),
                target_exif=pair.exif.target,
                source_exifs=[pair.exif.sources[k] for k in order],
            )
            took = time.perf_counter() - t0
            digest = hashlib.sha256(res.image.tobytes()).hexdigest()[:12]
            hashes.add(digest)
            shown = ",".join(str(k + 1) for k in order)
            print(f"| {name} | {shown} | {psnr(res.image, pair.target, hole):.2f} | {digest} | {took:.1f} |")
        print(f"| {name} | **distinct outputs** | | **{len(hashes)}** | |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
