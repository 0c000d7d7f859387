"""Per-tick time of every broad phase through World.step, and the studies doc/ cites.

    python test/broadphase_bench.py [--sizes 1000 10000 100000] [--scenes uniform ...]
    python test/broadphase_bench.py --study kd_tree   # rebuild or refit (kd_tree docstring)
    python test/broadphase_bench.py --study octree    # depth rules (octree docstring)

Prints one row per (scene, bodies, phase): median broad, narrow and broad + narrow
milliseconds per tick (World's wall-clock stage timings) over the measured ticks (the first,
which builds the structures and may compile, is not counted), the median CPU milliseconds of
the whole ``World.step`` (``time.process_time``: less disturbed when other processes share the
cores), the median candidate pairs and the phase that ran (what ``auto`` chose). A phase
whose first tick takes longer than ``--give-up`` seconds is skipped at that size and beyond.
Scenes come from ``collision_node.pipeline.scenes`` (the lead's benchmark scenes): ``uniform`` and
``clustered`` have half of the bodies static; ``flying_out`` is the "Discrete Collision
Algorithms" scene, measured over its first ``--seconds`` seconds (dense at first, sparse later).
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from collision_node import World  # noqa: E402 (after the path set-up)
from collision_node.pipeline import scenes  # noqa: E402 (after the path set-up)
from collision_node.pipeline.broadphase import NAMES, Settings  # noqa: E402
from collision_node.pipeline.broadphase.kd_tree import KdTreePhase  # noqa: E402
from collision_node.pipeline.broadphase.octree import Octree  # noqa: E402
from collision_node.pipeline.obb import Boxes, set_boxes  # noqa: E402

# (scene, bodies, ticks, seconds per tick) of the two studies
STUDY_SCENES = [('flying_out', 1024, 300, 1 / 60), ('uniform', 1024, 60, 1 / 30),
                ('clustered', 1024, 60, 1 / 30), ('flying_out', 10000, 60, 1 / 15),
                ('uniform', 10000, 100, 1 / 30), ('clustered', 10000, 100, 1 / 30)]


def phase_cpu_ms(scene, phase, ticks, dt):
    """CPU ms per tick of ``phase.find_pairs`` alone over ``ticks`` ticks after the first."""
    n_static, n_dynamic = len(scene.static_poses), scene.dynamic_count
    boxes = Boxes(n_static + n_dynamic)
    if n_static:
        set_boxes(boxes, 0, scene.static_poses, scene.static_half_extents)
    phase.set_static(boxes, n_static)
    total = 0.0
    for tick in range(ticks + 1):
        set_boxes(boxes, n_static, scene.dynamic_poses(dt * tick), scene.dynamic_half_extents)
        start = time.process_time()
        phase.find_pairs(boxes, n_static, n_dynamic)
        total += (time.process_time() - start) if tick else 0.0
    return 1e3 * total / ticks


def study(name):
    for scene_name, n, ticks, dt in STUDY_SCENES:
        scene = scenes.make_scene(scene_name, n)
        if name == 'kd_tree':
            cells = []
            for label, ratio in [('rebuild', 1.0), ('refit', float('inf')), ('adaptive', None)]:
                phase = KdTreePhase() if ratio is None else KdTreePhase(rebuild_ratio=ratio)
                ms = phase_cpu_ms(scene, phase, ticks, dt)
                cells.append('%s %.2f ms (%d builds)' % (label, ms, phase.stats['builds']))
        else:
            cells = []
            for label, depth, rule in ([('paper', 0, 'paper'), ('size', 0, 'size')]
                                       + [(str(d), d, 'size') for d in range(2, 8)]):
                phase = Octree(Settings(depth, 15), depth_rule=rule)
                ms = phase_cpu_ms(scene, phase, ticks, dt)
                cells.append('%s %.2f (depth %d)' % (label, ms, phase.stats['depth']))
        print('%-10s %6d  %s' % (scene_name, n, ';  '.join(cells)), flush=True)


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
    parser.add_argument('--study', choices=['kd_tree', 'octree'],
                        help="CPU ms of one phase's variants instead of the table")
    args = parser.parse_args()
    if args.study:
        study(args.study)
        return
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
