"""Timing runs: a scene stepped tick by tick at a fixed time step, summarised like the papers.

A tick is one call of ``World.step`` (poses in, sorted contacts out), timed from outside, so
it includes everything a caller pays. The scene's motion itself (``Scene.dynamic_poses``) is
computed between ticks and not timed: it stands for the simulation, not the collision check.
"""
import time

import numpy as np

from collision_node.obb import Boxes, set_boxes
from collision_node.sat import collide_pairs, COLLIDING
from collision_node.scenes import make_scene
from collision_node.world import World

# Each run is preceded by two ticks of the same configuration on a scene this small, so every
# kernel it calls is compiled (or loaded from numba's cache) before the clock starts.
WARM_UP_BODIES = 64
WARM_UP_TICKS = 2


def tick_poses(scene, ticks, dt):
    """Yield (tick, dynamic poses) at times 0, dt, 2 dt, ..."""
    for tick in range(ticks):
        yield tick, scene.dynamic_poses(tick * dt)


def summarize(tick_ms, planned_ticks, compared=(), **counts):
    """Summarise a run in the papers' columns: ticks per second (1/tick time), pairs compared.

    slowest = 1 / longest tick, quickest = 1 / shortest tick, average = ticks / total time.
    ``counts`` are per-tick series (candidate pairs, colliding pairs...): their min and max.
    """
    ms = np.asarray(tick_ms, dtype=np.float64)
    row = {
        'ticks': len(ms),
        'truncated': len(ms) < planned_ticks,
        'median_ms': float(np.median(ms)),
        'p99_ms': float(np.percentile(ms, 99)),
        'min_ms': float(ms.min()),
        'max_ms': float(ms.max()),
        'slowest_tps': 1e3 / float(ms.max()),
        'quickest_tps': 1e3 / float(ms.min()),
        'average_tps': 1e3 * len(ms) / float(ms.sum()),
    }
    for name, series in dict(counts, compared=compared).items():
        if len(series):
            row[name + '_min'] = int(np.min(series))
            row[name + '_max'] = int(np.max(series))
    return row


def run_world(scene, ticks, dt, budget_s, **world_options):
    """Step a ``World(**world_options)`` through ``ticks`` ticks of ``scene``.

    Stops early (``truncated``) once the run has taken ``budget_s`` seconds of wall time.
    """
    world = World(**world_options)
    world.set_static(scene.static_poses, scene.static_half_extents)
    tick_ms, stats = [], []
    started = time.perf_counter()
    for _, poses in tick_poses(scene, ticks, dt):
        before = time.perf_counter()
        result = world.step(poses, scene.dynamic_half_extents)
        tick_ms.append(1e3 * (time.perf_counter() - before))
        stats.append(result.stats)
        if time.perf_counter() - started > budget_s:
            break
    row = summarize(tick_ms, ticks,
                    compared=[s['compared'] for s in stats],
                    candidate_pairs=[s['candidate_pairs'] for s in stats],
                    sat_tests=[s['sat_tests'] for s in stats],
                    colliding=[s['colliding_pairs'] for s in stats])
    # Which phase ran: ``auto`` reports its pick in the stats.
    row['phases_used'] = sorted({s['broad_phase'] for s in stats})
    for stage in ('prepare', 'broad', 'narrow'):
        row[stage + '_ms'] = float(np.median([s[stage + '_ms'] for s in stats]))
    return row


def run_all_pairs_sat(scene, ticks, dt, budget_s):
    """Paper 000's baseline: the SAT on every dynamic-static and dynamic-dynamic pair."""
    n_static = len(scene.static_poses)
    n_dynamic = scene.dynamic_count
    boxes = Boxes(n_static + n_dynamic)
    set_boxes(boxes, 0, scene.static_poses, scene.static_half_extents)
    pairs = all_pairs(n_static, n_dynamic)
    tick_ms, colliding = [], []
    started = time.perf_counter()
    for _, poses in tick_poses(scene, ticks, dt):
        before = time.perf_counter()
        set_boxes(boxes, n_static, poses, scene.dynamic_half_extents)
        status = collide_pairs(boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii,
                               pairs, False)[0]
        tick_ms.append(1e3 * (time.perf_counter() - before))
        colliding.append(np.count_nonzero(status == COLLIDING))
        if time.perf_counter() - started > budget_s:
            break
    return summarize(tick_ms, ticks, compared=[len(pairs)] * len(tick_ms),
                     sat_tests=[len(pairs)] * len(tick_ms), colliding=colliding)


def all_pairs(n_static, n_dynamic):
    """Every pair with a dynamic row first: (dynamic, static) and (dynamic, earlier dynamic)."""
    n_total = n_static + n_dynamic
    first, second = np.triu_indices(n_total, 1)  # first < second
    keep = second >= n_static                     # at least one of them is dynamic
    return np.ascontiguousarray(np.stack([second[keep], first[keep]], axis=1))


def warmed(run, scene, ticks, dt, budget_s, **options):
    """``run(scene, ticks, dt, budget_s, **options)`` after a short run on a tiny scene.

    The tiny scene is of the same kind, so the same kernels with the same types are called.
    """
    run(make_scene(scene.name, WARM_UP_BODIES), WARM_UP_TICKS, dt, budget_s, **options)
    return run(scene, ticks, dt, budget_s, **options)
