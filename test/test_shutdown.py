"""SIGINT and SIGTERM end every program that spins with status 0 and no traceback.

Whenever they come: the script collision_node.benchmarks.shutdown_race provokes the race.

Before the fix (a context.ok() check, then spin_once) 9 of 40 signalled starts of the node
under a 1 kHz feed ended with status 1 and an RCLError traceback, so 24 starts miss such a
fault with a probability of (31/40)^24 < 0.3 %.
"""
import os
import random
import signal
import subprocess
import sys
import time

import pytest

from collision_node.benchmarks import shutdown_race

DOMAIN_ID = random.Random(os.getpid() + 41).randint(1, 200)


def signalled_starts(program, starts, when='active', max_delay_s=0.3, rate_hz=1000.0):
    lines = []
    failures = shutdown_race.race(program, starts, when, max_delay_s, rate_hz, DOMAIN_ID,
                                  seed=random.randrange(2**31), report=lines.append)
    assert failures == [], '\n'.join(lines)


@pytest.mark.slow
def test_node_signalled_at_random_moments_while_active_under_a_1khz_feed():
    signalled_starts('node', 24)


@pytest.mark.slow
def test_node_signalled_while_idle():
    signalled_starts('node', 6, rate_hz=0.0)


@pytest.mark.slow
def test_node_signalled_while_starting():
    """From the first line: imports, kernels loaded, the autostart transitions."""
    signalled_starts('node', 8, when='start', max_delay_s=2.5)


@pytest.mark.slow
@pytest.mark.parametrize('program', ['pose_publisher', 'collision_monitor', 'collision_demo'])
def test_tools_signalled_at_random_moments(program):
    signalled_starts(program, 6, when='active', max_delay_s=0.5)


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_before_the_start_is_a_clean_exit(signum):
    """A signal the latch holds (e.g. one during the imports) ends the start at once."""
    code = ('import os, signal, sys\n'
            'from collision_node.tools import programs\n'
            'from collision_node.ros.signal_latch import LATCH\n'
            'LATCH.install()\n'
            'os.kill(os.getpid(), %d)\n'  # received before the start: the start ends at once
            'sys.exit(programs.collision_node())\n' % signum)
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert (done.returncode, done.stderr) == (0, '')
    assert done.stdout == ''


def test_a_second_signal_ends_a_shutdown_that_hangs():
    """The first signal asks for a clean shutdown; a second one does not wait for it."""
    code = ('import os, signal, time\n'
            'from collision_node.ros.signal_latch import LATCH\n'
            'LATCH.install()\n'
            'os.kill(os.getpid(), signal.SIGINT)\n'
            'print("recorded", LATCH.received == signal.SIGINT, flush=True)\n'
            'os.kill(os.getpid(), signal.SIGTERM)\n'
            'time.sleep(30)\n'  # a shutdown that hangs
            'print("not reached")\n')
    started = time.monotonic()
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert (done.returncode, done.stdout, done.stderr) == (0, 'recorded True\n', '')
    assert time.monotonic() - started < 20.0


def test_an_error_with_the_context_valid_still_ends_the_program_with_it():
    """Only errors raised after a shutdown are swallowed: a real fault keeps its traceback."""
    code = ('from collision_node.ros.lifetime import RosProgram\n'
            'def broken():\n'
            '    raise ValueError("a real fault")\n'
            'with RosProgram() as program:\n'
            '    program.start(broken)\n')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          env=dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID)), timeout=60)
    assert done.returncode == 1
    assert 'ValueError: a real fault' in done.stderr
