"""The safety margin through the World: which pairs, their signed distance, every broad phase.

Independent references: python-fcl's box–box distance (its GJK is accurate on the generic
pairs used here; flush faces, where it is not, are test_distance.py's business) and
constructed pairs whose distance is known in closed form.
"""
from broadphase_reference import random_quaternions
import fcl
import numpy as np
import pytest

from collision_node import DYNAMIC, STATIC, World
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.obb import (check_margin, check_tolerance, InvalidDistance,
                                         MAX_COORDINATE)
from collision_node.pipeline.scenes import uniform

MARGIN = 0.05
STATIC_MARGIN = 0.02


def rotation(quaternion):
    x, y, z, w = np.asarray(quaternion) / np.linalg.norm(quaternion)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def fcl_distance(pose_a, extents_a, pose_b, extents_b):
    objects = [fcl.CollisionObject(fcl.Box(*(2.0 * np.asarray(e))),
                                   fcl.Transform(rotation(p[3:]), np.asarray(p[:3])))
               for p, e in ((pose_a, extents_a), (pose_b, extents_b))]
    return fcl.distance(*objects, fcl.DistanceRequest(), fcl.DistanceResult())


def keys(contacts):
    return [tuple(int(v) for v in row) for row in
            zip(contacts['id_a'], contacts['type_b'], contacts['id_b'])]


def scene_step(world, n=600, seed=2, time_s=0.0):
    scene = uniform(n, seed)
    world.set_static(scene.static_poses, scene.static_half_extents, margins=STATIC_MARGIN)
    return scene, world.step(scene.dynamic_poses(time_s), scene.dynamic_half_extents)


@pytest.mark.parametrize('name', NAMES)
def test_every_broad_phase_reports_brute_force_s_pairs(name):
    scene = uniform(1500, seed=7)
    reference, world = World('brute_force', margin=MARGIN), World(name, margin=MARGIN)
    for w in (reference, world):
        w.set_static(scene.static_poses, scene.static_half_extents, margins=STATIC_MARGIN)
    for time_s in (0.0, 0.1, 0.1, 0.3):  # the repeat: still bodies keep their near pairs
        poses = scene.dynamic_poses(time_s)
        poses[::3] = scene.dynamic_poses(0.0)[::3]
        expected = reference.step(poses, scene.dynamic_half_extents)
        result = world.step(poses, scene.dynamic_half_extents)
        assert result.stats['near_pairs'] > 50
        np.testing.assert_array_equal(result.contacts, expected.contacts)


def test_reported_pairs_and_distances_against_fcl():
    world = World('brute_force', margin=MARGIN)
    scene, result = scene_step(world)
    poses, extents = scene.dynamic_poses(0.0), scene.dynamic_half_extents
    reported = dict(zip(keys(result.contacts), result.contacts))
    bodies = {(DYNAMIC, i): (poses[i], extents[i]) for i in range(len(poses))}
    bodies.update({(STATIC, i): (scene.static_poses[i], scene.static_half_extents[i])
                   for i in range(len(scene.static_poses))})
    near_checked = 0
    for a in range(len(poses)):
        for (kind, b), (pose_b, extents_b) in bodies.items():
            if kind == DYNAMIC and b <= a:
                continue
            size = np.sum(extents[a]) + np.sum(extents_b)
            if np.linalg.norm(poses[a, :3] - pose_b[:3]) > 2 * size + 0.2:
                continue  # far apart: no need to ask fcl
            margin = MARGIN + (STATIC_MARGIN if kind == STATIC else 0.0)
            exact = fcl_distance(poses[a], extents[a], pose_b, extents_b)
            key = (a, kind, b)
            if exact > 0.0:
                tolerance = 1e-9 * size
                if exact < margin - tolerance:
                    assert key in reported, (key, exact)
                elif exact > margin + tolerance:
                    assert key not in reported, (key, exact)
                if key in reported:
                    near_checked += 1
                    contact = reported[key]
                    assert contact['distance'] == pytest.approx(exact, abs=tolerance)
                    assert contact['depth'] == 0.0
            elif key in reported:  # fcl says 0 when they overlap: ours has the depth
                assert reported[key]['distance'] == -reported[key]['depth'] <= 0.0
    assert near_checked > 100


def test_a_near_pair_has_its_closest_points_and_the_normal_between_them():
    world = World('brute_force', margin=1.0)
    rng = np.random.default_rng(3)
    poses = np.zeros((2, 7))
    poses[:, 3:] = random_quaternions(rng, 2)
    poses[1, :3] = (1.3, 0.4, -0.2)
    extents = np.array([[0.3, 0.2, 0.1], [0.25, 0.15, 0.35]])
    contact, = world.step(poses, extents).contacts
    normal = np.array([contact['normal_x'], contact['normal_y'], contact['normal_z']])
    point = np.array([contact['x'], contact['y'], contact['z']])
    distance = contact['distance']
    assert distance == pytest.approx(fcl_distance(poses[0], extents[0], poses[1], extents[1]),
                                     abs=1e-12)
    assert np.linalg.norm(normal) == pytest.approx(1.0)
    for sign, pose, half in ((-1, poses[0], extents[0]), (1, poses[1], extents[1])):
        closest = point + sign * normal * distance / 2
        local = rotation(pose[3:]).T @ (closest - pose[:3])
        assert np.all(np.abs(local) <= half + 1e-12)  # on (the surface of) its box


def test_the_normal_of_a_near_pair_is_unit_and_separating_at_tiny_gaps():
    # Closest points 1e-15..1e-11 apart are mostly rounding noise: their offset divided by the
    # distance once gave a "unit" normal 11 long. Whatever the gap (1e-15..1e-4 here), the
    # normal must be unit and separate the boxes: B's extent along it starts no earlier than
    # A's ends (to rounding).
    rng = np.random.default_rng(11)
    world = World('brute_force', margin=10.0)
    for _ in range(1000):
        poses = np.zeros((2, 7))
        poses[:, 3:] = random_quaternions(rng, 2)
        extents = rng.uniform(0.1, 1.0, (2, 3))
        direction = rng.normal(size=3)
        poses[1, :3] = 5.0 * direction / np.linalg.norm(direction)
        far = world.step(poses, extents).contacts[0]
        towards = -np.array([far['normal_x'], far['normal_y'], far['normal_z']])
        gap = 10.0 ** rng.uniform(-15, -4)
        poses[1, :3] += towards * (far['distance'] - gap)
        contact, = world.step(poses, extents).contacts
        normal = np.array([contact['normal_x'], contact['normal_y'], contact['normal_z']])
        assert np.linalg.norm(normal) == pytest.approx(1.0, abs=1e-12)
        reach = [np.abs(rotation(p[3:]).T @ normal) @ e for p, e in zip(poses, extents)]
        gap_along_normal = normal @ (poses[1, :3] - poses[0, :3]) - reach[0] - reach[1]
        assert gap_along_normal >= -1e-12
        assert contact['distance'] == pytest.approx(gap, abs=1e-11)


@pytest.mark.parametrize('gap', [0.3, 1e-3, 1e-9, 1e-12, 0.0, -1e-12, -1e-9, -1e-3, -0.3])
def test_distance_is_continuous_through_touching(gap):
    # Face to face along x, then a corner to a face: the distance is the gap either side of 0.
    world = World('brute_force', margin=1.0)
    turned = [0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8)]  # 45° about z: a vertical edge
    for quaternion, reach in (([0, 0, 0, 1.0], 0.5), (turned, 0.5 * np.sqrt(2))):
        poses = np.array([[0, 0, 0, 0, 0, 0, 1.0], [0.5 + reach + gap, 0.1, 0] + quaternion])
        contact, = world.step(poses, [0.5, 0.5, 0.5]).contacts
        assert contact['distance'] == pytest.approx(gap, abs=1e-15)
        assert contact['depth'] == max(-contact['distance'], 0.0)


def test_margin_zero_is_bit_for_bit_the_plain_world_and_margins_switch_back():
    scene = uniform(600, 2)
    poses, extents = scene.dynamic_poses(0.0), scene.dynamic_half_extents
    plain = World('grid')
    plain.set_static(scene.static_poses, scene.static_half_extents)
    expected = plain.step(poses, extents)
    world = World('grid', margin=0.0)
    world.set_static(scene.static_poses, scene.static_half_extents, margins=0.0)
    result = world.step(poses, extents)
    np.testing.assert_array_equal(result.contacts, expected.contacts)
    assert result.stats['near_pairs'] == 0
    world.margin = MARGIN
    assert world.step(poses, extents).stats['near_pairs'] > 0
    world.margin = 0.0
    np.testing.assert_array_equal(world.step(poses, extents).contacts, expected.contacts)


def test_a_static_collider_s_own_margin_adds_to_the_world_s():
    poses = np.array([[0.0, 0, 0, 0, 0, 0, 1]])
    for world_margin, own, reported in ((0.0, 0.0, False), (0.05, 0.0, False),
                                        (0.05, 0.06, True), (0.0, 0.11, True)):
        world = World('sweep_and_prune', margin=world_margin)
        world.set_static([[1.1, 0, 0, 0, 0, 0, 1]], [[0.5, 0.5, 0.5]], margins=own)
        contacts = world.step(poses, [0.5, 0.5, 0.5]).contacts
        assert (len(contacts) == 1) == reported
        if reported:
            assert contacts['distance'][0] == pytest.approx(0.1)


def test_distance_statistics():
    """Of a step's contacts, and of a batch's (whose rows have the state's index first)."""
    world = World('brute_force', margin=MARGIN)
    scene, step = scene_step(world)
    states = np.stack([scene.dynamic_poses(time_s) for time_s in (0.0, 0.2, 0.4)])
    for result in (step, world.check_states(states, scene.dynamic_half_extents)):
        distance = result.contacts['distance']
        stats = result.stats
        assert stats['near_pairs'] == np.count_nonzero(distance > 0) > 0
        assert stats['colliding_pairs'] == np.count_nonzero(distance <= 0) > 0
        closest = int(np.argmin(distance))
        assert stats['min_distance'] == distance[closest]
        assert stats['min_distance_pair'] == tuple(int(result.contacts[closest][k]) for k in (
            'id_a', 'type_a', 'id_b', 'type_b'))
        assert all(type(value) is int for value in stats['min_distance_pair'])


def test_the_margin_and_tolerance_rules_are_written_once():
    """The checks of obb, which the World, the static scene and the node's parameters call."""
    assert check_margin(0.0) == 0.0 and check_margin(MAX_COORDINATE) == MAX_COORDINATE
    np.testing.assert_array_equal(check_margin([0.1, 0.2]), [0.1, 0.2])
    for bad in (-0.1, float('nan'), float('inf'), 2 * MAX_COORDINATE):
        with pytest.raises(InvalidDistance, match=r'margin must be a distance in \[0'):
            check_margin(bad)
    with pytest.raises(InvalidDistance) as raised:
        check_margin([0.1, float('nan'), -1.0])
    assert raised.value.index == 1 and raised.value.problem.endswith('got nan')
    assert check_tolerance(1e-4) == 1e-4
    for bad in (0.0, -1e-4, float('nan')):
        with pytest.raises(InvalidDistance, match=r'tolerance must be a distance in \(0'):
            check_tolerance(bad)


@pytest.mark.parametrize('value', [-0.1, float('nan'), float('inf')])
def test_invalid_margins_are_refused(value):
    with pytest.raises(ValueError, match='margin must be a distance in'):
        World(margin=value)
    world = World()
    with pytest.raises(ValueError, match='margin must be a distance in'):
        world.margin = value
    assert world.margin == 0.0
