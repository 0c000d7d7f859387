"""sat_cost: what the SAT costs per pair, by verdict, on one tick's own candidate pairs.

    python -m collision_node.benchmarks.sat_cost --bodies 10000

The uniform scene (half static) steps a few ticks in a World; the candidate pairs of the last
tick (the default broad phase, oriented and ordered as the World does) are then timed through
``collide_pairs`` as a whole, and split by verdict: the colliding pairs (15 axes and a
contact point each, work every exact answer needs) and the others (a separating axis found,
or rejected by the sphere prefilter). The second share bounds what a separating-axis cache
could ever save.
"""
import argparse
import time

import numpy as np

from collision_node.benchmarks.collision_bench import machine
from collision_node.pipeline.sat import collide_pairs, COLLIDING, empty_output
from collision_node.pipeline.scenes import uniform
from collision_node.pipeline.warm_up import warm_up
from collision_node.pipeline.world import World

SETTLE_TICKS = 10


def sat_cost(bodies, repeats=30, seed=0):
    """Return {'all' | 'colliding' | 'other': (pairs, median ms)} for one tick's pairs."""
    scene = uniform(bodies, seed)
    world = World()
    world.set_static(scene.static_poses, scene.static_half_extents)
    for tick in range(SETTLE_TICKS):
        world.step(scene.dynamic_poses(tick / 60), scene.dynamic_half_extents)
    path = world._steps.general
    boxes, n_static = path.boxes, world.static_count
    pairs, _ = path.phase.find_pairs(boxes, n_static, scene.dynamic_count)
    pairs = path._oriented(pairs).copy()
    status = _run(boxes, pairs)[0]
    costs = {}
    for name, subset in (('all', pairs), ('colliding', pairs[status == COLLIDING]),
                         ('other', pairs[status != COLLIDING])):
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            _run(boxes, subset)
            times.append(time.perf_counter() - start)
        costs[name] = (len(subset), 1e3 * float(np.median(times)))
    return costs


def _run(boxes, pairs):
    output = [array[:len(pairs)] for array in empty_output(len(pairs))]
    collide_pairs(boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii, pairs,
                  True, output, 0.0, None)
    return output


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--bodies', type=int, nargs='+', default=[10000])
    args = parser.parse_args(argv)
    warm_up()
    info = machine()
    print('%s (%d cores), commit %s' % (info['cpu'], info['cores'], info['commit']))
    for bodies in args.bodies:
        for name, (pairs, ms) in sat_cost(bodies).items():
            print('%7d bodies, %-9s %7d pairs: %.3f ms, %.0f ns a pair'
                  % (bodies, name, pairs, ms, 1e6 * ms / max(pairs, 1)))


if __name__ == '__main__':
    main()
