"""Time of a fill against the number of references, one after the other or two at once.

    .venv/bin/python benchmarks/speed/multiref.py [--size 1280x720] [--repeat 3]

A ray-cast scene (:func:`geofill.synthetic.make_views`) with three references (left, right, and a
step forward); each configuration is filled ``--repeat`` times in this process after one warm-up
fill (so numba's compilation is not counted), interleaved so that load drifts hit all alike.
Prints the median wall time per configuration, the time per additional reference and the
per-stage split of the three-reference fill.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from geofill.config import FillConfig
from geofill.pipeline import fill
from geofill.synthetic import make_views

MOTIONS = (("sideways", -0.6, -12.0), ("sideways", 0.6, 12.0), ("forward", 0.5, None))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.size.split("x"))
    v = make_views(seed=0, width=w, height=h, motions=MOTIONS)
    hole = np.zeros((h, w), bool)
    hole[h // 4 : 3 * h // 4, : w // 6] = True
    hole[h // 4 : 3 * h // 4, -w // 6 :] = True
    configs = {
        f"{n} ref, parallel {p}": (n, FillConfig().updated({"fusion.parallel": p}))
        for n in (1, 2, 3)
        for p in ((1,) if n == 1 else (1, 2))
    }
    fill(v.target, hole, v.sources[:1], FillConfig())  # warm-up: numba compiles once per process
    times: dict[str, list[float]] = {k: [] for k in configs}
    stages: dict[str, float] = {}
    for _ in range(args.repeat):
        for name, (n, cfg) in configs.items():
            t0 = time.perf_counter()
            res = fill(v.target, hole, v.sources[:n], cfg)
            times[name].append(time.perf_counter() - t0)
            if name == "3 ref, parallel 1":
                stages = res.report.timings_s
    print(f"{w}x{h}, hole {hole.mean():.1%}, median of {args.repeat} (s):")
    med = {k: statistics.median(t) for k, t in times.items()}
    for name, t in med.items():
        print(f"  {name:<18s} {t:7.2f}")
    one, three = med["1 ref, parallel 1"], med["3 ref, parallel 1"]
    print(f"per additional reference (sequential): {(three - one) / 2:.2f} s")
    print(f"3 references, parallel 2 vs 1: x{med['3 ref, parallel 2'] / three:.2f}")
    print("stages of the 3-reference fill (s, summed over references): " + ", ".join(
        f"{k} {s:.2f}" for k, s in stages.items()))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
