"""Static boxes that move, resize, appear and disappear while the dynamic bodies move.

The referees: brute force (every phase must give its contacts, to the bit) and a World built
from scratch at every tick (no history, so no shortcut and no structure that could be stale).
"""
from broadphase_reference import contact_ids, random_quaternions
import numpy as np
import pytest

from collision_node import World
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.general_path import LOOSE_REBUILD_WORK
from collision_node.pipeline.obb import InvalidBox

IDENTITY = [0.0, 0.0, 0.0, 1.0]
SIDE = 6.0  # m: the statics and bodies share this cube, about one contact per body


class ChangingScene:
    """A pool of static colliders (ids for their lifetime) and moving dynamic bodies.

    Every tick some statics move or resize (none, a few, or all), every 20 ticks some appear
    or disappear, and the dynamic bodies move, sometimes only half of them, sometimes none.
    """

    def __init__(self, seed, n_static=160, n_dynamic=240):
        self.rng = np.random.default_rng(seed)
        rng = self.rng
        self.static_poses = np.concatenate([rng.uniform(0, SIDE, (n_static, 3)),
                                            random_quaternions(rng, n_static)], axis=1)
        self.static_extents = rng.uniform(0.05, 0.5, (n_static, 3))
        self.static_extents[:3] *= 8.0  # a few large ones (big boxes in cells and leaves)
        self.present = rng.random(n_static) < 0.8
        self.dynamic_poses = np.concatenate([rng.uniform(0, SIDE, (n_dynamic, 3)),
                                             random_quaternions(rng, n_dynamic)], axis=1)
        self.dynamic_extents = rng.uniform(0.1, 0.3, (n_dynamic, 3))

    def static(self):
        """Return (poses, half extents, ids) of the statics present now."""
        ids = np.flatnonzero(self.present)
        return self.static_poses[ids], self.static_extents[ids], ids

    def advance(self, tick):
        """Change the scene for ``tick``; return True when statics appeared or disappeared."""
        rng = self.rng
        roll = rng.random()
        n = len(self.static_poses)
        if roll < 0.1:
            moving = np.arange(n)  # all of them
        elif roll < 0.7:
            moving = rng.choice(n, rng.integers(1, 6), replace=False)
        else:
            moving = np.zeros(0, np.int64)
        self.static_poses[moving, :3] = (self.static_poses[moving, :3]
                                         + rng.normal(0.0, 0.3, (len(moving), 3))) % SIDE
        resized = moving[rng.random(len(moving)) < 0.3]
        self.static_extents[resized] = rng.uniform(0.05, 0.6, (len(resized), 3))
        dynamic_roll = rng.random()
        if dynamic_roll < 0.6:
            movers = np.arange(len(self.dynamic_poses))
        elif dynamic_roll < 0.85:
            movers = np.arange(0, len(self.dynamic_poses), 2)
        else:
            movers = np.zeros(0, np.int64)  # statics change under still bodies only
        self.dynamic_poses[movers, :3] = (self.dynamic_poses[movers, :3]
                                          + rng.normal(0.0, 0.1, (len(movers), 3))) % SIDE
        if tick % 20 == 19:
            flip = rng.choice(n, 12, replace=False)
            self.present[flip] = ~self.present[flip]
            return True
        return False


def run(names, ticks, seed, margin=0.0, continuous=False):
    """Step a World per name and a brute-force World built afresh each tick.

    Yields (tick, the fresh World's contacts, {name: result}, {name: loose rows before the
    step}). Continuous: the fresh World is given the previous dynamic poses first, so that it
    sweeps the same motion against the statics as they are now.
    """
    scene = ChangingScene(seed)
    worlds = {name: World(broad_phase=name, margin=margin, continuous=continuous)
              for name in names}
    for world in worlds.values():
        world.set_static(*_set_static_args(scene))
    previous = None
    for tick in range(ticks):
        if scene.advance(tick):
            for world in worlds.values():
                world.set_static(*_set_static_args(scene))
        else:
            poses, extents, ids = scene.static()
            for world in worlds.values():
                world.move_static(ids, poses, extents)
        fresh = World(broad_phase='brute_force', margin=margin, continuous=continuous)
        fresh.set_static(*_set_static_args(scene))
        if previous is not None:
            fresh.step(previous, scene.dynamic_extents)
        expected = fresh.step(scene.dynamic_poses, scene.dynamic_extents).contacts
        results = {name: world.step(scene.dynamic_poses, scene.dynamic_extents)
                   for name, world in worlds.items()}
        yield tick, expected, results, {name: len(world._steps.general.loose.rows)
                                        for name, world in worlds.items()}
        if continuous:
            previous = scene.dynamic_poses.copy()


def _set_static_args(scene):
    poses, extents, ids = scene.static()
    return poses, extents, ids, 0.02 * (ids % 3)  # margins of their own for some


@pytest.mark.parametrize('margin', [0.0, 0.05])
def test_every_phase_equals_brute_force_over_500_changing_ticks(margin):
    still_ticks = loose_ticks = 0
    for tick, expected, results, loose in run(NAMES, 500, seed=3, margin=margin):
        assert len(expected) > 50, tick  # not vacuous
        for name, result in results.items():
            assert result.contacts.tobytes() == expected.tobytes(), (name, tick)
        still_ticks += results['grid'].stats['still_bodies'] > 0
        loose_ticks += loose['grid'] > 0
    # Each path really ran: the still-body shortcut and the loose statics, often.
    assert still_ticks > 100 and loose_ticks > 100


@pytest.mark.parametrize('margin', [0.0, 0.05])
def test_every_phase_equals_brute_force_in_continuous_mode_while_statics_change(margin):
    # The swept bounds meet statics that move, resize, appear and disappear (some loose):
    # every phase sweeps the same motion against the same statics as brute force.
    swept = 0
    for tick, expected, results, _ in run(NAMES, 120, seed=5, margin=margin, continuous=True):
        assert len(expected) > 50, tick  # not vacuous
        for name, result in results.items():
            assert result.contacts.tobytes() == expected.tobytes(), (name, tick)
        swept += results['grid'].stats['swept_pairs']
        assert tick == 0 or results['grid'].stats['continuous'] == 'on'
    assert swept > 0  # pairs that touched only between two inputs were found


def test_static_changes_take_the_loose_path_and_the_rebuild_path():
    scene = ChangingScene(seed=4)
    world = World(broad_phase='grid')
    world.set_static(*_set_static_args(scene)[:3])
    world.step(scene.dynamic_poses, scene.dynamic_extents)
    builds = world._steps.general.phase.stats['static_builds']
    poses, extents, ids = scene.static()
    poses = poses.copy()
    poses[:2, 0] += 1e-3  # two boxes, within their cells: the grid refreshes its copies
    assert world.move_static(ids, poses, extents) == 2
    assert world.move_static(ids, poses, extents) == 0  # unchanged: nothing to do
    assert not len(world._steps.general.loose.rows)
    poses[:2, 0] += 3.0  # into other cells: loose, the grid's table stays
    assert world.move_static(ids, poses, extents) == 2
    world.step(scene.dynamic_poses, scene.dynamic_extents)
    assert world._steps.general.phase.stats['static_builds'] == builds
    assert len(world._steps.general.loose.rows) == 2
    poses[:, 0] += 3.0  # all of them: loose, they soon cost more than a rebuild
    world.move_static(ids, poses, extents)
    ticks = 0
    while len(world._steps.general.loose.rows) and ticks < 10:
        assert world._steps.general.phase.stats['static_builds'] == builds
        ticks += 1
        world.step(scene.dynamic_poses + [1e-6 * ticks, 0, 0, 0, 0, 0, 0],
                   scene.dynamic_extents)  # a new input: an unchanged one reuses the answer
    assert ticks == -(-LOOSE_REBUILD_WORK // len(scene.dynamic_poses))  # rounded up
    assert world._steps.general.phase.stats['static_builds'] == builds + 1


def two_boxes_world(name):
    """Put a static box at x = 0 and a dynamic one at x = 3 (apart); return the World."""
    world = World(broad_phase=name)
    world.set_static([[0.0, 0.0, 0.0] + IDENTITY, [10.0, 0.0, 0.0] + IDENTITY],
                     [[0.5, 0.5, 0.5]] * 2, ids=[4, 9])
    return world


DYNAMIC = np.array([[3.0, 0.0, 0.0] + IDENTITY, [-3.0, 0.0, 0.0] + IDENTITY])
SIZE = [0.5, 0.5, 0.5]


@pytest.mark.parametrize('name', NAMES)
def test_a_still_body_meets_a_static_box_that_moved_to_it(name):
    world = two_boxes_world(name)
    assert len(world.step(DYNAMIC, SIZE).contacts) == 0
    # The dynamic bodies keep their pose: the step must not reuse the last (empty) answer.
    world.move_static([4, 9], [[2.5, 0.0, 0.0] + IDENTITY, [10.0, 0.0, 0.0] + IDENTITY],
                      [SIZE] * 2)
    contacts = world.step(DYNAMIC, SIZE).contacts
    assert [(c['id_a'], c['id_b']) for c in contacts] == [(0, 4)]
    assert contacts[0]['depth'] == pytest.approx(0.5)
    # Moved away again while the body stays: the contact is gone, not kept from the last step.
    world.move_static([4, 9], [[0.0, 0.0, 0.0] + IDENTITY, [10.0, 0.0, 0.0] + IDENTITY],
                      [SIZE] * 2)
    assert len(world.step(DYNAMIC, SIZE).contacts) == 0


@pytest.mark.parametrize('name', NAMES)
def test_a_still_body_sees_a_static_box_grow_shrink_and_come_back(name):
    world = two_boxes_world(name)
    world.step(DYNAMIC, SIZE)
    poses = [[0.0, 0.0, 0.0] + IDENTITY, [10.0, 0.0, 0.0] + IDENTITY]
    world.move_static([4, 9], poses, [[2.7, 0.5, 0.5], SIZE])  # grows into both bodies
    contacts = world.step(DYNAMIC, SIZE).contacts
    assert [(c['id_a'], c['id_b']) for c in contacts] == [(0, 4), (1, 4)]
    assert contacts['depth'] == pytest.approx([0.2, 0.2])
    # Half the bodies move: the still one keeps its contact only while the box is unchanged.
    moved = DYNAMIC.copy()
    moved[1, 0] = -3.1
    world.move_static([4, 9], poses, [[2.6, 0.5, 0.5], SIZE])
    contacts = world.step(moved, SIZE).contacts
    assert contacts['depth'] == pytest.approx([0.1, 0.0])
    # Disabled (left out of the statics), then enabled again, the bodies still.
    world.set_static(poses[1:], [SIZE], ids=[9])
    assert len(world.step(moved, SIZE).contacts) == 0
    world.set_static(poses, [[2.6, 0.5, 0.5], SIZE], ids=[4, 9])
    contacts = world.step(moved, SIZE).contacts
    assert [(c['id_a'], c['id_b']) for c in contacts] == [(0, 4), (1, 4)]


def test_invalid_static_moves_change_nothing():
    world = two_boxes_world('grid')
    before = world.step(DYNAMIC, SIZE).contacts.copy()
    good = [[2.5, 0.0, 0.0] + IDENTITY, [10.0, 0.0, 0.0] + IDENTITY]
    bad = [[2.5, 0.0, 0.0] + IDENTITY, [np.nan, 0.0, 0.0] + IDENTITY]
    with pytest.raises(InvalidBox, match='static id 9: pose has a NaN') as error:
        world.move_static([4, 9], bad)
    assert error.value.body == 1
    with pytest.raises(ValueError, match=r'need shape \(2, 7\)'):
        world.move_static([4, 9], good[:1])
    with pytest.raises(ValueError, match='static id 4: half extents'):
        world.move_static([4, 9], good, [[-1.0, 0.5, 0.5], SIZE])
    with pytest.raises(ValueError, match=r'need shape \(2, 3\)'):
        world.move_static([4, 9], good, [SIZE])
    assert world.step(DYNAMIC + [1e-9, 0, 0, 0, 0, 0, 0], SIZE).contacts.tobytes() == \
        before.tobytes()
    assert world.move_static([4, 9], good) == 1
    assert contact_ids(world.step(DYNAMIC, SIZE)).tolist() == [[0, 1, 4]]


def test_a_new_margin_keeps_the_moved_poses():
    world = two_boxes_world('kd_tree')
    world.step(DYNAMIC, SIZE)
    world.move_static([4, 9], [[1.9, 0.0, 0.0] + IDENTITY, [10.0, 0.0, 0.0] + IDENTITY],
                      [SIZE] * 2)
    world.margin = 0.2  # set_static again from the World's own copy, moved pose included
    contacts = world.step(DYNAMIC, SIZE).contacts
    assert [(c['id_b'], round(float(c['distance']), 9)) for c in contacts] == [(4, 0.1)]
