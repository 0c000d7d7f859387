"""Long runs: 10,000 ticks of random motion, bodies coming and going, in every broad phase.

Every phase must give exactly brute force's contacts at every tick, and the process must not
grow: structures that are rebuilt, grown, cooled down and dropped over and over (octree
leaves, grid tables, sort orders, pair buffers) must not leak.
"""
import numpy as np
import pytest

from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.world import World

TICKS = 10_000
WARM_TICKS = 1_000       # RSS is compared from here on: buffers have grown to their size
MAX_GROWTH_MB = 4.0      # a leak of 450 bytes a tick over the 9,000 ticks measured
MAX_BODIES = 120
STATIC_BODIES = 40
SIDE = 6.0               # m, the cube the bodies wander in
TRAVEL_EVERY = 50        # ticks; then a few bodies jump 1e5 m away, and back 50 ticks later


def resident_mb():
    with open('/proc/self/statm') as statm:
        pages = int(statm.read().split()[1])
    return pages * 4096 / 2**20


class Wander:
    """Bodies on random walks in a cube; the count changes every few ticks."""

    def __init__(self, seed=7):
        self.rng = np.random.default_rng(seed)
        self.positions = self.rng.uniform(0.0, SIDE, (MAX_BODIES, 3))
        self.quaternions = self._unit(self.rng.normal(size=(MAX_BODIES, 4)))
        self.extents = self.rng.uniform(0.05, 0.5, (MAX_BODIES, 3))
        self.static_poses = np.hstack([self.rng.uniform(0.0, SIDE, (STATIC_BODIES, 3)),
                                       self._unit(self.rng.normal(size=(STATIC_BODIES, 4)))])
        self.static_extents = self.rng.uniform(0.05, 0.8, (STATIC_BODIES, 3))
        self.count = MAX_BODIES
        self.travellers = self.rng.permutation(MAX_BODIES)[:5]

    @staticmethod
    def _unit(quaternions):
        return quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)

    def step(self, tick):
        self.positions += self.rng.normal(0.0, 0.05, self.positions.shape)
        np.clip(self.positions, 0.0, SIDE, out=self.positions)
        self.quaternions = self._unit(
            self.quaternions + self.rng.normal(0.0, 0.05, self.quaternions.shape))
        if tick % 7 == 0:  # bodies enter and leave: the PoseArray length changes
            self.count = int(self.rng.integers(0, MAX_BODIES + 1))
        positions = self.positions.copy()
        if (tick // TRAVEL_EVERY) % 2:
            positions[self.travellers] += 1e5
        poses = np.hstack([positions, self.quaternions])[:self.count]
        return poses, self.extents[:self.count]


def test_ten_thousand_ticks_every_phase_equals_brute_force_and_memory_stays_flat():
    scene = Wander()
    worlds = {name: World(broad_phase=name) for name in NAMES}
    for world in worlds.values():
        world.set_static(scene.static_poses, scene.static_extents)
    compared_contacts = 0
    for tick in range(TICKS):
        if tick == WARM_TICKS:
            warm_mb = resident_mb()
        poses, extents = scene.step(tick)
        results = {name: world.step(poses, extents) for name, world in worlds.items()}
        truth = results['brute_force'].contacts[['id_a', 'type_b', 'id_b']]
        for name, result in results.items():
            found = result.contacts[['id_a', 'type_b', 'id_b']]
            assert np.array_equal(found, truth), (name, tick)
        compared_contacts += len(truth)
    growth_mb = resident_mb() - warm_mb
    assert compared_contacts > TICKS  # the bodies really collide, about 2 pairs a tick or more
    assert growth_mb < MAX_GROWTH_MB, 'RSS grew %.1f MB over %d ticks' % (
        growth_mb, TICKS - WARM_TICKS)


@pytest.mark.slow
def test_memory_of_a_long_large_run_stays_flat():
    """The same check with the grid at 20,000 bodies over 2,000 ticks (about 3 minutes)."""
    from collision_node.pipeline.scenes import uniform
    scene = uniform(20_000, seed=3)
    world = World(broad_phase='grid')
    world.set_static(scene.static_poses, scene.static_half_extents)
    for tick in range(2_000):
        if tick == 200:
            warm_mb = resident_mb()
        world.step(scene.dynamic_poses(tick / 30.0), scene.dynamic_half_extents)
    assert resident_mb() - warm_mb < MAX_GROWTH_MB
