"""Regenerate docs/results.md: run every measurement and paste its output under its command.

    make results            # or: .venv/bin/python benchmarks/make_results.py [--only NAME,...]
    make results-stale      # or: ... --stale: which sections predate the code they describe

Every number in docs/results.md comes from one of the commands listed there; nothing is typed in by
hand. Decisions drawn from these numbers are explained in docs/architecture.md. Takes a while (the
eval runs every method and ablation on every pair); ``--only`` regenerates some sections and keeps
the others from the previous file.

Every section is stamped with the revision (git short hash, "+ uncommitted changes" where the code
it ran differed from it) and the date it was generated, and a digest of the code it depends on
(:func:`dependencies`: the geofill and benchmark modules its command's processes imported, recorded
in ``benchmarks/results_deps.json``, and the scripts its command names; for a section generated
before that was recorded, all of ``src/geofill`` and ``benchmarks/common.py``). A change to the
painter thus stales the sections that fill, not the renderer's or the stereo's own benchmarks.
``--stale`` lists the sections whose code changed since (their digest, or for a stamp without one
the files changed since its revision) and those whose last run failed, with what each took to
generate; ``--only stale`` reruns them.
``--alongside`` says under each section it runs that other work ran on the machine at the same
time (the 2-core machine then runs two single-threaded sections at once: its times include that
contention, +13 % on one fill measured); concurrent ``--only`` runs update docs/results.md under a lock.
``--stamp-derived`` stamps sections that have no stamp with the commit that last changed their text
in docs/results.md (``git blame``), marked as derived: what code produced them is not known.
"""

from __future__ import annotations

import argparse
import ast
import datetime
import fcntl
import functools
import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, MULTIVIEW, PAIRS, ROOT, STATIC_PAIRS

OUT = ROOT / "docs" / "results.md"
PY = sys.executable


@dataclass
class Section:
    name: str
    title: str
    about: str
    command: list[str]
    #: File (relative to the command's temporary output folder) whose text is the result; None = stdout.
    result_file: str | None = None


def _eval(out: str, *extra: str, pairs: Path = PAIRS) -> list[str]:
    held_out = [arg for name in HELD_OUT for arg in ("--exclude", name)]
    return [PY, "-m", "geofill.cli", "eval", "--pairs", str(pairs), *held_out, "--out", out, *extra]


def _static(methods: str) -> list[str]:
    """``geofill eval --protocol static`` on the sets with GT poses and 3 synthetic view sets."""
    pairs = [arg for name in STATIC_PAIRS for arg in ("--pairs", name)]
    return [
        *[PY, "-m", "geofill.cli", "eval", "--protocol", "static", "--references", "all", "--out", "{out}"],
        *pairs,
        *["--methods", methods],
    ]


SECTIONS = [
    Section(
        "eval",
        "Fill quality on the real pairs (`geofill eval`)",
        "Deterministic DeepFillv2-style brush holes (seed 0, mean width 150 px at 720p). PSNR/SSIM over the "
        "whole image (papers' convention) and over the hole; wins count pairs with a higher hole PSNR.",
        _eval("{out}", "--methods", "opencv_inpaint,homography,geofill"),
        "summary.md",
    ),
    Section(
        "multiview",
        "Several references on the multi-reference sets (`geofill eval`)",
        "The 7 DEV sets of `../shared/data/multiview` (a target and 3-4 references each), the same stroke "
        "holes as the pairs. Every method with the primary reference alone, each other reference alone "
        "(`[ref k]`), and geofill with all references (`[all]`, feathered per-pixel winners).",
        _eval("{out}", "--methods", "homography,geofill", pairs=MULTIVIEW),
        "summary.md",
    ),
    Section(
        "multiview_seeds",
        "All references against the best single reference over three hole seeds "
        "(`benchmarks/quality/multiview_seeds.py`)",
        "The multi-view targets on the mean of seeds 0-2 (one seed's holes can favour either side): all "
        "references minus the best single reference per set and seed, and the sets where all references "
        "are at least as good; the default registers them jointly (`registration.joint=auto`, the `sfm` "
        "extra); `perpair` registers each reference with the target alone (`registration.joint=off`).",
        [PY, "benchmarks/quality/multiview_seeds.py", "--variant", "perpair:registration.joint=off"],
    ),
    Section(
        "reference_order",
        "The order of the references (`benchmarks/quality/reference_order.py`)",
        "The Lund red car and the living room (the evaluation's seed-0 hole), filled with all references "
        "listed in three orders: hole PSNR and the output's hash per order (one distinct output: the order "
        "does not change the fill).",
        [PY, "benchmarks/quality/reference_order.py"],
    ),
    Section(
        "multiview_graphcut",
        "Seams between references: graph cut (`geofill eval --methods geofill_graphcut`)",
        "As above with `fusion.seams=graphcut` (OpenCV graph-cut seams between the per-pixel winners) "
        "instead of feathered winners, all references only; compare its `[all]` row with the default's.",
        _eval("{out}", "--methods", "geofill_graphcut", "--references", "all", pairs=MULTIVIEW),
        "summary.md",
    ),
    Section(
        "removal_static",
        "Object removal, a static object (`geofill eval --protocol static`)",
        "A planar photo cutout placed in front of the scene and drawn, with the GT poses, into the target "
        "and every reference (the 3 DEV multi-reference sets with GT poses and 3 synthetic view sets); the "
        "methods get the target showing it. `leak`: the share of the hole's distinguishable pixels where "
        "the output reproduces the object. `geofill_object_allowed` is the fill before the screen stage.",
        _static("opencv_inpaint,homography,geofill,geofill_object_allowed"),
        "summary.md",
    ),
    Section(
        "removal_strangers",
        "Object removal, strangers in the references (`geofill eval --protocol strangers`)",
        "Cutouts pasted into the references over 30-60 % of where the hole's background appears in them; "
        "the target's hole shows another cutout. The screen stage refuses the render content that continues "
        "a stranger reaching beyond the hole (where the render disagrees with the target around it), and the "
        "fuse stage refuses a reference the others covering the same pixels contradict; a stranger "
        "wholly inside the hole's footprint that no other reference contradicts is not caught "
        "(docs/architecture.md).",
        _eval(
            "{out}",
            "--protocol",
            "strangers",
            "--references",
            "all",
            "--pairs",
            "synthetic-views:3",
            "--methods",
            "opencv_inpaint,homography,geofill",
            pairs=MULTIVIEW,
        ),
        "summary.md",
    ),
    Section(
        "removal_seeds",
        "Object removal over three seeds (`benchmarks/quality/removal_seeds.py`)",
        "Both removal protocols' all-reference fills on seeds 0-2 (the sections above are seed 0 alone, "
        "whose cases can swing a set by dB), the default against registering each reference with the "
        "target alone (`perpair`: `registration.joint=off`).",
        [PY, "benchmarks/quality/removal_seeds.py", "--variant", "perpair:registration.joint=off"],
    ),
    Section(
        "removal_kinds",
        "Object removal per kind of object, brushed holes (`benchmarks/quality/removal_kinds.py`)",
        "Each removal protocol (a planar cutout, a textured box and a one-colour box placed in 3D, "
        "strangers in the references, a walking figure alone and with passers-by) on the 3 DEV "
        "multi-reference sets with GT poses and 2 synthetic view sets, seed 0, holes brushed 15-45 px "
        "beyond the object (the default `--removal-mask brushed`): hole PSNR, leak (the object back in "
        "place), leak (all) (with each reference's objects mapped in) and ghost (an object or passer-by "
        "reproduced anywhere in the hole) of Telea's smear, the homography baseline and geofill with "
        "all references, against the targets (leak and ghost at most Telea's + 0.02, hole PSNR at least "
        "Telea's + 1.5 dB).",
        [PY, "benchmarks/quality/removal_kinds.py", "--seeds", "0", "--jobs", "2"],
    ),
    Section(
        "painter",
        "Single-image painters on whole holes (`benchmarks/quality/painter.py`)",
        "The first 8 DEV pairs (wide ones excluded) at a 720-px long side, the evaluation's stroke hole "
        "(seed 0) at a mean width of 100 px, painted whole (the single-image fallback). Gradient ratio: mean "
        "gradient magnitude in the hole over that in the 20-px known ring (a smear is far below 1); patch "
        "distance: RMS (0-255) from 400 fill patches (5x5) to their nearest known patch. Times: the same "
        "process, each painter alternated with Telea, under the load of the shared machine (column `load`).",
        [PY, "benchmarks/quality/painter.py", "--out", "{out}"],
        "painter.md",
    ),
    Section(
        "painter_surfaces",
        "The surface-aware painter against Telea, with its peak memory (`benchmarks/quality/painter.py`)",
        "As `painter`, Telea and the default painter only (each hole pixel copied from its own surface, "
        "structure diffused per surface), timed three times, and the painter's peak resident memory on a "
        "7600x7600 photo with an 89 % hole (each painter in its own process). The `painter` section above "
        "holds the painter before surfaces, for comparison.",
        [
            PY,
            "benchmarks/quality/painter.py",
            "--out",
            "{out}",
            "--painters",
            "telea,exemplar",
            "--repeats",
            "3",
        ]
        + ["--memory"],
        "painter.md",
    ),
    Section(
        "structure_scale",
        "The painter's structure scale against its two targets (`benchmarks/studies/structure_scale.py`)",
        "The `painter` cases (first 8 DEV pairs at 720 px, the stroke hole painted whole), Telea and the "
        "exemplar painter at each `inpaint.structure_sigma_px` (0: exemplars only; default 4): whether one "
        "scale gives both a hole PSNR at least Telea's and a gradient ratio of 0.8-1.2.",
        [PY, "benchmarks/studies/structure_scale.py"],
    ),
    Section(
        "painter_fills",
        "The painter inside reference fills (`geofill eval --methods geofill,geofill_telea`)",
        "The default (exemplar painter for what the references leave uncovered) against the `telea` preset "
        "on the first 8 DEV pairs, default restoration protocol.",
        _eval("{out}", "--limit", "8", "--methods", "geofill,geofill_telea"),
        "summary.md",
    ),
    Section(
        "painter_static",
        "The painter in object removal (`geofill eval --protocol static --methods geofill,geofill_telea`)",
        "The static object-removal cases of `removal_static`, default painter against the `telea` preset.",
        _static("geofill,geofill_telea"),
        "summary.md",
    ),
    Section(
        "real_panel",
        "Real removals judged by eye (`benchmarks/quality/real_panel.py`)",
        "The 15 cases of `benchmarks/panel/cases.json` (people and cars that move, static objects every "
        "reference shows, objects on cobbles, brick and grass, signs), brushed generously, filled by geofill "
        "(defaults, every reference), Telea and the homography warp of the first reference; the sheets are "
        "`docs/img/panel/<case>.jpg`. Scores by eye from `benchmarks/panel/scores.json`: 0 = the object or "
        "a passer-by comes back, 1 = gone but a result nobody would keep, 2 = fine at a glance, 3 = nobody "
        "would notice the edit. In brackets the run's proxies (`back`: share of the object's distinguishable "
        "pixels reproduced in place; `echo`: the object's appearance found anywhere in the hole; `tint`: its "
        "colours back in the hole at any size; see the script's docstring); the last column says where "
        "geofill's hole pixels came from. Each run: `real_panel.py --record benchmarks/panel/run_NAME.json` "
        "(10 min here).",
        [
            *[PY, "benchmarks/quality/real_panel.py", "--table", "benchmarks/panel/scores.json"],
            *["--table-md", "{out}/scores.md"],
        ],
        "scores.md",
    ),
    Section(
        "shared_focal",
        "One focal for all references (`benchmarks/studies/shared_focal.py`)",
        "The multi-reference sets with a true K: the target focal's error per pair (each reference alone) "
        "and from all pairs together (`intrinsics.shared_camera`).",
        [PY, "benchmarks/studies/shared_focal.py"],
    ),
    Section(
        "multiref",
        "Time against the number of references (`benchmarks/speed/multiref.py`)",
        "A 1280x720 ray-cast scene, 1-3 references, one after the other or two at once (`fusion.parallel`).",
        [PY, "benchmarks/speed/multiref.py"],
    ),
    Section(
        "multiref_process",
        "One reference against all, whole process, real sets (`benchmarks/speed/multiref_process.py`)",
        "Four DEV multi-reference sets, `geofill fill` from the primary reference alone and from every "
        "reference, alternated; the median of the per-run ratios (the limit for four references: 2.5x).",
        [PY, "benchmarks/speed/multiref_process.py"],
    ),
    Section(
        "sweep",
        "Hole-size study (`geofill eval --sweep hole-size`)",
        "The same hole shapes drawn with mean brush widths 90 to 210 px at 720p (the paper's Fig. 5).",
        _eval("{out}", "--methods", "homography,geofill", "--sweep", "hole-size"),
        "sweep.md",
    ),
    Section(
        "wide",
        "Wide baselines: plain SIFT against the matching ladder (`benchmarks/quality/wide_results.py`)",
        "The 5 `dev_wide_*` pairs and the 2 towers, 100-px brush holes (seed 0): each filled with the ladder "
        "capped at plain SIFT (`matching.max_rung=sift`, a fill before the ladder) and with the default "
        "ladder; fallback, rung, verified matches, the final pose's rotation / translation-direction error "
        "against the GT (deg; nan without GT), hole PSNR against the homography baseline, time.",
        [PY, "benchmarks/quality/wide_results.py"],
    ),
    Section(
        "learned",
        "Learned matching (XFeat + LighterGlue, the `learned` extra) on every DEV pair "
        "(`benchmarks/quality/wide_results.py`)",
        "The 23 DEV pairs, 100-px brush holes (seed 0), each filled without the learned matcher "
        "(`nolearned`: a base install), with the default ladder and the extra installed (`ladder`: the "
        "learned rung when SIFT is weak) and with the learned rung also cross-checking a verified SIFT "
        "geometry (`crosscheck`); rung, verified matches, pose error against the GT where given, hole "
        "PSNR against the homography baseline, the learned rung's wall and CPU seconds, fill time (one "
        "run, variants interleaved on a shared CPU). Needs the extra in the running environment "
        "(`make learned`).",
        [
            PY,
            "benchmarks/quality/wide_results.py",
            "--pairs",
            str(PAIRS),
            "--variants",
            "nolearned",
            "ladder",
            "crosscheck",
        ],
    ),
    Section(
        "learned_speed",
        "The learned rung's cost against the SIFT rung (`benchmarks/speed/learned_rung.py`)",
        "The 5 `dev_wide_*` pairs at the working size, hole blanked: the `sift` rung, the learned matcher "
        "at 2048 keypoints (the rung after a weak SIFT) and at 4096 (its re-check of a suspicious SIFT "
        "geometry), each on a new target and on a target already seen (another reference of the same "
        "fill), as configured (one torch thread, torch's fused attention) and as before (torch's default "
        "threads, kornia's CPU attention), alternated, medians of 3; wall and process CPU seconds, "
        "`uptime` before and after.",
        [PY, "benchmarks/speed/learned_rung.py"],
    ),
    Section(
        "wide_ladder",
        "The ladder on every DEV pair: rung and matching time (`benchmarks/studies/wide_bench.py`)",
        "Matching alone, plain SIFT against the ladder interleaved (3 repeats, median); on the pairs where "
        "plain SIFT verifies, the ladder must cost nothing and give the same matches.",
        [PY, "benchmarks/studies/wide_bench.py", "--repeats", "3"],
    ),
    Section(
        "pairs",
        "Pose accuracy and stage times per pair (`benchmarks/quality/pairs.py`)",
        "Default configuration. Pose errors against the GT pose where meta.json has one (TUM's pose is an "
        "estimate and is left out). Times in seconds.",
        [PY, "benchmarks/quality/pairs.py"],
    ),
    Section(
        "speed",
        "Speed and memory by image size, per stage, before and after the speed work "
        "(`benchmarks/speed/speed.py`)",
        "Synthetic pair, one fresh process per size reading and writing files like the CLI (medians of 3 "
        "runs); peak RSS is the process's VmHWM. `--baseline f15f0eb` runs the code as it was before the "
        "speed work (its defaults), alternating with this checkout run by run, and adds the ratios.",
        [
            PY,
            "benchmarks/speed/speed.py",
            "--sizes",
            "1280x720,3840x2160",
            "--runs",
            "3",
            "--baseline",
            "f15f0eb",
        ],
    ),
    Section(
        "speed_warm",
        "The stages' own cost: a second fill in one process (`benchmarks/speed/speed.py --warm`)",
        "As above at 1280x720, timing a second fill in each process: no numba start-up, lazy imports or "
        "first page faults. What the method costs after matching, whatever the process around it.",
        [PY, "benchmarks/speed/speed.py", "--sizes", "1280x720", "--runs", "3", "--warm"],
    ),
    Section(
        "refine_eval",
        "Refinement ablation on the real pairs (`geofill eval`)",
        "The render pasted as is (`no_refine`), residual flow only (`flow`), colour only (`colour`: smooth "
        "gain, no flow), and each colour model with the flow (`global` gain+offset, `poisson`); `geofill` is "
        "the default (smooth gain + flow). Each method runs the whole pipeline, so earlier stages may differ "
        "between rows where they are not deterministic; the next section compares on identical renders.",
        _eval(
            "{out}",
            "--methods",
            "homography,geofill,geofill_no_refine,geofill_flow,geofill_colour,geofill_global,geofill_poisson",
        ),
        "summary.md",
    ),
    Section(
        "refine",
        "Refinement variants on identical renders (`benchmarks/studies/refine_variants.py`)",
        "Each pair rendered once (default pipeline, refinement off); every variant refines and merges that "
        "same render. Hole PSNR (dB) per pair; `feather` = 4-px feathered merge, no colour/flow.",
        [PY, "benchmarks/studies/refine_variants.py"],
    ),
    Section(
        "render",
        "Mesh renderer speed and exactness (`benchmarks/speed/render_bench.py`)",
        "A 1280x720 ray-cast synthetic pair rendered with its exact depth and pose (1.8 M triangles).",
        [PY, "benchmarks/speed/render_bench.py"],
    ),
    Section(
        "fitspace",
        "Depth scale/offset fit: depth vs inverse-depth space (`benchmarks/studies/depth_fit_space.py`)",
        "GT depth of the GT-depth pairs given to the `file` backend as shifted relative inverse depth or as "
        "metric depth, aligned by the pipeline's own triangulated points, with the true intrinsics.",
        [PY, "benchmarks/studies/depth_fit_space.py"],
    ),
    Section(
        "fitspace_default",
        "Depth fit space, the pipeline's own intrinsics (`depth_fit_space.py --default-intrinsics`)",
        "As above, but the intrinsics are what the pipeline finds by itself (default prior, focal estimated "
        "from the pair, principal point at the centre): the setting a user without calibration gets.",
        [PY, "benchmarks/studies/depth_fit_space.py", "--default-intrinsics"],
    ),
    Section(
        "depth_eval",
        "Depth accuracy per backend (`benchmarks/studies/depth_eval.py`)",
        "The paper's supplement depth table: AbsRel, RMS-log and delta<1.25 of the source depth the pipeline "
        "renders with (after its own scale/offset), over all valid pixels and over those that project into "
        "the hole; synthetic scenes (exact depth) and the real pairs with GT depth. `onnx`/`fused` need "
        "weights, which these machines cannot download: reported as unavailable.",
        [PY, "benchmarks/studies/depth_eval.py"],
    ),
    Section(
        "depth_eval_true_k",
        "Depth accuracy per backend with the true intrinsics (`depth_eval.py --true-intrinsics`)",
        "As above with the GT-depth pairs' calibrated K given as flags, so that the depth error is not "
        "mixed with the focal estimate's.",
        [PY, "benchmarks/studies/depth_eval.py", "--synthetic", "0", "--true-intrinsics"],
    ),
    Section(
        "depth_backends",
        "Fill quality per depth backend (`geofill eval`)",
        "`geofill` = `auto` (here: stereo, no weights); `geofill_fused` fails without weights and is "
        "recorded as failed, not skipped.",
        _eval("{out}", "--methods", "homography,geofill_sparse,geofill_stereo,geofill_fused,geofill"),
        "summary.md",
    ),
    Section(
        "stereo_speed",
        "Stereo backend time at 1280x720 (`benchmarks/speed/stereo_speed.py`)",
        "Budget: 2 s on this 2-core machine.",
        [PY, "benchmarks/speed/stereo_speed.py"],
    ),
    Section(
        "optimize_synthetic",
        "Joint optimisation from a perturbed start, 1280x720 (`benchmarks/studies/optimize_bench.py`)",
        "Exact depth and pose, start perturbed by 5 deg rotation, 10 deg translation direction, depth x1.2. "
        "`paper` = DiffGrad at a quarter of the paper's iteration limits (1000/1750/2250/2500; the full "
        "limits take up to an hour on one scene here). Objective = the finest level's (lower is better).",
        [PY, "benchmarks/studies/optimize_bench.py", "synthetic", "--scenes", "3", "--paper-scale", "0.25"],
    ),
    Section(
        "optimize_real",
        "Joint optimisation on the real pairs (`benchmarks/studies/optimize_bench.py real`)",
        "Both solvers from the pipeline's own start (evaluation hole, seed 0); `paper` at a tenth of its "
        "iteration limits. Pose errors against the GT pose where meta.json has one (before = the start).",
        [PY, "benchmarks/studies/optimize_bench.py", "real", "--paper-scale", "0.1"],
    ),
    Section(
        "optimize_eval",
        "Optimisation variants and the paper's ablations (`geofill eval`)",
        "Same depth for every method (`optimize_bench.py eval` memoises the depth stage per pair). "
        "`geofill_paper` at a tenth of the paper's iteration limits. The paper's own numbers (RealEstate10K, "
        "with CST, whole-image PSNR): init 30.66, optimised 31.47; without L_photo / L_feat / L_negD 31.19 / "
        "30.88 / 31.23; W_h only 31.20, W_e only 31.12, neither 30.95.",
        [
            PY,
            "benchmarks/studies/optimize_bench.py",
            "eval",
            "--pairs",
            str(PAIRS),
            "--out",
            "{out}",
            "--methods",
            "geofill_init,geofill,geofill_paper,geofill_no_photo,geofill_no_feat,geofill_no_negd,"
            "geofill_no_hole_w,geofill_no_edge_w,geofill_uniform_w,geofill_refine_focal",
            "--set",
            "optimize.paper_iterations=[400,700,900,1000]",
        ],
        "summary.md",
    ),
    Section(
        "whole_process",
        "Whole-process time against the homography baseline (`benchmarks/speed/whole_process.py`)",
        "`geofill fill`, `geofill --help`, `geofill config` and `geofill serve` as a user runs them, each "
        "fill paired with the standalone OpenCV SIFT + MAGSAC homography + colour-gain script "
        "(`benchmarks/speed/homography_baseline.py`) on the same files, and with the code before the speed "
        "work (`--before f15f0eb`, its defaults) in the same rounds; medians of 7 runs after a warm-up. "
        "Both trees are byte-compiled first, as `pip install` leaves a package. The ratios to the "
        "baseline are the figures that carry over between machines (load average printed).",
        [
            PY,
            "benchmarks/speed/whole_process.py",
            "--runs",
            "7",
            "--cases",
            "720p,berlin,4k",
            "--before",
            "f15f0eb",
        ],
    ),
    Section(
        "speed_quality",
        "Fill quality before and after the speed work (`benchmarks/quality/eval_revisions.py`)",
        "`geofill eval` on the 23 DEV pairs with the code before the speed work (f15f0eb) and this "
        "checkout, mask seeds 0-2, hole PSNR changes per pair and seed.",
        [PY, "benchmarks/quality/eval_revisions.py", "--before", "f15f0eb", "--seeds", "0,1,2"],
    ),
    Section(
        "speed_quality_multiview",
        "Several references before and after the speed work (`benchmarks/quality/eval_revisions.py`)",
        "As above on the 7 multi-reference sets, the fill with all references (`geofill[all]`).",
        [PY, "benchmarks/quality/eval_revisions.py", "--before", "f15f0eb", "--seeds", "0,1,2"]
        + ["--pairs", str(MULTIVIEW), "--references", "all"],
    ),
    Section(
        "focal",
        "Focal length from the pair (`benchmarks/studies/focal_bench.py`)",
        "Focal and pose accuracy per estimator on the GT pairs and rendered scenes, then whole fills with "
        "the evaluation's masks (seeds 0-2): fixed focal, estimated (default), refined in the "
        "optimisation, true K, and the fixed focal x0.98 / x1.02 (how much a 2 % focal change moves a fill).",
        [PY, "benchmarks/studies/focal_bench.py", "--psnr-seeds", "0,1,2"],
    ),
    Section(
        "focal_curve",
        "Fill PSNR against the focal length (`benchmarks/studies/focal_bench.py --curve`)",
        "Hole PSNR per mask seed with the focal fixed at a grid of scales of the default, on the pair where "
        "the estimate lost most against the default (ETH3D terrace, no ground truth) and on two GT pairs; "
        "'estim.' is the default pipeline at the scale it chose. How far apart neighbouring focal lengths "
        "land is the noise floor of any per-pair comparison of two focal lengths.",
        [
            PY,
            "benchmarks/studies/focal_bench.py",
            "--curve",
            "eth3d,berlin_01_02,livingroom_f2",
            "--psnr-seeds",
            "0,1,2",
        ],
    ),
    Section(
        "focal_refine",
        "Focal refinement in the optimisation, synthetic (`benchmarks/studies/optimize_bench.py focal`)",
        "Rendered scenes whose true focal is 0.8x / 1.25x the assumed default, filled with and without "
        "`optimize.refine_focal` (estimation off, so the refinement alone moves the focal).",
        [
            PY,
            "benchmarks/studies/optimize_bench.py",
            "focal",
            "--scenes",
            "3",
            "--set",
            "intrinsics.estimate=none",
        ],
    ),
    Section(
        "batch",
        "Throughput of many fills (`benchmarks/speed/batch_bench.py`)",
        "The DEV pairs but the held-out TUM one as one batch (eval holes, seed 0): a shell loop of "
        "`geofill fill`, `geofill batch` with 1 and 2 worker processes and on a local Ray instance, run "
        "back to back on the same machine load; peak RSS per worker process; per-item overhead of the "
        "local pool and of Ray.",
        [PY, "benchmarks/speed/batch_bench.py"],
    ),
    Section(
        "server",
        "`geofill serve`: API overhead, memory, malformed requests (`benchmarks/speed/server_bench.py`)",
        "Over real HTTP against a `geofill serve` process with one worker: Fill -> result downloaded for a "
        "1280x720 synthetic pair against the CLI's pipeline time for the same fill (interleaved: the machine "
        "is shared, so only paired numbers compare); RSS of the server and its worker; 20 sequential fills; "
        "200 malformed requests.",
        [PY, "benchmarks/speed/server_bench.py"],
    ),
    Section(
        "server_overhead",
        "`geofill serve`: API against CLI time, more runs (`benchmarks/speed/server_bench.py --repeats 6`)",
        "The first part of the section above alone, six interleaved pairs: the machine's load moves single "
        "runs by several seconds.",
        [PY, "benchmarks/speed/server_bench.py", "--repeats", "6", "--fills", "0", "--malformed", "0"],
    ),
]


#: Paths (relative to the repository) a section's numbers depend on, besides its own scripts, when
#: what its command imports was not recorded.
CODE = ("src/geofill", "benchmarks/common.py")
#: Folder whose ``sitecustomize.py`` logs the geofill and benchmarks modules a command's processes import.
RECORDER = ROOT / "benchmarks" / "record_imports"
#: Per section, the files its command's processes imported when it last ran (written with docs/results.md).
DEPS = ROOT / "benchmarks" / "results_deps.json"
#: A section's start marker, with its stamp: ``rev=`` (short hash), ``date=``, then ``code=`` (the
#: digest of its dependencies) or ``derived`` (rev and date from docs/results.md's history).
MARKER = re.compile(r"<!-- section:(?P<name>\w+)(?P<stamp>(?: [\w=+.-]+)*) -->")


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout


def dependencies(sec: Section) -> list[str]:
    """The paths whose change makes ``sec``'s numbers stale: the package's modules and the benchmark
    modules its command's processes imported when it last ran (:data:`DEPS`, recorded by
    :data:`RECORDER`), or where none were recorded the whole package and the shared helpers; and
    every benchmark script its command runs."""
    recorded = json.loads(DEPS.read_text()).get(sec.name) if DEPS.is_file() else None
    return [*(recorded or CODE), *_scripts(sec)]


def _scripts(sec: Section) -> list[str]:
    return [c for c in sec.command if c.startswith("benchmarks/") and c.endswith(".py")]


def module_files(modules: set[str]) -> list[str]:
    """The repository's files behind ``modules`` (dotted names under geofill or benchmarks): each
    module's source, and for a geofill package every data file below it (the server's page, for
    one; numba's caches aside). The benchmarks' data files are named by their commands."""
    files = set()
    for name in modules:
        package = name.partition(".")[0] == "geofill"
        base = ROOT / ("src" if package else "") / name.replace(".", "/")
        if (base / "__init__.py").is_file():
            files.add(base / "__init__.py")
            if package:
                files.update(_data_files(base))
        elif base.with_suffix(".py").is_file():
            files.add(base.with_suffix(".py"))
    return sorted(str(f.relative_to(ROOT)) for f in files)


def _data_files(folder: Path) -> list[Path]:
    """The files of ``folder`` that are not Python, and those of its folders that are not packages
    (a subpackage has its own; numba's caches in ``__pycache__`` are not code)."""
    found = []
    for f in folder.iterdir():
        if f.is_file() and f.suffix != ".py":
            found.append(f)
        elif f.is_dir() and f.name != "__pycache__" and not (f / "__init__.py").is_file():
            found.extend(_data_files(f))
    return found


def code_digest(paths: list[str], hashes: dict[str, bytes] | None = None) -> str:
    """A digest of the working tree's files under ``paths`` (tracked and untracked, not ignored);
    with ``hashes`` (:func:`file_hashes`), of those files as they were when it was taken."""
    h = hashlib.sha256()
    for name, digest in sorted(file_hashes(paths).items() if hashes is None else _under(hashes, paths)):
        h.update(name.encode() + b"\0" + digest)
    return h.hexdigest()[:16]


def file_hashes(paths: list[str]) -> dict[str, bytes]:
    """SHA-256 of every file under ``paths`` (tracked and untracked, not ignored) in the working
    tree; of a Python file, of its code (:func:`code_of`)."""
    names = git("ls-files", "-co", "--exclude-standard", "--", *paths).split("\n")
    found = {}
    for n in names:
        if n and (ROOT / n).is_file():
            st = (ROOT / n).stat()
            found[n] = _code_hash(ROOT / n, st.st_mtime_ns, st.st_size)
    return found


@functools.cache
def _code_hash(path: Path, mtime_ns: int, size: int) -> bytes:
    """Keyed by the file's time and size as well: a file edited while a section runs is read again."""
    return hashlib.sha256(code_of(path)).digest()


def code_of(path: Path) -> bytes:
    """What of ``path`` can change a section's numbers: of a Python file, its syntax tree without
    docstrings (comments, docstrings and layout cannot; a corrected sentence would otherwise stale
    hours of results), of any other file its bytes.
    """
    data = path.read_bytes()
    if path.suffix != ".py":
        return data
    try:
        tree = ast.parse(data)
    except SyntaxError:
        return data
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                if isinstance(first.value.value, str):
                    node.body = node.body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


def _under(hashes: dict[str, bytes], paths: list[str]) -> list[tuple[str, bytes]]:
    prefixes = tuple(p.rstrip("/") + "/" for p in paths)
    return [(n, d) for n, d in hashes.items() if n in paths or n.startswith(prefixes)]


def new_stamp(sec: Section, deps: list[str] | None = None, hashes: dict[str, bytes] | None = None) -> str:
    """The stamp of a section generated now from this working tree (with ``deps`` and ``hashes``:
    from those files as :func:`file_hashes` found them when its command started)."""
    deps = dependencies(sec) if deps is None else deps
    rev = git("rev-parse", "--short", "HEAD").strip()
    if git("status", "--porcelain", "--", *deps).strip():
        rev += "+uncommitted"
    return f" rev={rev} date={datetime.date.today().isoformat()} code={code_digest(deps, hashes)}"


def parse_stamp(stamp: str) -> dict[str, str]:
    """``" rev=abc date=2026-01-01 code=..."`` -> {"rev": "abc", ...}; ``derived`` maps to ""."""
    return dict((*item.split("=", 1), "")[:2] for item in stamp.split())


def stamp_words(stamp: dict[str, str]) -> str:
    """How a section's stamp reads under it."""
    if not stamp:
        return "generated at an unknown revision"
    rev = stamp["rev"].replace("+uncommitted", " with uncommitted changes")
    if "derived" in stamp:
        return (
            f"generated at an unknown revision: its text last changed in {rev} on {stamp['date']} "
            "(git blame of docs/results.md)"
        )
    return f"generated at {rev} on {stamp['date']}"


def staleness(sec: Section, stamp: dict[str, str]) -> str:
    """Why section ``sec`` with ``stamp`` predates the code it describes ("" when it does not)."""
    if not stamp:
        return "no stamp: unknown revision"
    deps = dependencies(sec)
    if "code" in stamp and stamp["code"] == code_digest(deps):
        return ""
    rev = stamp["rev"].split("+")[0]
    try:
        changed = [f for f in git("diff", "--name-only", rev, "--", *deps).split("\n") if f]
    except subprocess.CalledProcessError:
        return f"revision {rev} not in this repository"
    if "code" in stamp:  # the digest differs: the code changed, whatever the diff against rev says
        return f"code changed since {stamp['rev']}" + (f" ({_files(changed)})" if changed else "")
    return f"{_files(changed)} changed since {rev}" if changed else ""


def _files(names: list[str]) -> str:
    return f"{len(names)} file(s): {', '.join(names[:4])}{', ...' if len(names) > 4 else ''}"


def sections_in(text: str) -> dict[str, tuple[dict[str, str], str]]:
    """Per section in docs/results.md's ``text``: its stamp and its whole text."""
    out = {}
    for m in MARKER.finditer(text):
        name = m.group("name")
        end = text.find(f"<!-- end:{name} -->\n", m.end())
        if end >= 0:
            out[name] = (parse_stamp(m.group("stamp")), text[m.start() : end + len(f"<!-- end:{name} -->\n")])
    return out


def outdated(sec: Section, stamp: dict[str, str], text: str) -> str:
    """Why section ``sec`` (its ``stamp`` and whole ``text``) needs a rerun: its code changed, it
    was never run, or its last run failed, which leaves no numbers however new the code ("" when
    none of these)."""
    if not text:
        return "not run yet"
    why = staleness(sec, stamp)
    if not why and FAILED_BODY.search(text):
        return f"its last run failed ({stamp_words(stamp)})"
    return why


#: How :func:`run_section` writes a failed command's body.
FAILED_BODY = re.compile(r"^FAILED \(exit -?\d+\):$", re.M)


def stale_report(path: Path = OUT) -> list[str]:
    """One line per section whose numbers predate the code they depend on, or which has no numbers
    (never run, or failed), with its cost."""
    found = sections_in(path.read_text() if path.exists() else "")
    lines = []
    for sec in SECTIONS:
        stamp, text = found.get(sec.name, ({}, ""))
        why = outdated(sec, stamp, text)
        if why:
            took = re.search(r"_\(took (\d+) s", text)
            cost = f"took {took.group(1)} s" if took else "cost unknown"
            lines.append(f"{sec.name}: {why}; {stamp_words(stamp)}; {cost}")
    return lines


#: The note under a stale section's heading (:func:`mark_stale`), so that a reader of
#: docs/results.md sees it where the numbers are.
STALE_NOTE = re.compile(r"^> \*\*Stale:\*\* .*\n\n", re.M)


def stale_note(sec: Section, why: str) -> str:
    return (
        f"> **Stale:** {why}: these numbers may no longer hold. Rerun: "
        f"`.venv/bin/python benchmarks/make_results.py --only {sec.name}`\n\n"
    )


def mark_stale(path: Path = OUT) -> list[str]:
    """Put :func:`stale_note` under the heading of every stale section of ``path`` and take it
    from the fresh ones; returns the stale sections' names."""
    text = path.read_text()
    stale = []
    for sec in SECTIONS:
        stamp, body = sections_in(text).get(sec.name, ({}, ""))
        if not body:
            continue
        why = outdated(sec, stamp, body)
        head, rest = body.split("\n\n", 1)  # the marker and the heading, then the rest
        rest = STALE_NOTE.sub("", rest, count=1)
        if why:
            stale.append(sec.name)
            rest = stale_note(sec, why) + rest
        text = text.replace(body, f"{head}\n\n{rest}")
    path.write_text(text)
    return stale


def derived_stamp(name: str) -> str:
    """For an unstamped section: the newest commit among the lines of its text in docs/results.md
    at HEAD (``git blame``), as ``rev=... date=... derived``."""
    rel = str(OUT.relative_to(ROOT))
    lines = git("show", f"HEAD:{rel}").split("\n")
    start = next(i for i, line in enumerate(lines) if line.startswith(f"<!-- section:{name}"))
    end = next(i for i, line in enumerate(lines) if line == f"<!-- end:{name} -->")
    blame = git("blame", "--porcelain", "-L", f"{start + 1},{end + 1}", "HEAD", "--", rel)
    newest, when, sha = 0, 0, ""
    for line in blame.split("\n"):
        if re.match(r"^[0-9a-f]{40} ", line):
            sha = line[:40]
        elif line.startswith("committer-time ") and int(line.split()[1]) > when:
            newest, when = sha, int(line.split()[1])
    date = datetime.datetime.fromtimestamp(when, datetime.UTC).date().isoformat()
    return f" rev={git('rev-parse', '--short', newest).strip()} date={date} derived"


def stamp_derived() -> list[str]:
    """Stamp every section of docs/results.md that has no stamp with :func:`derived_stamp`."""
    text = OUT.read_text()
    done = []
    for name, (stamp, body) in sections_in(text).items():
        if stamp:
            continue
        derived = derived_stamp(name)
        rest = body.split("\n", 1)[1]
        words = stamp_words(parse_stamp(derived))
        rest = re.sub(
            r"\n(_\((?:took \d+ s|results of an earlier run of this command))\)_\n",
            rf"\n\1; {words})_\n",
            rest,
        )
        text = text.replace(body, f"<!-- section:{name}{derived} -->\n{rest}")
        done.append(f"{name}:{derived}")
    OUT.write_text(text)
    return done


def run_section(
    sec: Section, reuse: Path | None = None, alongside: bool = False
) -> tuple[str, list[str] | None]:
    """Run ``sec``'s command and format its result; with ``reuse``, a folder an earlier run of the
    same command wrote its results to, take them from there instead (for eval sections). Returns
    the section's text and the package and benchmark files its processes imported (None when
    nothing was run or recorded: the section then depends on all of them). ``alongside``: another
    benchmark ran at the same time, which the section says under its times."""
    hashes = file_hashes([*CODE, "benchmarks", *_scripts(sec)])  # the code as the command starts
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as logs:
        cmd = [c.replace("{out}", tmp) for c in sec.command]
        log = Path(logs) / "imports"
        env = {
            **os.environ,
            "GEOFILL_IMPORT_LOG": str(log),
            "PYTHONPATH": os.pathsep.join(p for p in (str(RECORDER), os.environ.get("PYTHONPATH")) if p),
        }
        t0 = time.perf_counter()
        if reuse is not None:
            proc = subprocess.CompletedProcess(cmd, 0, "", "")
            tmp = str(reuse)
        else:
            proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env)
        took = time.perf_counter() - t0
        if proc.returncode != 0:
            body = f"FAILED (exit {proc.returncode}):\n{proc.stderr[-3000:]}"
        elif sec.result_file:
            body = (Path(tmp) / sec.result_file).read_text()
        else:
            body = proc.stdout
        # A command run as ``python -m module`` is run, not imported: the hook does not see it.
        modules = {cmd[i + 1] for i, c in enumerate(cmd[:-1]) if c == "-m"}
        recorded = module_files(modules | set(log.read_text().split())) if log.is_file() else None
    stamp = new_stamp(sec, [*(recorded or CODE), *_scripts(sec)], hashes)
    text = format_section(sec, body, None if reuse is not None else took, stamp, alongside)
    return text, recorded


def format_section(
    sec: Section, body: str, took: float | None, stamp: str | None = None, alongside: bool = False
) -> str:
    """The markdown of section ``sec`` whose command printed (or wrote) ``body`` in ``took`` s
    (None: taken from an earlier run of the command), stamped with ``stamp`` (:func:`new_stamp`;
    by default the working tree's now); ``alongside``: another benchmark ran at the same time."""
    shown = " ".join(shlex.quote(c) for c in sec.command).replace(PY, ".venv/bin/python")
    shown = shown.replace(str(PAIRS), "../shared/data/pairs").replace("{out}", "OUT")
    shown = shown.replace(str(MULTIVIEW), "../shared/data/multiview")
    if sec.result_file:
        body = re.sub(r"^# ", "#### ", body, flags=re.M).replace("\n## ", "\n#### ")
    else:
        body = f"```\n{body.rstrip()}\n```"
    when = "results of an earlier run of this command" if took is None else f"took {took:.0f} s"
    if alongside:
        when += " alongside other benchmarks or tests on this 2-core machine (its times include that"
        when += " contention)"
    stamp = new_stamp(sec) if stamp is None else stamp
    when += f"; {stamp_words(parse_stamp(stamp))}"
    return f"<!-- section:{sec.name}{stamp} -->\n## {sec.title}\n\n{sec.about}\n\n```bash\n{shown}\n```\n\n" \
        f"{body.rstrip()}\n\n_({when})_\n<!-- end:{sec.name} -->\n"  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="comma-separated section names: " + ",".join(s.name for s in SECTIONS))
    ap.add_argument(
        "--reuse", action="append", default=[], metavar="NAME=DIR",
        help="take section NAME's result file from DIR, where its command already wrote it",
    )  # fmt: skip
    ap.add_argument(
        "--stale", action="store_true", help="list the sections older than their code; run nothing"
    )
    ap.add_argument(
        "--mark-stale", action="store_true",
        help="note under each stale section's heading that it is stale (and take the note from fresh ones)",
    )  # fmt: skip
    ap.add_argument(
        "--stamp-derived", action="store_true",
        help="stamp unstamped sections with the commit that last changed their text (marked derived)",
    )  # fmt: skip
    ap.add_argument(
        "--alongside", action="store_true",
        help="another benchmark runs at the same time: say so under each section's times",
    )  # fmt: skip
    args = ap.parse_args(argv)
    if args.stamp_derived:
        print("\n".join(stamp_derived()))
    if args.stale:
        lines = stale_report()
        print("\n".join(lines) + f"\n{len(lines)} of {len(SECTIONS)} sections are stale")
    if args.mark_stale:
        print(f"{len(mark_stale())} of {len(SECTIONS)} sections marked stale in {OUT}")
    if args.stale or args.stamp_derived or args.mark_stale:
        return 0
    reuse = dict(item.split("=", 1) for item in args.reuse)
    if args.only == "stale":
        args.only = ",".join(line.split(":", 1)[0] for line in stale_report())
    wanted = args.only.split(",") if args.only else [s.name for s in SECTIONS]
    unknown = set(wanted) - {s.name for s in SECTIONS}
    if unknown:
        ap.error(f"unknown section(s) {sorted(unknown)}")
    for sec in SECTIONS:
        if sec.name in wanted:
            print(f"running {sec.name} ...", file=sys.stderr, flush=True)
            reused = Path(reuse[sec.name]) if sec.name in reuse else None
            text, recorded = run_section(sec, reused, args.alongside)
            write(sec.name, text, recorded)  # after each section: a long run keeps what it finished
    print(f"wrote {OUT}", file=sys.stderr)
    return 0


def write(name: str, text: str, recorded: list[str] | None = None) -> None:
    """Replace section ``name`` of docs/results.md with ``text`` and its recorded dependencies in
    :data:`DEPS` with ``recorded``; every other section is kept as the files have it now (so
    separate ``--only`` runs, at the same time too, can update different sections)."""
    with open(OUT.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        _write(name, text, recorded)


def _write(name: str, text: str, recorded: list[str] | None) -> None:
    deps = json.loads(DEPS.read_text()) if DEPS.is_file() else {}
    deps.pop(name, None)
    if recorded:
        deps[name] = recorded
    DEPS.write_text(json.dumps(dict(sorted(deps.items())), indent=1) + "\n")
    found = sections_in(OUT.read_text() if OUT.exists() else "")
    parts = [
        "# Results\n\nGenerated by `make results` (benchmarks/make_results.py) on this project's 2-core CPU "
        "machine; the real pairs are `../shared/data/pairs` (22 DEV pairs: its TUM RGB-D pair is held out, "
        "TUM images being reserved for independent checks; older sections say when they ran on 23, or on the "
        "first 18). Each section shows the command "
        "that produced it, and the revision and date it was generated at; a section whose code changed "
        "since carries a **Stale** note under its heading (`make results-stale` lists them). "
        "Why the defaults are what they are: docs/architecture.md.\n"
    ]
    for sec in SECTIONS:
        if sec.name == name:
            parts.append(text)
            continue
        stub = f"<!-- section:{sec.name} -->\n## {sec.title}\n\n(not run yet)\n<!-- end:{sec.name} -->\n"
        parts.append(found[sec.name][1] if sec.name in found else stub)
    OUT.write_text("\n".join(parts))


if __name__ == "__main__":
    sys.exit(main())
