"""One compiled pass from poses to contacts, for small scenes and batches of states.

A robot arm over a table is a few boxes: every pair can be tested, and what costs is not the
geometry (about 40 pair tests, 1–2 µs) but the calls around it. So a small scene is checked in
one pass: the dynamic boxes are written from the poses, every pair of boxes is tested (AABBs,
then the filters, then the SAT with margins and exact distances), and the contacts come out in
the cloud's order, (id_a, type_b, id_b), as the pairs are visited: no pair list, no sort, no
call per stage. The pass calls the very kernels of the general path: obb.write_boxes writes
the boxes, filters.pair_checked decides the filters (once per set of bodies: a table), the
SAT loop sat.collide_pair_rows runs on the pairs a state's AABBs let through, and
contacts.write_contact writes the rows; so its answers are the general path's to the bit.

:func:`check_states` runs the same pass for K states of the same D bodies, each against the
static boxes and independent of the others, into one array with each contact's state.

The kernels take structures, as pynndescent's search takes one tree and its query: ``rows``
the box rows, a copy of the scene's static rows 0..S-1 with room for the bodies after them,
(centers, rotations, extents, aabbs, radii, margins or None: no margin at all); ``statics``
what the pass needs of the static colliders besides their boxes, one int64 row per static
row in id order (row, id, category, mask, named in an ignored pair), so S is its length;
``options`` (margin or None: no margin at all, the bounds' padding, the sphere prefilter,
the filter table: :func:`checked_pairs`, all True without filters); and ``last`` the last
input checked (poses, half extents, valid). Plain tuples in these orders: numba types a
NamedTuple argument from Python on every call, slowly (robot.pack_model).
"""
import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.contacts import (CONTACT_DTYPE, DYNAMIC, STATE_CONTACT_DTYPE, STATIC,
                                              write_contact)
from collision_node.pipeline.filters import dynamic_bits, pair_checked, static_key
from collision_node.pipeline.flat_views import copy_into
from collision_node.pipeline.obb import aabbs_overlap, VALID, write_boxes
from collision_node.pipeline.sat import collide_pair_rows, COLLIDING, INVALID, NEAR

# Columns of ``statics``.
ROW, ID, CATEGORY, MASK, IGNORABLE = range(5)
# Counters of one pass, as its stats array holds them.
COMPARED, CANDIDATES, FILTERED, SAT_TESTS = range(4)
# Per reported pair, in the pass's output scratch: body a, body b (a static one: -1 - its index
# in ``statics``), then depth, normal (3) and point (3).
_FLOATS = 7


def statics_table(rows_ids, categories, masks, ignorable):
    """Return the ``statics`` array of the static rows (ids, bits and flags per row)."""
    count = len(rows_ids)
    table = np.empty((count, 5), np.int64)
    table[:, ROW] = np.arange(count)
    table[:, ID] = rows_ids
    table[:, CATEGORY] = categories
    table[:, MASK] = masks
    table[:, IGNORABLE] = ignorable
    return table[np.argsort(rows_ids, kind='stable')]


@kernel
def check_scene(poses, half_extents, last, statics, rows, options):
    """Check the D bodies of ``poses`` against each other and the static rows, in one pass.

    Dynamic body i is written to row S + i of ``rows``. ``half_extents`` has one row per body
    or one for all. ``last`` (poses, half extents, valid) holds the last checked input when
    valid[0] is 1: the same input again is not checked (``same`` 1); any other is copied there
    once checked. Returns (contacts, (compared, candidates, filtered, SAT tests), first
    invalid body or -1, its obb reason code, 1 if the SAT met NaN, same).
    """
    last_poses, last_half_extents, last_valid = last
    if last_valid[0] == 1 and same_input(last_poses, poses, last_half_extents, half_extents):
        return np.empty(0, CONTACT_DTYPE), (0, 0, 0, 0), -1, VALID, 0, 1
    last_valid[0] = 0
    # State 0 to 1 as int64 values, not literal constants (_jit, "Constant arguments": six
    # more variants of _check_states, about 20 s of a first start).
    first_state = np.int64(0)
    found, _, stats, _, bad, code, invalid = _check_states(
        poses, len(poses), half_extents, statics, rows, options, first_state, first_state + 1)
    count, ids, floats = found
    out = np.empty(count, CONTACT_DTYPE)
    _write_contacts(out, ids, floats, 0, count, statics, None)
    if bad < 0 and not invalid:
        copy_into(last_poses, poses)
        copy_into(last_half_extents, half_extents)
        last_valid[0] = 1
    return (out, (stats[COMPARED], stats[CANDIDATES], stats[FILTERED], stats[SAT_TESTS]), bad,
            code, invalid, 0)


@kernel
def check_states(poses, bodies, half_extents, statics, rows, options, first_state, stop_state):
    """Check states ``[first_state, stop_state)`` of ``poses`` ((K·D, 7), D = ``bodies``).

    Each state's bodies are written to rows S .. of ``rows`` (a chunk of states owns its
    rows) and checked as :func:`check_scene` does. Returns (contacts with their state, stats,
    first invalid state, its body, reason code, SAT met NaN).
    """
    found, ends, stats, failed, bad, code, invalid = _check_states(
        poses, bodies, half_extents, statics, rows, options, first_state, stop_state)
    if bad >= 0 or invalid:
        return np.empty(0, STATE_CONTACT_DTYPE), stats, failed, bad, code, invalid
    count, ids, floats = found
    out = np.empty(count, STATE_CONTACT_DTYPE)
    start = 0
    for state in range(first_state, stop_state):
        end = ends[state - first_state]
        _write_contacts(out, ids, floats, start, end, statics, state)
        start = end
    return out, stats, -1, -1, VALID, 0


@kernel
def same_input(poses, other_poses, half_extents, other_half_extents):
    """Whether two inputs are the same, bit for bit (NaN is never the same)."""
    if poses.shape != other_poses.shape or half_extents.shape != other_half_extents.shape:
        return False
    for i in range(poses.shape[0]):
        for k in range(7):
            if not poses[i, k] == other_poses[i, k]:
                return False
    for i in range(half_extents.shape[0]):
        for k in range(3):
            if not half_extents[i, k] == other_half_extents[i, k]:
                return False
    return True


@kernel
def checked_pairs(bodies, statics, categories, masks, ignored_keys, dynamic_ignorable):
    """Return which pairs the filters let through: (D, D + S) bool, as the pass visits them.

    Entry [a, j] is the pair of body a and dynamic body j (j < D, j > a) or static collider
    j - D of ``statics``; both filter rules (filters.pair_checked), decided once per set of
    bodies and settings instead of once per pair and state.
    """
    checked = np.ones((bodies, bodies + len(statics)), np.bool_)
    for a in range(bodies):
        for j in range(a + 1, bodies + len(statics)):
            if j < bodies:
                category_b, mask_b, ignorable_b = dynamic_bits(j, categories, masks,
                                                               dynamic_ignorable)
                key_b = j
            else:
                category_b = statics[j - bodies, CATEGORY]
                mask_b = statics[j - bodies, MASK]
                ignorable_b = statics[j - bodies, IGNORABLE] != 0
                key_b = static_key(statics[j - bodies, ID])
            checked[a, j] = pair_checked(a, key_b, category_b, mask_b, ignorable_b, categories,
                                         masks, ignored_keys, dynamic_ignorable)
    return checked


@kernel
def _check_states(poses, bodies, half_extents, statics, rows, options, first_state, stop_state):
    """Check states ``[first_state, stop_state)``; return their reported pairs.

    Returns ((count, ids, floats): the reported pairs in order, the end of each state's pairs
    in them, stats, then (state, body, code) of the first invalid body (-1: none) and 1 if
    the SAT met NaN. Pairs are visited in the cloud's order: for each body a by id, the dynamic
    bodies after it, then the static colliders by id; each pair in the frame of its body a,
    as the general path orients it (contacts.orient_pairs). One call for all states: a
    call numba does not inline reference-counts every array it is handed.
    """
    centers, rotations, extents, aabbs, radii, box_margins = rows
    margin, pad, sphere_prefilter, checked = options
    n_static = len(statics)
    most = bodies * (bodies - 1) // 2 + bodies * len(statics)  # pairs of one state
    # Allocated here on every call, not kept by the World: handed in from Python as kept
    # arrays, these nine cost more to unbox than to allocate (the arm's step: 6.1 µs, not 5.5).
    pairs = np.empty((most, 2), np.int64)
    owner = np.empty(most, np.int64)  # a candidate's body a
    which = np.empty(most, np.int64)  # and its b: j as the pass visits them
    status = np.empty(most, np.int8)
    depth = np.empty(most)
    normal = np.empty((most, 3))
    point = np.empty((most, 3))
    ids = np.empty((max(most, 1), 2), np.int64)
    floats = np.empty((max(most, 1), _FLOATS))
    count = 0
    ends = np.empty(stop_state - first_state, np.int64)
    compared = candidates = filtered = sat_tests = 0
    for state in range(first_state, stop_state):
        first = state * bodies
        bad, code = write_boxes(poses[first:first + bodies], half_extents, n_static, None,
                                centers, rotations, extents, aabbs, radii)
        if bad >= 0:
            return ((count, ids, floats), ends, _stats(compared, candidates, filtered, sat_tests),
                    state, bad, code, 0)
        if pad > 0.0:  # obb.pad_bounds for the dynamic rows (their own margin is 0)
            for i in range(n_static, n_static + bodies):
                for m in range(3):
                    aabbs[i, 0, m] -= pad
                    aabbs[i, 1, m] += pad
                radii[i] += pad
        n, state_compared, state_candidates, state_filtered = _candidates(
            aabbs, statics, bodies, checked, pairs, owner, which)
        compared += state_compared
        candidates += state_candidates
        filtered += state_filtered
        sat_tests += collide_pair_rows(centers, rotations, extents, radii, pairs[:n],
                                       sphere_prefilter, margin, box_margins, status, depth,
                                       normal, point)
        if len(ids) - count < n:
            ids, floats = _grown(ids, floats, count + n)
        for k in range(n):
            if status[k] == INVALID:
                return ((count, ids, floats), ends,
                        _stats(compared, candidates, filtered, sat_tests), state, -1, VALID, 1)
            if status[k] == COLLIDING or status[k] == NEAR:
                j = which[k]
                ids[count, 0] = owner[k]
                ids[count, 1] = j if j < bodies else bodies - 1 - j
                floats[count, 0] = depth[k]
                for m in range(3):
                    floats[count, 1 + m] = normal[k, m]
                    floats[count, 4 + m] = point[k, m]
                count += 1
        ends[state - first_state] = count
    return ((count, ids, floats), ends, _stats(compared, candidates, filtered, sat_tests), -1,
            -1, VALID, 0)


@kernel
def _candidates(aabbs, statics, bodies, checked, pairs, owner, which):
    """Write a state's pairs whose AABBs overlap and the filters let through to ``pairs``.

    With each pair's body a (``owner``) and its b as the pass visits them (``which``): for
    each body a by id, the dynamic bodies after it, then the statics by id; ``checked`` the
    filter table. Returns (pairs, compared, candidates, filtered).
    """
    n_static = len(statics)
    # Counted in registers: an array element bumped per pair is a store per pair.
    n = compared = candidates = filtered = 0
    for a in range(bodies):
        row_a = n_static + a
        for j in range(a + 1, bodies + n_static):
            row_b = n_static + j if j < bodies else statics[j - bodies, ROW]
            compared += 1
            if not aabbs_overlap(aabbs, row_a, row_b):
                continue
            candidates += 1
            if not checked[a, j]:
                filtered += 1
                continue
            pairs[n, 0] = row_a
            pairs[n, 1] = row_b
            owner[n] = a
            which[n] = j
            n += 1
    return n, compared, candidates, filtered


@kernel
def _stats(compared, candidates, filtered, sat_tests):
    stats = np.empty(4, np.int64)
    stats[COMPARED] = compared
    stats[CANDIDATES] = candidates
    stats[FILTERED] = filtered
    stats[SAT_TESTS] = sat_tests
    return stats


@kernel
def _grown(ids, floats, needed):
    capacity = max(2 * len(ids), needed)
    more_ids = np.empty((capacity, 2), np.int64)
    more_floats = np.empty((capacity, _FLOATS))
    copy_into(more_ids[:len(ids)], ids)
    copy_into(more_floats[:len(floats)], floats)
    return more_ids, more_floats


@kernel
def _write_contacts(out, ids, floats, start, end, statics, state):
    """Write pairs ``[start, end)`` to the same rows of ``out``, with their ``state``.

    ``state`` None: ``out`` has no state field (a None compiles its write out).
    """
    for k in range(start, end):
        b = ids[k, 1]
        write_contact(out[k], (floats[k, 4], floats[k, 5], floats[k, 6]),
                      (floats[k, 1], floats[k, 2], floats[k, 3]), floats[k, 0], 1.0,
                      ids[k, 0], b if b >= 0 else statics[-1 - b, ID],
                      DYNAMIC if b >= 0 else STATIC)
        if state is not None:
            out[k].state = state
