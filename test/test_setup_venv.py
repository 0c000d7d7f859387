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
UV_INSTALL = ['-m', 'uv', 'pip']
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
    # pip installs uv, uv the core, pip the package; then the compile and uv's install of the
    # tools run together, in either order.
    assert [call.split()[:3] for call in first[:3]] == [INSTALL, UV_INSTALL, INSTALL]
    assert first[0].endswith(' uv') and first[2].endswith(' -e .')
    assert ' numba ' in first[1] and ' ray ' not in first[1]
    tools = [call for call in first[3:] if call != COMPILE]
    assert len(first) == 5 and COMPILE in first[3:] and len(tools) == 1
    assert tools[0].split()[:3] == UV_INSTALL and ' numba ' in tools[0] and ' ray ' in tools[0]
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
    assert len(setup_venv(tmp_path, calls)) == 5


def test_a_failed_step_is_tried_again(tmp_path):
    calls = make_copy(tmp_path)
    python = tmp_path / '.venv' / 'bin' / 'python'
    python.write_text(RECORDING_PYTHON + 'exit 1\n')  # pip fails, e.g. PyPI out of reach
    # uv's install, uv's install of the core, pip's of the core: then it stops.
    assert len(setup_venv(tmp_path, calls, expect_success=False)) == 3
    python.write_text(RECORDING_PYTHON + '[ "$2" != collision_node.tools.compile_kernels ]\n')
    # The compile fails; the installs went on meanwhile.
    assert len(setup_venv(tmp_path, calls, expect_success=False)) == 5
    python.write_text(RECORDING_PYTHON)
    assert setup_venv(tmp_path, calls) == [COMPILE]


def test_pip_installs_what_uv_cannot(tmp_path):
    calls = make_copy(tmp_path)
    python = tmp_path / '.venv' / 'bin' / 'python'
    python.write_text(RECORDING_PYTHON + '[ "$2" != uv ]\n')  # uv fails, pip works
    made = setup_venv(tmp_path, calls)
    installs = [call.split()[:3] for call in made if call != COMPILE]
    assert installs == [INSTALL, UV_INSTALL, INSTALL, INSTALL, UV_INSTALL, INSTALL]
    assert made.count(COMPILE) == 1
    assert ' ray ' in [call for call in made if call != COMPILE][-1]  # pip's, of the tools


def test_a_failed_tools_install_fails_the_set_up_and_is_tried_again(tmp_path):
    calls = make_copy(tmp_path)
    python = tmp_path / '.venv' / 'bin' / 'python'
    python.write_text(RECORDING_PYTHON + 'case "$*" in *" ray "*) exit 1;; esac\n')
    # uv, then pip, fail on the tools. The compile, started beside the installs, may be
    # stopped before it records its call.
    assert len(setup_venv(tmp_path, calls, expect_success=False)) in (5, 6)
    python.write_text(RECORDING_PYTHON)
    assert len(setup_venv(tmp_path, calls)) == 5


def test_a_core_package_the_tools_replace_compiles_again(tmp_path):
    calls = make_copy(tmp_path)
    site = tmp_path / '.venv' / 'lib' / 'python3.11' / 'site-packages'
    (site / 'numpy-2.0.0.dist-info').mkdir(parents=True)
    python = tmp_path / '.venv' / 'bin' / 'python'
    python.write_text(RECORDING_PYTHON + 'case "$*" in *" ray "*) mv "%s/numpy-2.0.0.dist-info" '
                      '"%s/numpy-1.26.0.dist-info";; esac\n' % (site, site))
    first = setup_venv(tmp_path, calls)
    assert len(first) == 6 and first[-1] == COMPILE and first.count(COMPILE) == 2
    assert setup_venv(tmp_path, calls) == []
