"""scripts/repro_progress.py: `dvc repro` with each stage DVC comes to numbered, [k/N], on DVC's own output."""

import sys
import textwrap
from pathlib import Path

from script_loader import load_script

repro_progress = load_script("repro_progress")

# What `dvc repro` 3.67 writes to stdout (its info log and the stages' own prints) for a pipeline of 4 stages
# resumed after a failure: one unchanged, one restored from the run cache, two run.
DVC_OUTPUT = b"""Stage 'prepare_object@002_master_chef_can' didn't change, skipping
Stage 'sample_surface@002_master_chef_can' is cached - skipping run, checking out outputs
Running stage 'render_database@002_master_chef_can':
> python -m stages.render_database --params params.yaml --object 002_master_chef_can
002_master_chef_can: 2000 images; Running stage 'x': is no stage line here
Updating lock file 'dvc.lock'

Running stage 'train_ae':
> python -m stages.train_ae --params params.yaml
  Stage 'indented' didn't change, skipping
Updating lock file 'dvc.lock'

To track the changes with git, run:

\tgit add dvc.lock
"""


def test_each_stage_line_gets_its_place_in_the_pipeline_and_nothing_else_changes():
    out = list(repro_progress.annotate(DVC_OUTPUT.splitlines(keepends=True), 4))
    numbered = [line for line in out if line.startswith(b"[")]
    assert numbered == [b"[1/4] Stage 'prepare_object@002_master_chef_can' didn't change, skipping\n",
                        b"[2/4] Stage 'sample_surface@002_master_chef_can' is cached - skipping run, checking out outputs\n",
                        b"[3/4] Running stage 'render_database@002_master_chef_can':\n",
                        b"[4/4] Running stage 'train_ae':\n"]
    assert b"".join(line.split(b"] ", 1)[1] if line.startswith(b"[") else line for line in out) == DVC_OUTPUT


def test_without_a_total_the_stages_are_only_counted():
    out = list(repro_progress.annotate([b"Running stage 'report':\n"], None))
    assert out == [b"[1] Running stage 'report':\n"]


def fake_dvc(tmp_path: Path, status: int) -> list[str]:
    """A stand-in for `python -m dvc`: `stage list` names 4 stages, `repro` writes DVC_OUTPUT and exits ``status``."""
    script = tmp_path / "fake_dvc.py"
    (tmp_path / "output.txt").write_bytes(DVC_OUTPUT)
    script.write_text(textwrap.dedent(f"""
        import sys
        if sys.argv[1:3] == ["stage", "list"]:
            print("a\\nb\\nc\\nd")
            sys.exit(0)
        assert sys.argv[1] == "repro", sys.argv
        sys.stdout.buffer.write(open({str(tmp_path / "output.txt")!r}, "rb").read())
        sys.stderr.write("progress bars go to stderr\\n")
        sys.exit({status})
    """))
    return [sys.executable, str(script)]


def test_the_script_streams_dvc_and_returns_its_status(tmp_path, capfdbinary):
    assert repro_progress.main([], dvc=fake_dvc(tmp_path, 0)) == 0
    out, err = capfdbinary.readouterr()
    assert b"[3/4] Running stage 'render_database@002_master_chef_can':\n" in out
    assert out.count(b"[") == 4 and b"To track the changes" in out and err == b"progress bars go to stderr\n"
    # a failing stage: DVC stops and so does make, on DVC's status
    assert repro_progress.main(["--keep-going"], dvc=fake_dvc(tmp_path, 255)) == 255
    # with a target, DVC comes to only some stages: counted without a total
    assert repro_progress.main(["report"], dvc=fake_dvc(tmp_path, 0)) == 0
    assert b"[4] Running stage 'train_ae':" in capfdbinary.readouterr()[0]
