"""Per-tick time of every broad phase through World.step, for the README's table.

    python test/broadphase_bench.py [--sizes 1000 10000 100000] [--scenes uniform ...]

Prints one row per (scene, bodies, phase): median broad, narrow and broad + narrow
milliseconds per tick (World's wall-clock stage timings) over the measured ticks (the first,
which builds the structures and may compile, is not counted), the median CPU milliseconds of
the whole ``World.step`` (``time.process_time``: less disturbed when other processes share the
cores), the median candidate pairs and the phase that ran (what ``auto`` chose). A phase
whose first tick takes longer than ``--give-up`` seconds is skipped at that size and beyond.
Scenes come from ``collision_node.scenes`` (the lead's benchmark scenes): ``uniform`` and
``clustered`` have half of the bodies static; ``flying_out`` is paper 001's seed scene,
measured over its first ``--seconds`` seconds (dense at first, sparse later).
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from collision_node import scenes, World  # noqa: E402 (after the path set-up)
from collision_node.broadphase import NAMES  # noqa: E402


def measure(scene, phase, ticks, seconds, give_up):
    world = World(broad_phase=phase)
    world.set_static(scene.static_poses, scene.static_half_extents)
    rows = []
    for tick in range(ticks + 1):
        poses = scene.dynamic_poses(seconds * tick / ticks)
        start = time.perf_counter()
        cpu = time.process_time()
        result = world.step(poses, scene.dynamic_half_extents)
        cpu = time.process_time() - cpu
        if tick == 0 and time.perf_counter() - start > give_up:
            return None
        stats = result.stats
        rows.append((stats['broad_ms'], stats['narrow_ms'],
                     stats['broad_ms'] + stats['narrow_ms'], 1e3 * cpu,
                     stats['candidate_pairs']))
    used = result.stats['broad_phase']
    return np.median(np.array(rows[1:]), axis=0), used


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--sizes', type=int, nargs='+', default=[1000, 10000, 100000])
    parser.add_argument('--scenes', nargs='+', default=['uniform', 'clustered', 'flying_out'])
    parser.add_argument('--phases', nargs='+', default=list(NAMES))
    parser.add_argument('--ticks', type=int, default=20)
    parser.add_argument('--seconds', type=float, default=4.0,
                        help='scene time covered by the measured ticks')
    parser.add_argument('--give-up', type=float, default=2.0)
    args = parser.parse_args()
    print('%-11s %7s %-16s %9s %9s %9s %9s %10s  %s' % (
        'scene', 'bodies', 'phase', 'broad_ms', 'narrow_ms', 'total_ms', 'step_cpu', 'candidates',
        'ran'))
    for scene_name in args.scenes:
        too_slow = set()
        for n in args.sizes:
            scene = scenes.make_scene(scene_name, n)
            ticks = max(5, args.ticks * 10000 // max(n, 10000))
            for phase in args.phases:
                if phase in too_slow:
                    continue
                measured = measure(scene, phase, ticks, args.seconds, args.give_up)
                if measured is None:
                    too_slow.add(phase)
                    print('%-11s %7d %-16s   skipped (first tick > %g s)'
                          % (scene_name, n, phase, args.give_up))
                    continue
                (broad, narrow, total, cpu, candidates), used = measured
                print('%-11s %7d %-16s %9.3f %9.3f %9.3f %9.3f %10d  %s' % (
                    scene_name, n, phase, broad, narrow, total, cpu, candidates, used),
                    flush=True)


if __name__ == '__main__':
    main()
