"""The static colliders, by the caller's stable ids: the one owner of the static scene.

A collider is a box with an integer id chosen by the caller (the cloud's ``id_b`` for a static
body), its pose and half extents, its own margin, its collision category and mask, and whether
it is enabled: a disabled collider keeps its pose and settings but is never checked. The scene
changes only through the verbs below (MoveIt's ``collision_detection::World`` shape: verbs on
one object, keyed by id), and nothing else keeps a copy: the World derives its static rows and
the broad phase's static structure from it.

Each verb checks all of its input before it changes anything: an unknown or repeated id, a
pose that is not a rigid transform, or a size that is not a box raises ValueError naming the
id, and the scene stays exactly as it was. Every verb that changes the scene adds one to
``version``; a verb that finds nothing to change leaves it.

Storage: one flat array per field, a slot per collider in the order they were added (removing
one closes the gap, so slots keep that order); ``by_id`` lists the slots sorted by id, for
lookups by binary search.
"""
from typing import NamedTuple

import numpy as np

from collision_node.pipeline.filters import ALL_CATEGORIES, collision_bits, DEFAULT_CATEGORY
from collision_node.pipeline.obb import check_boxes, check_margin, InvalidBox, InvalidDistance

# The ids fit the cloud's UINT32 id fields.
MAX_STATIC_ID = 2**32 - 1


class InvalidCollider(InvalidBox):
    """A collider a verb refuses: ``static_id`` its id, ``body`` its index in the call."""

    def __init__(self, body, static_id, reason):
        ValueError.__init__(self, 'static id %d: %s' % (static_id, reason))
        self.body = body
        self.static_id = static_id
        self.reason = reason


class Colliders(NamedTuple):
    """The scene's colliders as read-only arrays, one entry per collider (slot order)."""

    ids: np.ndarray           # (S,) int64
    poses: np.ndarray         # (S, 7) x y z qx qy qz qw
    half_extents: np.ndarray  # (S, 3)
    margins: np.ndarray       # (S,) m, added to the World's margin for this collider's pairs
    categories: np.ndarray    # (S,) int64 collision bits
    masks: np.ndarray         # (S,) int64
    enabled: np.ndarray       # (S,) bool


def _empty():
    return Colliders(np.zeros(0, np.int64), np.zeros((0, 7)), np.zeros((0, 3)), np.zeros(0),
                     np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.bool_))


class StaticScene:
    """The static colliders and the verbs that change them (module docstring)."""

    def __init__(self):
        self._colliders = _empty()
        self._by_id = np.zeros(0, np.int64)  # slots in the order of their ids
        self.version = 0

    def __len__(self):
        return len(self._colliders.ids)

    @property
    def colliders(self):
        """Return the colliders now, as read-only views (:class:`Colliders`), until a verb."""
        views = []
        for array in self._colliders:
            view = array.view()
            view.flags.writeable = False
            views.append(view)
        return Colliders(*views)

    def slots(self, ids):
        """Return the slots of ``ids`` (int64); ValueError naming an unknown or repeated id."""
        ids = _ids(ids)
        known = self._colliders.ids
        if np.array_equal(ids, known):  # every collider in slot order: the usual move
            return np.arange(len(ids))
        _no_repeats(ids)
        at = np.searchsorted(known[self._by_id], ids)
        at = np.minimum(at, max(len(known) - 1, 0))
        found = len(known) > 0
        slots = self._by_id[at] if found else np.zeros(len(ids), np.int64)
        unknown = ~(known[slots] == ids) if found else np.ones(len(ids), np.bool_)
        if unknown.any():
            raise ValueError('static id %d: no such collider' % ids[np.argmax(unknown)])
        return slots

    def add(self, ids, poses, half_extents, margins=0.0, categories=DEFAULT_CATEGORY,
            masks=ALL_CATEGORIES, enabled=True):
        """Add colliders with new ``ids``; one value or one per collider for the others."""
        ids = _ids(ids)
        if not len(ids):
            return
        _no_repeats(ids)
        taken = np.isin(ids, self._colliders.ids)
        if taken.any():
            raise ValueError('static id %d: a collider with this id exists (ids are new in '
                             'add_static; move_static changes an existing one)'
                             % ids[np.argmax(taken)])
        added = _checked_colliders(ids, poses, half_extents, margins, categories, masks,
                                   enabled)
        self._set(Colliders(*(np.concatenate([mine, theirs])
                              for mine, theirs in zip(self._colliders, added))))

    def move(self, ids, poses=None, half_extents=None):
        """Give colliders ``ids`` new ``poses`` and/or ``half_extents`` (None: as they are).

        Returns the slots whose pose or size changed, in the order of ``ids``.
        """
        slots = self.slots(ids)
        current = self._colliders
        poses = current.poses[slots] if poses is None else _rows(poses, len(slots), 7, 'poses')
        extents = current.half_extents[slots] if half_extents is None else \
            _rows(half_extents, len(slots), 3, 'half extents')
        _check_boxes(current.ids[slots], poses, extents)
        changed = np.flatnonzero(~((current.poses[slots] == poses).all(axis=1)
                                   & (current.half_extents[slots] == extents).all(axis=1)))
        if len(changed):
            moved = slots[changed]
            current.poses[moved] = poses[changed]
            current.half_extents[moved] = extents[changed]
            self.version += 1
        return slots[changed]

    def remove(self, ids):
        """Remove colliders ``ids``."""
        slots = self.slots(ids)
        if len(slots):
            keep = np.ones(len(self), np.bool_)
            keep[slots] = False
            self._set(Colliders(*(array[keep] for array in self._colliders)))

    def enable(self, ids, enabled):
        """Enable or disable colliders ``ids`` (``enabled``: one flag for all, or one each)."""
        slots = self.slots(ids)
        flags = _per_collider('enabled', np.asarray(enabled), len(slots))
        if flags.dtype != np.bool_:
            raise ValueError('enabled must be True or False, got %s' % flags.dtype)
        if not np.array_equal(self._colliders.enabled[slots], flags):
            self._colliders.enabled[slots] = flags
            self.version += 1

    def update(self, ids, margins=None, categories=None, masks=None):
        """Change the margins, categories or masks of colliders ``ids`` (None: as they are)."""
        slots = self.slots(ids)
        current = self._colliders
        new = _checked_settings(
            len(slots), current.ids[slots],
            current.margins[slots] if margins is None else margins,
            current.categories[slots] if categories is None else categories,
            current.masks[slots] if masks is None else masks)
        old = (current.margins[slots], current.categories[slots], current.masks[slots])
        if not all(np.array_equal(a, b) for a, b in zip(old, new)):
            current.margins[slots], current.categories[slots], current.masks[slots] = new
            self.version += 1

    def replace(self, poses, half_extents, ids=None, margins=0.0,
                categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES, enabled=True):
        """Replace every collider; ``ids`` default to 0..S-1 (World.set_static)."""
        poses = np.asarray(poses, np.float64).reshape(-1, 7)
        ids = np.arange(len(poses)) if ids is None else _ids(ids)
        _no_repeats(ids)
        self._set(_checked_colliders(ids, poses, half_extents, margins, categories, masks,
                                     enabled))

    def validate(self):
        """Check the whole scene (for testing): raise AssertionError naming what is wrong."""
        colliders = self._colliders
        count = len(colliders.ids)
        for name, array in zip(Colliders._fields, colliders):
            assert len(array) == count, '%s has %d entries for %d colliders' % (
                name, len(array), count)
        assert len(np.unique(colliders.ids)) == count, 'an id appears twice'
        assert np.array_equal(np.sort(self._by_id), np.arange(count)), \
            'by_id is not a permutation of the slots'
        assert np.all(np.diff(colliders.ids[self._by_id]) > 0), 'by_id is not in id order'
        assert np.all((colliders.ids >= 0) & (colliders.ids <= MAX_STATIC_ID)), 'id range'
        try:
            _check_boxes(colliders.ids, colliders.poses, colliders.half_extents)
            _checked_settings(count, colliders.ids, colliders.margins, colliders.categories,
                              colliders.masks)
        except ValueError as error:
            raise AssertionError(str(error)) from None

    def _set(self, colliders):
        self._colliders = colliders
        self._by_id = np.argsort(colliders.ids, kind='stable')
        self.version += 1


def _ids(ids):
    """Return ``ids`` as int64 (K,); ValueError unless they are integers in the id range."""
    array = np.atleast_1d(np.asarray(ids))
    if array.ndim != 1 or (len(array) and array.dtype.kind not in 'iu'):
        raise ValueError('static ids must be a list of integers, got %r' % (ids,))
    array = array.astype(np.int64)
    bad = (array < 0) | (array > MAX_STATIC_ID)
    if bad.any():
        raise ValueError('static id %d: ids must be in [0, %d]'
                         % (array[np.argmax(bad)], MAX_STATIC_ID))
    return array


def _no_repeats(ids):
    ordered = np.sort(ids)
    repeated = ordered[1:] == ordered[:-1]
    if repeated.any():
        raise ValueError('static id %d: given twice' % ordered[1:][np.argmax(repeated)])


def _rows(values, count, width, name):
    array = np.asarray(values, np.float64)
    if width == 3 and array.shape == (3,):
        array = np.broadcast_to(array, (count, 3))
    if array.shape != (count, width):
        raise ValueError('static %s: need shape (%d, %d), one per id, got %s'
                         % (name, count, width, array.shape))
    return np.array(array)


def _per_collider(name, values, count):
    """Return one value for all, or one per collider, as one per collider."""
    values = np.atleast_1d(values)
    if values.ndim != 1 or len(values) not in (1, count):
        raise ValueError('static %s: give one value or one per box (%d), got %d'
                         % (name, count, values.size))
    return np.broadcast_to(values, (count,)).copy()


def _check_boxes(ids, poses, half_extents):
    try:
        check_boxes(poses, half_extents)
    except InvalidBox as error:
        raise InvalidCollider(error.body, int(ids[error.body]), error.reason) from None


def _checked_settings(count, ids, margins, categories, masks):
    margins = _per_collider('margins', np.asarray(margins, np.float64), count)
    try:
        check_margin(margins)
    except InvalidDistance as error:
        raise ValueError('static id %d: %s' % (ids[error.index], error)) from None
    return (margins, _per_collider('categories', collision_bits('static categories', categories),
                                   count),
            _per_collider('masks', collision_bits('static masks', masks), count))


def _checked_colliders(ids, poses, half_extents, margins, categories, masks, enabled):
    count = len(ids)
    poses = _rows(poses, count, 7, 'poses')
    extents = _rows(half_extents, count, 3, 'half extents')
    _check_boxes(ids, poses, extents)
    margins, categories, masks = _checked_settings(count, ids, margins, categories, masks)
    flags = _per_collider('enabled', np.asarray(enabled), count)
    if flags.dtype != np.bool_:
        raise ValueError('static enabled must be True or False, got %s' % flags.dtype)
    return Colliders(ids, poses, extents, margins, categories, masks, flags)
