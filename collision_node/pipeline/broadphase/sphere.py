"""Bounding spheres (the "sphere test" of "Engine Algorithms"): brute force on squared distances.

"Engine Algorithms" measured it up to 2× faster than SAT on all pairs at 500 + 500 boxes; against
an AABB brute force it only pays where spheres are tight (near-cubic boxes). Its candidates are the
pairs whose bounding spheres overlap, not those whose AABBs do; both sets hold every pair of
touching boxes. The same test runs before the SAT after any broad phase when the World's
``sphere_prefilter`` is on.

When to use: as the paper's baseline. Like brute force it is O(D·S + D²/2); the measured
``auto`` prefers brute force below ~60 bodies and the sweep or the grid above
(doc/benchmarks.md).
"""
from collision_node.pipeline.broadphase.brute_force import BruteForce


class Sphere(BruteForce):
    """All pairs, filtered by their bounding spheres."""

    name = 'sphere'
    uses_spheres = True
