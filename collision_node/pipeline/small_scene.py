"""One compiled pass from poses to contacts, for small scenes and batches of states.

A robot arm over a table is a few boxes: every pair can be tested, and what costs is not the
geometry (about 40 pair tests, 1–2 µs) but the calls around it. So a small scene is checked in
one pass: the dynamic boxes are written from the poses, every pair of boxes is tested (AABBs,
then the filters, then the SAT with margins and exact distances), and the contacts come out in
the cloud's order, (id_a, type_b, id_b), as the pairs are visited: no pair list, no sort, no
call per stage. The pass calls the very kernels the general path calls for one body, one pair
and one contact (obb.write_box, filters.pair_checked, sat.collide_boxes,
contacts.write_contact), so its answers are the general path's to the bit.

:func:`check_states` runs the same pass for K states of the same D bodies, each against the
static boxes and independent of the others, into one array with each contact's state.

The static boxes are read from the World's rows (written when the scene changed); what the
pass needs of the static colliders besides their boxes comes as one int64 array ``statics``,
one row per collider in id order: (row, id, category, mask, named in an ignored pair).
"""
import numpy as np

from collision_node.pipeline._jit import inlined_kernel, kernel
from collision_node.pipeline.contacts import CONTACT_DTYPE, DYNAMIC, STATIC, write_contact
from collision_node.pipeline.filters import dynamic_bits, pair_checked, static_key
from collision_node.pipeline.obb import aabbs_overlap, VALID, write_box
from collision_node.pipeline.sat import box, collide_boxes, COLLIDING, INVALID, NEAR, pair_margin

# The contacts of a batch, each with its state's index (the state_collisions cloud's fields).
STATE_CONTACT_DTYPE = np.dtype(CONTACT_DTYPE.descr + [('state', np.uint32)])
# Columns of ``statics``.
ROW, ID, CATEGORY, MASK, IGNORABLE = range(5)
# Counters of one pass, as its stats array holds them.
COMPARED, CANDIDATES, FILTERED, SAT_TESTS = range(4)
# Per reported pair, in the pass's scratch: body a, body b (a static one: -1 - its index in
# ``statics``), then depth, normal (3) and point (3).
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
def check_scene(poses, half_extents, n_static, statics, centers, rotations, extents, aabbs,
                radii, box_margins, margin, pad, sphere_prefilter, filtering, categories,
                masks, ignored_keys, dynamic_ignorable):
    """Check the D bodies of ``poses`` against each other and the static rows, in one pass.

    Dynamic body i is written to row ``n_static + i``. ``half_extents`` has one row per body
    or one for all; ``margin`` None (no margin at all) or the World's, ``box_margins`` None or
    one per row, ``pad`` half the margin (the dynamic bounds' padding). Returns (contacts,
    stats (4,) int64, first invalid body or -1, its obb reason code, 1 if the SAT met NaN).
    """
    stats = np.zeros(4, np.int64)
    ids, floats = _scratch(len(poses), len(statics))
    bad, code, count, invalid = _check_state(
        poses, 0, len(poses), half_extents, n_static, statics, centers, rotations, extents,
        aabbs, radii, box_margins, margin, pad, sphere_prefilter, filtering, categories,
        masks, ignored_keys, dynamic_ignorable, ids, floats, 0, stats)
    out = np.empty(count, CONTACT_DTYPE)
    _write_contacts(out, ids, floats, 0, count, statics, None)
    return out, stats, bad, code, invalid


@kernel
def check_states(poses, bodies, half_extents, n_static, statics, centers, rotations, extents,
                 aabbs, radii, box_margins, margin, pad, sphere_prefilter, filtering,
                 categories, masks, ignored_keys, dynamic_ignorable, first_state, stop_state):
    """Check states ``[first_state, stop_state)`` of ``poses`` ((K·D, 7), D = ``bodies``).

    Each state's bodies are written to rows ``n_static ..`` of the given arrays (a chunk of
    states owns its arrays) and checked as :func:`check_scene` does. Returns (contacts with
    their state, stats, first invalid state, its body, reason code, SAT met NaN).
    """
    stats = np.zeros(4, np.int64)
    ids, floats = _scratch(bodies, len(statics))
    count = 0
    ends = np.empty(stop_state - first_state, np.int64)
    for state in range(first_state, stop_state):
        if len(ids) - count < _pairs(bodies, len(statics)):
            ids, floats = _grown(ids, floats, count + _pairs(bodies, len(statics)))
        bad, code, count, invalid = _check_state(
            poses, state * bodies, bodies, half_extents, n_static, statics, centers, rotations,
            extents, aabbs, radii, box_margins, margin, pad, sphere_prefilter, filtering,
            categories, masks, ignored_keys, dynamic_ignorable, ids, floats, count, stats)
        if bad >= 0 or invalid:
            return np.empty(0, STATE_CONTACT_DTYPE), stats, state, bad, code, invalid
        ends[state - first_state] = count
    out = np.empty(count, STATE_CONTACT_DTYPE)
    start = 0
    for state in range(first_state, stop_state):
        end = ends[state - first_state]
        _write_contacts(out, ids, floats, start, end, statics, state)
        start = end
    return out, stats, -1, -1, VALID, 0


@kernel
def _pairs(bodies, n_statics):
    """Return the most pairs one state can report."""
    return bodies * (bodies - 1) // 2 + bodies * n_statics


@kernel
def _scratch(bodies, n_statics):
    capacity = max(_pairs(bodies, n_statics), 1)
    return np.empty((capacity, 2), np.int64), np.empty((capacity, _FLOATS))


@kernel
def _grown(ids, floats, needed):
    capacity = max(2 * len(ids), needed)
    more_ids = np.empty((capacity, 2), np.int64)
    more_floats = np.empty((capacity, _FLOATS))
    more_ids[:len(ids)] = ids
    more_floats[:len(floats)] = floats
    return more_ids, more_floats


@inlined_kernel
def _check_state(poses, first, bodies, half_extents, n_static, statics, centers, rotations,
                 extents, aabbs, radii, box_margins, margin, pad, sphere_prefilter, filtering,
                 categories, masks, ignored_keys, dynamic_ignorable, ids, floats, count,
                 stats):
    """Write one state's boxes and append its reported pairs to ``ids``/``floats``.

    Returns (first invalid body or -1, its reason code, the new count, 1 if the SAT met NaN).
    Pairs are visited in the cloud's order: for each body a by id, the dynamic bodies after
    it, then the static colliders by id; each pair in the frame of its body a, as the
    general path orients it (contacts.orient_pairs). Inlined into its callers, and calling
    nothing with arrays per pair, so that no array is reference-counted in the loops.
    """
    per_body = len(half_extents) > 1
    for i in range(bodies):
        code = write_box(poses, half_extents, first + i, i if per_body else 0, n_static + i,
                         centers, rotations, extents, aabbs, radii)
        if code != VALID:
            return i, code, count, 0
        if pad > 0.0:  # obb.pad_bounds for a dynamic row (its own margin is 0)
            for m in range(3):
                aabbs[n_static + i, 0, m] -= pad
                aabbs[n_static + i, 1, m] += pad
            radii[n_static + i] += pad
    for a in range(bodies):
        row_a = n_static + a
        box_a = box(centers, rotations, extents, radii, row_a)
        # b: the dynamic bodies after a (by id), then the statics by id.
        for j in range(a + 1, bodies + len(statics)):
            if j < bodies:
                row_b, b, key_b = n_static + j, j, j
            else:
                row_b, b, key_b = statics[j - bodies, ROW], bodies - 1 - j, \
                    static_key(statics[j - bodies, ID])
            stats[COMPARED] += 1
            if not aabbs_overlap(aabbs, row_a, row_b):
                continue
            stats[CANDIDATES] += 1
            if filtering:
                if j < bodies:
                    category_b, mask_b, ignorable_b = dynamic_bits(j, categories, masks,
                                                                   dynamic_ignorable)
                else:
                    category_b = statics[j - bodies, CATEGORY]
                    mask_b = statics[j - bodies, MASK]
                    ignorable_b = statics[j - bodies, IGNORABLE] != 0
                if not pair_checked(a, key_b, category_b, mask_b, ignorable_b, categories,
                                    masks, ignored_keys, dynamic_ignorable):
                    stats[FILTERED] += 1
                    continue
            tested, status, depth, normal, point = collide_boxes(
                box_a, box(centers, rotations, extents, radii, row_b), sphere_prefilter,
                pair_margin(margin, box_margins, row_a, row_b))
            stats[SAT_TESTS] += tested
            if status == INVALID:
                return -1, VALID, count, 1
            if status == COLLIDING or status == NEAR:
                ids[count, 0] = a
                ids[count, 1] = b
                floats[count, 0] = depth
                for m in range(3):
                    floats[count, 1 + m] = normal[m]
                    floats[count, 4 + m] = point[m]
                count += 1
    return -1, VALID, count, 0


@kernel
def _write_contacts(out, ids, floats, start, end, statics, state):
    """Write scratch pairs ``[start, end)`` to the same rows of ``out``, with their ``state``.

    ``state`` None: ``out`` has no state field (a None compiles its write out).
    """
    for k in range(start, end):
        b = ids[k, 1]
        write_contact(out, k, (floats[k, 4], floats[k, 5], floats[k, 6]),
                      (floats[k, 1], floats[k, 2], floats[k, 3]), floats[k, 0], 1.0,
                      ids[k, 0], b if b >= 0 else statics[-1 - b, ID],
                      DYNAMIC if b >= 0 else STATIC)
        if state is not None:
            out[k].state = state
