"""The World's tick against an earlier commit's, in alternating processes (a developer's tool).

For whoever changes this package: it answers "did my change cost time?", so it is not a console
script and the user documentation leaves it out; its results belong in commit messages.

    python -m collision_node.benchmarks.against_commit --base d153dac
    python -m collision_node.benchmarks.against_commit --base HEAD~3 --bodies 1000 --rounds 10
    python -m collision_node.benchmarks.against_commit --base b59f077 --cases low_motion:10000 \
        flying_out:1024 --stages

A change must often cost nothing where it does not apply (a margin of 0, continuous checking
off). Two versions of the package cannot share one process (same module names), and a timing
of each taken minutes apart mostly measures the machine's mood, so the two take turns: each
round runs one process per version, in alternating order, each timing ``World.step`` on the
uniform scene (half static, default settings) for the given sizes, and on the ``--cases``
(CHILD lists the scenes). The verdict is the median
over rounds of the per-round ratio (this tree / base), which cancels the drift a shared VM
shows between rounds.

The base is exported with ``git archive`` into a temporary directory; a first untimed process
per version fills its numba cache, so no round pays compile time. The child only uses
``World``, ``warm_up`` and ``scenes.uniform``, ``flying_out`` and ``arm``, which every compared
version has (``arm`` since the one pass).
"""
import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

import collision_node
from collision_node.benchmarks.collision_bench import machine

REPO = pathlib.Path(collision_node.__file__).resolve().parent.parent

# Run in each version's process: median ms of World.step and of its stages per case, as JSON.
# A case is "scene:bodies"; the scenes (scenes.py's, driven here so that every compared
# version sees the same inputs):
#   uniform     the uniform scene, half static, at 60 Hz
#   low_motion  the same, one dynamic body in ten moving, the others still
#   flying_out  the "Discrete Collision Algorithms" scene, no static bodies, flying apart,
#               at 12 Hz
#   teleport    the uniform scene's bodies at a random time each tick (no coherence at all)
#   count       the uniform scene with one body more or fewer every tick
#   arm         the arm of config/arm.yaml (its 7 links, whatever the bodies; its margins and
#               filters) at 60 Hz: a small scene, the one pass
CHILD = """
import json, sys, time
import numpy as np
from collision_node import World, warm_up
from collision_node.pipeline import scenes
warm_up()
STAGES = ('prepare_ms', 'broad_ms', 'narrow_ms')
def inputs(name, scene, k):
    extents = scene.dynamic_half_extents
    if name == 'flying_out':
        return scene.dynamic_poses(k / 12), extents
    if name == 'low_motion':
        poses = scene.dynamic_poses(0.0)
        poses[::10] = scene.dynamic_poses(k / 60)[::10]
    elif name == 'teleport':
        poses = scene.dynamic_poses(np.random.default_rng(k).uniform(0, 60))
    elif name == 'count':
        poses = scene.dynamic_poses(k / 60)[:scene.dynamic_count - k % 2]
        extents = extents[:len(poses)]
    else:
        poses = scene.dynamic_poses(k / 60)
    return poses, extents
medians = {}
sizes, threads = json.loads(sys.argv[1])
for case, ticks in sizes:
    name, n = case.split(':')
    scene = scenes.flying_out(int(n), 0) if name == 'flying_out' else scenes.arm() \
        if name == 'arm' else scenes.uniform(int(n), 0)
    world = World(threads=threads, margin=0.05 if name == 'arm' else 0.0)
    if name == 'arm':
        world.set_static(scene.static_poses, scene.static_half_extents,
                         margins=[0.0, 0.0, 0.05])
        world.set_filters(ignored_pairs=[(i, 0, i + 1, 0) for i in range(6)] + [(0, 0, 0, 1)])
    elif name != 'flying_out':
        world.set_static(scene.static_poses, scene.static_half_extents)
    times = []
    stages = []
    for k in range(5 + ticks):
        poses, extents = inputs(name, scene, k)
        start = time.perf_counter()
        stats = world.step(poses, extents).stats
        times.append(time.perf_counter() - start)
        stages.append([stats[stage] for stage in STAGES])
    row = {'tick': 1e3 * float(np.median(times[5:]))}
    row.update(zip(STAGES, np.median(stages[5:], axis=0).tolist()))
    medians[case] = row
    world.close()
print(json.dumps(medians))
"""


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--base', required=True, help='the commit to compare with (git ref)')
    parser.add_argument('--bodies', type=int, nargs='+', default=[1000, 10000],
                        help='sizes of the uniform scene')
    parser.add_argument('--cases', nargs='+', default=[],
                        help='more cases, scene:bodies (scenes: %s)' % ', '.join(SCENE_NAMES))
    parser.add_argument('--rounds', type=int, default=6)
    parser.add_argument('--tick-budget', type=float, default=600.0,
                        help='ms of ticks per case and process (more ticks for small sizes)')
    parser.add_argument('--threads', type=int, default=1,
                        help="the World's threads in both trees (default 1)")
    parser.add_argument('--stages', action='store_true',
                        help='also print the median stage times (World.step stats) per case')
    args = parser.parse_args(argv)
    cases = ['uniform:%d' % n for n in args.bodies] + args.cases
    for case in cases:
        name, _, bodies = case.partition(':')
        if name not in SCENE_NAMES or not bodies.isdigit():
            parser.error('case %r: give scene:bodies, scene one of %s'
                         % (case, ', '.join(SCENE_NAMES)))
    with tempfile.TemporaryDirectory(prefix='against_commit_') as base_tree:
        export(args.base, base_tree)
        trees = {'base': base_tree, 'this': str(REPO)}
        sizes = [(case, ticks_for(int(case.split(':')[1]), args.tick_budget))
                 for case in cases]
        for tree in trees.values():  # compile into each tree's cache, untimed
            run_child(tree, [(case, 1) for case in cases], args.threads)
        rounds = []
        for k in range(args.rounds):
            order = ('base', 'this') if k % 2 == 0 else ('this', 'base')
            rounds.append({name: run_child(trees[name], sizes, args.threads) for name in order})
            base, this = rounds[-1]['base'], rounds[-1]['this']
            print('round %d: %s' % (k + 1, '  '.join(
                '%s: base %.4f this %.4f ms' % (case, base[case]['tick'], this[case]['tick'])
                for case in cases)), flush=True)
    info = machine()
    print('\n%s (%d cores); this tree %s, base %s, %d rounds, %d thread(s)'
          % (info['cpu'], info['cores'], info['commit'], args.base, args.rounds, args.threads))
    for case, ratios in summary(rounds, cases).items():
        print('%16s: this / base per round %s; median %.3f'
              % (case, ' '.join('%.3f' % r for r in ratios), statistics.median(ratios)))
    if args.stages:
        print('\nmedian ms over rounds | %s' % ' | '.join(
            '%s base | %s this' % (stage, stage) for stage in STAGE_NAMES))
        for case in cases:
            print('%16s | %s' % (case, ' | '.join(
                '%.3f | %.3f' % tuple(statistics.median(r[tree][case][stage] for r in rounds)
                                      for tree in ('base', 'this'))
                for stage in STAGE_KEYS)))


SCENE_NAMES = ('uniform', 'low_motion', 'flying_out', 'teleport', 'count', 'arm')
STAGE_KEYS = ('tick', 'prepare_ms', 'broad_ms', 'narrow_ms')
STAGE_NAMES = ('tick', 'prepare', 'broad', 'narrow')


def summary(rounds, cases):
    """Return {case: [this / base tick of each round]} from the rounds' medians."""
    return {case: [r['this'][case]['tick'] / r['base'][case]['tick'] for r in rounds]
            for case in cases}


def ticks_for(bodies, budget_ms):
    """Return how many ticks fill ``budget_ms`` at about 0.5 µs per body, at least 20."""
    return max(20, int(budget_ms / (0.0005 * bodies)))


def export(ref, directory):
    """Write the package of commit ``ref`` into ``directory``."""
    archive = subprocess.run(['git', '-C', str(REPO), 'archive', ref, 'collision_node'],
                             check=True, capture_output=True).stdout
    subprocess.run(['tar', '-x', '-C', directory], input=archive, check=True)


def run_child(tree, sizes, threads):
    """Return {case: {stage: median ms}} of World.step, timed in a process importing ``tree``."""
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, '-c', CHILD, json.dumps([sizes, threads])], env=env,
                         cwd=tree, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


if __name__ == '__main__':
    main()
