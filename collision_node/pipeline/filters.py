"""Which pairs are checked at all: collision categories and masks, and ignored pairs.

Two rules, applied to every pair the broad phase finds and before the SAT, so a filtered pair
costs a few bit tests and never a SAT:

1. Categories and masks (Box2D, Bullet and Jolt semantics): bodies A and B are checked only if
   ``category_a & mask_b != 0 and category_b & mask_a != 0``. Each is a 64-bit pattern (an
   int64; -1 sets every bit). Defaults: category 1 and mask -1, which check every pair.
2. Ignored pairs (MoveIt's allowed-collision entries): a pair listed there is never checked,
   whatever the masks say. An entry naming a dynamic body the input does not have applies to
   no pair of that input.

The two rules only ever remove pairs, so their order does not matter: a pair is checked when
the masks accept it and it is not ignored.

Bodies are named as in the ``collisions`` cloud: ``(id, type)`` with type DYNAMIC (id = index in
the input) or STATIC (id = the collider's id). The ignored pairs are kept as a sorted array of
64-bit keys, one per pair (the dynamic body's id in the high half, the other body's in the low
half), and looked up by binary search only for pairs whose two bodies both appear in some entry
(one flag per body): O(1) for every other pair.
"""
import reprlib

import numpy as np

from collision_node.pipeline._jit import inlined_kernel, kernel
from collision_node.pipeline.contacts import DYNAMIC, STATIC

DEFAULT_CATEGORY = 1
ALL_CATEGORIES = -1  # every bit set: a mask that accepts every category
MAX_ID = 2**31 - 1    # ids fit in the key's 31 low bits; the 32nd marks a static body
_STATIC_KEY_BIT = 1 << 31


def collision_bits(name, values):
    """Return one integer or a list of integers as an int64 array; ValueError naming ``name``.

    A uint64 value keeps its 64 bits (0xFFFFFFFFFFFFFFFF is -1).
    """
    array = np.atleast_1d(np.asarray(values))
    if array.ndim != 1 or array.dtype.kind not in 'iu' and len(array):
        raise ValueError('%s must be one integer or a list of integers, got %s'
                         % (name, reprlib.repr(values)))
    return (array.view(np.int64) if array.dtype == np.uint64 else array).astype(np.int64)


def ignored_pair_keys(pairs):
    """Return the keys of ignored ``(id_a, type_a, id_b, type_b)`` rows, sorted and unique.

    Also returns the ids of the dynamic and of the static bodies they name. Raises ValueError
    on a negative or too large id or an unknown type. A pair of two static bodies is never
    checked anyway; it is left out.
    """
    rows = np.asarray(pairs, dtype=np.int64).reshape(-1, 4)
    keys, dynamic, static = [], [], []
    for id_a, type_a, id_b, type_b in rows.tolist():
        for body_id, body_type in ((id_a, type_a), (id_b, type_b)):
            if body_type not in (DYNAMIC, STATIC):
                raise ValueError('ignored pair %s: type must be %d (dynamic) or %d (static)'
                                 % ((id_a, type_a, id_b, type_b), DYNAMIC, STATIC))
            if not 0 <= body_id <= MAX_ID:
                raise ValueError('ignored pair %s: ids must be in [0, %d]'
                                 % ((id_a, type_a, id_b, type_b), MAX_ID))
        if type_a == STATIC and type_b == STATIC:
            continue
        if type_a == STATIC or (type_b == DYNAMIC and id_b < id_a):  # as the pairs come
            id_a, type_a, id_b, type_b = id_b, type_b, id_a, type_a
        dynamic.append(id_a)
        (static if type_b == STATIC else dynamic).append(id_b)
        keys.append((id_a << 32) | id_b | (_STATIC_KEY_BIT if type_b == STATIC else 0))
    return np.unique(np.array(keys, np.int64)), dynamic, static


def _flags(ids):
    flags = np.zeros(max(ids) + 1 if ids else 0, np.bool_)
    flags[ids] = True
    return flags


def filters_nothing(categories, masks):
    """Whether bodies with these categories and masks pass the mask rule with every body."""
    return bool(np.all(categories != 0) and np.all(masks == ALL_CATEGORIES))


class PairFilter:
    """The dynamic bodies' categories and masks and the ignored pairs; statics come per row."""

    def __init__(self, categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES, ignored_pairs=()):
        """Raise ValueError on values that are not integers or on malformed ignored pairs."""
        self.categories = collision_bits('dynamic collision_category', categories)
        self.masks = collision_bits('dynamic collision_mask', masks)
        if not (len(self.categories) and len(self.masks)):
            raise ValueError('dynamic collision categories and masks need a value for every '
                             'body, or one per body')
        self.ignored_keys, dynamic, static = ignored_pair_keys(ignored_pairs)
        self.dynamic_ignorable = _flags(dynamic)  # by dynamic id: named in an ignored pair
        self.static_ignorable = _flags(static)    # by static id

    @property
    def is_default(self):
        """Whether the dynamic bodies' settings and the ignored pairs filter no pair."""
        return filters_nothing(self.categories, self.masks) and not len(self.ignored_keys)

    def check_count(self, count):
        """Raise ValueError when per-body categories or masks do not fit ``count`` bodies."""
        for name, values in (('collision_category', self.categories),
                             ('collision_mask', self.masks)):
            if len(values) not in (1, count):
                raise ValueError('%s has %d values, the input %d bodies'
                                 % (name, len(values), count))

    def keep_checked(self, pairs, n_static, static_ids, static_categories, static_masks,
                     static_ignorable, dynamic_ids):
        """Move the pairs that pass both rules to the front of ``pairs``; return how many.

        ``pairs`` are box rows as the World orders them (A dynamic; two dynamic bodies in id
        order); the static arrays are per static row.
        """
        return _keep_checked(pairs, n_static, static_ids, static_categories, static_masks,
                             static_ignorable, dynamic_ids, self.categories, self.masks,
                             self.ignored_keys, self.dynamic_ignorable)


@kernel
def _keep_checked(pairs, n_static, static_ids, static_categories, static_masks,
                  static_ignorable, dynamic_ids, categories, masks, ignored_keys,
                  dynamic_ignorable):
    kept = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        id_a = dynamic_ids[a - n_static]
        if b < n_static:
            keep = pair_checked(id_a, static_key(static_ids[b]), static_categories[b],
                                static_masks[b], static_ignorable[b], categories, masks,
                                ignored_keys, dynamic_ignorable)
        else:
            id_b = dynamic_ids[b - n_static]
            category_b, mask_b, ignorable_b = dynamic_bits(id_b, categories, masks,
                                                           dynamic_ignorable)
            keep = pair_checked(id_a, id_b, category_b, mask_b, ignorable_b, categories, masks,
                                ignored_keys, dynamic_ignorable)
        pairs[kept, 0] = a
        pairs[kept, 1] = b
        kept += keep
    return kept


@kernel
def static_key(static_id):
    """Return a static body's id as it appears in an ignored pair's key."""
    return static_id | _STATIC_KEY_BIT


@inlined_kernel
def dynamic_bits(body, categories, masks, dynamic_ignorable):
    """Return (category, mask, named in an ignored pair) of dynamic body ``body``."""
    return (categories[body if len(categories) > 1 else 0],
            masks[body if len(masks) > 1 else 0],
            body < len(dynamic_ignorable) and dynamic_ignorable[body])


@inlined_kernel
def pair_checked(id_a, key_b, category_b, mask_b, ignorable_b, categories, masks,
                 ignored_keys, dynamic_ignorable):
    """Whether dynamic body ``id_a`` and body b pass both rules.

    b is given by its key (its id; a static one's with :func:`static_key`), its bits and
    whether it is named in an ignored pair.
    """
    category_a, mask_a, ignorable_a = dynamic_bits(id_a, categories, masks, dynamic_ignorable)
    keep = (category_a & mask_b) != 0 and (category_b & mask_a) != 0
    if keep and ignorable_b and ignorable_a:
        key = (np.int64(id_a) << 32) | key_b
        at = np.searchsorted(ignored_keys, key)
        keep = not (at < len(ignored_keys) and ignored_keys[at] == key)
    return keep
