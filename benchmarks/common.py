"""What the benchmark scripts share: where the repository and its data are, a git revision's
``src`` exported for a before/after run, and the wall time and peak RSS of a child process.

A script in ``benchmarks/<group>/`` imports it after putting the repository root on ``sys.path``::

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root
    from benchmarks.common import PAIRS
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: The repository root (this checkout).
ROOT = Path(__file__).resolve().parents[1]
#: The real pairs and the multi-reference sets, next to the repository.
PAIRS = ROOT.parent / "shared" / "data" / "pairs"
MULTIVIEW = ROOT.parent / "shared" / "data" / "multiview"
#: DEV pair folders never read here: TUM RGB-D images are reserved for independent checks of this
#: project, and one DEV pair (from slambook2's copy) is made of them.
HELD_OUT = ("dev_tum_fr2_desk_rgbd",)
#: ``geofill eval --protocol static``'s sets: the multi-reference sets with GT poses, then rendered ones.
STATIC_PAIRS = [
    *(
        str(MULTIVIEW / n)
        for n in ("dev_mv_instantngp_fox_lower", "dev_mv_instantngp_fox_upper", "dev_mv_slambook_livingroom")
    ),
    "synthetic-views:3",
]


def child_usage(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, resource.struct_rusage]:
    """(wall s, resource usage) of one child process; raises if it fails. Its stdout is
    discarded."""
    with tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode:
            err.seek(0)
            text = err.read().decode(errors="replace").strip()[-500:]
            raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {text}")
    return wall, usage


def timed_child(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall s, peak RSS MiB) of one child process (its own peak, ``os.wait4``); raises if it
    fails."""
    wall, usage = child_usage(cmd, env)
    return wall, usage.ru_maxrss / 1024.0


def earlier_cli(*args: str) -> list[str]:
    """The command running an earlier tree's ``geofill`` with ``args`` as its console script does
    (``run()`` of its ``geofill.cli``, or ``main()`` where there was no ``run()`` yet), with its own
    defaults: it need not know today's config keys. Put that tree's src on PYTHONPATH."""
    launch = "import sys; from geofill import cli; sys.exit((getattr(cli, 'run', None) or cli.main)())"
    return [sys.executable, "-c", launch, *args]


def export_src(rev: str, folder: Path) -> str:
    """The ``src`` folder of git revision ``rev`` of this checkout, exported under ``folder``."""
    git = ["git", "-C", str(ROOT)]
    archive = subprocess.run([*git, "archive", rev, "src"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    short = subprocess.check_output([*git, "rev-parse", "--short", rev], text=True).strip()
    print(f"before: {rev} = {short}")
    return str(folder / "src")


def eval_scores(
    out: Path, args: list[str], fields: tuple[str, ...] = ("psnr_hole",)
) -> dict[str, dict[str, dict[str, float]]]:
    """``geofill eval --out out *args`` (its output discarded): per pair and method, the ``fields``
    of its results.csv that have a value."""
    cmd = [sys.executable, "-m", "geofill.cli", "eval", "--out", str(out), *args]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return read_scores(out, fields)


def read_scores(
    out: Path, fields: tuple[str, ...] = ("psnr_hole",)
) -> dict[str, dict[str, dict[str, float]]]:
    """Per pair and method, the ``fields`` that have a value in ``out``'s results.csv (a ``geofill
    eval`` output folder)."""
    import csv

    scores: dict[str, dict[str, dict[str, float]]] = {}
    with open(out / "results.csv", newline="") as f:
        for row in csv.DictReader(f):
            got = {k: float(row[k]) for k in fields if row.get(k)}
            if got:
                scores.setdefault(row["pair"], {})[row["method"]] = got
    return scores


def add_sweep_arguments(ap: argparse.ArgumentParser, variant_help: str) -> None:
    """``--seeds``, ``--variant NAME:KEY=VALUE[;KEY=VALUE...]`` (repeatable) and ``--keep DIR``, as
    the scripts that run ``geofill eval`` over several seeds and settings take them."""
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated seeds (default 0,1,2)")
    ap.add_argument(
        "--variant", action="append", default=[], metavar="NAME:KEY=VALUE[;KEY=VALUE...]", help=variant_help
    )
    ap.add_argument("--keep", type=Path, help="keep the eval folders here (default: a temporary folder)")


def sweep_variants(specs: list[str]) -> list[tuple[str, list[str]]]:
    """``--variant`` specs as (name, ``KEY=VALUE`` settings)."""
    out = []
    for spec in specs:
        name, _, settings = spec.partition(":")
        out.append((name, [kv for kv in settings.split(";") if kv]))
    return out
