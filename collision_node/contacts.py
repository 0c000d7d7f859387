"""Contacts: the colliding pairs of a tick as one structured array, in the cloud's order.

Fields, ids and order are those of the ``collisions`` PointCloud2 (README, "The collisions
cloud"), with float64 instead of float32: body A is always dynamic; ``type`` is DYNAMIC (id =
index in the PoseArray) or STATIC (id = index in the ``static_colliders`` list); two dynamic
bodies come as id_a < id_b; rows are sorted by (id_a, type_b, id_b).
"""
import numpy as np

from collision_node._jit import kernel
from collision_node.sat import COLLIDING

DYNAMIC = 0  # body types, MoveIt's body_type convention
STATIC = 1

CONTACT_DTYPE = np.dtype([
    ('x', np.float64), ('y', np.float64), ('z', np.float64),
    ('normal_x', np.float64), ('normal_y', np.float64), ('normal_z', np.float64),
    ('depth', np.float64),
    ('id_a', np.uint32), ('type_a', np.uint32), ('id_b', np.uint32), ('type_b', np.uint32),
])

# Contacts of one body are sorted by insertion sort up to this many, by np.argsort beyond
# (a body usually touches a handful of others; a huge box may touch thousands).
INSERTION_SORT_MAX = 32


def assemble_contacts(pairs, status, depth, normal, point, n_static, n_dynamic, static_ids,
                      dynamic_ids=None):
    """Return the COLLIDING rows of the SAT's output as a sorted CONTACT_DTYPE array.

    ``pairs`` are box rows (static rows first, then dynamic); ``static_ids`` maps a static
    row to the collider id reported for it, ``dynamic_ids`` (default: the identity) a dynamic
    row minus ``n_static`` to the body's index in the PoseArray. Two dynamic bodies must come
    in id order (:func:`orient_pairs`).
    """
    if dynamic_ids is None:
        dynamic_ids = np.arange(n_dynamic)
    n_hits = int(np.count_nonzero(status == COLLIDING))
    contacts = np.empty(n_hits, CONTACT_DTYPE)
    if n_hits:
        _assemble(pairs, status, depth, normal, point, n_static, n_dynamic, static_ids,
                  dynamic_ids, contacts)
    return contacts


@kernel
def orient_pairs(pairs, n_static, dynamic_ids):
    """Swap the dynamic pairs whose second body has the smaller id, in place.

    The SAT works in the frame of a pair's first box and the contact is reported from body A,
    the smaller id: so the pair of two given bodies is computed the same way, to the bit,
    however the rows are ordered in storage.
    """
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        if b >= n_static and dynamic_ids[b - n_static] < dynamic_ids[a - n_static]:
            pairs[k, 0] = b
            pairs[k, 1] = a


@kernel
def _assemble(pairs, status, depth, normal, point, n_static, n_dynamic, static_ids,
              dynamic_ids, out):
    # Counting sort on id_a (O(hits + bodies)), then each body's few contacts by (type_b, id_b).
    starts = np.zeros(n_dynamic + 1, np.int64)
    for k in range(pairs.shape[0]):
        if status[k] == COLLIDING:
            starts[dynamic_ids[pairs[k, 0] - n_static] + 1] += 1
    for body in range(n_dynamic):
        starts[body + 1] += starts[body]
    slot = starts[:-1].copy()
    order = np.empty(starts[-1], np.int64)
    rank_b = np.empty(pairs.shape[0], np.int64)
    for k in range(pairs.shape[0]):
        if status[k] == COLLIDING:
            body = dynamic_ids[pairs[k, 0] - n_static]
            order[slot[body]] = k
            slot[body] += 1
            b = pairs[k, 1]
            rank_b[k] = (STATIC << 32) | static_ids[b] if b < n_static \
                else (DYNAMIC << 32) | dynamic_ids[b - n_static]
    for body in range(n_dynamic):
        _sort_by_rank(order, starts[body], starts[body + 1], rank_b)
    for row in range(order.shape[0]):
        k = order[row]
        b = pairs[k, 1]
        out[row].x = point[k, 0]
        out[row].y = point[k, 1]
        out[row].z = point[k, 2]
        out[row].normal_x = normal[k, 0]
        out[row].normal_y = normal[k, 1]
        out[row].normal_z = normal[k, 2]
        out[row].depth = max(depth[k], 0.0)
        out[row].id_a = dynamic_ids[pairs[k, 0] - n_static]
        out[row].type_a = DYNAMIC
        out[row].id_b = rank_b[k] & 0xFFFFFFFF
        out[row].type_b = STATIC if b < n_static else DYNAMIC


@kernel
def _sort_by_rank(indices, start, end, rank):
    """Sort ``indices[start:end]`` by ``rank[indices]``."""
    if end - start > INSERTION_SORT_MAX:
        part = indices[start:end]
        part[:] = part[np.argsort(rank[part], kind='mergesort')]
        return
    for i in range(start + 1, end):
        current = indices[i]
        j = i - 1
        while j >= start and rank[indices[j]] > rank[current]:
            indices[j + 1] = indices[j]
            j -= 1
        indices[j + 1] = current
