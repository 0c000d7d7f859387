"""The World API: ids, types, order, static handling, validation and result reuse."""
import numpy as np
import pytest

from collision_node import CONTACT_DTYPE, DYNAMIC, STATIC, World
from collision_node.pipeline import general_path, scene_rows
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.general_path import Z_ORDER_MIN_TICKS
from collision_node.pipeline.obb import MAX_COORDINATE, QUATERNION_NORM_TOLERANCE
from collision_node.pipeline.scenes import uniform
from collision_node.pipeline.z_order import z_order, Z_ORDER_BITS

IDENTITY = [0.0, 0.0, 0.0, 1.0]


def pose(x, y=0.0, z=0.0, quaternion=IDENTITY):
    return [x, y, z] + list(quaternion)


def reference_pairs(static_poses, static_extents, poses, extents):
    """(id_a, type_b, id_b) of every colliding pair, by SAT on all pairs, no broad phase."""
    from collision_node.pipeline.obb import Boxes, set_boxes
    from collision_node.pipeline.sat import collide_pairs, COLLIDING
    n_static, n_dynamic = len(static_poses), len(poses)
    boxes = Boxes(n_static + n_dynamic)
    if n_static:
        set_boxes(boxes, 0, static_poses, static_extents)
    set_boxes(boxes, n_static, poses, extents)
    pairs = [(n_static + a, b) for a in range(n_dynamic) for b in range(n_static)]
    pairs += [(n_static + a, n_static + b) for a in range(n_dynamic)
              for b in range(a + 1, n_dynamic)]
    status = collide_pairs(boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii,
                           np.array(pairs).reshape(-1, 2))[0]
    found = []
    for (a, b), verdict in zip(pairs, status):
        if verdict == COLLIDING:
            found.append((a - n_static, STATIC if b < n_static else DYNAMIC,
                          b if b < n_static else b - n_static))
    return sorted(found)


def contact_keys(contacts):
    return list(zip(contacts['id_a'].tolist(), contacts['type_b'].tolist(),
                    contacts['id_b'].tolist()))


def test_ids_types_and_order_follow_the_cloud_convention():
    world = World(broad_phase='brute_force')
    world.set_static([pose(0.0), pose(10.0)], [[1.0, 1.0, 1.0]] * 2, ids=[3, 7])
    # body 0 overlaps static 7 (the id given); bodies 1 and 2 overlap static 3 and each other.
    poses = [pose(10.5), pose(0.5), pose(1.2)]
    result = world.step(poses, [0.5, 0.5, 0.5])
    assert result.contacts.dtype == CONTACT_DTYPE
    assert contact_keys(result.contacts) == [(0, STATIC, 7), (1, DYNAMIC, 2), (1, STATIC, 3),
                                             (2, STATIC, 3)]
    assert (result.contacts['type_a'] == DYNAMIC).all()
    assert result.stats['broad_phase'] == 'brute_force'
    assert result.stats['colliding_pairs'] == 4


def test_known_depths_and_normals():
    world = World(broad_phase='brute_force', sphere_prefilter=False)
    world.set_static([pose(0.0)], [[1.0, 1.0, 1.0]])
    result = world.step([pose(1.3, 0.1)], [0.5, 0.5, 0.5])
    (contact,) = result.contacts
    # overlap along x: (1 + 0.5) - 1.3 = 0.2; normal from A (the dynamic box) to B (static).
    assert contact['depth'] == pytest.approx(0.2, abs=1e-12)
    assert (contact['normal_x'], contact['normal_y'], contact['normal_z']) == \
        pytest.approx((-1.0, 0.0, 0.0), abs=1e-12)
    # the contact point lies halfway through the overlap slab x in [0.8, 1.0]
    assert contact['x'] == pytest.approx(0.9, abs=1e-12)


def test_matches_sat_on_all_pairs_over_several_ticks():
    scene = uniform(400, seed=3)
    world = World(broad_phase='brute_force')
    world.set_static(scene.static_poses, scene.static_half_extents)
    for tick in range(3):
        poses = scene.dynamic_poses(tick * 0.5)
        result = world.step(poses, scene.dynamic_half_extents)
        expected = reference_pairs(scene.static_poses, scene.static_half_extents, poses,
                                   scene.dynamic_half_extents)
        assert contact_keys(result.contacts) == expected
        assert len(expected) > 100  # the scene really collides


def test_static_pairs_never_reported_and_no_dynamic_means_no_work():
    world = World(broad_phase='brute_force')
    world.set_static([pose(0.0), pose(0.5)], [1.0, 1.0, 1.0])  # overlapping statics
    result = world.step(np.zeros((0, 7)), [0.5, 0.5, 0.5])
    assert len(result.contacts) == 0
    assert result.stats['compared'] == 0 and result.stats['candidate_pairs'] == 0


def test_identical_input_reuses_the_result_and_changes_do_not():
    world = World(broad_phase='brute_force')
    poses = np.array([pose(0.0), pose(0.5)])
    first = world.step(poses, [0.5, 0.5, 0.5])
    again = world.step(poses.copy(), [0.5, 0.5, 0.5])
    assert again.stats['reused'] and contact_keys(again.contacts) == contact_keys(first.contacts)
    moved = poses.copy()
    moved[1, 0] = 5.0
    after = world.step(moved, [0.5, 0.5, 0.5])
    assert not after.stats['reused'] and len(after.contacts) == 0


def test_dynamic_count_may_change_every_tick():
    world = World(broad_phase='brute_force')
    world.set_static([pose(0.0)], [1.0, 1.0, 1.0])
    for n in (1, 3000, 0, 2, 1500):
        poses = np.array([pose(0.5 + 3.0 * i) for i in range(n)]).reshape(-1, 7)
        result = world.step(poses, [0.5, 0.5, 0.5])
        assert contact_keys(result.contacts) == ([(0, STATIC, 0)] if n else [])


def naive_z_order(points):
    """Sort the indices of ``points`` by interleaved cell bits, ties by index (plain Python)."""
    if not len(points):
        return []
    clamped = [[0.0 if np.isnan(x) else min(max(float(x), -MAX_COORDINATE), MAX_COORDINATE)
                for x in point] for point in points]
    low = [min(point[k] for point in clamped) for k in range(3)]
    high = [max(point[k] for point in clamped) for k in range(3)]
    span = [max(high[k] - low[k], np.finfo(float).tiny) for k in range(3)]

    def key(i):
        cells = [int((clamped[i][k] - low[k]) / span[k] * ((1 << Z_ORDER_BITS) - 1))
                 for k in range(3)]
        return sum(((cells[k] >> bit) & 1) << (3 * bit + k)
                   for bit in range(Z_ORDER_BITS) for k in range(3))
    return sorted(range(len(points)), key=lambda i: (key(i), i))


def test_z_order_matches_a_naive_reference():
    rng = np.random.default_rng(8)
    points = rng.uniform(-5.0, 5.0, (400, 3))
    points[10:20] = points[0]  # ties keep their input order
    points[30] = np.nan
    points[31, 1] = np.inf
    points[32, 2] = -1e300
    for part in (points[:0], points[:1], points[:29], points):
        assert z_order(part).tolist() == naive_z_order(part)


@pytest.mark.parametrize('phase', NAMES)
def test_rows_are_sorted_again_once_the_bodies_travel(phase):
    """Sort the rows again after far travel, at most every Z_ORDER_MIN_TICKS ticks.

    No bit of a result changes, in every broad phase.
    """
    scene = uniform(300, seed=4)
    world = World(broad_phase=phase)
    world.set_static(scene.static_poses, scene.static_half_extents)
    rows = []
    for tick in range(3 * Z_ORDER_MIN_TICKS):
        poses = scene.dynamic_poses(0.01 * tick)
        if tick >= Z_ORDER_MIN_TICKS:  # then the bodies travel 3 m every tick
            poses[:, 0] += 3.0 * (tick - Z_ORDER_MIN_TICKS + 1)
        result = world.step(poses, scene.dynamic_half_extents)
        rows.append(world._steps.general.dynamic.ids.copy())
        if tick % 7 == 0 or tick in (Z_ORDER_MIN_TICKS, 2 * Z_ORDER_MIN_TICKS):
            fresh = World(broad_phase='brute_force')
            fresh.set_static(scene.static_poses, scene.static_half_extents)
            assert np.array_equal(result.contacts,
                                  fresh.step(poses, scene.dynamic_half_extents).contacts)
    sorts = [tick for tick in range(1, len(rows)) if not np.array_equal(rows[tick],
                                                                        rows[tick - 1])]
    # Slow motion never re-sorts; far travel re-sorts at the first chance and then once every
    # Z_ORDER_MIN_TICKS ticks.
    assert sorts == [Z_ORDER_MIN_TICKS, 2 * Z_ORDER_MIN_TICKS]


@pytest.mark.parametrize('phase', NAMES)
@pytest.mark.parametrize('one_size', [False, True])
def test_still_bodies_keep_their_contacts_without_a_sat(phase, one_size):
    """Only pairs with a moved (or resized) body reach the SAT; every result stays exact."""
    scene = uniform(400, seed=6)
    rng = np.random.default_rng(6)
    world = World(broad_phase=phase)
    world.set_static(scene.static_poses, scene.static_half_extents)
    poses = scene.dynamic_poses(0.0)
    extents = scene.dynamic_half_extents[0] if one_size else scene.dynamic_half_extents.copy()
    partial = 0
    for tick, fraction in enumerate([1.0, 0.1, 0.5, 0.0, 0.9, 0.02, 1.0, 0.3, 0.3]):
        moving = rng.random(len(poses)) < fraction
        poses = np.where(moving[:, None], scene.dynamic_poses(0.3 * (tick + 1)), poses)
        if tick == 7 and not one_size:  # a new size is a change too
            resized = rng.random(len(poses)) < 0.2
            extents = np.where(resized[:, None], 1.2 * extents, extents)
            moving |= resized
        result = world.step(poses, extents)
        reference, fresh = World(broad_phase='brute_force'), World(broad_phase=phase)
        for world_from_scratch in (reference, fresh):
            world_from_scratch.set_static(scene.static_poses, scene.static_half_extents)
        assert np.array_equal(result.contacts, reference.step(poses, extents).contacts)
        assert not result.contacts.flags.writeable
        expected = fresh.step(poses, extents)
        if tick and not moving.any():
            assert result.stats['reused']
        elif tick and not moving.all():
            partial += 1
            assert result.stats['still_bodies'] == len(poses) - moving.sum()
            assert result.stats['sat_tests'] < expected.stats['sat_tests']
            # The grid leaves out still bodies' pairs with statics; the others find them all.
            fewer = result.stats['broad_phase'] == 'grid'
            assert (result.stats['candidate_pairs'] < expected.stats['candidate_pairs']) == fewer
        else:
            assert result.stats['still_bodies'] == 0
            assert result.stats['candidate_pairs'] == expected.stats['candidate_pairs']
    assert partial >= 5


def test_a_bad_extents_shape_is_refused_when_the_rows_could_be_sorted():
    scene = uniform(40, seed=5)
    world = World(broad_phase='grid')
    poses = scene.dynamic_poses(0.0)
    for tick in range(Z_ORDER_MIN_TICKS):
        world.step(scene.dynamic_poses(0.01 * tick), scene.dynamic_half_extents)
    far = poses.copy()
    far[:, 0] += 100.0
    with pytest.raises(ValueError, match='half extents must have shape'):
        world.step(far, scene.dynamic_half_extents[:-1])
    assert len(world.step(far, scene.dynamic_half_extents).contacts) > 0


@pytest.mark.parametrize('bad, reason', [
    (pose(np.nan), 'NaN or Inf'),
    (pose(0.0, np.inf), 'NaN or Inf'),
    (pose(0.0, quaternion=[0.0, 0.0, 0.0, 0.0]), 'quaternion'),
    (pose(0.0, quaternion=[0.0, 0.0, 0.0, 1.0 + 3 * QUATERNION_NORM_TOLERANCE]), 'quaternion'),
    (pose(0.0, quaternion=[np.nan, 0.0, 0.0, 1.0]), 'NaN or Inf'),
])
def test_invalid_pose_is_rejected_naming_the_body(bad, reason):
    world = World(broad_phase='brute_force')
    with pytest.raises(ValueError, match='body 1: .*%s' % reason):
        world.step([pose(0.0), bad, pose(2.0)], [0.5, 0.5, 0.5])


def test_slightly_off_unit_quaternion_is_normalised():
    world = World(broad_phase='brute_force')
    scale = 1.0 + 0.5 * QUATERNION_NORM_TOLERANCE
    tilted = np.array([0.0, 0.0, np.sin(0.3), np.cos(0.3)])
    exact = world.step([pose(0.0), pose(1.05, quaternion=tilted)], [0.5, 0.5, 0.5])
    scaled = World(broad_phase='brute_force').step(
        [pose(0.0), pose(1.05, quaternion=tilted * scale)], [0.5, 0.5, 0.5])
    assert contact_keys(exact.contacts) == contact_keys(scaled.contacts) == [(0, DYNAMIC, 1)]
    assert scaled.contacts['depth'][0] == pytest.approx(exact.contacts['depth'][0], rel=1e-12)


@pytest.mark.parametrize('extents, message', [
    ([0.5, 0.5], 'shape'),
    ([[0.5, 0.5, 0.5]] * 3, 'shape'),
    ([0.5, -0.1, 0.5], 'finite, >= 0'),
    ([0.5, np.nan, 0.5], 'finite, >= 0'),
    ([0.5, 2e9, 0.5], r'finite, >= 0 and <= 1e\+09 m'),
])
def test_invalid_half_extents_are_rejected(extents, message):
    with pytest.raises(ValueError, match=message):
        World(broad_phase='brute_force').step([pose(0.0), pose(1.0)], extents)


def test_invalid_static_leaves_the_world_unchanged():
    world = World(broad_phase='brute_force')
    world.set_static([pose(0.0)], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match='static id 1'):
        world.set_static([pose(5.0), pose(np.nan)], [1.0, 1.0, 1.0])
    assert world.static_count == 1
    assert contact_keys(world.step([pose(0.5)], [0.1, 0.1, 0.1]).contacts) == [(0, STATIC, 0)]


def test_unknown_settings_are_refused_with_the_choices():
    with pytest.raises(ValueError, match='brute_force'):
        World(broad_phase='quadtree')
    world = World(broad_phase='brute_force')
    with pytest.raises(ValueError, match='depth'):
        world.configure(octree_max_depth=-1)
    assert world.broad_phase == 'brute_force'


@pytest.mark.parametrize('threads', [1, 2])
def test_a_refused_input_is_not_kept_for_the_bodies_that_did_not_change_back(
        threads, monkeypatch):
    # Only the bodies that moved are written to their rows; after a refused input the rows
    # before the bad body (and, on threads, other chunks' rows) hold it, so they must be
    # written again even where the next input equals the last accepted one.
    monkeypatch.setattr(scene_rows, 'MIN_BODIES_PER_CHUNK', 16)
    scene = uniform(400, seed=4)  # 200 dynamic bodies
    world = World(broad_phase='grid', threads=threads)
    reference = World(broad_phase='brute_force')
    for w in (world, reference):
        w.set_static(scene.static_poses, scene.static_half_extents)
    accepted = scene.dynamic_poses(0.0)
    world.step(accepted, scene.dynamic_half_extents)
    for moving in (slice(None), slice(None, None, 3)):
        refused = accepted.copy()
        refused[moving] = scene.dynamic_poses(5.0)[moving]
        refused[99, 3:] = 0.0  # a zero quaternion, refused after the bodies before it
        with pytest.raises(ValueError, match='body 99: .*quaternion'):
            world.step(refused, scene.dynamic_half_extents)
        accepted = accepted.copy()
        accepted[100:] = scene.dynamic_poses(0.2)[100:]  # half change, the rest as before
        assert np.array_equal(world.step(accepted, scene.dynamic_half_extents).contacts,
                              reference.step(accepted, scene.dynamic_half_extents).contacts)
    world.close()


def test_threads_name_the_first_invalid_body_whichever_chunk_met_it(monkeypatch):
    monkeypatch.setattr(scene_rows, 'MIN_BODIES_PER_CHUNK', 8)
    poses = np.array([pose(3.0 * k) for k in range(64)])
    poses[50, 0] = np.inf  # a later chunk, which a helper may well meet first
    poses[20, 3:] = 0.0
    world = World(broad_phase='grid', threads=3)
    for _ in range(5):
        with pytest.raises(ValueError, match='body 20: .*quaternion'):
            world.step(poses, [0.5, 0.5, 0.5])
    poses[20, 3:] = (0.0, 0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match='body 50: .*NaN or Inf'):
        world.step(poses, [0.5, 0.5, 0.5])
    world.close()


@pytest.mark.parametrize('margin', [0.0, 0.05])
def test_pairs_sorted_by_row_give_the_same_contacts_to_the_bit(monkeypatch, margin):
    # Large scenes sort the candidate pairs by row before the SAT; small ones keep the broad
    # phase's order. The order must change no bit: both against each other and brute force.
    scene = uniform(600, seed=11)
    worlds = {name: World(broad_phase=phase, margin=margin)
              for name, phase in (('sorted', 'grid'), ('unsorted', 'grid'),
                                  ('brute_force', 'brute_force'))}
    for world in worlds.values():
        world.set_static(scene.static_poses, scene.static_half_extents)
    for tick in range(4):
        results = {}
        for name, world in worlds.items():
            monkeypatch.setattr(general_path, 'SORT_PAIRS_ROWS', 0 if name == 'sorted' else 10**9)
            results[name] = world.step(scene.dynamic_poses(0.3 * tick),
                                       scene.dynamic_half_extents).contacts
        assert len(results['sorted']) > 100
        assert results['sorted'].tobytes() == results['unsorted'].tobytes()
        assert np.array_equal(contact_keys(results['sorted']),
                              contact_keys(results['brute_force']))
