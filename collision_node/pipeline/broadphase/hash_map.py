"""An open-addressing hash map from int64 keys to int64 values, in two flat arrays.

Linear probing in a power-of-two table; deletion shifts the following entries of the probe
run back (Knuth 6.4, algorithm R), so there are no tombstones and look-ups stay short however
many keys come and go. The octree keeps its leaves here: leaves are created and dropped every
tick, which is exactly the case tombstones handle badly.

Keys are hashed by Fibonacci hashing (``key * 2**64 / golden ratio``, high bits folded into
the low ones). The caller keeps the load at most 1/2; the functions assume a free slot exists.
"""
import numpy as np

from collision_node.pipeline._jit import kernel

EMPTY = -1  # value of a free slot (values are indices, never negative)
HASH_MULTIPLIER = np.uint64(0x9E3779B97F4A7C15)  # 2**64 / golden ratio


def empty_map(capacity):
    """Arrays (keys, values) for a table of ``capacity`` slots, a power of two."""
    return np.zeros(capacity, np.int64), np.full(capacity, EMPTY, np.int64)


@kernel
def home_slot(key, mask):
    """Return the slot where the probe for ``key`` starts."""
    mixed = np.uint64(key) * HASH_MULTIPLIER
    # The product's high bits depend on all of the key's bits; fold them into the low ones.
    return np.int64(mixed ^ (mixed >> np.uint64(29))) & mask


@kernel
def find(keys, values, key):
    """Return the value stored for ``key``, or EMPTY."""
    mask = len(keys) - 1
    slot = home_slot(key, mask)
    while values[slot] != EMPTY:
        if keys[slot] == key:
            return values[slot]
        slot = (slot + 1) & mask
    return EMPTY


@kernel
def insert(keys, values, key, value):
    """Store ``value`` for ``key``, which must not be in the map yet."""
    mask = len(keys) - 1
    slot = home_slot(key, mask)
    while values[slot] != EMPTY:
        slot = (slot + 1) & mask
    keys[slot] = key
    values[slot] = value


@kernel
def remove(keys, values, key):
    """Remove ``key`` (which must be in the map), closing the gap in its probe run."""
    mask = len(keys) - 1
    hole = home_slot(key, mask)
    while keys[hole] != key or values[hole] == EMPTY:
        hole = (hole + 1) & mask
    slot = hole
    while True:
        slot = (slot + 1) & mask
        if values[slot] == EMPTY:
            break
        home = home_slot(keys[slot], mask)
        # The entry may fill the hole unless its home lies cyclically in (hole, slot].
        if (slot - home) & mask >= (slot - hole) & mask:
            keys[hole] = keys[slot]
            values[hole] = values[slot]
            hole = slot
    values[hole] = EMPTY
