"""docs/results.md's sections carry the revision and date they were generated at, and `make
results-stale` finds those whose code changed since (benchmarks/make_results.py)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def mr():
    if subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True).returncode != 0:
        pytest.skip("not a git checkout")
    spec = importlib.util.spec_from_file_location("make_results", REPO / "benchmarks" / "make_results.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_results"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_a_generated_section_is_stamped_with_its_revision_date_and_code(mr, tmp_path, monkeypatch):
    monkeypatch.setattr(mr, "DEPS", tmp_path / "none.json")  # no recorded imports: the whole package
    sec = next(s for s in mr.SECTIONS if s.name == "render")
    text = mr.format_section(sec, "numbers", 3.0)
    stamp, body = mr.sections_in(text)["render"]
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True)
    assert stamp["rev"].split("+")[0] == head.stdout.strip()
    assert stamp["code"] == mr.code_digest(mr.dependencies(sec)) and len(stamp["date"]) == 10
    assert f"took 3 s; generated at {stamp['rev'].split('+')[0]}" in body
    deps = mr.dependencies(sec)
    assert "benchmarks/speed/render_bench.py" in deps and "src/geofill" in deps
    # Fresh now; stale once the code it depends on is not what it ran.
    assert mr.staleness(sec, stamp) == ""
    assert mr.staleness(sec, {**stamp, "code": "0" * 16}).startswith("code changed since")


def test_an_unstamped_or_old_section_is_stale(mr):
    sec = next(s for s in mr.SECTIONS if s.name == "eval")
    assert mr.staleness(sec, {}) == "no stamp: unknown revision"
    # A derived stamp at the first commit: src/geofill has changed since.
    first = subprocess.run(
        ["git", "rev-list", "--max-parents=0", "HEAD"], cwd=REPO, capture_output=True, text=True
    ).stdout.split()[0][:7]
    why = mr.staleness(sec, mr.parse_stamp(f" rev={first} date=2026-01-01 derived"))
    assert why.endswith(f"changed since {first}") and "src/geofill/" in why
    words = mr.stamp_words(mr.parse_stamp(f" rev={first} date=x derived"))
    assert "unknown revision: its text last changed in" in words


def test_every_section_of_results_md_is_stamped(mr):
    found = mr.sections_in(mr.OUT.read_text())
    assert set(found) == {s.name for s in mr.SECTIONS}
    assert [name for name, (stamp, _) in found.items() if not stamp.get("rev") or not stamp.get("date")] == []


def test_a_stale_section_says_so_under_its_heading_and_a_fresh_one_does_not(mr, tmp_path):
    fresh, old = (next(s for s in mr.SECTIONS if s.name == n) for n in ("render", "speed"))
    stale_text = mr.format_section(old, "| a | 1 |", 5.0).replace(" code=", " code=0000")
    doc = tmp_path / "results.md"
    doc.write_text("# Results\n\n" + mr.format_section(fresh, "| b | 2 |", 3.0) + "\n" + stale_text)
    assert mr.mark_stale(doc) == ["speed"]
    marked = mr.sections_in(doc.read_text())
    assert "> **Stale:** code changed since" in marked["speed"][1]
    assert "--only speed`" in marked["speed"][1] and "| a | 1 |" in marked["speed"][1]
    assert "Stale" not in marked["render"][1]
    # Marking twice leaves one note; once the section is fresh again, the note goes.
    assert mr.mark_stale(doc) == ["speed"] and doc.read_text().count("> **Stale:**") == 1
    doc.write_text(doc.read_text().replace(marked["speed"][1], mr.format_section(old, "| a | 1 |", 5.0)))
    assert mr.mark_stale(doc) == [] and "Stale" not in doc.read_text()


def test_docstrings_comments_and_layout_do_not_stale_a_section_and_code_does(mr, tmp_path):
    a, b, c, d = (tmp_path / f"{n}.py" for n in "abcd")
    a.write_text('"""Old words."""\n\n\ndef f(x):\n    """Twice x."""\n    return 2 * x  # why\n')
    b.write_text('"""New words: 0.02 dB."""\n\n\ndef f(x):\n    return 2 * x\n')
    c.write_text('"""Old words."""\n\n\ndef f(x):\n    """Twice x."""\n    return 3 * x\n')
    d.write_text("def f(x):\n    '''Only a docstring.'''\n")
    assert mr.code_of(a) == mr.code_of(b) != mr.code_of(c)
    assert b"Pass" in mr.code_of(d)  # a body that was only its docstring still has a body
    data = tmp_path / "page.html"
    data.write_text("<p>1</p>")
    assert mr.code_of(data) == b"<p>1</p>"  # any other file: its bytes


def test_a_section_whose_last_run_failed_is_listed_for_a_rerun_though_its_code_is_current(mr, tmp_path):
    sec = next(s for s in mr.SECTIONS if s.name == "batch")
    doc = tmp_path / "results.md"
    doc.write_text("# Results\n\n" + mr.format_section(sec, "| mode | 1 |", 3.0))
    assert not [line for line in mr.stale_report(doc) if line.startswith("batch:")]
    failed = mr.format_section(sec, "FAILED (exit 1):\nTraceback ...\nAssertionError", 3.0)
    doc.write_text("# Results\n\n" + failed)
    stamp = mr.sections_in(failed)["batch"][0]
    assert mr.staleness(sec, stamp) == ""  # the code is current ...
    (line,) = [line for line in mr.stale_report(doc) if line.startswith("batch:")]
    assert line.startswith("batch: its last run failed (generated at")  # ... yet it has no numbers
    assert mr.mark_stale(doc) == ["batch"] and "> **Stale:** its last run failed" in doc.read_text()


def test_a_section_depends_on_the_modules_its_processes_imported_and_goes_stale_only_with_them(
    mr, tmp_path, monkeypatch
):
    monkeypatch.setattr(mr, "DEPS", tmp_path / "deps.json")
    monkeypatch.setattr(mr, "OUT", tmp_path / "results.md")
    # The renderer in the command's process, the focal module in a forked worker (which leaves
    # without running exit handlers).
    code = (
        "import multiprocessing as mp\nimport geofill.render\n"
        "def child(_):\n    import geofill.focal\n    return 0\n"
        "if __name__ == '__main__':\n    with mp.get_context('fork').Pool(1) as p:\n"
        "        p.map(child, [0])\n    print('done')\n"
    )
    sec = mr.Section("imports", "Imports", "", [mr.PY, "-c", code])
    text, recorded = mr.run_section(sec)
    assert "done" in text
    assert {"src/geofill/__init__.py", "src/geofill/render.py", "src/geofill/focal.py"} <= set(recorded)
    assert "src/geofill/pipeline.py" not in recorded and "src/geofill/screen/surface.py" not in recorded
    mr.write("imports", text, recorded)
    assert mr.dependencies(sec) == recorded
    stamp = mr.sections_in(text)["imports"][0]
    assert mr.staleness(sec, stamp) == ""
    # A change to a module it did not import leaves it fresh; one to a module it did, stale.
    hashes = mr.file_hashes

    def changed(name):
        return lambda paths: {n: (b"x" if n == name else d) for n, d in hashes(paths).items()}

    monkeypatch.setattr(mr, "file_hashes", changed("src/geofill/screen/surface.py"))
    assert mr.staleness(sec, stamp) == ""
    monkeypatch.setattr(mr, "file_hashes", changed("src/geofill/focal.py"))
    assert mr.staleness(sec, stamp).startswith("code changed since")


def test_a_write_waits_for_another_runs_write_and_keeps_its_section(mr, tmp_path, monkeypatch):
    import fcntl
    import threading

    monkeypatch.setattr(mr, "DEPS", tmp_path / "deps.json")
    monkeypatch.setattr(mr, "OUT", tmp_path / "results.md")
    render, speed = (next(s for s in mr.SECTIONS if s.name == n) for n in ("render", "speed"))
    mr.write("render", mr.format_section(render, "render numbers", 1.0))
    # Another `--only` run holds the lock while it rewrites the file: this run's write waits.
    with open(mr.OUT.with_suffix(".lock"), "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        writer = threading.Thread(
            target=mr.write, args=("speed", mr.format_section(speed, "speed numbers", 2.0, alongside=True))
        )
        writer.start()
        writer.join(0.5)
        assert writer.is_alive()
        mr.OUT.write_text(mr.OUT.read_text().replace("render numbers", "render numbers, rerun"))
    writer.join(10)
    found = mr.sections_in(mr.OUT.read_text())
    assert "render numbers, rerun" in found["render"][1] and "speed numbers" in found["speed"][1]
    assert "took 2 s alongside other benchmarks or tests" in found["speed"][1]
    assert "alongside" not in found["render"][1]
