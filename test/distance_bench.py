"""Time per pair of distance.box_distance on random near pairs.

    python test/distance_bench.py [--pairs 100000] [--repeats 20] [--seed 0]

The pairs are what the SAT kernel will hand over: separated by at most a margin. Random
orientations, half extents 0.05 to 0.5 m, B's centre in a random direction, kept when the
SAT finds the pair separated and the distance is below 0.2 m (about half the boxes' size).
The inputs are laid out as (rel, t, ea, eb) arrays; one compiled loop calls the kernel on
each pair and sums the distances (so nothing is optimised away). Prints the median and the
best nanoseconds per pair over the repeats, and the same for sat.separating_axis_test on the
same pairs for scale.

The timing loops live in this file, and numba's cache does not notice a change in a function
they call from another file: each run compiles into a fresh cache directory (~5 s) unless
NUMBA_CACHE_DIR is set.
"""
import argparse
import os
import sys
import tempfile
import time

import numpy as np

if 'NUMBA_CACHE_DIR' not in os.environ:
    FRESH_CACHE = tempfile.TemporaryDirectory(prefix='distance_bench-')  # removed at exit
    os.environ['NUMBA_CACHE_DIR'] = FRESH_CACHE.name
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from collision_node.pipeline import sat  # noqa: E402 (after the path set-up)
from collision_node.pipeline._jit import kernel  # noqa: E402
from collision_node.pipeline.distance import box_distance  # noqa: E402
from collision_node.pipeline.obb import EPS, TIE_ULPS  # noqa: E402

MARGIN = 0.2  # metres: the pairs kept are separated by less


def rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    x, y, z, w = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                     2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                     2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
                    axis=1).reshape(n, 3, 3)


def near_pairs(count, seed):
    """Return (rel (N, 9), t (N, 3), ea (N, 3), eb (N, 3)) of separated pairs near each other."""
    rng = np.random.default_rng(seed)
    kept = []
    while sum(len(k[0]) for k in kept) < count:
        n = 2 * count
        ra, rb = rotations(rng, n), rotations(rng, n)
        ea, eb = rng.uniform(0.05, 0.5, (n, 3)), rng.uniform(0.05, 0.5, (n, 3))
        direction = rng.normal(size=(n, 3))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        d = direction * rng.uniform(0.1, 1.2, (n, 1))
        rel = np.einsum('nki,nkj->nij', ra, rb).reshape(n, 9)
        t = np.einsum('nki,nk->ni', ra, d)
        distance = _distances(rel, t, ea, eb, np.zeros(n))
        keep = (distance > 0.0) & (distance < MARGIN)
        kept.append((rel[keep], t[keep], ea[keep], eb[keep]))
    return tuple(np.ascontiguousarray(np.concatenate(part)[:count]) for part in zip(*kept))


@kernel
def _distances(rel, t, ea, eb, out):
    """Distances of the pairs; 0 where the SAT finds them colliding."""
    for k in range(rel.shape[0]):
        r = (rel[k, 0], rel[k, 1], rel[k, 2], rel[k, 3], rel[k, 4], rel[k, 5], rel[k, 6],
             rel[k, 7], rel[k, 8])
        tk = (t[k, 0], t[k, 1], t[k, 2])
        a = (ea[k, 0], ea[k, 1], ea[k, 2])
        b = (eb[k, 0], eb[k, 1], eb[k, 2])
        tie = TIE_ULPS * EPS * (a[0] + a[1] + a[2] + b[0] + b[1] + b[2])
        if sat.separating_axis_test(r, tk, a, b, tie, None)[0] == sat.COLLIDING:
            out[k] = 0.0
        else:
            out[k] = box_distance(r, tk, a, b)[0]
    return out


@kernel
def _time_distance(rel, t, ea, eb):
    total = 0.0
    for k in range(rel.shape[0]):
        r = (rel[k, 0], rel[k, 1], rel[k, 2], rel[k, 3], rel[k, 4], rel[k, 5], rel[k, 6],
             rel[k, 7], rel[k, 8])
        distance, p, q, _ = box_distance(r, (t[k, 0], t[k, 1], t[k, 2]),
                                         (ea[k, 0], ea[k, 1], ea[k, 2]),
                                         (eb[k, 0], eb[k, 1], eb[k, 2]))
        total += distance + p[0] + q[0]
    return total


@kernel
def _time_sat(rel, t, ea, eb):
    total = 0.0
    for k in range(rel.shape[0]):
        r = (rel[k, 0], rel[k, 1], rel[k, 2], rel[k, 3], rel[k, 4], rel[k, 5], rel[k, 6],
             rel[k, 7], rel[k, 8])
        total += sat.separating_axis_test(r, (t[k, 0], t[k, 1], t[k, 2]),
                                          (ea[k, 0], ea[k, 1], ea[k, 2]),
                                          (eb[k, 0], eb[k, 1], eb[k, 2]), 1e-14, None)[1]
    return total


def nanoseconds_per_pair(function, inputs, repeats):
    function(*inputs)  # compile or load
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function(*inputs)
        times.append(time.perf_counter() - start)
    per_pair = 1e9 * np.array(times) / len(inputs[0])
    return float(np.median(per_pair)), float(per_pair.min())


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--pairs', type=int, default=100000)
    parser.add_argument('--repeats', type=int, default=20)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    inputs = near_pairs(args.pairs, args.seed)
    for name, function in (('box_distance', _time_distance),
                           ('sat.separating_axis_test', _time_sat)):
        median, best = nanoseconds_per_pair(function, inputs, args.repeats)
        print('%-28s %7.1f ns/pair median, %7.1f best (%d pairs, %d repeats)'
              % (name, median, best, args.pairs, args.repeats))


if __name__ == '__main__':
    main()
