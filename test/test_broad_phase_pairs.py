"""World.broad_phase_pairs: what a general step's broad phase hands the SAT, changing no step."""
import numpy as np
import pytest

from collision_node import DYNAMIC, STATIC, World
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.obb import aabbs_overlap
from collision_node.pipeline.scenes import uniform


def pair_keys(broad):
    """Return the set of (id_a, type_b, id_b) of the pairs, a dynamic pair with id_a < id_b."""
    keys = set()
    for a, b in broad.pairs.tolist():
        assert broad.types[a] == DYNAMIC
        id_a, id_b, type_b = int(broad.ids[a]), int(broad.ids[b]), int(broad.types[b])
        if type_b == DYNAMIC and id_b < id_a:
            id_a, id_b = id_b, id_a
        keys.add((id_a, type_b, id_b))
    return keys


def contact_keys(contacts):
    return set(zip(contacts['id_a'].tolist(), contacts['type_b'].tolist(),
                   contacts['id_b'].tolist()))


def overlapping_keys(broad):
    """Return the keys of every (body, other) pair of rows whose AABBs overlap: brute force."""
    n_static = int(np.sum(broad.types == STATIC))
    keys = set()
    for a in range(n_static, len(broad.ids)):
        for b in range(a):
            if aabbs_overlap(broad.boxes.aabbs, a, b):
                pair = np.array([[a, b]])
                keys |= pair_keys(broad._replace(pairs=pair))
    return keys


def scene_world(phase, seed=3, **settings):
    scene = uniform(400, seed=seed)
    world = World(broad_phase=phase, **settings)
    world.set_static(scene.static_poses, scene.static_half_extents,
                     ids=np.arange(len(scene.static_poses)) + 100)
    return scene, world


@pytest.mark.parametrize('phase', NAMES)
def test_the_pairs_hold_every_colliding_pair_of_step(phase):
    scene, world = scene_world(phase)
    for tick in range(3):
        poses = scene.dynamic_poses(tick * 0.5)
        broad = world.broad_phase_pairs(poses, scene.dynamic_half_extents)
        contacts = world.step(poses, scene.dynamic_half_extents).contacts
        assert len(contacts) > 100
        assert contact_keys(contacts) <= pair_keys(broad)
        assert broad.compared >= broad.candidates >= len(broad.pairs)
        assert set(broad.ids[broad.types == STATIC].tolist()) == set(range(100, 300))
        assert sorted(broad.ids[broad.types == DYNAMIC].tolist()) == list(range(len(poses)))


def test_brute_force_pairs_are_exactly_the_overlapping_aabbs():
    scene, world = scene_world('brute_force', seed=5)
    poses = scene.dynamic_poses(0.25)
    broad = world.broad_phase_pairs(poses, scene.dynamic_half_extents)
    assert pair_keys(broad) == overlapping_keys(broad)
    assert len(broad.pairs) == len(pair_keys(broad))  # each pair once
    n_dynamic, n_static = len(poses), len(scene.static_poses)
    assert broad.compared == n_dynamic * (n_dynamic - 1) // 2 + n_dynamic * n_static
    # The boxes are those the poses give: each body's row is centred at its position.
    rows = np.flatnonzero(broad.types == DYNAMIC)
    assert np.array_equal(broad.boxes.centers[rows], poses[broad.ids[rows], :3])
    assert not broad.pairs.flags.writeable and not broad.boxes.aabbs.flags.writeable


@pytest.mark.parametrize('phase', ['grid', 'octree', 'brute_force'])
def test_a_call_changes_no_step(phase):
    """A World that is asked between steps answers, and reuses, as one that is not."""
    scene, asked = scene_world(phase, margin=0.01)
    _, plain = scene_world(phase, margin=0.01)
    extents = scene.dynamic_half_extents
    first, second = scene.dynamic_poses(0.0), scene.dynamic_poses(0.5)
    some_moved = first.copy()
    some_moved[::10] = second[::10]
    for poses in (first, first, some_moved, second):
        asked.broad_phase_pairs(scene.dynamic_poses(1.0), extents)
        got, expected = asked.step(poses, extents), plain.step(poses, extents)
        assert got.contacts.tobytes() == expected.contacts.tobytes()
        for key in ('reused', 'still_bodies', 'compared', 'candidate_pairs', 'sat_tests'):
            assert got.stats[key] == expected.stats[key], key
    asked.validate()


def test_invalid_poses_are_refused_as_by_step():
    _, world = scene_world('grid')
    with pytest.raises(ValueError, match='body 1'):
        world.broad_phase_pairs([[0, 0, 0, 0, 0, 0, 1], [np.nan, 0, 0, 0, 0, 0, 1]],
                                [0.5, 0.5, 0.5])
    broad = world.broad_phase_pairs(np.zeros((0, 7)), [0.5, 0.5, 0.5])
    assert len(broad.pairs) == 0 and broad.compared == 0
