"""Fill quality of this checkout against an earlier revision: ``geofill eval`` on the DEV pairs for
both, over several mask seeds, then the per-pair and per-seed changes (``compare_eval.py``).

    .venv/bin/python benchmarks/quality/eval_revisions.py --before REV [--seeds 0,1,2] [--pairs DIR]
        [--keep DIR]
        [--references all]   # multi-reference sets (../shared/data/multiview): the fill with all references

The earlier revision's ``src`` is exported to a temporary folder and run with ``PYTHONPATH`` (its own
defaults); both use this environment's packages. A speed change is meant to leave the mean within
0.1 dB and no pair worse by more than 0.5 dB; one seed alone moves single pairs by a few tenths of
a dB from rounding-level changes, hence several seeds.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import PAIRS, export_src

HERE = Path(__file__).resolve().parent


def _eval(out: Path, args: argparse.Namespace, seed: str, src: str | None) -> None:
    env = {**os.environ, "PYTHONPATH": src} if src else None
    cmd = [sys.executable, "-m", "geofill.cli", "eval", "--pairs", args.pairs, "--out", str(out)]
    cmd += ["--methods", "geofill", "--seed", seed]
    if args.references:
        cmd += ["--references", args.references]
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, metavar="REV|SRC", help="git revision or src folder")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--pairs", default=str(PAIRS))
    ap.add_argument("--keep", metavar="DIR", help="write the eval folders here (default: a temporary one)")
    ap.add_argument(
        "--references", help="multi-reference sets: eval's --references (e.g. all), compared as geofill[all]"
    )
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep or tmp)
        before = args.before if Path(args.before).is_dir() else export_src(args.before, Path(tmp))
        for seed in args.seeds.split(","):
            _eval(work / f"before_s{seed}", args, seed, before)
            _eval(work / f"after_s{seed}", args, seed, None)
        compare = [sys.executable, str(HERE / "compare_eval.py"), str(work / "before_s{seed}")]
        compare += [str(work / "after_s{seed}"), "--seeds", args.seeds]
        if args.references:
            compare += ["--method", f"geofill[{args.references}]"]
        return subprocess.run(compare, check=False).returncode


if __name__ == "__main__":
    sys.exit(main())
