"""Run time against error: every broad phase in every accuracy mode, against exact pairs.

Ground truth is the float64 SAT on every pair whose AABBs overlap (``World(broad_phase=
'brute_force')``): pairs with disjoint AABBs cannot collide, so this is the SAT on all pairs.
The modes, cheapest first, each counting as colliding:

``every compared pair (classic)``
    every pair the broad phase compared: the "classic" octree of "Discrete Collision Algorithms",
    which calls every pair sharing a leaf a collision. The phases do not return these pairs, only
    their number (``compared``: each pair sharing a leaf or cell once, as the octree and grid count
    them; every pair for brute force), so its false positives are counted as compared − true pairs,
    which assumes, as holds for every phase here, that the compared pairs include the true ones
    (the SAT float64 rows show they do: no false negatives);
``broad phase only``
    every candidate pair the broad phase returns (the phases here already drop the pairs
    whose AABBs, or for ``sphere`` bounding spheres, are apart);
``spheres only`` / ``AABBs only``
    the candidates whose bounding spheres / AABBs overlap (no SAT);
``SAT float32 boxes``
    the SAT kernel run on the boxes rounded to float32 (centres, rotations and extents, as a
    float32 pipeline would store them; the relative pose is then computed in float32);
``SAT float64``
    the World itself: broad phase, sphere prefilter and float64 SAT, as users get it.

Every mode reads the World's public calls only: the candidate pairs, their comparison count
and the boxes the SAT reads come from ``World.broad_phase_pairs`` (the pairs a discrete general
step's broad phase hands the SAT, computed on a scratch path of the World's own), and
``SAT float64`` times ``step`` on the same World (the call changes no step's state).

False positives and false negatives are pair-set differences against the ground truth, summed
over the ticks. Tick time is the ``broad_phase_pairs`` call (writing the dynamic boxes, the
broad phase's ``find_pairs``, and orienting and filtering its pairs, as a step does) + the
mode's test, timed stage by stage in one pass (the float32 rounding of the boxes is not timed:
a float32 pipeline would not pay it), and the World's whole ``step`` for ``SAT float64``.
"""
import time

import numpy as np

from collision_node.benchmarks.runs import tick_poses
from collision_node.pipeline._jit import kernel
from collision_node.pipeline.obb import aabbs_overlap, spheres_apart
from collision_node.pipeline.sat import collide_pairs, COLLIDING
from collision_node.pipeline.world import DYNAMIC, STATIC, World

CLASSIC = 'every compared pair (classic)'
BROAD_ONLY = 'broad phase only'
SPHERES_ONLY = 'spheres only'
AABBS_ONLY = 'AABBs only'
SAT_FLOAT32 = 'SAT float32 boxes'
SAT_FLOAT64 = 'SAT float64'
MODES = (CLASSIC, BROAD_ONLY, SPHERES_ONLY, AABBS_ONLY, SAT_FLOAT32, SAT_FLOAT64)
TRUTH_PHASE = 'brute_force'

_SPHERE_TEST = 0  # codes for _keep_close
_AABB_TEST = 1


def pair_keys(pairs, n_total):
    """Sorted unique int64 keys ``low row * n_total + high row`` of the pairs (P, 2)."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    low = np.minimum(pairs[:, 0], pairs[:, 1])
    high = np.maximum(pairs[:, 0], pairs[:, 1])
    return np.unique(low * n_total + high)


def contact_keys(contacts, n_static, n_total):
    """Pair keys of a World's contacts (static ids are the default 0..S-1, i.e. their rows)."""
    rows_a = contacts['id_a'].astype(np.int64) + n_static
    rows_b = contacts['id_b'].astype(np.int64) + np.where(contacts['type_b'] == STATIC, 0,
                                                          n_static)
    return pair_keys(np.stack([rows_a, rows_b], axis=1), n_total)


def row_keys(pairs, broad, n_static, n_total):
    """Pair keys of ``pairs`` (P, 2), rows of World.broad_phase_pairs' answer ``broad``.

    A row's key index is its collider id (the default ids 0..S-1) or S + its body index, as
    in :func:`contact_keys`.
    """
    index = broad.ids.astype(np.int64) + np.where(broad.types == DYNAMIC, n_static, 0)
    return pair_keys(index[np.asarray(pairs, np.int64).reshape(-1, 2)], n_total)


def pair_errors(found, truth):
    """Count (false positives, false negatives) of the key set ``found`` against ``truth``."""
    return (len(np.setdiff1d(found, truth, assume_unique=True)),
            len(np.setdiff1d(truth, found, assume_unique=True)))


@kernel
def _keep_close(pairs, aabbs, centers, radii, test, out):
    """Copy the pairs passing ``test`` (spheres or AABBs overlap) to ``out``; return count."""
    count = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        if test == _SPHERE_TEST:
            close = not spheres_apart(centers, radii, a, b)
        else:
            close = aabbs_overlap(aabbs, a, b)
        if close:
            out[count, 0] = a
            out[count, 1] = b
            count += 1
    return count


def ground_truth(scene, ticks, dt, budget_s):
    """Pair keys per tick from the float64 SAT on all AABB-overlapping pairs.

    Stops early once ``budget_s`` seconds have passed (however long a tick takes: the truth
    is brute force by design); the other modes then run as many ticks.
    """
    world = World(broad_phase=TRUTH_PHASE)
    world.set_static(scene.static_poses, scene.static_half_extents)
    n_static = len(scene.static_poses)
    n_total = n_static + scene.dynamic_count
    truth = []
    started = time.perf_counter()
    for _, poses in tick_poses(scene, ticks, dt):
        contacts = world.step(poses, scene.dynamic_half_extents).contacts
        truth.append(contact_keys(contacts, n_static, n_total))
        if time.perf_counter() - started > budget_s:
            break
    return truth


def measure_modes(scene, dt, truth, phase_name):
    """Errors and tick times of each mode for one broad phase, over the ticks of ``truth``.

    Only the World's public calls: ``broad_phase_pairs`` for the candidates and the boxes the
    SAT reads, ``step`` for SAT float64. Returns ({mode: {'false_positives',
    'false_negatives', 'tick_ms' (list)}}, the broad phase's pair comparisons per tick (list)).
    """
    n_static = len(scene.static_poses)
    n_total = n_static + scene.dynamic_count
    world = World(broad_phase=phase_name)  # broad_phase_pairs leaves its steps' state alone
    world.set_static(scene.static_poses, scene.static_half_extents)
    out = {mode: {'false_positives': 0, 'false_negatives': 0, 'tick_ms': []} for mode in MODES}
    kept = np.empty((0, 2), np.int64)
    compared = []

    def record(mode, found, ms, tick):  # found: (P, 2) rows of ``broad``
        errors = pair_errors(row_keys(found, broad, n_static, n_total), truth[tick])
        out[mode]['false_positives'] += errors[0]
        out[mode]['false_negatives'] += errors[1]
        out[mode]['tick_ms'].append(ms)

    for tick, poses in tick_poses(scene, len(truth), dt):
        start = time.perf_counter()
        broad = world.broad_phase_pairs(poses, scene.dynamic_half_extents)
        broad_ms = 1e3 * (time.perf_counter() - start)
        pairs, boxes = broad.pairs, broad.boxes
        compared.append(broad.compared)
        record(BROAD_ONLY, pairs, broad_ms, tick)
        out[CLASSIC]['false_positives'] += broad.compared - len(truth[tick])
        out[CLASSIC]['tick_ms'].append(broad_ms)

        if len(kept) < len(pairs):
            kept = np.empty((len(pairs), 2), np.int64)
        for mode, test in ((SPHERES_ONLY, _SPHERE_TEST), (AABBS_ONLY, _AABB_TEST)):
            before = time.perf_counter()
            count = _keep_close(pairs, boxes.aabbs, boxes.centers, boxes.radii, test, kept)
            record(mode, kept[:count], broad_ms + 1e3 * (time.perf_counter() - before), tick)

        rounded = [np.asarray(array, dtype=np.float32) for array in (
            boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii)]
        before = time.perf_counter()
        status = collide_pairs(*rounded, pairs, False)[0]
        ms = broad_ms + 1e3 * (time.perf_counter() - before)
        record(SAT_FLOAT32, pairs[status == COLLIDING], ms, tick)

        before = time.perf_counter()
        contacts = world.step(poses, scene.dynamic_half_extents).contacts
        ms = 1e3 * (time.perf_counter() - before)
        out[SAT_FLOAT64]['tick_ms'].append(ms)
        errors = pair_errors(contact_keys(contacts, n_static, n_total), truth[tick])
        out[SAT_FLOAT64]['false_positives'] += errors[0]
        out[SAT_FLOAT64]['false_negatives'] += errors[1]
    return out, compared


def accuracy_rows(scene, ticks, dt, phase_names, budget_s, progress=None, skip=None):
    """One row per (broad phase, mode): counts summed over the ticks, median and p99 ms.

    ``skip(name)`` may give a reason not to run a phase (then one row says so).
    """
    truth = ground_truth(scene, ticks, dt, budget_s)
    true_pairs = int(sum(len(keys) for keys in truth))
    rows = []
    for name in phase_names:
        reason = skip and skip(name)
        if reason:
            rows.append(dict(_ids(scene, name, None, len(truth), true_pairs), skipped=reason))
            continue
        if progress:
            progress('  accuracy %s n=%d %s' % (scene.name, _bodies(scene), name))
        try:
            modes, compared = measure_modes(scene, dt, truth, name)
        except Exception as error:  # a broken phase is reported, the others still run
            rows.append(dict(_ids(scene, name, None, len(truth), true_pairs),
                             error='%s: %s' % (type(error).__name__, error)))
            continue
        for mode in MODES:
            ms = np.asarray(modes[mode]['tick_ms'])
            rows.append(dict(_ids(scene, name, mode, len(truth), true_pairs),
                             compared=int(np.sum(compared)),
                             false_positives=modes[mode]['false_positives'],
                             false_negatives=modes[mode]['false_negatives'],
                             median_ms=float(np.median(ms)),
                             p99_ms=float(np.percentile(ms, 99))))
    return rows


def _bodies(scene):
    return len(scene.static_poses) + scene.dynamic_count


def _ids(scene, phase_name, mode, ticks, true_pairs):
    return {'scene': scene.name, 'bodies': _bodies(scene), 'broad_phase': phase_name,
            'mode': mode, 'ticks': ticks, 'true_pairs': true_pairs}
