"""``geofill demo``: fill a self-generated synthetic two-view scene whose ground truth is exact, and
report how close the fill and the recovered geometry are to it."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from .camera import pose_errors_deg
from .composite.inpaint import inpaint_single
from .config import FillConfig
from .evaluation.metrics import psnr, ssim
from .io import write_image_atomic
from .pipeline import fill
from .progress import Progress
from .synthetic import blanked, make_pair


def _label(image: np.ndarray, text: str) -> np.ndarray:
    out = image.copy()
    cv2.rectangle(out, (0, 0), (min(out.shape[1], 12 + 11 * len(text)), 26), (0, 0, 0), -1)
    cv2.putText(out, text, (6, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def run_demo(out_dir: Path, seed: int = 0, quiet: bool = False, width: int = 640, height: int = 480) -> dict:
    """Run the demo, write ``side_by_side.png``, ``fill.png`` and ``numbers.json``; return the numbers."""
    prog = Progress(quiet=quiet)
    prog.say(f"generating synthetic scene (seed {seed}, {width}x{height})")
    pair = make_pair(seed=seed, width=width, height=height)
    cfg = FillConfig()
    # The hole shows nothing (the restoration input): here it hides no object, only what the
    # reference sees, which the screen stage would otherwise refuse as the thing being removed.
    result = fill(blanked(pair.target, pair.hole), pair.hole, pair.source, cfg, progress=prog)
    single = inpaint_single(pair.target, pair.hole, cfg.inpaint)
    ref = result.references[0]
    T = ref.geometry.T if ref.geometry is not None else np.eye(4)
    rot_err, t_err = pose_errors_deg(T, pair.T_source_to_target)
    numbers = {
        "scene": {"seed": seed, "width": width, "height": height, "hole_fraction": float(pair.hole.mean())},
        "geofill": {
            "psnr_hole_db": psnr(result.image, pair.target, pair.hole),
            "ssim_hole": ssim(result.image, pair.target, pair.hole),
            "psnr_db": psnr(result.image, pair.target),
            "status": result.report.status,
            "hole_coverage": result.report.supplied_fraction[0],
            "rotation_error_deg": rot_err,
            "translation_direction_error_deg": t_err,
            "time_s": sum(result.report.timings_s.values()),
        },
        "single_image_inpainting": {
            "psnr_hole_db": psnr(single, pair.target, pair.hole),
            "ssim_hole": ssim(single, pair.target, pair.hole),
            "psnr_db": psnr(single, pair.target),
        },
    }
    masked = pair.target.copy()
    masked[pair.hole] = (masked[pair.hole] * 0.3 + np.array([255, 0, 255]) * 0.7).astype(np.uint8)
    source = cv2.resize(pair.source, (width, height), interpolation=cv2.INTER_AREA)
    g, s = numbers["geofill"], numbers["single_image_inpainting"]
    tiles = [
        _label(masked, "target + hole"),
        _label(source, "source"),
        _label(result.image, f"geofill {g['psnr_hole_db']:.1f} dB"),
        _label(single, f"single-image {s['psnr_hole_db']:.1f} dB"),
        _label(pair.target, "ground truth"),
    ]
    out_dir.mkdir(parents=True, exist_ok=True)
    write_image_atomic(out_dir / "side_by_side.png", np.concatenate(tiles, axis=1))
    write_image_atomic(out_dir / "fill.png", result.image)
    (out_dir / "numbers.json").write_text(json.dumps(numbers, indent=2) + "\n")
    prog.say(
        f"hole PSNR: geofill {g['psnr_hole_db']:.2f} dB vs single-image {s['psnr_hole_db']:.2f} dB; "
        f"pose error: rotation {rot_err:.2f} deg, translation direction {t_err:.2f} deg"
    )
    prog.say(f"wrote {out_dir / 'side_by_side.png'} and {out_dir / 'numbers.json'}")
    return numbers
