"""What every path reads: the static rows derived from the scene, and the World's options.

The World owns one :class:`SceneRows` and is its only writer; the paths (general_path.py,
one_pass.py, robot_path.py) read it and never change it. From the scene (static_scene.py) it
derives the static rows: the enabled colliders, in spatial order (z_order.py), as boxes padded
by half the margin, with each row's id, collision bits and the ``statics`` table of the one
pass (small_scene.py).

Versions. Every change draws a number from one counter, ``version``: a change that can alter
any answer (the rows derived again, the filters, an option) records it as ``rebuilt_at``; a
static collider that moves stamps its row with it (``moved_at``), and ``moved_version`` is the
last such stamp; ``built_at`` is the version the rows were derived at. A path keys each of its
caches on these numbers and its own inputs, so no change has to remember to drop a cache, and
no path drops another's: a new option reaches every path as new :class:`Options` with a new
version, which each path meets on its next call.
"""
from typing import NamedTuple

import numpy as np

from collision_node.pipeline.broadphase import Settings
from collision_node.pipeline.filters import filters_nothing, PairFilter
from collision_node.pipeline.obb import Boxes, InvalidBox, pad_bounds, set_boxes
from collision_node.pipeline.small_scene import checked_pairs, statics_table
from collision_node.pipeline.z_order import inverse, z_order

# Least bodies in a chunk when their boxes are written over threads: ~35 ns a body, so ~0.3 ms
# a chunk.
MIN_BODIES_PER_CHUNK = 8192


class Options(NamedTuple):
    """The World's settings that change answers or how they are found (world.py's setters)."""

    broad_phase: str
    phase_settings: Settings
    margin: float             # m
    sphere_prefilter: bool
    continuous: bool
    tolerance: float          # m, continuous.py

    def settings(self):
        """Return the World constructor's keyword arguments that give these options."""
        return {'broad_phase': self.broad_phase, 'sphere_prefilter': self.sphere_prefilter,
                'octree_max_depth': self.phase_settings.octree_max_depth,
                'octree_leaf_cooldown_ticks': self.phase_settings.octree_leaf_cooldown_ticks,
                'margin': self.margin, 'continuous': self.continuous,
                'continuous_tolerance': self.tolerance}


class StaticRows(NamedTuple):
    """One entry per static row (enabled collider)."""

    slots: np.ndarray        # the collider's slot in the scene
    ids: np.ndarray          # its id, as the cloud reports it
    categories: np.ndarray   # its collision bits
    masks: np.ndarray
    ignorable: np.ndarray    # named in an ignored pair (filters.py)
    moved_at: np.ndarray     # the version of its last move (at least one entry, for kernels)
    row_of_slot: np.ndarray  # per scene slot: its row, -1 when disabled
    own_margins: bool        # whether any collider has a margin of its own
    by_id: np.ndarray        # small_scene.statics_table: rows, ids, bits and flags by id

    @property
    def count(self):
        return len(self.ids)


class SceneRows:
    """The static rows and options at a version (module docstring): the paths' common input."""

    def __init__(self, options, workers):
        self.version = 0
        self.rebuilt_at = 0
        self.built_at = 0
        self.moved_version = 0
        self.options = options
        self.filter = PairFilter()
        self.filtering = False  # whether any filter can drop a pair
        self.workers = workers
        self.boxes = Boxes(1)  # the static rows' boxes, padded by half the margin
        self.rows = None

    @property
    def count(self):
        return self.rows.count

    def derive(self, colliders):
        """Derive the static rows from the scene's ``colliders``: the enabled ones."""
        slots = np.flatnonzero(colliders.enabled)
        count = len(slots)
        poses = colliders.poses[slots]
        order = z_order(poses[:, :3])
        rows = inverse(order)
        boxes = Boxes(max(count, 1))
        set_boxes(boxes, 0, poses, colliders.half_extents[slots], rows)
        margins = colliders.margins[slots]
        boxes.margins[:count] = margins[order]
        own_margins = bool(np.any(margins > 0.0))
        margin = self.options.margin
        if margin > 0.0 or own_margins:  # padding with 0 changes no bit
            pad_bounds(boxes.aabbs, boxes.radii, boxes.margins, rows, 0, margin / 2)
        row_of_slot = np.full(len(colliders.ids), -1, np.int64)
        row_of_slot[slots] = rows
        in_rows = slots[order]
        self.boxes = boxes
        self.changed()
        self.built_at = self.version
        self._set_rows(StaticRows(
            in_rows, colliders.ids[in_rows], colliders.categories[in_rows],
            colliders.masks[in_rows], np.zeros(count, np.bool_),
            np.zeros(max(count, 1), np.int64), row_of_slot, own_margins, None))

    def move(self, colliders, slots):
        """Write the rows of the moved colliders ``slots`` again; return the rows, sorted."""
        rows = self.rows.row_of_slot[slots]
        rows = np.sort(rows[rows >= 0])  # in memory order
        if not len(rows):
            return rows
        moved = self.rows.slots[rows]
        write_bodies(self.boxes, 0, colliders.poses[moved], colliders.half_extents[moved],
                     rows, slice(None), self.workers)
        if self.has_margins:
            pad_bounds(self.boxes.aabbs, self.boxes.radii, self.boxes.margins, rows, 0,
                       self.options.margin / 2)
        self.version += 1
        self.moved_version = self.version
        self.rows.moved_at[rows] = self.version
        return rows

    def set_filter(self, pair_filter):
        """Take ``pair_filter`` (filters.py) for every pair."""
        self.filter = pair_filter
        self._set_rows(self.rows)
        self.changed()

    def set_options(self, options, colliders):
        """Take new ``options``; the rows are derived again when the margin pads them."""
        margin = self.options.margin
        self.options = options
        if options.margin != margin:
            self.derive(colliders)
        else:
            self.changed()

    def changed(self):
        """Record a change after which no earlier answer holds (module docstring)."""
        self.version += 1
        self.rebuilt_at = self.version

    def _set_rows(self, rows):
        """Take ``rows`` as the static rows, with their ignorable flags for the filter."""
        flags = self.filter.static_ignorable
        ignorable = np.zeros(rows.count, np.bool_) if not len(flags) else \
            flags[np.minimum(rows.ids, len(flags) - 1)] & (rows.ids < len(flags))
        self.rows = rows._replace(ignorable=ignorable, by_id=statics_table(
            rows.ids, rows.categories, rows.masks, ignorable))
        self.filtering = not (self.filter.is_default
                              and filters_nothing(rows.categories, rows.masks))

    def pass_rows(self, bodies):
        """Return small_scene's ``rows``: a copy of the static rows with room for ``bodies``.

        With any margin the box margins go too, as the general path passes them, even when no
        collider has one of its own (it adds 0.0: no bit changes): one compiled variant of
        the one pass fewer.
        """
        boxes = self.boxes.grown(self.count + bodies, self.count)
        return (boxes.centers, boxes.rotations, boxes.half_extents, boxes.aabbs, boxes.radii,
                boxes.margins if self.has_margins else None)

    def pass_options(self, bodies):
        """Return small_scene's ``options`` for ``bodies`` bodies (its module docstring)."""
        margin = self.options.margin
        return (margin if self.has_margins else None, margin / 2,
                self.options.sphere_prefilter, self.filter_table(bodies))

    @property
    def has_margins(self):
        """Whether any pair has a margin: the World's, or a collider's own."""
        return self.options.margin > 0.0 or self.rows.own_margins

    def filter_table(self, count):
        """Return small_scene.checked_pairs for ``count`` bodies (all True: no filter at all).

        A table even without filters, not None: the one pass then compiles one variant fewer
        (half a first start's compile of it), for a load per candidate pair.
        """
        if not self.filtering:
            return np.ones((count, count + len(self.rows.by_id)), np.bool_)
        filters = self.filter
        return checked_pairs(count, self.rows.by_id, filters.categories, filters.masks,
                             filters.ignored_keys, filters.dynamic_ignorable)

    def validate(self, colliders):
        """Check the rows against the scene's ``colliders``: raise AssertionError if stale."""
        rows = self.rows
        enabled = np.flatnonzero(colliders.enabled)
        assert np.array_equal(np.sort(rows.slots), enabled), \
            'the static rows are not the enabled colliders'
        assert np.array_equal(rows.row_of_slot[rows.slots], np.arange(rows.count)), \
            'row_of_slot does not invert the rows'
        assert np.all(rows.row_of_slot[~colliders.enabled] == -1), 'a disabled row'
        assert np.array_equal(rows.ids, colliders.ids[rows.slots]), 'a row has another id'
        assert np.array_equal(rows.categories, colliders.categories[rows.slots]) and \
            np.array_equal(rows.masks, colliders.masks[rows.slots]), 'stale filter bits'
        expected = Boxes(rows.count)
        set_boxes(expected, 0, colliders.poses[rows.slots], colliders.half_extents[rows.slots])
        for name in ('centers', 'rotations', 'half_extents'):
            assert np.array_equal(getattr(expected, name),
                                  getattr(self.boxes, name)[:rows.count]), \
                'a static row holds another %s than its collider' % name
        assert np.array_equal(self.boxes.margins[:rows.count],
                              colliders.margins[rows.slots]), 'a static row has another margin'


def write_bodies(boxes, first, poses, half_extents, rows, bodies, workers):
    """Write ``poses[bodies]`` to rows ``first + rows[bodies]``; return ``rows[bodies]``.

    ``bodies``: an index array, or ``slice(None)`` for all (views, no copies); ``half_extents``
    one per pose or (3,) for all. The bodies are cut into chunks over the ``workers``' threads
    (each writes its own rows). Raises InvalidBox naming the first invalid body by its index
    in ``poses``, whichever thread met it; the other chunks may be written.
    """
    if half_extents.shape not in ((3,), (len(poses), 3)):  # chunks would hide a mismatch
        raise ValueError('half extents must have shape (3,) or (%d, 3), got %s'
                         % (len(poses), half_extents.shape))
    written = rows[bodies]
    taken = poses[bodies]
    extents = half_extents[bodies] if half_extents.ndim == 2 else half_extents

    def chunk(_, start, stop):
        try:
            set_boxes(boxes, first, taken[start:stop],
                      extents[start:stop] if extents.ndim == 2 else extents,
                      written[start:stop])
        except InvalidBox as error:
            return start + error.body, error.reason
        return None

    refused = [bad for bad in workers.map_ranges(chunk, len(written), MIN_BODIES_PER_CHUNK)
               if bad is not None]
    if refused:
        index, reason = min(refused)
        raise InvalidBox(int(np.arange(len(poses))[bodies][index]), reason)
    return written


def as_poses(poses):
    """Return ``poses`` as a writable C-contiguous float64 (N, 7) array (no copy if it is)."""
    if type(poses) is not np.ndarray or poses.dtype != np.float64 or poses.ndim != 2 \
            or not poses.flags.c_contiguous or not poses.flags.writeable:
        # Writable too: numba compiles a read-only array (a message's bytes) apart.
        poses = np.require(poses, np.float64, ['C', 'A', 'W']).reshape(-1, 7)
    if poses.shape[1] != 7:
        raise ValueError('poses must have shape (N, 7) as x y z qx qy qz qw, got %s'
                         % (poses.shape,))
    return poses
