"""Which space should the depth scale/offset fit live in? Measured on the pairs with GT depth.

For each pair with ``depth_source.png`` and a pose, the GT depth is handed to the pipeline through
the ``file`` backend in two forms a user or a network would give:
  * ``inverse+shift``: relative inverse depth a/z + c (how MiDaS/DPT/Depth Anything output), and
  * ``metric depth``: z in metres (phone LiDAR / RGB-D),
and the pipeline's own triangulated points fix scale/offset, with the fit in depth space or in
inverse-depth space, with the pair's true intrinsics (``--default-intrinsics``: the default guess).
Printed: AbsRel and delta<1.25 of the aligned depth against GT (pose units brought to metres with
the GT baseline), and the hole PSNR of the fill.

    .venv/bin/python benchmarks/studies/depth_fit_space.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from geofill.config import FillConfig
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.pipeline import fill

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS


def depth_metrics(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    ok = np.isfinite(pred) & (gt > 0) & (pred > 0)
    ratio = pred[ok] / gt[ok]
    return float(np.mean(np.abs(pred[ok] - gt[ok]) / gt[ok])), float(
        np.mean(np.maximum(ratio, 1 / ratio) < 1.25)
    )


def main() -> int:
    true_k = "--default-intrinsics" not in sys.argv[1:]
    pairs = [
        p for p in load_pairs([PAIRS], exclude=HELD_OUT) if p.path and (p.path / "depth_source.png").is_file()
    ]
    tmp = Path(tempfile.mkdtemp())
    print(f"{'pair':<34s} {'input':<14s} {'fit space':<10s} {'AbsRel':>7s} {'d<1.25':>7s} {'PSNR hole':>9s}")
    summary: dict[tuple[str, str], list[tuple[float, float, float]]] = {}
    for pair in pairs:
        gt = cv2.imread(str(pair.path / "depth_source.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        T = pair.meta.get("T_source_to_target") or pair.meta.get("T_source_to_target_estimated")
        baseline_m = float(np.linalg.norm(np.array(T)[:3, 3]))
        z = np.where(gt > 0, gt, np.nan)
        inputs = {
            "inverse+shift": ("inverse_depth", 3.7 / z + 0.25 * np.nanmedian(1 / z)),
            "metric depth": ("depth", z),
        }
        hole = pair_mask(pair, 0)
        # True intrinsics: isolates the fit space from intrinsics error.
        k_t, k_s = (
            [K[0][0], K[1][1], K[0][2], K[1][2]] for K in (pair.meta["K_target"], pair.meta["K_source"])
        )
        for name, (kind, values) in inputs.items():
            path = tmp / f"{pair.id}_{kind}.npy"
            np.save(path, values.astype(np.float32))
            for space in ("depth", "inverse"):
                cfg = FillConfig().updated(
                    {"depth.backend": "file", "depth.file_path": str(path), "depth.file_kind": kind,
                     "geometry.fit_space": space}
                    | ({"intrinsics.target": k_t, "intrinsics.source": k_s} if true_k else {})
                )  # fmt: skip
                res = fill(pair.target, hole, pair.source, cfg)
                if res.references[0].depth is None:
                    print(f"{pair.id:<34s} {name:<14s} {space:<10s} failed: {res.report.fallbacks}")
                    continue
                absrel, d1 = depth_metrics(res.references[0].depth.depth * baseline_m, gt)
                p = psnr(res.image, pair.target, hole)
                summary.setdefault((name, space), []).append((absrel, d1, p))
                print(f"{pair.id:<34s} {name:<14s} {space:<10s} {absrel:7.3f} {d1:7.3f} {p:9.2f}")
    print("\nmean over pairs:")
    for (name, space), vals in summary.items():
        a = np.array(vals)
        print(f"  {name:<14s} fit in {space:<8s} AbsRel {a[:, 0].mean():.3f}  d<1.25 {a[:, 1].mean():.3f}  "
              f"PSNR hole {a[:, 2].mean():.2f} dB  (n={len(a)})")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
