"""Where a tick's time goes, at the sizes of the performance targets.

Two views of the same ticks: the stage timings the World reports in ``Result.stats``
(prepare = input checks + set_boxes, broad, narrow = SAT + contact assembly, other = the
rest of ``step`` as seen from outside), and the same pipeline rebuilt from the public pieces
and timed stage by stage (set_boxes, find_pairs, the SAT with the sphere prefilter, contact
assembly), which splits the World's stages further. The replica keeps the boxes in input
order; the World sorts its rows along a Z-order curve, so at sizes where the box arrays
outgrow the caches its narrow phase beats the replica's SAT.
"""
import time

import numpy as np

from collision_node.pipeline.broadphase import make_broad_phase, Settings
from collision_node.pipeline.contacts import assemble_contacts
from collision_node.pipeline.obb import Boxes, set_boxes
from collision_node.pipeline.sat import collide_pairs
from collision_node.pipeline.world import World

WORLD_STAGES = ('tick', 'prepare', 'broad', 'narrow', 'other')
# Untimed ticks first, so the profile shows the steady state of stateful phases: ``auto``
# holds a new choice for several ticks before switching, the octree builds its leaves.
# Settling also ends when it has used the run's time budget.
SETTLE_TICKS = 10
PIPELINE_STAGES = ('set_boxes', 'find_pairs', 'sat', 'contacts')


def profile_stages(scene, ticks, dt, limits, phase_name='auto'):
    """Median milliseconds per stage over the ticks, both views, keyed by stage name.

    The ticks timed follow up to SETTLE_TICKS untimed ones (fewer when they use up the time
    budget); ``limits`` (:class:`.runs.Limits`) stop the run early, and a settling tick over
    the tick limit skips it.
    """
    n_static = len(scene.static_poses)
    n_dynamic = scene.dynamic_count
    world = World(broad_phase=phase_name)
    world.set_static(scene.static_poses, scene.static_half_extents)
    boxes = Boxes(n_static + n_dynamic)
    set_boxes(boxes, 0, scene.static_poses, scene.static_half_extents)
    phase = make_broad_phase(phase_name, Settings())
    phase.set_static(boxes, n_static)
    static_ids = np.arange(n_static)
    ms = {stage: [] for stage in WORLD_STAGES + PIPELINE_STAGES}
    phases_used = set()
    settled = False
    started = time.perf_counter()
    stopped = None
    tick = 0
    while len(ms['tick']) < ticks:
        poses = scene.dynamic_poses(tick * dt)
        tick += 1
        before = time.perf_counter()
        stats = world.step(poses, scene.dynamic_half_extents).stats
        world_ms = 1e3 * (time.perf_counter() - before)
        times = [time.perf_counter()]
        set_boxes(boxes, n_static, poses, scene.dynamic_half_extents)
        times.append(time.perf_counter())
        pairs, _ = phase.find_pairs(boxes, n_static, n_dynamic)
        times.append(time.perf_counter())
        status, depth, normal, point, _ = collide_pairs(
            boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii, pairs, True)
        times.append(time.perf_counter())
        assemble_contacts(pairs, status, depth, normal, point, n_static, n_dynamic, static_ids)
        times.append(time.perf_counter())
        slowest_s = max(1e-3 * world_ms, times[-1] - times[0])

        if not settled:
            if slowest_s > limits.tick_s:
                return {'skipped': 'a settling (untimed) tick took %.3g s' % slowest_s}
            if tick >= SETTLE_TICKS or time.perf_counter() - started > limits.budget_s:
                settled = True
                started = time.perf_counter()
            continue
        phases_used.add(stats['broad_phase'])
        ms['tick'].append(world_ms)
        for stage in ('prepare', 'broad', 'narrow'):
            ms[stage].append(stats[stage + '_ms'])
        ms['other'].append(world_ms - stats['prepare_ms'] - stats['broad_ms']
                           - stats['narrow_ms'])
        for stage, begin, end in zip(PIPELINE_STAGES, times, times[1:]):
            ms[stage].append(1e3 * (end - begin))
        stopped = limits.reason_to_stop(started, slowest_s)
        if stopped:
            break
    row = {stage + '_ms': float(np.median(values)) for stage, values in ms.items()}
    row.update(scene=scene.name, bodies=n_static + n_dynamic, broad_phase=phase_name,
               phases_used=sorted(phases_used), ticks=len(ms['tick']),
               settling_ticks=tick - len(ms['tick']),
               stopped=stopped if len(ms['tick']) < ticks else None)
    return row
