"""The stored section runs of ``make bench`` (benchmarks/store.py) and the report assembled
from them (run_all.main, write_report).

Reference behaviour (the module's notes): a section's run is stored the moment it ends,
atomically; a run stopped before its end keeps what it measured; the repository's report
is assembled from the latest run of every section, each heading and verdict of a section
measured at another commit carrying that commit, and the provenance table naming the
measured code changed since. No benchmark is run: the sections below are fakes.
"""

from __future__ import annotations

import json
import subprocess
from types import SimpleNamespace

import numpy as np
import pytest
from benchmarks.judge import MET, NOT_MEASURED
from benchmarks.sections import Section
from benchmarks.store import (
    SectionRun,
    changed_since,
    load_runs,
    provenance_table,
    runs_from_json,
    save_run,
    section_stamp,
)

from benchmarks import run_all, store

_META = {
    "git": "aaa1111",
    "started": "2026-12-06 00:00:00",
    "date": "2026-12-06 00:10",
    "elapsed_s": 600.0,
    "stamp": "",
    "machine": {"platform": "p", "python": "3", "Model name": "CPU X", "cores": 2},
    "load_start": [1.0, 1.0, 1.0],
    "load_end": [2.0, 2.0, 2.0],
    "command": "python -m benchmarks.run_all --huge",
    "quick": False,
    "dirty": [],
    "versions": {"maglevid": "x"},
    "blas_threads": 1,
    "memory_limit_gb": 8.0,
}


def test_a_run_is_stored_and_read_back_with_numpy_values(tmp_path):
    run = SectionRun("pbsid", {"rows": [{"t": np.float64(0.5), "v": np.arange(3)}]}, _META)
    path = save_run(run, tmp_path)
    assert path == tmp_path / "pbsid.json"
    runs, problems = load_runs(["pbsid", "bearing"], tmp_path)
    assert problems == [] and list(runs) == ["pbsid"]
    assert runs["pbsid"].result == {"rows": [{"t": 0.5, "v": [0, 1, 2]}]}
    assert runs["pbsid"].meta["git"] == "aaa1111"


def test_a_write_that_fails_leaves_the_previous_run(tmp_path):
    save_run(SectionRun("pbsid", {"x": 1}, _META), tmp_path)
    before = (tmp_path / "pbsid.json").read_text()
    with pytest.raises(TypeError, match="not JSON-serialisable"):
        save_run(SectionRun("pbsid", {"x": object()}, _META), tmp_path)
    assert (tmp_path / "pbsid.json").read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pbsid.json"]  # no temporary left


def test_an_unreadable_stored_run_is_named_and_left_out(tmp_path):
    save_run(SectionRun("a", {"x": 1}, _META), tmp_path)
    (tmp_path / "b.json").write_text('{"name": "b", "meta": {')  # cut mid-write by hand
    runs, problems = load_runs(["a", "b"], tmp_path)
    assert list(runs) == ["a"]
    assert len(problems) == 1 and problems[0].startswith("b.json: not readable")


def test_stamp_names_another_commit_or_a_modified_tree():
    run = SectionRun("a", {}, _META)
    assert section_stamp(run, "aaa1111") == ""
    assert section_stamp(run, "bbb2222") == " [git aaa1111]"
    dirty = SectionRun("a", {}, {**_META, "stamp": " [modified tree, git aaa1111]"})
    assert section_stamp(dirty, "aaa1111") == " [modified tree, git aaa1111]"


def _git(repo, *args):
    subprocess.run(["git", *args], cwd=repo, check=True, capture_output=True)
    return subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True, text=True
    ).stdout.strip()


def test_changed_since_lists_the_measured_code_only(tmp_path):
    repo = tmp_path / "repo"
    (repo / "src").mkdir(parents=True)
    (repo / "benchmarks" / "results").mkdir(parents=True)
    (repo / "src" / "m.py").write_text("a = 1\n")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    first = _git(
        repo,
        "-c",
        "user.email=t@t",
        "-c",
        "user.name=t",
        "commit",
        "-q",
        "-m",
        "a",
        "--allow-empty",
    )
    (repo / "src" / "m.py").write_text("a = 2\n")
    (repo / "benchmarks" / "results" / "x.json").write_text("{}\n")  # an output, not code
    (repo / "README.md").write_text("docs\n")  # not measured code
    (repo / "benchmarks" / "README.md").write_text("how to run\n")  # prose, not code
    _git(repo, "add", ".")
    head = _git(repo, "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-q", "-m", "b")
    assert changed_since(first, repo) == ["src/m.py"]
    assert changed_since(head, repo) == []
    assert changed_since("0000000", repo) is None
    rows = provenance_table({"a": SectionRun("a", {}, {**_META, "git": first})}, head, repo)
    assert rows[2].startswith(f"| a | {first} | 2026-12-06 00:10 | 10.0 | 1.0 / 2.0 | CPU X |")
    assert rows[2].endswith("1 file(s): `src/m.py` |")


# ------------------------------------------------------------------ run_all.main
def _fake_sections(calls, fail=()):
    def measure(name):
        def m(run, plan, args):
            calls.append(name)
            if name in fail:
                raise fail[name]
            return {"value": len(calls)}

        return m

    def targets(res, judge):
        judge.add("value measured", str(res["value"]), True)

    return [
        Section(n, measure(n), lambda res, n=n: [f"## {n}", "", f"value {res['value']}"], targets)
        for n in ("first", "second")
    ]


@pytest.fixture
def fake_bench(monkeypatch, tmp_path):
    calls: list[str] = []
    state = {"git": "aaa1111", "fail": {}}
    monkeypatch.setattr(
        run_all, "all_sections", lambda: (_fake_sections(calls, state["fail"]), [])
    )
    monkeypatch.setattr(run_all, "git_state", lambda: (state["git"], []))
    monkeypatch.setattr(run_all, "_machine", lambda: {"platform": "p", "python": "3"})
    monkeypatch.setattr(run_all, "_versions", lambda: {"maglevid": "x"})
    monkeypatch.setattr(store, "changed_since", lambda rev, root=None: ["src/maglevid/m.py"])
    folder, out = tmp_path / "results", tmp_path / "B.md"

    def bench(*args):
        return run_all.main(["--out", str(out), "--store", str(folder), *args])

    return SimpleNamespace(bench=bench, calls=calls, state=state, folder=folder, out=out)


def test_one_run_of_every_section_is_one_run_report(fake_bench):
    fb = fake_bench
    assert fb.bench() == 0
    assert fb.calls == ["first", "second"]
    assert sorted(p.name for p in fb.folder.iterdir()) == ["first.json", "second.json"]
    text = fb.out.read_text()
    assert "Every number below comes from this one run" in text
    assert "[git" not in text and "Assembled" not in text


def test_one_section_refreshed_the_others_from_the_store_stamped(fake_bench):
    fb = fake_bench
    assert fb.bench() == 0
    fb.state["git"] = "bbb2222"
    assert fb.bench("--sections", "second") == 0
    assert fb.calls == ["first", "second", "second"]
    text = fb.out.read_text()
    assert "Assembled by" in text and "measured in 2 runs" in text
    assert "## first [git aaa1111]" in text and "## second\n" in text
    assert "| value measured | 1 | met [git aaa1111] |" in text
    assert "| value measured | 3 | met |" in text
    assert "1 file(s): `src/maglevid/m.py`" in text  # first's row of the provenance table
    assert json.loads((fb.folder / "second.json").read_text())["meta"]["git"] == "bbb2222"


def test_assemble_measures_nothing(fake_bench):
    fb = fake_bench
    assert fb.bench() == 0
    fb.out.unlink()
    assert fb.bench("--assemble") == 0
    assert fb.calls == ["first", "second"]
    assert "value 1" in fb.out.read_text() and "value 2" in fb.out.read_text()


def test_a_run_stopped_midway_keeps_the_sections_it_finished(fake_bench):
    fb = fake_bench
    fb.state["fail"] = {"second": KeyboardInterrupt()}
    with pytest.raises(KeyboardInterrupt):
        fb.bench()
    assert [p.name for p in fb.folder.iterdir()] == ["first.json"]
    fb.state["fail"] = {}
    assert fb.bench("--sections", "second") == 0
    text = fb.out.read_text()
    assert "measured in 2 runs" in text and "[git" not in text  # both at the report's commit


def test_a_section_that_fails_is_stored_as_failed(fake_bench):
    fb = fake_bench
    fb.state["fail"] = {"first": RuntimeError("worker crashed")}
    assert fb.bench() == 0
    stored = json.loads((fb.folder / "first.json").read_text())
    assert stored["result"] == {"error": "RuntimeError: worker crashed"}
    assert "The section failed: RuntimeError: worker crashed" in fb.out.read_text()


def test_report_elsewhere_holds_this_runs_sections_only(fake_bench, tmp_path):
    fb = fake_bench
    assert fb.bench() == 0
    other = tmp_path / "other.md"
    assert run_all.main(["--out", str(other), "--sections", "second"]) == 0
    text = other.read_text()
    assert "## second" in text and "## first" not in text
    assert "never measured" not in text


def test_import_of_an_older_json_file(tmp_path):
    raw = {
        "meta": {**_META, "elapsed_s": 7800.0, "absent": []},
        "results": {"pbsid": {"rows": []}, "bearing": {"error": "boom"}},
    }
    runs = {r.name: r for r in runs_from_json(raw)}
    assert runs["pbsid"].meta["elapsed_s"] is None
    assert runs["pbsid"].meta["run_elapsed_s"] == 7800.0
    assert runs["pbsid"].run_key == runs["bearing"].run_key  # one run
    path = tmp_path / "old.json"
    path.write_text(json.dumps(raw))
    assert store.main(["--import-json", str(path), "--store", str(tmp_path / "r")]) == 0
    loaded, _ = load_runs(["pbsid", "bearing"], tmp_path / "r")
    assert set(loaded) == {"pbsid", "bearing"}
    judge = run_all.write_report(
        loaded, {"command": "c", "date": "d", "git": "aaa1111"}, tmp_path / "B.md", [
            Section("bearing", lambda *a: {}, lambda res: ["## bearing"], run_all._targets_bearing)
        ],
    )  # fmt: skip
    assert judge.count(MET) == 0 and judge.count(NOT_MEASURED) == 1
    assert "in 130.0 min" in (tmp_path / "B.md").read_text()
