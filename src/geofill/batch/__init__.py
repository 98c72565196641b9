"""``geofill batch``: many fills from folders or a manifest, in parallel worker processes or on a
Ray cluster, resumable, with one results.jsonl line per item.

- :mod:`.items`: the items (folders matched by stem, one mask for all, manifests);
- :mod:`.references`: picking each target's references by measured overlap;
- :mod:`.worker`: one item in a worker (read, fill, write atomically, record);
- :mod:`.runner`: local processes or Ray, results.jsonl, resume, Ctrl-C, exit status;
- :mod:`.display`: progress bar or plain lines, summary table.
"""

from .items import BatchItem, items_from_folders, read_manifest
from .runner import BatchOutcome, BatchSettings, run_batch

__all__ = ["BatchItem", "BatchOutcome", "BatchSettings", "items_from_folders", "read_manifest", "run_batch"]
