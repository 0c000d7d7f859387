"""Broad phases: each one finds the candidate pairs whose boxes may touch.

Every broad phase is a class with the same small API, so the World does not know which one it
holds:

``BroadPhase(settings)``
    ``settings`` is a :class:`Settings`; a phase reads only the fields it needs.
``set_static(boxes, n_static)``
    Called once per static scene. Static boxes are rows ``[0, n_static)`` of ``boxes``
    (an :class:`collision_node.obb.Boxes`); a phase builds what depends on them here.
``find_pairs(boxes, n_static, n_dynamic) -> (pairs, compared)``
    Called every tick; dynamic boxes are rows ``[n_static, n_static + n_dynamic)``.
    ``pairs`` is an (P, 2) int64 array of row indices: column 0 is a dynamic box, column 1 a
    static box or a dynamic box with a larger row; no pair twice, no static-static pair. It
    holds at least every pair whose AABBs overlap (``sphere``: whose bounding spheres
    overlap; both contain every pair of touching boxes). ``compared`` counts the pair comparisons
    the phase made (the seeds' "compared" column). The array stays valid until the next call.
"""
from typing import NamedTuple

from collision_node.broadphase.brute_force import BruteForce
from collision_node.broadphase.grid import Grid
from collision_node.broadphase.kd_tree import KdTreePhase
from collision_node.broadphase.octree import Octree
from collision_node.broadphase.sphere import Sphere
from collision_node.broadphase.sweep_and_prune import SweepAndPrune


class Settings(NamedTuple):
    """Tunables of the broad phases, named like the node's parameters."""

    octree_max_depth: int = 0            # 0: chosen from the body count
    octree_leaf_cooldown_ticks: int = 15  # ticks an emptied leaf lives before it is dropped


BROAD_PHASES = {phase.name: phase for phase in (BruteForce, Sphere, Octree, KdTreePhase,
                                                SweepAndPrune, Grid)}
NAMES = tuple(BROAD_PHASES) + ('auto',)


def make_broad_phase(name, settings=Settings()):
    """Return a new broad phase called ``name`` (one of :data:`NAMES`)."""
    if name == 'auto':
        from collision_node.broadphase.auto import Auto
        return Auto(settings)
    if name not in BROAD_PHASES:
        raise ValueError('unknown broad phase %r; choose one of %s' % (name, ', '.join(NAMES)))
    return BROAD_PHASES[name](settings)
