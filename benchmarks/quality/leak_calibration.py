"""What the leak metric of the removal protocols says about outputs whose nature is known, on the
protocols' own cases: the objects copied into the hole exactly, shifted by 2 px, with a colour gain
(x1.1 + 8), blurred (sigma 1 px); the truth with noise (sigma 8) or blurred (sigma 2 px); and
OpenCV's Telea inpainting, which cannot copy anything (the chance level of a smooth fill).

    .venv/bin/python benchmarks/quality/leak_calibration.py [--pairs DIR|synthetic:N ...] [--seed 0]

Default sets: the multi-view DEV sets and synthetic:3. Prints, per protocol, the mean leak and leak
(all) of each output over the sets.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from geofill.evaluation.baselines import opencv_inpaint
from geofill.evaluation.metrics import leak
from geofill.evaluation.pairs import load_pairs
from geofill.evaluation.removal import REMOVAL_PROTOCOLS, ProtocolSkip, RemovalCase, make_case

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, MULTIVIEW


def known_outputs(case: RemovalCase, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Outputs of known nature for ``case`` (whole images; only the hole is scored)."""
    truth = case.truth
    copy = truth.copy()
    for obj, mask in case.objects:
        copy[mask] = obj[mask]
    noisy = np.clip(truth + rng.normal(0.0, 8.0, truth.shape), 0, 255).astype(np.uint8)
    return {
        "objects copied": copy,
        "copied, shifted 2 px": np.roll(copy, 2, axis=1),
        "copied, gain 1.1 + 8": np.clip(copy * 1.1 + 8.0, 0, 255).astype(np.uint8),
        "copied, blurred 1 px": cv2.GaussianBlur(copy, (0, 0), 1.0),
        "truth + noise 8": noisy,
        "truth, blurred 2 px": cv2.GaussianBlur(truth, (0, 0), 2.0),
        "opencv_inpaint": opencv_inpaint(case.pair.target, case.hole),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--pairs", action="append", metavar="DIR", help="sets (default: multi-view + synthetic:3)"
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    pairs = load_pairs(args.pairs or [MULTIVIEW, "synthetic:3"], exclude=HELD_OUT)
    rng = np.random.default_rng(0)
    for protocol in REMOVAL_PROTOCOLS:
        scores: dict[str, list[tuple[float, float]]] = {}
        n = 0
        for pair in pairs:
            try:
                case = make_case(protocol, pair, args.seed)
            except ProtocolSkip:
                continue
            n += 1
            everything = [*case.objects, *case.extra_objects]
            for name, image in known_outputs(case, rng).items():
                out = np.where(case.hole[..., None], image, case.truth)
                own = leak(out, case.truth, case.objects, case.hole).fraction
                both = leak(out, case.truth, everything, case.hole).fraction
                scores.setdefault(name, []).append((own or 0.0, both or 0.0))
        print(f"\n{protocol} ({n} sets): mean leak / leak (all)")
        for name, values in scores.items():
            own, both = np.mean(values, axis=0)
            print(f"  {name:22s} {own:.3f} / {both:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
