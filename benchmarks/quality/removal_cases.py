"""The four real object removals users tried (masks brushed over objects): a bush and a parked red
car in Lund, a sign on a facade, people on Berlin cathedral's steps. Each is filled with the removed
object refused (today's default) and allowed (``screen.removed_object=allow``, the fill before
object removal), refused with Telea painting what no reference shows (the ``telea`` preset), and by
single-image inpainting; prints what each fill copied, refused and painted, and writes one contact
sheet per case.

    .venv/bin/python benchmarks/quality/removal_cases.py [--out docs/img]

There is no ground truth for these: the sheets are for looking at, the numbers say where the hole's
pixels came from.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from geofill.composite.inpaint import inpaint_single
from geofill.config import FillConfig
from geofill.evaluation.pairs import load_pair
from geofill.pipeline import fill

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW, PAIRS

#: (name, set folder, brushed regions as polygons in target pixels). The brush covers each object
#: with a margin, as a user's does.
CASES = (
    ("lund_bush", PAIRS / "dev_opensfm_lund_04_05", [[(232, 400), (338, 400), (345, 520), (225, 525)]]),
    (
        "facade_sign",
        PAIRS / "dev_lightglue_facade_dsc0410_0411",
        [[(95, 410), (218, 410), (218, 562), (178, 562), (180, 660), (128, 660), (130, 562), (95, 562)]],
    ),
    (
        "lund_red_car",
        MULTIVIEW / "dev_mv_opensfm_lund_redcar",
        [[(532, 418), (738, 418), (738, 578), (532, 578)]],
    ),
    (
        "berlin_people",
        PAIRS / "dev_opensfm_berlin_01_02",
        [
            [(132, 680), (198, 680), (198, 800), (132, 800)],
            [(262, 680), (350, 680), (350, 800), (262, 800)],
            [(380, 750), (450, 750), (450, 920), (380, 920)],
            [(670, 735), (768, 735), (768, 900), (670, 900)],
            [(1050, 735), (1280, 735), (1280, 950), (1050, 950)],
        ],
    ),
)


def brushed(shape: tuple[int, ...], polygons: list[list[tuple[int, int]]]) -> np.ndarray:
    """The hole: the polygons filled."""
    mask = np.zeros(shape[:2], np.uint8)
    cv2.fillPoly(mask, [np.array(p, np.int32) for p in polygons], 255)
    return mask > 0


def _crop(image: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """The hole's bounding box grown by its own size on each side (what the eye judges)."""
    ys, xs = np.nonzero(hole)
    h, w = ys.max() - ys.min(), xs.max() - xs.min()
    y0, y1 = max(ys.min() - h, 0), min(ys.max() + h + 1, hole.shape[0])
    x0, x1 = max(xs.min() - w, 0), min(xs.max() + w + 1, hole.shape[1])
    return image[y0:y1, x0:x1]


def _tile(image: np.ndarray, label: str, height: int = 300) -> np.ndarray:
    h, w = image.shape[:2]
    out = cv2.resize(image, (round(w * height / h), height), interpolation=cv2.INTER_AREA)
    cv2.rectangle(out, (0, 0), (out.shape[1], 22), (0, 0, 0), -1)
    cv2.putText(out, label, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def _where(report) -> str:
    parts = [f"{100 * f:.0f}% ref {i}" for i, f in enumerate(report.supplied_fraction, 1) if f >= 0.005]
    parts.append(f"{100 * report.painted_fraction:.0f}% painted")
    refused = report.refused_fraction.get("removed_object", 0.0)
    return ", ".join(parts) + (f"; refused {100 * refused:.0f}%" if refused >= 0.005 else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/img", help="folder for removal_<case>.jpg")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    refuse, allow = FillConfig(), FillConfig().updated({"screen.removed_object": "allow"})
    for name, folder, polygons in CASES:
        pair = load_pair(folder)
        hole = brushed(pair.target.shape, polygons)
        exif = {"target_exif": pair.exif.target, "source_exifs": list(pair.exif.sources)}
        t0 = time.perf_counter()
        after = fill(pair.target, hole, pair.sources, refuse, **exif)
        t_after = time.perf_counter() - t0
        t0 = time.perf_counter()
        before = fill(pair.target, hole, pair.sources, allow, **exif)
        t_before = time.perf_counter() - t0
        smeared = fill(pair.target, hole, pair.sources, refuse.preset("telea"), **exif)
        painted = inpaint_single(pair.target, hole, refuse.inpaint)
        print(
            f"{name}: hole {100 * hole.mean():.1f}% of the target, {len(pair.sources)} reference(s)\n"
            f"  refused (default): {_where(after.report)}  [{t_after:.1f} s]\n"
            f"  allowed (before):  {_where(before.report)}  [{t_before:.1f} s]"
        )
        shown = pair.target.copy()
        shown[hole] = (0.5 * shown[hole] + [127, 0, 127]).astype(np.uint8)
        tiles = [_tile(shown, "target + brushed hole")]
        tiles += [_tile(s, f"reference {k}") for k, s in enumerate(pair.sources, 1)]
        tiles += [
            _tile(_crop(before.image, hole), "object allowed (before)"),
            _tile(_crop(after.image, hole), "object refused (now)"),
            _tile(_crop(smeared.image, hole), "refused, Telea painter"),
            _tile(_crop(painted, hole), f"single-image ({after.report.inpaint_method.split()[0]})"),
        ]
        row = np.concatenate(tiles, axis=1)
        cv2.imwrite(
            str(out / f"removal_{name}.jpg"),
            cv2.cvtColor(row, cv2.COLOR_RGB2BGR),
            [cv2.IMWRITE_JPEG_QUALITY, 85],
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
