"""What the benchmark scripts share: where the repository and its data are, a git revision's
``src`` exported for a before/after run, and the wall time and peak RSS of a child process.

A script in ``benchmarks/<group>/`` imports it after putting the repository root on ``sys.path``::

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root
    from benchmarks.common import PAIRS
"""

from __future__ import annotations

import os
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


def timed_child(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall s, peak RSS MiB) of one child process; raises if it fails. The peak RSS is the
    child's own (``os.wait4``), its stdout is discarded."""
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
