"""Start a program many times, signal it at a random moment, count the unclean exits.

    python -m collision_node.benchmarks.shutdown_race --starts 200 --rate 1000
    python -m collision_node.benchmarks.shutdown_race --program pose_publisher --starts 20
    python -m collision_node.benchmarks.shutdown_race --when start --max-delay 3 --starts 50

A shutdown by SIGINT or SIGTERM must end every program that spins with status 0 and no
traceback, whenever the signal comes. A race with the signal shows only when it lands in a
window of microseconds, so this script provokes it: it feeds the node the room scene at
``--rate`` from a pose_publisher child, starts the program (``--program``, the node by default),
waits until it logs that it is active (``--when active``; ``--when start``: from the moment it
handles the signals, so the signal can land in the imports, the warm-up or the autostart
transitions), waits a random delay up to ``--max-delay`` seconds, sends SIGINT or SIGTERM
(alternating), and reads the exit status and output. It prints each unclean start and a
summary; its exit status is 1 if any start was unclean.
"""
import argparse
import os
import pathlib
import random
import signal
import subprocess
import sys
import threading
import time

from collision_node.tools.processes import stop_process
from collision_node.tools.programs import child_command

CONFIG = pathlib.Path(__file__).resolve().parents[2] / 'config' / 'default.yaml'
# What each program logs once it spins; the node says so after its autostart transitions.
READY_LINES = {
    'node': 'active: checking inputs',
    'pose_publisher': None,  # it logs nothing: any moment after its start
    'collision_monitor': None,
    'collision_demo': 'waiting for the first diagnostics',
}
# Each as its console script runs it (collision_node.tools.programs), with its arguments.
PROGRAMS = {
    'node': ('collision_node', '--ros-args', '--params-file', str(CONFIG)),
    'pose_publisher': ('pose_publisher', '--scene', 'room', '--rate', '1000'),
    'collision_monitor': ('collision_monitor',),
    'collision_demo': ('collision_demo', '--rate', '1000'),
}

READY_TIMEOUT_S = 180.0  # a cold numba cache compiles for minutes
EXIT_TIMEOUT_S = 20.0
SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Run:
    """One started program whose output is read by a thread, line by line."""

    def __init__(self, program, env, ready_line):
        self.process = subprocess.Popen(child_command(*PROGRAMS[program]), env=env,
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                        text=True)
        self.lines = []
        self.ready_line = ready_line
        self.said_ready = threading.Event()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def wait_ready(self, timeout_s):
        """Wait until the program handles both signals, then for its ready line if it has one.

        Before its first line of Python runs, the interpreter's own start (site, the venv)
        takes SIGINT as a KeyboardInterrupt and SIGTERM as death: no program can be held to
        what happens before it exists. A program handles the signals once its latch is in.
        """
        deadline = time.monotonic() + timeout_s
        while not handles_shutdown_signals(self.process.pid):
            if self.process.poll() is not None or time.monotonic() > deadline:
                return False
            time.sleep(0.001)
        if self.ready_line is None:
            return True
        return self.said_ready.wait(max(0.0, deadline - time.monotonic()))

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line)
            if self.ready_line is not None and self.ready_line in line:
                self.said_ready.set()
        self.said_ready.set()  # ended before it was ready: nothing more to wait for

    def stop(self, signum):
        """Send ``signum``; return (exit status, output)."""
        if self.process.poll() is None:
            self.process.send_signal(signum)
        try:
            code = self.process.wait(EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            code = stop_process(self.process, EXIT_TIMEOUT_S)
            self.lines.append('[did not exit within %g s of the signal]\n' % EXIT_TIMEOUT_S)
        self.reader.join(EXIT_TIMEOUT_S)
        return code, ''.join(self.lines)


def handles_shutdown_signals(pid):
    """Tell whether process ``pid`` catches both SIGINT and SIGTERM (Linux: /proc)."""
    try:
        with open('/proc/%d/status' % pid) as status:
            caught = next(int(line.split()[1], 16) for line in status
                          if line.startswith('SigCgt:'))
    except (OSError, StopIteration):  # gone already
        return False
    return all(caught >> (signum - 1) & 1 for signum in SIGNALS)


def unclean(code, output):
    """Return why an exit is not clean, or None: status 0 and no traceback."""
    if code != 0:
        return 'status %d' % code
    if 'Traceback' in output:
        return 'a traceback'
    return None


def race(program, starts, when, max_delay_s, rate_hz, domain_id, seed, report=print):
    """Run ``starts`` signalled starts of ``program``; return the list of unclean ones."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1')
    feed = subprocess.Popen(
        child_command('pose_publisher', '--scene', 'room', '--rate', str(rate_hz)), env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) if rate_hz > 0 else None
    randoms = random.Random(seed)
    failures = []
    try:
        for start in range(starts):
            run = Run(program, env, READY_LINES[program] if when == 'active' else None)
            if not run.wait_ready(READY_TIMEOUT_S):
                report('start %d: not ready within %g s' % (start, READY_TIMEOUT_S))
            time.sleep(randoms.uniform(0.0, max_delay_s))
            signum = SIGNALS[start % len(SIGNALS)]
            code, output = run.stop(signum)
            why = unclean(code, output)
            if why is not None:
                failures.append((start, signum, why, output))
                name = signal.Signals(signum).name
                report('start %d, %s: %s\n%s' % (start, name, why, output.rstrip()))
    finally:
        if feed is not None:
            stop_process(feed, EXIT_TIMEOUT_S)
    return failures


def parse_arguments(argv):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--program', choices=sorted(PROGRAMS), default='node')
    parser.add_argument('--starts', type=int, default=200)
    parser.add_argument('--when', choices=('active', 'start'), default='active',
                        help='the random delay counts from the active log line, or the start')
    parser.add_argument('--max-delay', type=float, default=0.5, help='seconds')
    parser.add_argument('--rate', type=float, default=1000.0,
                        help='Hz of the room feed; 0: no feed')
    parser.add_argument('--domain-id', type=int, default=77)
    parser.add_argument('--seed', type=int, default=0)
    return parser.parse_args(argv)


def main(argv=None):
    options = parse_arguments(argv)
    started = time.monotonic()
    failures = race(options.program, options.starts, options.when, options.max_delay,
                    options.rate, options.domain_id, options.seed)
    statuses = sum(1 for _, _, why, _ in failures if why.startswith('status'))
    tracebacks = sum(1 for _, _, _, output in failures if 'Traceback' in output)
    print('%s: %d signalled starts (%s, up to %g s after), %d non-zero exits, %d with a '
          'traceback, %.0f s' % (options.program, options.starts, options.when,
                                 options.max_delay, statuses, tracebacks,
                                 time.monotonic() - started))
    return 1 if failures else 0


if __name__ == '__main__':
    sys.exit(main())
