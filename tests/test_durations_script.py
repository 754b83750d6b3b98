"""scripts/test_durations.py: each test file's seconds from a JUnit report, which orders make test's files."""

import json

from script_loader import load_script

durations = load_script("test_durations")

REPORT = """<?xml version="1.0" encoding="utf-8"?>
<testsuites><testsuite name="pytest" tests="4">
<testcase classname="tests.test_b" name="test_one" time="1.5" />
<testcase classname="tests.test_a" name="test_two[0]" time="0.25" />
<testcase classname="tests.test_b" name="test_three" time="2.0" />
<testcase classname="tests.sub.test_c" name="test_four" time="4.0"><skipped /></testcase>
<testcase classname="other.module" name="test_five" time="9.0" />
</testsuite></testsuites>
"""


def test_the_seconds_of_each_file_longest_first(tmp_path):
    report = tmp_path / "junit.xml"
    report.write_text(REPORT)
    seconds = durations.junit_to_file_seconds(report)
    assert seconds == {"tests/sub/test_c.py": 4.0, "tests/test_b.py": 3.5, "tests/test_a.py": 0.2}
    assert list(seconds) == ["tests/sub/test_c.py", "tests/test_b.py", "tests/test_a.py"]
    out = tmp_path / "durations.json"
    assert durations.main([str(report), "--out", str(out)]) == 0
    assert json.loads(out.read_text()) == seconds


def test_a_report_without_tests_of_the_suite_is_an_error(tmp_path, capsys):
    report = tmp_path / "junit.xml"
    report.write_text('<testsuites><testsuite name="pytest" tests="0"></testsuite></testsuites>')
    assert durations.main([str(report), "--out", str(tmp_path / "d.json")]) == 2
    assert "no test cases" in capsys.readouterr().err
    assert not (tmp_path / "d.json").exists()


def test_the_committed_file_lists_test_files_that_exist():
    listed = json.loads(durations.OUT.read_text())
    assert listed and all((durations.REPO / name).is_file() for name in listed), listed
    assert list(listed.values()) == sorted(listed.values(), reverse=True)
