"""The static scene's verbs, by collider id: each all or nothing, any sequence exact.

The referee is a World built afresh from the colliders that survive a sequence of verbs
(``set_static`` with the enabled ones): after every verb and step, the World that lived
through the sequence must answer to the bit as that fresh World does, for every broad phase,
and ``validate()`` must find its scene and its derived rows consistent. A refused verb must
leave everything as it was.
"""
from broadphase_reference import random_quaternions
import numpy as np
import pytest

from collision_node import World
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.static_scene import InvalidCollider, StaticScene

IDENTITY = [0.0, 0.0, 0.0, 1.0]
SIDE = 5.0  # m: colliders and bodies share this cube


def pose(x, y=0.0, z=0.0):
    return [x, y, z] + IDENTITY


def snapshot(scene):
    return [array.copy() for array in scene.colliders] + [scene.version]


def same(a, b):
    return all(np.array_equal(x, y) for x, y in zip(a, b))


# ---------------------------------------------------------------- the scene alone

def test_verbs_change_the_colliders_by_id():
    scene = StaticScene()
    scene.add([7, 3], [pose(0.0), pose(1.0)], [[0.5] * 3] * 2, margins=[0.1, 0.0])
    assert scene.colliders.ids.tolist() == [7, 3] and scene.version == 1
    assert scene.move([3], [pose(2.0)]).tolist() == [1]  # slot 1 moved
    assert scene.colliders.poses[1, 0] == 2.0 and scene.version == 2
    assert scene.move([3], [pose(2.0)]).tolist() == []  # nothing changed: no new version
    assert scene.version == 2
    scene.move([7], half_extents=[[0.2, 0.3, 0.4]])
    assert scene.colliders.half_extents[0].tolist() == [0.2, 0.3, 0.4]
    assert scene.colliders.poses[0, 0] == 0.0  # the pose stays
    scene.enable([7], False)
    assert scene.colliders.enabled.tolist() == [False, True]
    scene.update([3], margins=0.25, masks=6)
    assert scene.colliders.margins.tolist() == [0.1, 0.25]
    assert scene.colliders.masks.tolist() == [-1, 6]
    scene.remove([7])
    assert scene.colliders.ids.tolist() == [3]
    scene.add([7], [pose(4.0)], [0.5, 0.5, 0.5])  # a removed id is free again
    assert scene.colliders.ids.tolist() == [3, 7]
    scene.validate()
    scene.replace([pose(0.0)] * 3, [0.5, 0.5, 0.5])
    assert scene.colliders.ids.tolist() == [0, 1, 2]
    scene.validate()


@pytest.mark.parametrize('verb, words', [
    (lambda s: s.add([2], [pose(0.0)], [1, 1, 1]), 'static id 2: a collider with this id'),
    (lambda s: s.add([5, 5], [pose(0.0)] * 2, [1, 1, 1]), 'static id 5: given twice'),
    (lambda s: s.add([5, 6], [pose(0.0), [0.0] * 7], [1, 1, 1]), 'static id 6: quaternion'),
    (lambda s: s.add([5], [pose(np.nan)], [1, 1, 1]), 'static id 5: pose has a NaN'),
    (lambda s: s.add([5], [pose(0.0)], [1, -1, 1]), 'static id 5: half extents'),
    (lambda s: s.add([5], [pose(0.0)], [1, 1, 1], margins=-1.0), 'static id 5: margin'),
    (lambda s: s.add([-1], [pose(0.0)], [1, 1, 1]), 'static id -1: ids must be in'),
    (lambda s: s.add([5.5], [pose(0.0)], [1, 1, 1]), 'list of integers'),
    (lambda s: s.add([5], [pose(0.0)] * 2, [1, 1, 1]), r'need shape \(1, 7\)'),
    (lambda s: s.move([9], [pose(0.0)]), 'static id 9: no such collider'),
    (lambda s: s.move([1, 1], [pose(0.0)] * 2), 'static id 1: given twice'),
    (lambda s: s.move([1, 2], [pose(0.0), pose(1e10)]), 'static id 2: position beyond'),
    (lambda s: s.move([2], half_extents=[[np.inf, 1, 1]]), 'static id 2: half extents'),
    (lambda s: s.remove([1, 9]), 'static id 9: no such collider'),
    (lambda s: s.enable([1, 9], False), 'static id 9: no such collider'),
    (lambda s: s.enable([1], 'yes'), 'True or False'),
    (lambda s: s.update([2], categories=[1, 2]), 'one value or one per box'),
    (lambda s: s.update([9], margins=0.1), 'static id 9: no such collider'),
    (lambda s: s.replace([pose(0.0)] * 2, [1, 1, 1], ids=[4, 4]), 'static id 4: given twice'),
    (lambda s: s.replace([pose(0.0), pose(np.inf)], [1, 1, 1], ids=[3, 8]), 'static id 8'),
])
def test_a_refused_verb_names_the_id_and_changes_nothing(verb, words):
    scene = StaticScene()
    scene.add([1, 2, 3], [pose(0.0), pose(1.0), pose(2.0)], [0.5, 0.5, 0.5])
    before = snapshot(scene)
    with pytest.raises(ValueError, match=words):
        verb(scene)
    assert same(snapshot(scene), before)
    scene.validate()


def test_a_bad_pose_names_the_collider_and_its_place_in_the_call():
    scene = StaticScene()
    scene.add([10, 20], [pose(0.0), pose(1.0)], [0.5, 0.5, 0.5])
    with pytest.raises(InvalidCollider) as error:
        scene.move([10, 20], [pose(0.0), [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0]])
    assert (error.value.static_id, error.value.body) == (20, 1)


@pytest.mark.parametrize('sabotage, words', [
    (lambda s: s._by_id.__setitem__(0, 1), 'permutation'),
    (lambda s: s._colliders.ids.__setitem__(0, 3), 'appears twice'),
    (lambda s: s._colliders.poses.__setitem__((1, 6), 3.0), 'quaternion'),
    (lambda s: setattr(s, '_colliders', s._colliders._replace(
        margins=s._colliders.margins[:2])), 'margins has 2 entries'),
])
def test_validate_finds_a_broken_scene(sabotage, words):
    scene = StaticScene()
    scene.add([1, 2, 3], [pose(0.0), pose(1.0), pose(2.0)], [0.5, 0.5, 0.5])
    scene.validate()
    sabotage(scene)
    with pytest.raises(AssertionError, match=words):
        scene.validate()


# ---------------------------------------------------------------- the World's verbs

class Pool:
    """Colliders under random verbs, the truth kept here as plain dicts by id."""

    def __init__(self, rng):
        self.rng = rng
        self.colliders = {}  # id -> dict(pose, half_extents, margin, category, mask, enabled)
        self.next_id = 0

    def new(self, count):
        rng = self.rng
        ids = list(range(self.next_id, self.next_id + count))
        self.next_id += count + int(rng.integers(0, 3))  # ids with gaps
        poses = np.concatenate([rng.uniform(0, SIDE, (count, 3)),
                                random_quaternions(rng, count)], axis=1)
        extents = rng.uniform(0.05, 0.6, (count, 3))
        margins = rng.choice([0.0, 0.0, 0.05], count)
        categories = rng.choice([1, 1, 2], count)
        masks = rng.choice([-1, -1, 1, 3], count)
        enabled = rng.random(count) < 0.85
        return ids, poses, extents, margins, categories, masks, enabled

    def record(self, ids, poses, extents, margins, categories, masks, enabled):
        for k, i in enumerate(ids):
            self.colliders[i] = {'pose': poses[k].copy(), 'half_extents': extents[k].copy(),
                                 'margin': float(margins[k]), 'category': int(categories[k]),
                                 'mask': int(masks[k]), 'enabled': bool(enabled[k])}

    def some(self, fraction=0.3):
        ids = sorted(self.colliders)
        chosen = [i for i in ids if self.rng.random() < fraction]
        return chosen or ids[:1]

    def fresh(self, **settings):
        """Return a World built from the surviving enabled colliders alone."""
        world = World(**settings)
        on = [i for i, c in sorted(self.colliders.items()) if c['enabled']]
        c = self.colliders
        world.set_static(np.array([c[i]['pose'] for i in on]).reshape(-1, 7),
                         np.array([c[i]['half_extents'] for i in on]).reshape(-1, 3),
                         ids=on, margins=[c[i]['margin'] for i in on] or 0.0,
                         categories=[c[i]['category'] for i in on] or 1,
                         masks=[c[i]['mask'] for i in on] or -1)
        return world


def random_verb(world, pool):
    """Apply one random verb to ``world`` and ``pool``; return its name."""
    rng = pool.rng
    roll = rng.random()
    if roll < 0.1 or not pool.colliders:
        arguments = pool.new(int(rng.integers(1, 6)))
        world.add_static(*arguments)
        pool.record(*arguments)
        return 'add'
    ids = pool.some()
    if roll < 0.45:
        poses = np.array([pool.colliders[i]['pose'] for i in ids])
        poses[:, :3] = (poses[:, :3] + rng.normal(0.0, 0.4, (len(ids), 3))) % SIDE
        extents = None
        if rng.random() < 0.3:
            extents = rng.uniform(0.05, 0.6, (len(ids), 3))
        world.move_static(ids, poses, extents)
        for k, i in enumerate(ids):
            pool.colliders[i]['pose'] = poses[k]
            if extents is not None:
                pool.colliders[i]['half_extents'] = extents[k]
        return 'move'
    if roll < 0.55:
        world.remove_static(ids)
        for i in ids:
            del pool.colliders[i]
        return 'remove'
    if roll < 0.7:
        flags = rng.random(len(ids)) < 0.5
        world.enable_static(ids, flags)
        for i, flag in zip(ids, flags):
            pool.colliders[i]['enabled'] = bool(flag)
        return 'enable'
    if roll < 0.8:
        margins = rng.choice([0.0, 0.1], len(ids))
        masks = rng.choice([-1, 1, 2], len(ids))
        world.update_static(ids, margins=margins, masks=masks)
        for i, margin, mask in zip(ids, margins, masks):
            pool.colliders[i].update(margin=float(margin), mask=int(mask))
        return 'update'
    if roll < 0.85:
        pool.colliders = {}
        arguments = pool.new(int(rng.integers(5, 20)))
        ids, poses, extents, margins, categories, masks, enabled = arguments
        world.set_static(poses, extents, ids, margins, categories, masks)
        pool.record(ids, poses, extents, margins, categories, masks,
                    np.ones(len(ids), np.bool_))
        return 'set'
    return 'none'


def refused_verb(world, pool):
    """Call a verb that must be refused; return the error's text."""
    rng = pool.rng
    known = sorted(pool.colliders) or [0]
    unknown = pool.next_id + 1000
    calls = [
        lambda: world.move_static([known[0], unknown], [pose(0.0)] * 2),
        lambda: world.move_static(known[:1] * 2, [pose(0.0)] * 2),
        lambda: world.move_static(known[:1], [[0.0] * 7]),
        lambda: world.remove_static([unknown]),
        lambda: world.enable_static([unknown], True),
        lambda: world.update_static(known[:1], margins=np.nan),
        lambda: world.add_static(known[:1], [pose(0.0)], [1.0, 1.0, 1.0]),
        lambda: world.add_static([unknown], [pose(np.nan)], [1.0, 1.0, 1.0]),
        lambda: world.set_static([pose(0.0), pose(1.0)], [[1.0, 1.0, -1.0]] * 2),
    ]
    with pytest.raises(ValueError) as error:
        calls[int(rng.integers(len(calls)))]()
    return str(error.value)


def run_sequence(name, seed, steps, margin=0.0, continuous=False):
    rng = np.random.default_rng([seed, NAMES.index(name)])
    pool = Pool(rng)
    settings = {'broad_phase': name, 'margin': margin, 'continuous': continuous}
    world = World(**settings)
    arguments = pool.new(25)
    world.add_static(*arguments)
    pool.record(*arguments)
    dynamic = np.concatenate([rng.uniform(0, SIDE, (40, 3)), random_quaternions(rng, 40)], 1)
    extents = rng.uniform(0.1, 0.3, (40, 3))
    world.step(dynamic, extents)  # continuous: a motion from here on, also before a refusal
    previous = dynamic.copy()
    verbs = set()
    for step in range(steps):
        for _ in range(int(rng.integers(0, 3))):
            verbs.add(random_verb(world, pool))
        if rng.random() < 0.2:
            last = world.step(dynamic, extents).contacts.tobytes()
            refused_verb(world, pool)
            world.validate()
            # Nothing changed: the same input still gets the same answer.
            assert world.step(dynamic, extents).contacts.tobytes() == last
        movers = rng.random(len(dynamic)) < rng.choice([0.0, 0.3, 1.0])
        dynamic[movers, :3] = (dynamic[movers, :3]
                               + rng.normal(0.0, 0.1, (movers.sum(), 3))) % SIDE
        world.validate()
        fresh = pool.fresh(**settings)
        if continuous:
            fresh.step(previous, extents)
        expected = fresh.step(dynamic, extents).contacts
        got = world.step(dynamic, extents).contacts
        assert got.tobytes() == expected.tobytes(), (name, seed, step)
        previous = dynamic.copy()
    return verbs


@pytest.mark.parametrize('name', NAMES)
def test_any_sequence_of_verbs_answers_as_a_fresh_world(name):
    verbs = set()
    for seed in range(2):
        verbs |= run_sequence(name, seed, 40, margin=0.05 * seed)
    assert verbs >= {'add', 'move', 'remove', 'enable', 'update', 'set'}  # all of them ran


@pytest.mark.slow
@pytest.mark.parametrize('name', NAMES)
def test_any_sequence_of_verbs_answers_as_a_fresh_world_many(name):
    for seed in range(2, 8):
        run_sequence(name, seed, 120, margin=0.05 * (seed % 2), continuous=seed % 3 == 0)


def test_a_disabled_collider_keeps_its_moves_for_when_it_is_enabled():
    world = World(broad_phase='grid')
    world.add_static([5], [pose(0.0)], [0.5, 0.5, 0.5], enabled=False)
    body = [pose(3.0)]
    assert len(world.step(body, [0.5, 0.5, 0.5]).contacts) == 0
    assert world.move_static([5], [pose(2.5)]) == 1  # moved while disabled: no row, no tick
    assert world.static_count == 0
    world.enable_static([5], True)
    assert world.step(body, [0.5, 0.5, 0.5]).contacts[['id_a', 'id_b']].tolist() == [(0, 5)]
    world.validate()


def test_validate_finds_a_row_that_lost_its_collider():
    world = World(broad_phase='brute_force')
    world.add_static([1, 2], [pose(0.0), pose(3.0)], [0.5, 0.5, 0.5])
    world.validate()
    world._rows.boxes.centers[0, 0] += 1e-9  # a static row no longer holds its collider's box
    with pytest.raises(AssertionError, match='static row holds another centers'):
        world.validate()
