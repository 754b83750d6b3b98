"""Each stage's time record (tactile6d.runtime.stage_clock): written with its fields by a stage that ends well
under DVC, never by one that fails, is interrupted or runs outside DVC."""

import datetime
import json
import os
import subprocess
import sys
import textwrap

import pytest

from tactile6d.core.errors import DataError, exit_on_error
from tactile6d.runtime import stage_clock

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_a_stage_that_ends_well_under_dvc_writes_its_record(tmp_path, monkeypatch):
    monkeypatch.setenv("DVC_STAGE", "render_database@004_sugar_box")
    main = stage_clock.timed(lambda argv=None: 0, tmp_path)
    assert exit_on_error(main) == 0
    rec = json.loads((tmp_path / "render_database@004_sugar_box.json").read_text())
    assert set(rec) == {"stage", "seconds", "started", "finished", "cpu", "cores"}
    assert rec["stage"] == "render_database@004_sugar_box" and rec["cores"] == os.cpu_count()
    assert isinstance(rec["cpu"], str) and rec["cpu"]
    started, finished = (datetime.datetime.fromisoformat(rec[k]) for k in ("started", "finished"))
    assert started.tzinfo is not None and (finished - started).total_seconds() == round(rec["seconds"])
    # counted from this process's start (pytest's), so at least as long as the process has run
    assert rec["seconds"] >= 0 and abs((datetime.datetime.now().astimezone() - finished).total_seconds()) < 60
    assert [p.name for p in tmp_path.iterdir()] == ["render_database@004_sugar_box.json"]  # no temporary left


@pytest.mark.parametrize("exc", [DataError("no mesh"), KeyboardInterrupt(), RuntimeError("bug")])
def test_a_stage_that_raises_writes_nothing(tmp_path, monkeypatch, exc):
    monkeypatch.setenv("DVC_STAGE", "train_ae")

    def main():
        raise exc

    with pytest.raises(type(exc)):  # passed on untouched, to exit_on_error outside
        stage_clock.timed(main, tmp_path)()
    assert list(tmp_path.iterdir()) == []
    if isinstance(exc, DataError):  # a user error: exit status 2, as without the clock
        assert exit_on_error(stage_clock.timed(main, tmp_path)) == 2
        assert list(tmp_path.iterdir()) == []


def test_a_failing_status_or_a_run_outside_dvc_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("DVC_STAGE", "train_ae")
    assert stage_clock.timed(lambda: 3, tmp_path)() == 3
    monkeypatch.delenv("DVC_STAGE")
    assert stage_clock.timed(lambda: None, tmp_path)() == 0
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_the_time_counts_from_the_start_of_the_process(tmp_path):
    """A real process that sleeps before it imports anything of tactile6d: that time counts too (on Linux)."""
    script = textwrap.dedent(f"""
        import sys, time
        time.sleep(0.6)  # stands for Python's start-up and a stage's imports
        sys.path.insert(0, {REPO!r})
        from tactile6d.runtime.stage_clock import timed
        sys.exit(timed(lambda: time.sleep(0.2), {str(tmp_path)!r})())
    """)
    env = dict(os.environ, DVC_STAGE="select_tuples@caddeo2023-ours")
    subprocess.run([sys.executable, "-c", script], env=env, check=True)
    seconds = json.loads((tmp_path / "select_tuples@caddeo2023-ours.json").read_text())["seconds"]
    assert seconds >= (0.78 if sys.platform == "linux" else 0.19) and seconds < 60


def test_records_read_back_in_order_of_start(tmp_path):
    now = datetime.datetime(2026, 11, 25, 10, 0, tzinfo=datetime.timezone.utc)
    stage_clock.write_record(tmp_path / "b.json", stage_clock.record("b", 5.0, now))
    stage_clock.write_record(tmp_path / "a.json", stage_clock.record("a", 50.0, now))
    (tmp_path / "notes.txt").write_text("not a record")
    assert [r["stage"] for r in stage_clock.read_records(tmp_path)] == ["a", "b"]
    assert stage_clock.read_records(tmp_path / "missing") == []


def test_durations_read_as_the_readme_writes_them():
    assert [stage_clock.duration(s) for s in (42.4, 485, 4211)] == ["42 s", "8 min 5 s", "70 min 11 s"]
