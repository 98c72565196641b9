"""Cost of the learned matching rung (XFeat + LighterGlue, the ``learned`` extra) against the plain
SIFT rung, per wide DEV pair at the working size (1280-px long side), the hole blanked as in a fill.

    .venv/bin/python benchmarks/speed/learned_rung.py [--pairs DIR ...] [--repeats 3]

Per pair, alternated in the same process (``--repeats`` rounds, medians): the ``sift`` rung
(``matching.max_rung=sift``: SIFT on both images, matching, F verification), and for each keypoint
budget (default: ``matching.learned_max_keypoints``, the rung after a weak SIFT, and
``matching.learned_recheck_max_keypoints``, its re-check of a suspicious SIFT geometry) and each
matcher variant the learned matcher on a new target (features of both images + LighterGlue) and on
a target already seen (another reference of the same fill: the target's features are reused).
Variants (``--variants THREADS:ATTENTION:CONFIDENCE ...``): torch threads (0: torch's default,
one per core), ``fused`` (torch's fused attention, the matcher's own) or ``kornia`` (kornia's CPU
cross-attention), and LightGlue's early-exit/pruning confidence; by default the matcher as
configured (``matching.learned_threads``, fused, ``matching.learned_confidence``) against the
one it replaced (``0:kornia:0.95``). The matches found are printed per variant: the
variants must agree. Wall seconds and the process's CPU
seconds (all threads; torch runs ``torch.get_num_threads()`` of them): on a shared machine the wall
time includes waiting for other processes, the CPU time does not. ``uptime`` before and after.
The weights are loaded once before the rounds (printed). Figures, not a test.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import subprocess
import sys
import time
from pathlib import Path

from geofill.config import FillConfig
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.match import match_pair
from geofill.match.features import keypoint_mask, to_gray_u8
from geofill.match.xfeat import INSTALL, XFeatLighterGlue, missing_modules
from geofill.prepare import prepare_views

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

WIDE = ("dev_wide_",)


def _uptime() -> str:
    return subprocess.check_output(["uptime"], text=True).strip()


def _timed(fn, *args) -> tuple[object, float, float]:
    """``fn(*args)``, its wall and its CPU seconds."""
    w, c = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, time.perf_counter() - w, time.process_time() - c


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", action="append", help="pair folder(s) (default: the wide DEV pairs)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--keypoints", type=int, nargs="+", help="XFeat keypoint budgets (default: both)")
    ap.add_argument(
        "--variants", nargs="+", help="THREADS:fused|kornia:CONFIDENCE (default: configured, 0:kornia:0.95)"
    )
    args = ap.parse_args(argv)
    if missing_modules():
        print(f"the learned extra is not installed: {INSTALL}")
        return 1
    import torch

    pairs = load_pairs(args.pairs or [str(PAIRS)], exclude=HELD_OUT)
    if not args.pairs:
        pairs = [p for p in pairs if p.id.startswith(WIDE)]
    cfg = FillConfig()
    mc = cfg.matching
    sift_only = dataclasses.replace(mc, max_rung="sift", learned="off")
    budgets = args.keypoints or [mc.learned_max_keypoints, mc.learned_recheck_max_keypoints]
    variants = args.variants or [f"{mc.learned_threads}:fused:{mc.learned_confidence:g}", "0:kornia:0.95"]
    matchers = {}
    for kp in budgets:
        for var in variants:
            threads, attention, confidence = var.split(":")
            w, c = time.perf_counter(), time.process_time()
            matchers[f"{kp}/{var}"] = m = XFeatLighterGlue(
                kp, mc.learned_max_side, int(threads), float(confidence), fused_attention=attention == "fused"
            )
            wall, cpu = time.perf_counter() - w, time.process_time() - c
            print(f"{kp}/{var}: loaded {m.describe} in {wall:.2f} s ({cpu:.2f} s CPU)")
    print(f"torch threads by default {torch.get_num_threads()}; load: {_uptime()}")
    keys = ["sift"] + [f"{k}{name}" for name in matchers for k in ("new", "seen")]
    head = ["size"] + [f"{k}_{x}" for k in keys for x in ("wall", "cpu")] + [f"matches{m}" for m in matchers]
    print(f"{'pair':<38s} " + " ".join(f"{h:>12s}" for h in head))
    rows = []
    for pair in pairs:
        hole = pair_mask(pair, 0, 100.0)
        target = pair.target.copy()
        target[hole] = 0  # as the fill sees it
        v = prepare_views(target, hole, pair.source, cfg, None, None)
        gray_t, gray_s = to_gray_u8(v.target_gray), to_gray_u8(v.source_gray)
        mask = keypoint_mask(v.hole, mc.hole_margin_px * v.px_scale)
        times: dict[str, list[tuple[float, float]]] = {k: [] for k in keys}
        found = {}
        for _ in range(args.repeats):
            _, *t = _timed(match_pair, v.target_gray, v.source_gray, v.hole, sift_only, v.px_scale)
            times["sift"].append(tuple(t))
            for name, matcher in matchers.items():
                matcher._targets.clear()
                _, *t = _timed(matcher, gray_t, gray_s, mask)
                times[f"new{name}"].append(tuple(t))
                out, *t = _timed(matcher, gray_t, gray_s, mask)
                times[f"seen{name}"].append(tuple(t))
                found[name] = len(out[0])
        med = {
            k: (statistics.median(x[0] for x in ts), statistics.median(x[1] for x in ts))
            for k, ts in times.items()
        }
        rows.append(med)
        cells = [f"{gray_t.shape[1]}x{gray_t.shape[0]}"] + [f"{x:.2f}" for k in keys for x in med[k]]
        cells += [str(found[name]) for name in matchers]
        print(f"{pair.id[:38]:<38s} " + " ".join(f"{x:>12s}" for x in cells), flush=True)
    names = {"sift": "sift rung"}
    for name in matchers:
        kp, var = name.split("/")
        names |= {
            f"new{name}": f"learned {kp} kp {var}, new target",
            f"seen{name}": f"learned {kp} kp {var}, target seen",
        }
    for k, name in names.items():
        print(
            f"{name}: median wall {statistics.median(r[k][0] for r in rows):.2f} s, "
            f"CPU {statistics.median(r[k][1] for r in rows):.2f} s"
        )
    print(f"load: {_uptime()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
