"""The painter's structure scale against the painter targets: can one setting give both a hole PSNR
at least Telea's and a gradient ratio of 0.8-1.2?

    .venv/bin/python benchmarks/studies/structure_scale.py [--sigmas 0,2,3,4,5,6,8,12] [--pairs 8]

``inpaint.structure_sigma_px`` splits the exemplar painter's fill: below that Gaussian scale the
copied exemplars' detail, above it the diffusion's structure (0: exemplars only). On the painter
benchmark's cases (:mod:`benchmarks.quality.painter`: the first 8 DEV pairs at 720 px, the stroke
hole painted whole) each scale is run beside Telea, and the table says per scale: hole PSNR, hole
SSIM, gradient ratio (mean gradient magnitude in the hole over the known ring's; the truth's own is
printed) and whether it meets each target. A scale meeting both would settle the painter's
targets by a setting; the table shows whether one exists.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.*
from benchmarks.quality.painter import dev_pairs, quality

#: The painter targets: hole PSNR at least Telea's, gradient ratio within this range.
GRADIENT_RANGE = (0.8, 1.2)


def painters(sigmas: list[float]) -> dict:
    """Telea and the exemplar painter at each structure scale, as ``quality`` runs them."""
    from geofill.composite.inpaint import get_inpainter
    from geofill.config import InpaintConfig

    def run(cfg: InpaintConfig):
        inp = get_inpainter(cfg)
        return lambda img, hole: inp.fill(img, hole)

    out = {"telea": run(InpaintConfig(method="telea"))}
    for s in sigmas:
        out[f"exemplar, sigma {s:g} px"] = run(InpaintConfig(method="exemplar", structure_sigma_px=s))
    return out


def table(rows: dict) -> str:
    """Markdown: per painter the mean hole PSNR, SSIM and gradient ratio, and the targets met."""
    mean = {name: {k: statistics.fmean(v) for k, v in r.items()} for name, r in rows.items()}
    telea = mean["telea"]["psnr"]
    lines = [
        f"truth's own gradient ratio: {mean['truth']['grad']:.2f}",
        "",
        "| painter | hole PSNR (dB) | - Telea | hole SSIM | gradient ratio | PSNR >= Telea | ratio 0.8-1.2 |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, m in mean.items():
        if name == "truth":
            continue
        psnr_ok = "-" if name == "telea" else ("yes" if m["psnr"] >= telea else "no")
        grad_ok = "yes" if GRADIENT_RANGE[0] <= m["grad"] <= GRADIENT_RANGE[1] else "no"
        lines.append(
            f"| {name} | {m['psnr']:.2f} | {m['psnr'] - telea:+.2f} | {m['ssim']:.3f} | {m['grad']:.2f} "
            f"| {psnr_ok} | {grad_ok} |"
        )
    both = [
        n
        for n, m in mean.items()
        if n not in ("truth", "telea")
        and m["psnr"] >= telea
        and GRADIENT_RANGE[0] <= m["grad"] <= GRADIENT_RANGE[1]
    ]
    lines += ["", f"scales meeting both targets: {', '.join(both) if both else 'none'}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigmas", default="0,2,3,4,5,6,8,12", help="structure scales (px), comma-separated")
    ap.add_argument("--pairs", type=int, default=8, help="first N DEV pairs")
    args = ap.parse_args(argv)
    sigmas = [float(s) for s in args.sigmas.split(",")]
    folders = dev_pairs(args.pairs)
    if not folders:
        print("no DEV pairs here (../shared/data/pairs is absent)")
        return 0
    print(table(quality(painters(sigmas), folders, None)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
