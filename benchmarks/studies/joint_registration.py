"""One registration for all the images of a set (COLMAP's incremental SfM with bundle adjustment,
through pycolmap) against geofill's own per-pair registration, on the multi-reference sets with
ground-truth poses.

    <venv with pycolmap>/bin/python benchmarks/studies/joint_registration.py [--seed 0] [--set KEY=VALUE ...]

pycolmap is not a geofill dependency (135 MB installed, and its dense stereo needs CUDA): run
this in a separate venv, ``pip install pycolmap==4.2.1`` next to geofill. Per set: the target with
the evaluation's stroke hole (``--seed``) masked out for COLMAP's features and blanked for
geofill's, every reference as is. COLMAP: one camera for all images (SIMPLE_RADIAL, focal
estimated), exhaustive matching, incremental mapping. geofill: every reference through its stages
up to ``optimize`` (the fill's registration, shared focal where ``intrinsics.shared_camera``
applies). Printed per reference: rotation error (degrees) of source->target against the GT pose,
the translation direction's error (degrees), and the target focal's error (%) against the GT K;
plus the wall time of each registration.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW

SETS = ("dev_mv_instantngp_fox_lower", "dev_mv_instantngp_fox_upper", "dev_mv_slambook_livingroom")


def colmap(pair, hole: np.ndarray, work: Path) -> tuple[list[np.ndarray | None], float | None, float]:
    """COLMAP's source->target poses (None for a reference it did not register), its target focal
    (px) and the wall time."""
    import pycolmap

    images, masks = work / "images", work / "masks"
    images.mkdir()
    masks.mkdir()
    names = ["target.png"] + [f"source{k}.png" for k in range(len(pair.sources))]
    for name, img in zip(names, [pair.target, *pair.sources], strict=True):
        cv2.imwrite(str(images / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        keep = ~hole if name == "target.png" else np.ones(img.shape[:2], bool)
        cv2.imwrite(str(masks / f"{name}.png"), keep.astype(np.uint8) * 255)  # COLMAP: 0 = ignored
    t0 = time.perf_counter()
    db = work / "db.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "SIMPLE_RADIAL"
    reader.mask_path = str(masks)
    pycolmap.extract_features(db, images, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader)
    pycolmap.match_exhaustive(db)
    maps = pycolmap.incremental_mapping(db, images, work / "sparse")
    wall = time.perf_counter() - t0
    if not maps:
        return [None] * len(pair.sources), None, wall
    rec = max(maps.values(), key=lambda r: r.num_reg_images())
    by_name = {img.name: img for img in rec.images.values()}
    if "target.png" not in by_name:
        return [None] * len(pair.sources), None, wall
    t = by_name["target.png"]
    world_to_t = t.cam_from_world().matrix()
    focal = float(rec.cameras[t.camera_id].params[0])
    out = []
    for name in names[1:]:
        if name not in by_name:
            out.append(None)
            continue
        s = np.eye(4)
        s[:3] = by_name[name].cam_from_world().matrix()
        w = np.eye(4)
        w[:3] = world_to_t
        out.append(w @ np.linalg.inv(s))
    return out, focal, wall


def own(
    pair, hole: np.ndarray, overrides: dict[str, str]
) -> tuple[list[np.ndarray | None], list[float | None], float]:
    """geofill's source->target poses and target focal (px, at the input size) per reference, and
    the wall time of its registration (every reference up to ``optimize``)."""
    from geofill.config import FillConfig
    from geofill.pipeline import ReferenceArtifacts, prepare_fill, run_all_references
    from geofill.progress import Progress

    t0 = time.perf_counter()
    cfg = FillConfig().updated(overrides) if overrides else FillConfig()
    target = pair.target.copy()
    target[hole] = 0
    ctx = prepare_fill(target, hole.astype(np.uint8) * 255, pair.sources, cfg)
    refs = [ReferenceArtifacts(i + 1, s) for i, s in enumerate(pair.sources)]
    refs, _ = run_all_references(ctx, refs, Progress(), until="optimize")
    wall = time.perf_counter() - t0
    poses, focals = [], []
    h, w = pair.target.shape[:2]
    for r in refs:
        if r.geometry is None or r.dropped:
            poses.append(None)
            focals.append(None)
            continue
        poses.append(r.geometry.T)
        focals.append(r.geometry.K_target.resized(w, h).fx)
    return poses, focals, wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="geofill's configuration")
    args = ap.parse_args(argv)
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        print("needs pycolmap: run it in a venv with `pip install pycolmap==4.2.1` (see the docstring)")
        return 1
    from geofill.camera import pose_errors_deg
    from geofill.evaluation.pairs import load_pair, pair_geometry, pair_mask

    print("set / reference            COLMAP (joint BA)                 geofill (per pair)")
    print("                           rot deg  dir deg  focal %        rot deg  dir deg  focal %")
    for name in SETS:
        if not (MULTIVIEW / name).is_dir():
            print(f"{name}: skipped, not found")
            continue
        pair = load_pair(MULTIVIEW / name)
        hole = np.asarray(pair_mask(pair, args.seed)) > 0
        geo = pair_geometry(pair)
        f_gt = float(geo.K_target[0, 0])
        with tempfile.TemporaryDirectory() as tmp:
            c_poses, c_focal, c_wall = colmap(pair, hole, Path(tmp))
        o_poses, o_focals, o_wall = own(pair, hole, dict(kv.split("=", 1) for kv in args.set))
        print(f"{name}  (COLMAP {c_wall:.1f} s, geofill {o_wall:.1f} s)")
        for k, T_gt in enumerate(geo.T_source_to_target):
            cells = []
            for T, f in ((c_poses[k], c_focal), (o_poses[k], o_focals[k])):
                if T is None or T_gt is None:
                    cells.append(f"{'not registered':>31s}")
                    continue
                rot, direction = pose_errors_deg(T, T_gt)
                ferr = 100.0 * (f - f_gt) / f_gt if f is not None else float("nan")
                cells.append(f"{rot:8.2f} {direction:8.2f} {ferr:+8.1f}")
            print(f"  ref {k + 1:<21d}{cells[0]}       {cells[1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
