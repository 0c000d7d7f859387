"""Timing runs: a scene stepped tick by tick at a fixed time step, summarised like the papers.

A tick is one call of ``World.step`` (poses in, sorted contacts out), timed from outside, so
it includes everything a caller pays. The scene's motion itself (``Scene.dynamic_poses``) is
computed between ticks and not timed: it stands for the simulation, not the collision check.
"""
import math
import time
from typing import NamedTuple

import numpy as np

from collision_node.pipeline.obb import Boxes, set_boxes
from collision_node.pipeline.sat import collide_pairs, COLLIDING
from collision_node.pipeline.scenes import make_scene
from collision_node.pipeline.world import World

# Each run is preceded by two ticks of the same configuration on a scene this small, so every
# kernel it calls is compiled (or loaded from numba's cache) before the clock starts.
WARM_UP_BODIES = 64
WARM_UP_TICKS = 2


class Limits(NamedTuple):
    """When a run stops early.

    Once it has used ``budget_s`` seconds of wall time, or right after one tick longer than
    ``tick_s`` (a tick cannot be interrupted, only not repeated).
    """

    budget_s: float
    tick_s: float = math.inf

    def reason_to_stop(self, started, tick_s):
        """Why a run that began at ``started`` should stop after a tick of ``tick_s``, or None."""
        if tick_s > self.tick_s:
            return 'stopped: a tick took %.3g s' % tick_s
        if time.perf_counter() - started > self.budget_s:
            return 'stopped: %g s budget used' % self.budget_s
        return None


def tick_poses(scene, ticks, dt):
    """Yield (tick, dynamic poses) at times 0, dt, 2 dt, ..."""
    for tick in range(ticks):
        yield tick, scene.dynamic_poses(tick * dt)


def summarize(tick_ms, planned_ticks, stopped=None, compared=(), **counts):
    """Summarise a run in the papers' columns: ticks per second (1/tick time), pairs compared.

    slowest = 1 / longest tick, quickest = 1 / shortest tick, average = ticks / total time.
    ``counts`` are per-tick series (candidate pairs, colliding pairs...): their min and max.
    ``stopped`` says why the run ended before ``planned_ticks``.
    """
    ms = np.asarray(tick_ms, dtype=np.float64)
    row = {
        'ticks': len(ms),
        'truncated': len(ms) < planned_ticks,
        'stopped': stopped if len(ms) < planned_ticks else None,
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


def run_world(scene, ticks, dt, limits, **world_options):
    """Step a ``World(**world_options)`` through ``ticks`` ticks of ``scene``.

    Stops early (``truncated``) when the :class:`Limits` say so.
    """
    world = World(**world_options)
    world.set_static(scene.static_poses, scene.static_half_extents)
    tick_ms, stats = [], []
    started = time.perf_counter()
    stopped = None
    for _, poses in tick_poses(scene, ticks, dt):
        before = time.perf_counter()
        result = world.step(poses, scene.dynamic_half_extents)
        tick_ms.append(1e3 * (time.perf_counter() - before))
        stats.append(result.stats)
        stopped = limits.reason_to_stop(started, 1e-3 * tick_ms[-1])
        if stopped:
            break
    world.close()
    row = summarize(tick_ms, ticks, stopped,
                    compared=[s['compared'] for s in stats],
                    candidate_pairs=[s['candidate_pairs'] for s in stats],
                    sat_tests=[s['sat_tests'] for s in stats],
                    colliding=[s['colliding_pairs'] for s in stats])
    # Which phase ran: ``auto`` reports its pick in the stats.
    row['phases_used'] = sorted({s['broad_phase'] for s in stats})
    for stage in ('prepare', 'broad', 'narrow'):
        row[stage + '_ms'] = float(np.median([s[stage + '_ms'] for s in stats]))
    return row


def run_all_pairs_sat(scene, ticks, dt, limits):
    """Run the baseline of "Engine Algorithms": the SAT on every pair with a dynamic body."""
    n_static = len(scene.static_poses)
    n_dynamic = scene.dynamic_count
    boxes = Boxes(n_static + n_dynamic)
    set_boxes(boxes, 0, scene.static_poses, scene.static_half_extents)
    pairs = all_pairs(n_static, n_dynamic)
    tick_ms, colliding = [], []
    started = time.perf_counter()
    stopped = None
    for _, poses in tick_poses(scene, ticks, dt):
        before = time.perf_counter()
        set_boxes(boxes, n_static, poses, scene.dynamic_half_extents)
        status = collide_pairs(boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii,
                               pairs, False)[0]
        tick_ms.append(1e3 * (time.perf_counter() - before))
        colliding.append(np.count_nonzero(status == COLLIDING))
        stopped = limits.reason_to_stop(started, 1e-3 * tick_ms[-1])
        if stopped:
            break
    return summarize(tick_ms, ticks, stopped, compared=[len(pairs)] * len(tick_ms),
                     sat_tests=[len(pairs)] * len(tick_ms), colliding=colliding)


def all_pairs(n_static, n_dynamic):
    """Every pair with a dynamic row first: (dynamic, static) and (dynamic, earlier dynamic)."""
    n_total = n_static + n_dynamic
    first, second = np.triu_indices(n_total, 1)  # first < second
    keep = second >= n_static                     # at least one of them is dynamic
    return np.ascontiguousarray(np.stack([second[keep], first[keep]], axis=1))


def warmed(run, scene, ticks, dt, limits, **options):
    """``run(scene, ticks, dt, limits, **options)`` after a short run on a tiny scene.

    The tiny scene is of the same kind, so the same kernels with the same types are called.
    """
    run(make_scene(scene.name, WARM_UP_BODIES), WARM_UP_TICKS, dt, limits, **options)
    return run(scene, ticks, dt, limits, **options)
