"""The World's tick against an earlier commit's, in alternating processes.

    python -m collision_node.benchmarks.against_commit --base d153dac
    python -m collision_node.benchmarks.against_commit --base HEAD~3 --bodies 1000 --rounds 10

A change must often cost nothing where it does not apply (a margin of 0, continuous checking
off). Two versions of the package cannot share one process (same module names), and a timing
of each taken minutes apart mostly measures the machine's mood, so the two take turns: each
round runs one process per version, in alternating order, each timing ``World.step`` on the
uniform scene (half static, default settings) for the given sizes. The verdict is the median
over rounds of the per-round ratio (this tree / base), which cancels the drift a shared VM
shows between rounds.

The base is exported with ``git archive`` into a temporary directory; a first untimed process
per version fills its numba cache, so no round pays compile time. The child only uses
``World``, ``warm_up`` and ``scenes.uniform``, which every compared version has.
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

# Run in each version's process: median ms of World.step per size, as JSON.
CHILD = """
import json, sys, time
import numpy as np
from collision_node import World, warm_up
from collision_node.pipeline.scenes import uniform
warm_up()
medians = {}
for n, ticks in json.loads(sys.argv[1]):
    scene = uniform(n, 0)
    world = World()
    world.set_static(scene.static_poses, scene.static_half_extents)
    times = []
    for k in range(5 + ticks):
        poses = scene.dynamic_poses(k / 60)
        start = time.perf_counter()
        world.step(poses, scene.dynamic_half_extents)
        times.append(time.perf_counter() - start)
    medians[n] = 1e3 * float(np.median(times[5:]))
print(json.dumps(medians))
"""


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--base', required=True, help='the commit to compare with (git ref)')
    parser.add_argument('--bodies', type=int, nargs='+', default=[1000, 10000])
    parser.add_argument('--rounds', type=int, default=6)
    parser.add_argument('--tick-budget', type=float, default=600.0,
                        help='ms of ticks per size and process (more ticks for small sizes)')
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix='against_commit_') as base_tree:
        export(args.base, base_tree)
        trees = {'base': base_tree, 'this': str(REPO)}
        sizes = [(n, ticks_for(n, args.tick_budget)) for n in args.bodies]
        for tree in trees.values():  # compile into each tree's cache, untimed
            run_child(tree, [(n, 1) for n in args.bodies])
        rounds = []
        for k in range(args.rounds):
            order = ('base', 'this') if k % 2 == 0 else ('this', 'base')
            rounds.append({name: run_child(trees[name], sizes) for name in order})
            base, this = rounds[-1]['base'], rounds[-1]['this']
            print('round %d: %s' % (k + 1, '  '.join(
                '%d: base %.4f this %.4f ms' % (n, base[str(n)], this[str(n)])
                for n in args.bodies)), flush=True)
    info = machine()
    print('\n%s (%d cores); this tree %s, base %s, %d rounds'
          % (info['cpu'], info['cores'], info['commit'], args.base, args.rounds))
    for n, ratios in summary(rounds, args.bodies).items():
        print('%7d bodies: this / base per round %s; median %.3f'
              % (n, ' '.join('%.3f' % r for r in ratios), statistics.median(ratios)))


def summary(rounds, bodies):
    """Return {bodies: [this / base of each round]} from the rounds' medians."""
    return {n: [r['this'][str(n)] / r['base'][str(n)] for r in rounds] for n in bodies}


def ticks_for(bodies, budget_ms):
    """Return how many ticks fill ``budget_ms`` at about 0.5 µs per body, at least 20."""
    return max(20, int(budget_ms / (0.0005 * bodies)))


def export(ref, directory):
    """Write the package of commit ``ref`` into ``directory``."""
    archive = subprocess.run(['git', '-C', str(REPO), 'archive', ref, 'collision_node'],
                             check=True, capture_output=True).stdout
    subprocess.run(['tar', '-x', '-C', directory], input=archive, check=True)


def run_child(tree, sizes):
    """Return {str(bodies): median ms} of World.step, timed in a process importing ``tree``."""
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, '-c', CHILD, json.dumps(sizes)], env=env, cwd=tree,
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


if __name__ == '__main__':
    main()
