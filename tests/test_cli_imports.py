"""The commands a user types most answer ``--help`` and a bad option at once: their modules do not load the
estimator's heavy libraries (torch, JAX, trimesh: seconds each) until a command runs."""

import subprocess
import sys

import pytest

HEAVY = ("torch", "jax", "trimesh")
# command words -> module under tactile6d.cli
COMMANDS = {"estimate": "estimate", "identify": "identify", "track": "track", "inspect": "inspect",
            "calibrate-sensors": "calibrate_sensors"}


def run_python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("module", sorted(COMMANDS.values()))
@pytest.mark.slow
def test_a_command_module_imports_without_the_heavy_libraries(module):
    done = run_python(f"import sys, tactile6d.cli.{module}; "
                      f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "", f"tactile6d.cli.{module} loads {done.stdout.strip()} on import"


@pytest.mark.parametrize("words", sorted(COMMANDS))
@pytest.mark.slow
def test_help_prints_the_options_without_loading_them(words):
    done = run_python("import sys; from tactile6d.cli import main\n"
                      "try:\n"
                      f"    main([{words!r}, '--help'])\n"
                      "except SystemExit as exit:\n"
                      "    assert exit.code == 0, exit.code\n"
                      f"print('LOADED', ' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    assert done.returncode == 0, done.stderr
    assert f"usage: tactile6d {words}" in done.stdout
    assert done.stdout.strip().splitlines()[-1] == "LOADED", done.stdout.splitlines()[-1]


@pytest.mark.slow
def test_a_bad_option_is_refused_without_loading_them():
    done = run_python("import sys; from tactile6d.cli import main\n"
                      "try:\n"
                      "    main(['estimate', '--object', 'x', '--no-such-option'])\n"
                      "except SystemExit as exit:\n"
                      "    assert exit.code == 2, exit.code\n"
                      f"print('LOADED', ' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    assert done.returncode == 0, done.stderr
    assert "unrecognized arguments: --no-such-option" in done.stderr
    assert done.stdout.strip().splitlines()[-1] == "LOADED"
