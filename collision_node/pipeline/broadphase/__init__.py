"""Broad phases: each one finds the candidate pairs whose boxes may touch.

Every broad phase is a class with the same small API, so the World does not know which one it
holds:

``BroadPhase(settings)``
    ``settings`` is a :class:`Settings`; a phase reads only the fields it needs. The grid (and
    ``auto``, for its grid) also takes a :class:`~collision_node.pipeline.workers.Workers` to
    spread its pair search over threads; the other phases run on the caller's thread.
``set_static(boxes, n_static)``
    Called once per static scene. Static boxes are rows ``[0, n_static)`` of ``boxes``
    (an :class:`collision_node.pipeline.obb.Boxes`); a phase builds what depends on them here.
``move_static(boxes, rows) -> kept``
    Called when static ``rows`` (int64) changed in ``boxes`` (moved or resized) since the
    last set_static or move_static. ``kept`` (bool per row) says which of them the phase's
    static structure now holds as they are; the World pairs the others itself until it calls
    set_static again (:meth:`~collision_node.pipeline.world.World.move_static`). A phase that
    cannot tell returns False: never a structure that is silently stale.
``find_pairs(boxes, n_static, n_dynamic, moved=None) -> (pairs, compared)``
    Called every tick; dynamic boxes are rows ``[n_static, n_static + n_dynamic)``.
    ``moved`` (bool per dynamic row, or None: all) says which dynamic boxes changed since the
    last tick: a phase may leave out the pairs of an unchanged box with a static box or with
    another unchanged box, whose contacts the World keeps from the last tick (the grid does;
    the others ignore it).
    ``pairs`` is an (P, 2) int64 array of row indices: column 0 is a dynamic box, column 1 a
    static box or a dynamic box with a larger row; no pair twice, no static-static pair. It
    holds at least every pair whose AABBs overlap (``sphere``: whose bounding spheres
    overlap; both contain every pair of touching boxes). ``compared`` counts the pair
    comparisons the phase made (the seeds' "compared" column): the AABB (or sphere) tests,
    after the cheap filters that skip a pair without looking at its boxes (a cell phase's
    first-shared-cell rule, a tree's node boxes, the sweep's sorted order). The array stays
    valid until the next call.
``validate(boxes, n_static, n_dynamic, loose=None)``
    For testing (Box2D's ``b2DynamicTree_Validate``): checks the phase's whole structure,
    against itself and against ``boxes`` as its calls left them: static rows as of the last
    set_static or move_static, dynamic rows ``[n_static, n_static + n_dynamic)`` as of the
    last find_pairs. ``loose`` (bool per static row, None: none) marks the rows move_static
    did not keep since the last set_static: the structure still holds them where they were,
    so only their place in it is checked, not their boxes. Raises
    :class:`~.validation.InvalidStructure` (an AssertionError) naming the first
    inconsistency. A dynamic structure made for other counts (bodies came or went, or
    set_static changed the static count) is checked on its own only, as the next find_pairs
    makes a new one: after a set_static on boxes whose dynamic rows are not the last tick's
    (the World writes new storage), pass ``n_dynamic=0``. Plain Python and numpy, never
    called on the tick path: call it from tests, after any call, before the boxes change.
``name``
    The phase's name in :data:`NAMES`; ``auto`` sets it to the phase that ran last.
``stats``
    A dict of the phase's own counters (octree leaves created and dropped, bodies that stayed
    in their leaves, sorts, builds, ...) for the diagnostics.

The phases and when to use each: :mod:`~.brute_force`, :mod:`~.sphere`, :mod:`~.octree`,
:mod:`~.kd_tree`, :mod:`~.sweep_and_prune`, :mod:`~.grid` and :mod:`~.auto` (their module
docstrings; doc/broad-phases.md; the numbers are in doc/benchmarks.md).
"""
from numbers import Integral
from typing import NamedTuple

from collision_node.pipeline.broadphase.brute_force import BruteForce
from collision_node.pipeline.broadphase.grid import Grid
from collision_node.pipeline.broadphase.kd_tree import KdTreePhase
from collision_node.pipeline.broadphase.octree import MAX_DEPTH, Octree
from collision_node.pipeline.broadphase.sphere import Sphere
from collision_node.pipeline.broadphase.sweep_and_prune import SweepAndPrune
from collision_node.pipeline.broadphase.validation import InvalidStructure  # noqa: F401


class Settings(NamedTuple):
    """Tunables of the broad phases, named like the node's parameters."""

    octree_max_depth: int = 0            # 0: chosen from the body size (octree.size_depth)
    octree_leaf_cooldown_ticks: int = 15  # ticks an emptied leaf lives before it is dropped


def check_settings(settings):
    """Return ``settings`` if every field is valid, else raise ValueError saying why."""
    depth = settings.octree_max_depth
    if isinstance(depth, bool) or not isinstance(depth, Integral) or not 0 <= depth <= MAX_DEPTH:
        raise ValueError('octree max depth must be an integer from 0 (automatic) to %d, '
                         'got %r' % (MAX_DEPTH, depth))
    cooldown = settings.octree_leaf_cooldown_ticks
    if isinstance(cooldown, bool) or not isinstance(cooldown, Integral) or cooldown < 0:
        raise ValueError('octree leaf cooldown must be an integer >= 0 ticks, got %r'
                         % (cooldown,))
    return settings


BROAD_PHASES = {phase.name: phase for phase in (BruteForce, Sphere, Octree, KdTreePhase,
                                                SweepAndPrune, Grid)}
NAMES = tuple(BROAD_PHASES) + ('auto',)


def check_broad_phase(name):
    """Return ``name`` if it is one of :data:`NAMES`, else raise ValueError listing them."""
    if name not in NAMES:
        raise ValueError('unknown broad phase %r; choose one of %s' % (name, ', '.join(NAMES)))
    return name


def make_broad_phase(name, settings=Settings(), workers=None):
    """Return a new broad phase called ``name`` (one of :data:`NAMES`).

    ``workers`` (default: the caller's thread only) is handed to the phases that use threads.
    Raises ValueError for an unknown name or invalid settings (:func:`check_settings`).
    """
    check_broad_phase(name)
    check_settings(settings)
    if name == 'auto':
        from collision_node.pipeline.broadphase.auto import Auto
        return Auto(settings, workers)
    if name == Grid.name:
        return Grid(settings, workers)
    return BROAD_PHASES[name](settings)
