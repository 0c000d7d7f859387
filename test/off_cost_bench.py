"""What continuous checking costs when it is off: World.step before and after, A/B.

    git archive c2b1d71 | tar -x -C /tmp/before    # the tree before continuous checking
    .venv/bin/python test/off_cost_bench.py /tmp/before . --rounds 10 --ticks 150

Each round runs one process per tree, alternately (two copies of the package in one process
compile differently and measure their import order, not their code): the median
World.step of the uniform scene, 10,000 bodies half static, default phase, continuous off.
"""
import argparse
import os
import subprocess
import sys

import numpy as np

ONE_RUN = """
import sys, time
import numpy as np
from collision_node.pipeline.scenes import uniform
from collision_node.pipeline.world import warm_up, World
warm_up()
scene = uniform(10000, seed=0)
world = World()
world.set_static(scene.static_poses, scene.static_half_extents)
times = []
for tick in range(%d):
    poses = scene.dynamic_poses(tick / 60)
    start = time.perf_counter()
    world.step(poses, scene.dynamic_half_extents)
    times.append(time.perf_counter() - start)
print(1e3 * np.median(times[3:]))
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('before')
    parser.add_argument('after')
    parser.add_argument('--rounds', type=int, default=10)
    parser.add_argument('--ticks', type=int, default=150)
    args = parser.parse_args()
    medians = {args.before: [], args.after: []}
    for _ in range(args.rounds):
        for tree in (args.before, args.after):
            env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
            out = subprocess.run([sys.executable, '-c', ONE_RUN % args.ticks], env=env,
                                 capture_output=True, text=True, check=True, cwd='/')
            medians[tree].append(float(out.stdout))
    before, after = (np.array(medians[tree]) for tree in (args.before, args.after))
    print('before: %s ms' % ' '.join('%.3f' % m for m in before))
    print('after:  %s ms' % ' '.join('%.3f' % m for m in after))
    print('median of the medians %.3f -> %.3f ms (%+.1f %%); mean %+.1f %%' % (
        np.median(before), np.median(after), 100 * (np.median(after) / np.median(before) - 1),
        100 * (after.mean() / before.mean() - 1)))


if __name__ == '__main__':
    main()
