"""The package's docstring examples (``--doctest-modules`` over src/geofill): a module that imports
an extra's library at its top cannot be imported without that extra, so where the extra is not
installed its examples are skipped with the extra's name rather than failing to collect."""

from __future__ import annotations

from pathlib import Path

import pytest

from geofill.extras import available

#: Package folders whose modules import their extra's libraries at the top, with those libraries.
_NEEDS_EXTRA = {
    Path("src/geofill/server"): ("server", ("fastapi", "fastapi_offline", "uvicorn", "python_multipart")),
}


class _ExtraMissing(pytest.File):
    """Stands for a module of an extra that is not installed: collecting it is a skip."""

    def collect(self):
        pytest.skip(self.reason)


@pytest.hookimpl(wrapper=True)
def pytest_collect_file(file_path: Path, parent):
    collected = yield
    here = Path(__file__).parent
    for folder, (extra, modules) in _NEEDS_EXTRA.items():
        missing = [m for m in modules if not available(m)]
        if missing and file_path.suffix == ".py" and (here / folder) in file_path.parents:
            item = _ExtraMissing.from_parent(parent, path=file_path)
            item.reason = f"needs the '{extra}' extra (not installed: {', '.join(missing)})"
            return [item]
    return collected
