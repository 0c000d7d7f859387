"""The cluster's numbers (doc/cluster.md): speed-up, a chunk's overhead, collision_label's memory.

    python -m collision_node.benchmarks.cluster_bench [--states 1000000] [--label-states 10000000]

1. 10^6 states of the 7-box arm (config/arm.yaml, benchmarks/robot.py) through a
   ClusterChecker of 1 local worker, then of 2, in the same run: states/s and their ratio.
2. One chunk of 10^4 states through one actor against the same chunk in this process (median
   of repeats): the overhead.
3. collision_label on K configurations of the Panda (example-robot-data) in a child process,
   labels streamed to disk: that process's peak memory (ru_maxrss).

Each result is printed with its target and whether it was met. Not a test: nothing fails.
"""
import argparse
import os
import re
import subprocess
import sys
import sysconfig
import tempfile
import time

import numpy as np

from collision_node.benchmarks.robot import arm_states, arm_world
from collision_node.pipeline import scenes

SPEED_UP_TARGET = 1.7      # 2 workers against 1
OVERHEAD_TARGET = 0.10     # a chunk through an actor against in-process
MEMORY_TARGET_MB = 1024.0  # collision_label's process, K = 10^7
CHUNK = 10_000
REPEATS = 15


def verdict(measured, target, better_below):
    met = measured <= target if better_below else measured >= target
    return 'met' if met else 'NOT met'


def median_time(call, repeats=REPEATS):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def throughput(world, states, half_extents, workers):
    from collision_node.cluster import ClusterChecker
    with ClusterChecker(world, workers=workers, chunk=CHUNK) as checker:
        checker.check_states(states[:4 * CHUNK], half_extents)  # actors started, kernels loaded
        start = time.perf_counter()
        contacts = checker.check_states(states, half_extents).contacts
        return len(states) / (time.perf_counter() - start), contacts


def panda_paths():
    prefix = os.path.join(sysconfig.get_paths()['purelib'], 'cmeel.prefix')
    panda = os.path.join(prefix, 'share', 'example-robot-data', 'robots', 'panda_description')
    return prefix, os.path.join(panda, 'urdf', 'panda.urdf'), \
        os.path.join(panda, 'srdf', 'panda.srdf')


def label_memory(count):
    """Run collision_label on ``count`` Panda configurations; return (peak MB, states/s)."""
    prefix, urdf, srdf = panda_paths()
    with tempfile.TemporaryDirectory() as directory:
        output = os.path.join(directory, 'labels.npy')
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, '-m', 'collision_node.tools.label', '--urdf', urdf, '--srdf',
             srdf, '--count', str(count), '--margin', '0.02', '--static', '0.5', '0', '0.3',
             '0', '0', '0', '1', '0.05', '0.3', '0.3', '--output', output, '--quiet'],
            capture_output=True, text=True, env=dict(os.environ, AMENT_PREFIX_PATH=prefix))
        elapsed = time.perf_counter() - start
        if done.returncode != 0:
            raise RuntimeError(done.stderr[-2000:])
        peak = float(re.search(r'peak memory of this process (\d+) MB', done.stdout).group(1))
        return peak, count / elapsed, done.stdout.strip()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--states', type=int, default=1_000_000)
    parser.add_argument('--label-states', type=int, default=10_000_000)
    args = parser.parse_args(argv)
    # Here, not at the top: importing this module (the package's import test) loads no Ray.
    from collision_node.cluster import ClusterChecker, local_ray
    print('CPU: %s, %d cores' % (cpu_model(), os.cpu_count()))
    world = arm_world()
    half_extents = scenes.arm().dynamic_half_extents
    # One period in 10^4 states, repeated: the same work per state as 10^6 distinct ones.
    states = np.tile(arm_states(CHUNK), (-(-args.states // CHUNK), 1, 1))[:args.states]
    expected_chunk = world.check_states(states[:CHUNK], half_extents).contacts
    in_process = median_time(lambda: world.check_states(states[:CHUNK], half_extents))
    with local_ray(num_cpus=2):
        one, contacts_one = throughput(world, states, half_extents, 1)
        two, contacts_two = throughput(world, states, half_extents, 2)
        assert np.array_equal(contacts_one, contacts_two)
        with ClusterChecker(world, workers=1, chunk=CHUNK) as checker:
            assert np.array_equal(checker.check_states(states[:CHUNK], half_extents).contacts,
                                  expected_chunk)
            remote = median_time(lambda: checker.check_states(states[:CHUNK], half_extents))
    print('in process, one World, 1 thread: %.0f states/s (one chunk of %d: %.2f ms)'
          % (CHUNK / in_process, CHUNK, 1e3 * in_process))
    print('%d arm states, 1 worker: %.0f states/s; 2 workers: %.0f states/s'
          % (len(states), one, two))
    ratio, overhead = two / one, remote / in_process - 1.0
    print('speed-up 2 workers / 1: %.2fx (target >= %.1fx: %s)'
          % (ratio, SPEED_UP_TARGET, verdict(ratio, SPEED_UP_TARGET, False)))
    print('one chunk of %d states through an actor: %.2f ms against %.2f ms in process, '
          'overhead %+.1f %% (target <= %.0f %%: %s)'
          % (CHUNK, 1e3 * remote, 1e3 * in_process, 100 * overhead, 100 * OVERHEAD_TARGET,
             verdict(overhead, OVERHEAD_TARGET, True)))
    if args.label_states:
        peak, rate, line = label_memory(args.label_states)
        print('collision_label, %d Panda configurations: %s' % (args.label_states, line))
        print('collision_label peak memory (its process): %.0f MB at %.0f states/s overall '
              '(target <= %.0f MB: %s)'
              % (peak, rate, MEMORY_TARGET_MB, verdict(peak, MEMORY_TARGET_MB, True)))


def cpu_model():
    try:
        with open('/proc/cpuinfo') as info:
            return re.search(r'model name\s*:\s*(.*)', info.read()).group(1)
    except (OSError, AttributeError):
        return 'unknown'


if __name__ == '__main__':
    sys.exit(main())
