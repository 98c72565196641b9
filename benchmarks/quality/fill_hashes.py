"""SHA-256 of the fill of every DEV pair and multi-reference set (all references), to show that a
change leaves fills byte-identical: hash two trees and compare the JSON files.

    .venv/bin/python benchmarks/quality/fill_hashes.py OUT.json [--before REV|SRC] [--set KEY=VALUE]

The hole is the evaluation's brush-stroke mask (seed 0), blanked as ``geofill eval`` gives it. The
inputs are made by this checkout; ``--before`` fills them with an earlier revision's (or a source
folder's) ``geofill.fill`` in a child process with its own ``PYTHONPATH``, in this environment.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, MULTIVIEW, PAIRS, export_src


def write_inputs(folder: Path) -> None:
    """One ``<set>.npz`` per set: the blanked target, the hole and the references."""
    from geofill.evaluation.pairs import load_pair, pair_mask
    from geofill.synthetic import blanked

    for pair_dir in sorted(
        p for root in (PAIRS, MULTIVIEW) for p in root.iterdir() if p.is_dir() and p.name not in HELD_OUT
    ):
        pair = load_pair(pair_dir)
        hole = pair_mask(pair, seed=0)
        sources = {f"source{k}": s for k, s in enumerate(pair.sources)}
        np.savez(folder / f"{pair_dir.name}.npz", target=blanked(pair.target, hole), hole=hole, **sources)


def hash_fills(folder: Path, overrides: list[str]) -> dict[str, list]:
    """Per set in ``folder``: the fill's SHA-256 (first 16 hex digits), status and supplied fractions
    (only the public ``geofill.fill``, which every revision has), with the config ``overrides``
    (``KEY=VALUE``; none for the default config)."""
    from geofill import fill
    from geofill.config import FillConfig, parse_overrides

    cfg = FillConfig().updated(parse_overrides(overrides)) if overrides else None

    out = {}
    for path in sorted(folder.glob("*.npz")):
        data = np.load(path)
        sources = [data[f"source{k}"] for k in range(len(data.files) - 2)]
        res = fill(data["target"], data["hole"], sources, cfg)
        digest = hashlib.sha256(res.image.tobytes()).hexdigest()[:16]
        out[path.stem] = [digest, res.report.status, [round(f, 4) for f in res.report.supplied_fraction]]
        print(path.stem, *out[path.stem], flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="JSON file to write")
    ap.add_argument(
        "--before", metavar="REV|SRC", help="fill with an earlier revision's (or src folder's) geofill"
    )
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="config override of the fills"
    )
    ap.add_argument("--inputs", metavar="DIR", help=argparse.SUPPRESS)  # the child's: inputs already made
    args = ap.parse_args(argv)
    if args.inputs:
        Path(args.out).write_text(json.dumps(hash_fills(Path(args.inputs), args.set), indent=1))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        inputs = Path(tmp) / "inputs"
        inputs.mkdir()
        write_inputs(inputs)
        env = None
        if args.before:
            src = args.before if Path(args.before).is_dir() else export_src(args.before, Path(tmp))
            env = {**os.environ, "PYTHONPATH": str(src)}
        cmd = [sys.executable, __file__, args.out, "--inputs", str(inputs)]
        cmd += [f"--set={s}" for s in args.set]
        return subprocess.run(cmd, env=env, check=False).returncode


if __name__ == "__main__":
    sys.exit(main())
