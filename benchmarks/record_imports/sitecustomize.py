"""Log every geofill and benchmarks module this interpreter imports (one name per line) to the file
named by ``$GEOFILL_IMPORT_LOG``: ``benchmarks/make_results.py`` puts this folder first on the
``PYTHONPATH`` of a section's command, so that the section's staleness follows the code its
processes ran, not every file of the package.

An audit hook, not an ``atexit`` handler: a forked worker (multiprocessing's pools) leaves with
``os._exit`` and runs no exit handlers, but inherits the hook and logs its own imports as they happen.
"""

import os
import sys

_LOG = os.environ.get("GEOFILL_IMPORT_LOG")
_HERE = os.path.dirname(os.path.abspath(__file__))


def _log_import(event: str, args: tuple) -> None:
    if event == "import" and str(args[0]).partition(".")[0] in ("geofill", "benchmarks"):
        with open(_LOG, "a") as f:
            f.write(f"{args[0]}\n")


if _LOG:
    sys.addaudithook(_log_import)

# This file shadows the environment's own sitecustomize (Debian's Python ships one): run that too.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != _HERE]
_self = sys.modules.pop("sitecustomize", None)
try:
    import sitecustomize  # noqa: F401
except ImportError:
    # No other sitecustomize: put this one back, or the import statement that is running this file
    # finds no module under its name when it returns (KeyError: 'sitecustomize').
    if _self is not None:
        sys.modules["sitecustomize"] = _self
