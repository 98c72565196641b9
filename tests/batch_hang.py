"""``geofill batch`` in which every item whose name starts with ``hang`` writes its output and then
never returns, as a worker does when it is stopped between its write and its record: a stop test
started with it knows the batch cannot finish before its signal, and what a stop does to an output
no record names.

    python tests/batch_hang.py batch --images ... (the arguments of ``geofill batch``)
"""

from __future__ import annotations

import signal
import sys
import time
from typing import Any

from geofill.batch import runner, worker


def run_item_then_hang(*args: Any) -> dict[str, Any]:
    """:func:`geofill.batch.worker.run_item`, then, for a ``hang`` item, a wait for the signal that
    terminates the worker."""
    record = worker.run_item(*args)
    while record["item"].startswith("hang"):
        time.sleep(1.0)
    return record


if __name__ == "__main__":
    # Spawned workers unpickle this function from this file (run as their __mp_main__).
    runner.run_item = run_item_then_hang
    # Ctrl-C as a terminal delivers it: a shell starts a background job with SIGINT ignored, and
    # Python keeps an inherited SIG_IGN, so a test run in the background would not be interrupted.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    from geofill.cli import main

    sys.exit(main(sys.argv[1:]))
