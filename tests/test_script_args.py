"""tactile6d.runtime.script_args: overrides written after a list option reach the config, not the list."""

import argparse
import re
from pathlib import Path

import pytest

from tactile6d.runtime.script_args import is_override, parse_with_overrides

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def scenes_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenes", nargs="+", required=True)
    parser.add_argument("--out")
    parser.add_argument("overrides", nargs="*")
    return parser


def test_plain_argparse_takes_an_override_after_a_list_option_for_a_list_item():
    """The failure the helper exists for: the run would quietly use the default config."""
    args = scenes_parser().parse_args(["--scenes", "kinematic", "sensors.pose_sigma_mm=3"])
    assert args.scenes == ["kinematic", "sensors.pose_sigma_mm=3"] and args.overrides == []


@pytest.mark.parametrize("argv", [
    ["--scenes", "kinematic", "validation", "sensors.pose_sigma_mm=3", "rank.candidates=60"],
    ["sensors.pose_sigma_mm=3", "--scenes", "kinematic", "validation", "rank.candidates=60"],
    ["--scenes", "kinematic", "sensors.pose_sigma_mm=3", "validation", "rank.candidates=60"],
])
def test_overrides_anywhere_go_to_the_config_in_their_order(argv):
    args = parse_with_overrides(scenes_parser(), argv)
    assert args.scenes == ["kinematic", "validation"]
    assert args.overrides == ["sensors.pose_sigma_mm=3", "rank.candidates=60"]


def test_an_option_written_with_equals_stays_an_option():
    args = parse_with_overrides(scenes_parser(), ["--out=report.txt", "--scenes", "kinematic", "+x=1", "~y"])
    assert args.out == "report.txt" and args.scenes == ["kinematic", "~y"] and args.overrides == ["+x=1"]
    assert not is_override("--out=report.txt") and not is_override("kinematic") and is_override("~rank.refine=null")


def test_subcommands_keep_their_own_arguments():
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command", required=True)
    dump = sub.add_parser("dump")
    dump.add_argument("--scenes", nargs="+", required=True)
    dump.add_argument("overrides", nargs="*")
    args = parse_with_overrides(parser, ["dump", "--scenes", "offaxis:10", "select.N=100"])
    assert args.command == "dump" and args.scenes == ["offaxis:10"] and args.overrides == ["select.N=100"]


def test_every_script_with_a_list_option_and_overrides_parses_with_the_helper():
    """A script that takes both must not lose its overrides to the list (the bug of pose_floor.py's
    documented ``--scenes kinematic [override ...]`` before 2026-12-01)."""
    list_option = re.compile(r'add_argument\(\s*"--[^)]*nargs="[*+]"')  # an option, not the overrides themselves
    offenders = [p.name for p in sorted(SCRIPTS.glob("*.py"))
                 if list_option.search(text := p.read_text()) and '"overrides"' in text
                 and "parse_with_overrides" not in text]
    assert offenders == []
