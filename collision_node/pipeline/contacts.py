"""Contacts: the reported pairs of a tick as one structured array, in the cloud's order.

Fields, ids and order are those of the ``collisions`` PointCloud2 (doc/design.md, "The collisions
cloud"), with float64 instead of float32: body A is always dynamic; ``type`` is DYNAMIC (id = index
in the PoseArray) or STATIC (id = the collider's id, set_static's ``ids``); two dynamic bodies come
as id_a < id_b; rows are sorted by (id_a, type_b, id_b). A pair is reported when it collides
(``distance`` = −``depth`` ≤ 0) or lies within its margin (``distance`` > 0, ``depth`` 0). ``toi``
is the first time in the tick's interval [0, 1] at which the pair came within its margin
(continuous.py); 1 when the World checks only this input's poses.
"""
import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.sat import COLLIDING, NEAR

DYNAMIC = 0  # body types, MoveIt's body_type convention
STATIC = 1

CONTACT_DTYPE = np.dtype([
    ('x', np.float64), ('y', np.float64), ('z', np.float64),
    ('normal_x', np.float64), ('normal_y', np.float64), ('normal_z', np.float64),
    ('depth', np.float64),
    ('id_a', np.uint32), ('type_a', np.uint32), ('id_b', np.uint32), ('type_b', np.uint32),
    ('distance', np.float64),
    ('toi', np.float64),
])
# The contacts of a batch of states (World.check_states): each with its state's index, first
# (it is the first sort key; and so the contacts' fields are not a prefix of these, which numba
# would take for a subtype). Aligned: each float64 field at a multiple of 8, as the clouds'
# writer reads them.
STATE_CONTACT_DTYPE = np.dtype([('state', np.uint32)] + CONTACT_DTYPE.descr, align=True)

# Contacts of one body are sorted by insertion sort up to this many, by np.argsort beyond
# (a body usually touches a handful of others; a huge box may touch thousands).
INSERTION_SORT_MAX = 32
# Least candidate pairs per thread for the contacts to be assembled over threads, so that a
# helper's dispatch (~50 µs) stays small beside its share; measured against 32,768 in
# doc/benchmarks.md ("Threads").
MIN_PAIRS_PER_THREAD = 8192


def assemble_contacts(pairs, status, depth, normal, point, n_static, n_dynamic, static_ids,
                      dynamic_ids=None, toi=None, workers=None):
    """Return the COLLIDING and NEAR rows of the SAT's output as a sorted CONTACT_DTYPE array.

    ``pairs`` are box rows (static rows first, then dynamic); ``static_ids`` maps a static
    row to the collider id reported for it, ``dynamic_ids`` (default: the identity) a dynamic
    row minus ``n_static`` to the body's index in the PoseArray. Two dynamic bodies must come
    in id order (:func:`orient_pairs`). ``toi``: one per pair, or None for 1 everywhere.
    ``workers`` (:class:`~.workers.Workers`) spread the rows over threads from
    ``MIN_PAIRS_PER_THREAD`` pairs a thread, each thread the rows of a range of bodies A.
    """
    if dynamic_ids is None:
        dynamic_ids = np.arange(n_dynamic)
    # Threads take equal ranges of bodies A, each writing its own rows; the counting pass
    # lists every range's colliding pairs apart, so that no thread reads the others'.
    parts = 1 if workers is None else min(workers.threads,
                                          max(1, len(pairs) // MIN_PAIRS_PER_THREAD))
    first_bodies = np.array([n_dynamic * j // parts for j in range(parts + 1)], np.int64)
    ends = np.zeros(n_dynamic + 1, np.int64)
    colliding = np.empty((parts, len(pairs)), np.int64)
    listed = np.zeros(parts, np.int64)
    count = _count_by_body(pairs, status, n_static, dynamic_ids,
                           first_bodies if parts > 1 else None, ends, colliding, listed)
    contacts = np.empty(count, CONTACT_DTYPE)
    if not count:
        return contacts

    def assemble_parts(_, first, stop):
        for j in range(first, stop):
            _assemble(pairs, colliding[j, :listed[j]], first_bodies[j], first_bodies[j + 1],
                      depth, normal, point, n_static, static_ids, dynamic_ids, toi, ends,
                      contacts)

    if parts == 1:
        assemble_parts(0, 0, 1)
    else:
        workers.map_ranges(assemble_parts, parts, 1)
    return contacts


def joined(parts):
    """Return the contact arrays ``parts`` (one dtype, each contiguous) end to end.

    Copied as their bytes: numpy copies a structured dtype with padding (the 4 bytes after
    STATE_CONTACT_DTYPE's ``state``) field by field, 16 times slower (6,900 rows: 315 against
    19 µs on the README's Xeon), a tenth of a batch's time.
    """
    return np.concatenate([part.view(np.uint8) for part in parts]).view(parts[0].dtype)


@kernel
def closest_contact(distance):
    """Return (near pairs, smallest distance, its row) of contacts' ``distance``; row -1 if none.

    One pass over the field (a strided view, which numba takes without the slow typing of a
    structured array): numpy's count and argmin cost ~1 % of a 1,000-body tick.
    """
    near = 0
    closest = -1
    smallest = np.inf
    for row in range(len(distance)):
        near += distance[row] > 0.0
        if closest < 0 or distance[row] < smallest:
            closest, smallest = row, distance[row]
    return near, smallest, closest


def merge_contacts(first, second):
    """Return the rows of two sorted CONTACT_DTYPE arrays (no pair in both), sorted."""
    out = np.empty(len(first) + len(second), CONTACT_DTYPE)
    _merge(first, second, out)
    return out


@kernel
def _merge(first, second, out):
    i = 0
    j = 0
    for k in range(len(out)):
        if j == len(second) or (i < len(first) and _sorts_before(first, i, second, j)):
            out[k] = first[i]
            i += 1
        else:
            out[k] = second[j]
            j += 1


@kernel
def _sorts_before(x, i, y, j):
    """Whether row ``i`` of ``x`` comes before row ``j`` of ``y`` by (id_a, type_b, id_b)."""
    if x[i].id_a != y[j].id_a:
        return x[i].id_a < y[j].id_a
    return _rank_b(x, i) < _rank_b(y, j)


@kernel
def orient_pairs(pairs, n_static, dynamic_ids, starts, out):
    """Write ``pairs`` to ``out`` oriented, and ordered by row unless ``starts`` is None.

    With ``starts`` None the pairs keep their order, and ``out`` may be ``pairs``.

    Oriented: a dynamic pair whose second body has the smaller id is swapped. The SAT works in
    the frame of a pair's first box and the contact is reported from body A, the smaller id:
    so the pair of two given bodies is computed the same way, to the bit, however the rows
    are ordered in storage.

    Ordered: a stable counting sort on the pair's smaller row (``starts`` has one more entry
    than there are rows). Rows are in spatial order, so the SAT then reads each box's data
    for its pairs together, which pays once the boxes outgrow the caches (World).
    """
    if starts is not None:
        starts[:] = 0
        for k in range(pairs.shape[0]):
            starts[min(pairs[k, 0], pairs[k, 1]) + 1] += 1
        for row in range(len(starts) - 1):
            starts[row + 1] += starts[row]
    # Swapped without a branch: ids are in random order, so a branch mispredicts about half
    # of the dynamic pairs (measured 3x slower). A static b looks up a valid dummy id.
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        swap = (b >= n_static) & (dynamic_ids[max(b - n_static, 0)] < dynamic_ids[a - n_static])
        e = k
        if starts is not None:
            e = starts[min(a, b)]
            starts[min(a, b)] = e + 1
        out[e, 0] = b if swap else a
        out[e, 1] = a if swap else b


@kernel
def _count_by_body(pairs, status, n_static, dynamic_ids, first_bodies, ends, colliding, listed):
    """Set ``ends[body + 1]`` to the number of contacts of bodies up to ``body``; return all.

    Body range j is ``[first_bodies[j], first_bodies[j + 1])``: the indices of its colliding
    pairs are listed in the first ``listed[j]`` entries of ``colliding[j]``. ``first_bodies``
    None: one range, all bodies.
    """
    count = 0
    for k in range(pairs.shape[0]):
        # Counted and listed without a branch: a pair collides or not at random (measured
        # ~2x faster). Its range, for the same reason, is a sum of comparisons.
        hit = (status[k] == COLLIDING) | (status[k] == NEAR)
        body = dynamic_ids[pairs[k, 0] - n_static]
        ends[body + 1] += hit
        if first_bodies is None:  # one range: its counter stays in a register
            colliding[0, count] = k
            count += hit
        else:
            part = 0
            for j in range(1, len(first_bodies) - 1):
                part += body >= first_bodies[j]
            colliding[part, listed[part]] = k
            listed[part] += hit
    if first_bodies is None:
        listed[0] = count
    for body in range(len(ends) - 1):
        ends[body + 1] += ends[body]
    return ends[-1]


@kernel
def _assemble(pairs, colliding, first_body, stop_body, depth, normal, point, n_static,
              static_ids, dynamic_ids, toi, ends, out):
    """Write and sort the rows of bodies ``[first_body, stop_body)``; ``ends``: their first rows.

    A counting sort on id_a (O(hits + bodies)) that writes each contact straight to its row,
    then each body's few rows sorted by (type_b, id_b): the SAT's arrays are read in order
    (measured 1.2x faster than sorting indices and then gathering the rows, at 10k and 100k
    bodies). ``colliding`` lists the colliding pairs of these bodies: no branch on the verdict
    here. Ranges of bodies have disjoint rows and cursors in ``ends``, so threads can write
    them at once.
    """
    start = ends[first_body]
    for c in range(len(colliding)):
        k = colliding[c]
        body = dynamic_ids[pairs[k, 0] - n_static]
        row = ends[body]
        ends[body] = row + 1
        b = pairs[k, 1]
        write_contact(out[row], (point[k, 0], point[k, 1], point[k, 2]),
                      (normal[k, 0], normal[k, 1], normal[k, 2]), depth[k],
                      1.0 if toi is None else toi[k], body,
                      static_ids[b] if b < n_static else dynamic_ids[b - n_static],
                      STATIC if b < n_static else DYNAMIC)
    held = out[:1].copy()  # a row's copy while insertion sort moves the others
    for body in range(first_body, stop_body):  # ends[body] is now the end of the body's rows
        end = ends[body]
        if end - start > INSERTION_SORT_MAX:
            _sort_by_b(out, start, end)
        else:  # inline: a call per body, with its reference counting, cost more than the sort
            for i in range(start + 1, end):
                current = _rank_b(out, i)
                if _rank_b(out, i - 1) <= current:
                    continue
                held[0] = out[i]
                j = i - 1
                while j >= start and _rank_b(out, j) > current:
                    out[j + 1] = out[j]
                    j -= 1
                out[j + 1] = held[0]
        start = end


@kernel
def write_contact(row, point, normal, depth, toi, id_a, id_b, type_b):
    """Write a pair's contact to the record ``row``: ``depth`` as the SAT gives it (< 0: NEAR).

    A record, not its array: a call numba does not inline reference-counts an array.
    """
    row.x = point[0]
    row.y = point[1]
    row.z = point[2]
    row.normal_x = normal[0]
    row.normal_y = normal[1]
    row.normal_z = normal[2]
    row.depth = max(depth, 0.0)
    row.distance = -depth  # a NEAR pair's depth is minus its distance
    row.toi = toi
    row.id_a = id_a
    row.type_a = DYNAMIC
    row.id_b = id_b
    row.type_b = type_b


@kernel
def _rank_b(out, row):
    return (np.int64(out[row].type_b) << 32) | np.int64(out[row].id_b)


@kernel
def _sort_by_b(out, start, end):
    """Sort rows ``out[start:end]`` by (type_b, id_b), stably."""
    rank = np.empty(end - start, np.int64)
    for i in range(start, end):
        rank[i - start] = _rank_b(out, i)
    order = np.argsort(rank, kind='mergesort')
    rows = out[start:end].copy()
    for i in range(end - start):
        out[start + i] = rows[order[i]]
