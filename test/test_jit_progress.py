"""Compile progress: a line at the first compile, then one a period with a count and an estimate.

The lines are checked on numba's own compile events, in processes with an empty cache (two
small kernels; the node's whole warm-up under the ``slow`` marker), and their arithmetic on a
scripted sequence of events with a stand-in clock.
"""
import os
import pathlib
import random
import subprocess
import sys

import pytest
from ros_helpers import node_command, node_environment

from collision_node.pipeline import jit_progress

REPO = pathlib.Path(__file__).resolve().parent.parent
DOMAIN_ID = random.Random(os.getpid() + 17).randint(1, 200)
FIRST_LINE = ('compiling the numba kernels missing from its cache (every kernel, on a first '
              'start); they are cached for later starts')
SMALL_KERNELS = """
from collision_node.pipeline._jit import kernel


@kernel
def add_one(x):
    return x + 1


@kernel
def add_one_twice(x):
    return add_one(add_one(x))
"""
RUN_SMALL_KERNELS = """
import sys
sys.path.insert(0, sys.argv[1])
from collision_node.pipeline._jit import KERNELS
from collision_node.pipeline.jit_progress import compile_progress
import small_kernels
print('%d kernels' % len(KERNELS))
with compile_progress(print, period_s=0.0):
    assert small_kernels.add_one_twice(1) == 3
"""


class FakeKernel:
    """A numba dispatcher as the progress sees it: its Python function, its compiled types."""

    def __init__(self, name, compiled=False):
        self.py_func = lambda: None
        self.py_func.__module__, self.py_func.__name__ = 'collision_node.pipeline.sat', name
        self.overloads = {'int64': 'code'} if compiled else {}


class FakeEvent:
    """numba's compile event as the progress reads it."""

    def __init__(self, dispatcher):
        self.data = {'dispatcher': dispatcher}


def run_small_kernels(tmp_path):
    (tmp_path / 'small_kernels.py').write_text(SMALL_KERNELS)
    done = subprocess.run(
        [sys.executable, '-c', RUN_SMALL_KERNELS, str(tmp_path)], cwd=REPO,
        env=dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / 'cache')), capture_output=True,
        text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    count, *lines = done.stdout.splitlines()
    return int(count.split()[0]), lines


def test_a_compile_is_reported_and_a_load_from_the_cache_is_not(tmp_path):
    kernels, lines = run_small_kernels(tmp_path)
    # add_one_twice starts compiling, then add_one inside it; nothing was compiled before.
    assert lines[:2] == [FIRST_LINE, 'compiling kernel 1 of %d (small_kernels.add_one), 0 s so '
                         'far' % kernels]
    assert lines[2].startswith('compiled 2 kernels in ') and len(lines) == 3
    assert run_small_kernels(tmp_path) == (kernels, [])


def test_counts_periods_and_estimate(monkeypatch):
    collide, axis, sort, helper = (FakeKernel(name)
                                   for name in ('collide', 'axis', 'sort', 'helper'))
    warm = FakeKernel('warm', compiled=True)  # compiled before: not to do
    monkeypatch.setattr(jit_progress, 'KERNELS', {collide, axis, sort, warm})
    now = [0.0]
    lines = []
    progress = jit_progress.CompileProgress(lines.append, period_s=5.0, clock=lambda: now[0])
    for time_s, kind, kernel in [
            (0.0, 'start', collide), (1.0, 'start', helper),  # numba's helper: not counted
            (1.5, 'end', helper), (2.0, 'end', collide),
            (6.0, 'start', axis), (7.0, 'end', axis), (7.5, 'start', axis), (8.0, 'end', axis),
            (9.0, 'start', sort), (10.0, 'end', sort),
            (12.0, 'start', axis), (12.5, 'end', axis),  # a third type of a counted kernel
            (18.0, 'start', warm), (18.5, 'end', warm)]:  # a new type of a kernel compiled before
        now[0] = time_s
        getattr(progress, 'on_' + kind)(FakeEvent(kernel))
    progress.finish()
    assert lines == [
        FIRST_LINE,
        # 1 of 3 done in 6 s: the 2 left take 12 s more
        'compiling kernel 2 of 3 (sat.axis), 6 s so far, about 12 s left',
        # 9.0 s: less than a period after the last line
        # 12.0 s: axis again, already counted, so not a fourth kernel of 3
        'compiling kernel 3 of 3 (sat.axis), 12 s so far, about 0 s left',
        # 18.0 s: warm was compiled before the block, so it is not a kernel to do
        'compiling kernel 3 of 3 (sat.warm), 18 s so far, about 0 s left',
        'compiled 3 kernels in 18.5 s']  # axis compiled three types, counted once


@pytest.mark.slow
def test_the_node_reports_its_first_start_and_not_its_second(tmp_path):
    """The node on an empty cache (about 30 s), then again on the cache it filled."""
    starts = []
    for _ in range(2):
        env = dict(node_environment(DOMAIN_ID), NUMBA_CACHE_DIR=str(tmp_path))
        process = subprocess.Popen(node_command(), cwd=REPO, env=env, stderr=subprocess.PIPE,
                                   text=True)
        lines = []
        try:
            for line in process.stderr:
                lines.append(line.split(']: ', 1)[-1].rstrip())
                if 'JIT warm-up' in line:
                    break
        finally:
            process.kill()
            process.wait()
        starts.append(lines[:-1])
    first, second = starts
    assert first[0] == FIRST_LINE and first[-1].startswith('compiled ')
    counts = [line.split()[2:5] for line in first[1:-1]]  # [k, 'of', n] of 'kernel k of n'
    assert counts and all(line.startswith('compiling kernel ') and line.endswith(' s left')
                          for line in first[1:-1])
    done = [int(k) for k, _, _ in counts]
    assert done == sorted(done) and len({n for _, _, n in counts}) == 1
    assert done[-1] <= int(first[-1].split()[1]) <= int(counts[0][2])
    assert second == []
