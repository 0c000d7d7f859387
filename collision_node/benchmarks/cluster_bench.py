"""The cluster's numbers (doc/cluster.md): speed-up, a chunk's overhead, collision_label's memory.

    python -m collision_node.benchmarks.cluster_bench [--states 1000000] [--label-states 10000000]

1. 10^6 states of the 7-box arm (config/arm.yaml, benchmarks/robot.py) through a
   ClusterChecker of 1 local worker, then of 2, in the same run: states/s and their ratio.
   With the caller's CPU time per chunk (validating, putting the chunk into Ray's object
   store, assembling the answer): the caller shares the two cores with the workers, so on
   two cores doing nothing else 2 workers can at best reach 2 t1 / (t1 + caller), t1 one
   worker's time per chunk.
2. One chunk of 10^4 states through one actor against the same chunk in this process: the
   overhead. Like for like: both Worlds are built from the same description with 1 thread
   (the checker's default ``threads``), both are warm (a first call, untimed), and the calls
   alternate, median of repeats, so that the machine's slow moments hit both. The actor's
   time is the caller's whole ``check_states`` call: validating the chunk, sending it, the
   worker's check (its input read from the object store, copied: the World's compiled pass
   takes writable arrays), the contacts back and assembled. Printed with Ray's floor: the same
   chunk sent to an actor that checks nothing and answers the same contacts.
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


def alternating_medians(calls, repeats=REPEATS):
    """Return each call's median time (s), the calls taking turns so that noise hits all."""
    times = [[] for _ in calls]
    for _ in range(repeats):
        for call, spent in zip(calls, times):
            start = time.perf_counter()
            call()
            spent.append(time.perf_counter() - start)
    return [float(np.median(spent)) for spent in times]


def throughput(world, states, half_extents, workers):
    """Return (states/s, the caller's CPU s per chunk, contacts) of ``workers`` workers."""
    from collision_node.cluster import ClusterChecker
    with ClusterChecker(world, workers=workers, chunk=CHUNK) as checker:
        checker.check_states(states[:4 * CHUNK], half_extents)  # actors started, kernels loaded
        start, cpu = time.perf_counter(), time.process_time()
        contacts = checker.check_states(states, half_extents).contacts
        chunks = -(-len(states) // CHUNK)
        return len(states) / (time.perf_counter() - start), \
            (time.process_time() - cpu) / chunks, contacts


def chunk_times(world, chunk, half_extents):
    """Return median s of ``chunk`` in process, through an actor, and Ray's floor for it."""
    from collision_node.cluster import ClusterChecker, transport_only
    expected = world.check_states(chunk, half_extents).contacts
    # Ray's floor: the chunk's trip to an actor and the same contacts' trip back, no check.
    send = transport_only(expected)
    with ClusterChecker(world, workers=1, chunk=CHUNK) as checker:
        assert np.array_equal(checker.check_states(chunk, half_extents).contacts, expected)
        send(chunk)
        return alternating_medians([
            lambda: world.check_states(chunk, half_extents),
            lambda: checker.check_states(chunk, half_extents),
            lambda: send(chunk)])


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
    from collision_node.cluster import local_ray
    print('CPU: %s, %d cores' % (cpu_model(), os.cpu_count()))
    world = arm_world()
    half_extents = scenes.arm().dynamic_half_extents
    # One period in 10^4 states, repeated: the same work per state as 10^6 distinct ones.
    states = np.tile(arm_states(CHUNK), (-(-args.states // CHUNK), 1, 1))[:args.states]
    with local_ray(num_cpus=2):
        one, _, contacts_one = throughput(world, states, half_extents, 1)
        two, caller, contacts_two = throughput(world, states, half_extents, 2)
        assert np.array_equal(contacts_one, contacts_two)
        in_process, remote, floor = chunk_times(world, states[:CHUNK], half_extents)
    print('%d arm states, 1 worker: %.0f states/s; 2 workers: %.0f states/s'
          % (len(states), one, two))
    ratio, per_chunk = two / one, CHUNK / one
    print('speed-up 2 workers / 1: %.2fx (target >= %.1fx: %s); the caller used %.1f ms CPU '
          'a chunk with 2 workers, one worker took %.1f ms a chunk: 2 otherwise idle cores '
          'allow %.2fx'
          % (ratio, SPEED_UP_TARGET, verdict(ratio, SPEED_UP_TARGET, False), 1e3 * caller,
             1e3 * per_chunk, 2 * per_chunk / (per_chunk + caller)))
    overhead = remote / in_process - 1.0
    print('one chunk of %d states, both Worlds 1 thread, warm, alternating, median of %d: '
          '%.2f ms through an actor against %.2f ms in process, overhead %+.1f %% '
          '(target <= %.0f %%: %s)'
          % (CHUNK, REPEATS, 1e3 * remote, 1e3 * in_process, 100 * overhead,
             100 * OVERHEAD_TARGET, verdict(overhead, OVERHEAD_TARGET, True)))
    print("Ray's floor for that chunk (to an actor that checks nothing, the same contacts "
          'back): %.2f ms, %+.1f %% of the in-process check'
          % (1e3 * floor, 100 * floor / in_process))
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
