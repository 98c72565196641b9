"""The classic reference-based fill as one standalone script: OpenCV SIFT on both images, ratio test,
one MAGSAC++ homography, the source warped into the target, a per-channel colour gain fitted on the
known ring around the hole, pasted into the hole (Telea for hole pixels the warp does not reach).

It imports only OpenCV and NumPy, so its wall time is what the simplest useful reference fill costs
on this machine: ``benchmarks/speed/whole_process.py`` runs it interleaved with ``geofill fill`` and
reports geofill's time as a ratio to it, which cancels the machine's load. It is also a quick
comparison for users (``geofill eval --methods homography`` is the evaluation's own version, on
geofill's matcher).

    python benchmarks/speed/homography_baseline.py --target t.jpg --mask m.png --source s.jpg -o out.png
"""

from __future__ import annotations

import argparse
import sys

import cv2
import numpy as np

#: Lowe's ratio test.
RATIO = 0.8
#: MAGSAC++ inlier threshold, px at a 1280-px long side (scaled with the image).
THRESHOLD_PX = 3.0
#: Width of the known ring around the hole the colour gain is fitted on, px at a 1280-px long side.
BAND_PX = 32.0
#: Fewer homography inliers than this and the script refuses (exit status 1).
MIN_INLIERS = 12


def _read_rgb(path: str) -> np.ndarray:
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise SystemExit(f"cannot read image {path}")
    return image


def homography_fill(target: np.ndarray, hole: np.ndarray, source: np.ndarray) -> np.ndarray:
    """``target`` (HxWx3 uint8) with ``hole`` (HxW bool) filled from ``source`` by one homography."""
    h, w = hole.shape
    scale = max(h, w) / 1280.0
    sift = cv2.SIFT_create()
    gray_t = cv2.cvtColor(target, cv2.COLOR_BGR2GRAY)
    gray_s = cv2.cvtColor(source, cv2.COLOR_BGR2GRAY)
    known = (~hole).astype(np.uint8) * 255
    kp_t, des_t = sift.detectAndCompute(gray_t, known)
    kp_s, des_s = sift.detectAndCompute(gray_s, None)
    if des_t is None or des_s is None:
        raise SystemExit("no SIFT features")
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(des_s, des_t, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < RATIO * m[1].distance]
    if len(good) < MIN_INLIERS:
        raise SystemExit(f"only {len(good)} matches pass the ratio test")
    src = np.float32([kp_s[m.queryIdx].pt for m in good])
    dst = np.float32([kp_t[m.trainIdx].pt for m in good])
    H, inliers = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, THRESHOLD_PX * max(scale, 0.5))
    if H is None or int(inliers.sum()) < MIN_INLIERS:
        raise SystemExit("the homography fit failed")
    warped = cv2.warpPerspective(source, H, (w, h), flags=cv2.INTER_LINEAR)
    valid = cv2.warpPerspective(np.ones(source.shape[:2], np.uint8), H, (w, h), flags=cv2.INTER_NEAREST)
    valid = cv2.erode(valid, np.ones((3, 3), np.uint8)).astype(bool)
    r = max(2, round(BAND_PX * scale))
    ring = cv2.dilate(hole.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2))
    band = ring.astype(bool) & ~hole & valid
    gain = target[band].astype(np.float64).mean(0) / np.maximum(warped[band].astype(np.float64).mean(0), 1.0)
    corrected = np.clip(warped * gain.astype(np.float32) + 0.5, 0, 255).astype(np.uint8)
    out = target.copy()
    covered = hole & valid
    out[covered] = corrected[covered]
    if (hole & ~valid).any():
        out = cv2.inpaint(out, (hole & ~valid).astype(np.uint8), 5, cv2.INPAINT_TELEA)
    return np.where(hole[..., None], out, target)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", required=True)
    ap.add_argument("--mask", required=True, help="hole where >= 127 (single channel)")
    ap.add_argument("--source", required=True)
    ap.add_argument("-o", "--output", required=True)
    args = ap.parse_args(argv)
    target, source = _read_rgb(args.target), _read_rgb(args.source)
    mask = cv2.imread(args.mask, cv2.IMREAD_GRAYSCALE)
    if mask is None or mask.shape != target.shape[:2]:
        raise SystemExit("the mask is unreadable or not the target's size")
    cv2.imwrite(args.output, homography_fill(target, mask >= 127, source))
    return 0


if __name__ == "__main__":
    sys.exit(main())
