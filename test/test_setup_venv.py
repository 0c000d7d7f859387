""".ci/setup-venv does each step once: a second run finds the venv complete and does nothing.

The script runs in a copy of the repository's files it reads, with a stand-in for the venv's
Python that records each call instead of running pip or compiling, so no test needs PyPI.
"""
import os
import pathlib
import shutil
import subprocess

REPO = pathlib.Path(__file__).resolve().parent.parent
# Records its arguments, one call a line; exits 0 as pip does when all went well.
RECORDING_PYTHON = '#!/bin/sh\necho "$@" >> "$(dirname "$0")/../calls"\n'
INSTALL = ['-m', 'pip', 'install']
COMPILE = '-m collision_node.tools.compile_kernels'


def make_copy(root):
    for name in ('.ci/setup-venv', 'setup.py', 'setup.cfg', 'collision_node/ros/node.py'):
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / name, root / name)
    python = root / '.venv' / 'bin' / 'python'
    python.parent.mkdir(parents=True)
    python.write_text(RECORDING_PYTHON)
    python.chmod(0o755)
    return root / '.venv' / 'calls'


def setup_venv(root, calls, expect_success=True):
    """Run the copy's setup-venv; return the calls it made to the venv's Python."""
    done = subprocess.run(['bash', str(root / '.ci' / 'setup-venv')], capture_output=True,
                          text=True, timeout=60, env=dict(os.environ, PYTHON='false'))
    assert (done.returncode == 0) == expect_success, done.stderr
    made = calls.read_text().splitlines() if calls.exists() else []
    calls.unlink(missing_ok=True)
    return made


def edit_after_compile(root, path):
    """Make ``path`` a second newer than the last compile, as an edit after it."""
    edited = os.stat(root / path).st_mtime
    os.utime(root / '.venv' / '.collision_node-compiled', (edited - 1.0, edited - 1.0))


def test_a_second_run_does_nothing(tmp_path):
    calls = make_copy(tmp_path)
    first = setup_venv(tmp_path, calls)
    assert [call.split()[:3] for call in first[:2]] == [INSTALL, INSTALL]
    assert first[1].endswith(' -e .') and first[2:] == [COMPILE]
    assert setup_venv(tmp_path, calls) == []


def test_an_edited_source_compiles_again_and_installs_nothing(tmp_path):
    calls = make_copy(tmp_path)
    setup_venv(tmp_path, calls)
    edit_after_compile(tmp_path, 'collision_node/ros/node.py')
    assert setup_venv(tmp_path, calls) == [COMPILE]
    assert setup_venv(tmp_path, calls) == []


def test_a_changed_setup_py_installs_and_compiles_again(tmp_path):
    calls = make_copy(tmp_path)
    setup_venv(tmp_path, calls)
    with open(tmp_path / 'setup.py', 'a') as setup_py:
        setup_py.write('# a new entry point, say\n')
    assert len(setup_venv(tmp_path, calls)) == 3


def test_a_failed_step_is_tried_again(tmp_path):
    calls = make_copy(tmp_path)
    python = tmp_path / '.venv' / 'bin' / 'python'
    python.write_text(RECORDING_PYTHON + 'exit 1\n')  # pip fails, e.g. PyPI out of reach
    assert len(setup_venv(tmp_path, calls, expect_success=False)) == 1
    python.write_text(RECORDING_PYTHON + '[ "$2" = pip ] || exit 1\n')  # the compile fails
    assert len(setup_venv(tmp_path, calls, expect_success=False)) == 3
    python.write_text(RECORDING_PYTHON)
    assert setup_venv(tmp_path, calls) == [COMPILE]
