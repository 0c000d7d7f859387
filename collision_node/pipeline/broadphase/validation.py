"""Whole-structure checks of the broad phases, for testing (Box2D's ``b2DynamicTree_Validate``).

Every phase's ``validate(boxes, n_static, n_dynamic, loose=None)`` (the API list in
:mod:`collision_node.pipeline.broadphase`) checks its structure with the helpers here and raises
:class:`InvalidStructure` naming the first inconsistency. The checks are plain Python and
numpy, run only when a test calls them: nothing here is on the path of a tick.
"""
import numpy as np

from collision_node.pipeline.broadphase import hash_map
from collision_node.pipeline.broadphase.cells import cell_range, KEY_BITS, KEY_OFFSET


class InvalidStructure(AssertionError):
    """A broad phase's structure disagrees with itself or with the boxes it was given."""


def check(condition, message, *args):
    """Raise :class:`InvalidStructure` with ``message % args`` unless ``condition``."""
    if not condition:
        raise InvalidStructure(message % args if args else message)


def loose_mask(loose, n_static):
    """Return ``loose`` (bool per static row, or None: none loose) as n_static bools."""
    if loose is None:
        return np.zeros(n_static, np.bool_)
    loose = np.asarray(loose, np.bool_)
    check(loose.ndim == 1 and len(loose) >= n_static,
          'loose must hold a bool per static row (%d), got shape %s', n_static, loose.shape)
    return loose[:n_static]


def check_permutation(values, rows, what):
    """Check that ``values`` holds each of ``rows`` exactly once."""
    values = np.asarray(values)
    check(len(values) == len(rows), '%s: %d rows, expected %d', what, len(values), len(rows))
    got, expected = np.sort(values), np.sort(rows)
    wrong = np.flatnonzero(got != expected)
    check(not len(wrong), '%s is not a permutation of its rows: sorted, position %d holds %s '
          'instead of %s', what, wrong[0] if len(wrong) else 0,
          got[wrong[0]] if len(wrong) else None, expected[wrong[0]] if len(wrong) else None)


def check_distinct(values, what):
    """Check that ``values`` holds no value twice."""
    values, counts = np.unique(np.asarray(values), return_counts=True)
    check(not np.any(counts > 1), '%s holds %s more than once', what,
          values[counts > 1][:1].tolist())


def cell_ranges(lattice, aabbs, rows):
    """Return the (len(rows), 2, 3) cell ranges of boxes ``rows`` on ``lattice``."""
    ranges = np.zeros((len(rows), 2, 3), np.int64)
    for i, row in enumerate(rows):
        cell_range(lattice, aabbs, int(row), ranges, i)
    return ranges


def cell_counts(ranges):
    """Return the number of cells of each (2, 3) range (no cap: callers compare with it)."""
    return np.prod(ranges[:, 1] - ranges[:, 0] + 1, axis=1)


def cell_of_key(key):
    """Return the cell (x, y, z) that :func:`~.cells.cell_key` packed into ``key``."""
    mask = (1 << KEY_BITS) - 1
    key = int(key)
    return ((key >> (2 * KEY_BITS)) - KEY_OFFSET, ((key >> KEY_BITS) & mask) - KEY_OFFSET,
            (key & mask) - KEY_OFFSET)


def range_holds(ranges, slot, cell):
    """Tell whether ``cell`` lies in range ``ranges[slot]``."""
    return all(ranges[slot, 0, k] <= cell[k] <= ranges[slot, 1, k] for k in range(3))


def first_row_where(bad):
    """Index of the first True of ``bad``, or -1 (for messages)."""
    found = np.flatnonzero(bad)
    return int(found[0]) if len(found) else -1


def check_contains(outer, inner, what):
    """Check that AABBs ``outer`` (..., 2, 3) contain AABBs ``inner`` (same shape)."""
    bad = np.any(outer[..., 0, :] > inner[..., 0, :], axis=-1) \
        | np.any(outer[..., 1, :] < inner[..., 1, :], axis=-1)
    first = first_row_where(np.ravel(bad))
    check(first < 0, '%s: item %d, %s does not contain %s', what, first,
          np.reshape(outer, (-1, 2, 3))[first].tolist() if first >= 0 else None,
          np.reshape(inner, (-1, 2, 3))[first].tolist() if first >= 0 else None)


def check_hash_map(keys, values, what):
    """Check an open-addressing map (:mod:`~.hash_map`); return its contents as a dict.

    Every stored key must be found from its home slot: a free slot inside its probe run (a
    broken deletion) would hide it from look-ups.
    """
    size = len(keys)
    check(size == len(values) and size > 0 and size & (size - 1) == 0,
          '%s: %d keys, %d values, not one power-of-two table', what, size, len(values))
    stored = np.flatnonzero(values != hash_map.EMPTY)
    check(len(stored) < size, '%s: no free slot (look-ups would never end)', what)
    contents = {}
    for slot in stored:
        key = int(keys[slot])
        check(key not in contents, '%s: key %d stored twice', what, key)
        found = hash_map.find(keys, values, keys[slot])
        check(found == values[slot], '%s: key %d in slot %d is found as %d, not %d (a free '
              'slot in its probe run)', what, key, slot, found, values[slot])
        contents[key] = int(values[slot])
    return contents
