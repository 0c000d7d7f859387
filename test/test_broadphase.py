"""Broad phases: every one gives brute force's contacts, on every scene, tick after tick.

Two references, both independent of the phase under test: the World with ``brute_force``
(the final contact ids must be identical) and a numpy all-pairs AABB test written from the
definition (the candidates must contain every overlapping pair, once, in interface order).
"""
from broadphase_reference import (
    contact_ids, flying_out, log_scale_half_extents, poses, random_quaternions,
    reference_overlaps, Scene, sorted_pairs, uniform)
import numpy as np
import pytest

from collision_node import World
from collision_node.pipeline import contacts as contacts_module
from collision_node.pipeline import general_path, scene_rows
from collision_node.pipeline.broadphase import (check_settings, grid, make_broad_phase, NAMES,
                                                Settings)
from collision_node.pipeline.broadphase.auto import Auto, SWITCH_AFTER_TICKS
from collision_node.pipeline.broadphase.kd_tree import KdTreePhase
from collision_node.pipeline.broadphase.octree import Octree, paper_depth, size_depth
from collision_node.pipeline.broadphase.sweep_and_prune import SweepAndPrune
from collision_node.pipeline.obb import Boxes, set_boxes

PHASES = [name for name in NAMES if name != 'brute_force']  # brute force is the reference
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def still(static_poses, static_extents, dynamic_poses, dynamic_extents):
    """Make a scene whose dynamic boxes do not move."""
    dynamic = (np.asarray(dynamic_poses, float).reshape(-1, 7),
               np.asarray(dynamic_extents, float).reshape(-1, 3))
    return Scene(static_poses, static_extents, lambda tick: dynamic)


def axis_aligned(positions):
    positions = np.asarray(positions, float).reshape(-1, 3)
    return poses(positions, np.tile(IDENTITY, (len(positions), 1)))


def one_point_scene(n=120, seed=1):
    rng = np.random.default_rng(seed)
    extents = rng.uniform(0.0, 0.3, (n, 3))
    quaternion = random_quaternions(rng, n)
    position = np.tile([3.0, -2.0, 7.0], (n, 1))
    half = n // 3
    return still(poses(position[:half], quaternion[:half]), extents[:half],
                 poses(position[half:], quaternion[half:]), extents[half:])


def big_boxes_scene(seed=2):
    """Small boxes and a few 100x larger ones (far larger than any cell or leaf)."""
    base = uniform(400, seed=seed)
    rng = np.random.default_rng(seed)
    big_static = axis_aligned([[2.0, 2.0, 2.0], [30.0, 0.0, 0.0]])
    big_extents = np.array([[20.0, 0.5, 20.0], [1.0, 40.0, 1.0]])

    def dynamic(tick):
        p, e = base.dynamic(tick)
        e = e.copy()
        e[rng.permutation(len(e))[:3]] = [15.0, 15.0, 0.2]  # three huge plates
        return p, e

    return Scene(np.concatenate([base.static_poses, big_static]),
                 np.concatenate([base.static_half_extents, big_extents]), dynamic)


def touching_scene():
    """Put unit cubes on a lattice of pitch 1: neighbours touch by faces, edges, corners."""
    grid = np.stack(np.meshgrid(*[np.arange(5.0)] * 3, indexing='ij'), -1).reshape(-1, 3)
    static = grid[::2]
    dynamic = grid[1::2]
    return still(axis_aligned(static), np.full((len(static), 3), 0.5),
                 axis_aligned(dynamic), np.full((len(dynamic), 3), 0.5))


def degenerate_scene():
    """Flat, zero-size and far-away boxes, and boxes exactly touching at a large offset."""
    far = 1e6
    static = axis_aligned([[0, 0, 0], [far, far, far], [-far, 0, far], [0.0, 0.0, 5.0]])
    static_extents = [[1, 1, 0], [0.5, 0.5, 0.5], [2, 2, 2], [0, 0, 0]]
    dynamic = axis_aligned([[0, 0, 0], [0.5, 0.5, 0], [far + 1.0, far, far], [-far, 0, far],
                            [0, 0, 5.0], [0, 0, 5.0], [3, 3, 3], [3, 3, 3.0]])
    dynamic_extents = [[0, 0, 0], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0, 0, 0], [0, 0, 0],
                       [1, 0, 0], [0, 0, 0], [0, 0, 0]]
    return still(static, static_extents, dynamic, dynamic_extents)


def drifting(static_poses, static_extents, dynamic_poses, dynamic_extents, step):
    """Make a scene whose dynamic boxes all move by ``step`` (3,) a tick."""
    def dynamic(tick):
        moved = np.array(dynamic_poses, float)
        moved[:, :3] += tick * np.asarray(step)
        return moved, np.asarray(dynamic_extents, float)

    return Scene(static_poses, static_extents, dynamic)


def needles_scene(n=300, seed=6):
    """Long thin boxes at random angles: AABBs far larger than the boxes, most pairs apart."""
    rng = np.random.default_rng(seed)
    all_poses = poses(rng.uniform(0.0, 6.0, (n, 3)), random_quaternions(rng, n))
    extents = np.tile([1.5, 0.02, 0.02], (n, 1))
    half = n // 2
    return drifting(all_poses[:half], extents[:half], all_poses[half:], extents[half:],
                    [0.05, 0.0, 0.0])


def planar_scene(n=400, seed=7):
    """Make a mobile robot's world: boxes on one floor, turned about z only, at one height."""
    rng = np.random.default_rng(seed)
    position = np.column_stack([rng.uniform(0.0, 12.0, (n, 2)), np.full(n, 0.25)])
    yaw = rng.uniform(-np.pi, np.pi, n)
    quaternion = np.column_stack([np.zeros((n, 2)), np.sin(yaw / 2), np.cos(yaw / 2)])
    extents = np.column_stack([rng.uniform(0.1, 0.4, (n, 2)), np.full(n, 0.25)])
    half = n // 2
    all_poses = poses(position, quaternion)
    return drifting(all_poses[:half], extents[:half], all_poses[half:], extents[half:],
                    [0.03, 0.02, 0.0])


def mixed_scales_scene(n=400, seed=8):
    """Make boxes from 1 mm to 50 m across in one scene, each side drawn on a log scale.

    Cells and leaves sized from the mean size fit almost no body, and many are big boxes.
    """
    rng = np.random.default_rng(seed)
    extents = log_scale_half_extents(rng, n)
    all_poses = poses(rng.uniform(-30.0, 30.0, (n, 3)), random_quaternions(rng, n))
    third = n // 3
    return drifting(all_poses[:third], extents[:third], all_poses[third:], extents[third:],
                    [0.2, -0.1, 0.05])


SCENES = {
    'uniform': lambda: uniform(600),
    'clustered': lambda: uniform(600, clustered=True),
    'flying_out': lambda: flying_out(256),
    'one_point': one_point_scene,
    'one_body': lambda: still(uniform(50).static_poses, uniform(50).static_half_extents,
                              axis_aligned([[3.0, 3.0, 3.0]]), [[2.0, 2.0, 2.0]]),
    'one_body_alone': lambda: still(np.zeros((0, 7)), np.zeros((0, 3)),
                                    axis_aligned([[3.0, 3.0, 3.0]]), [[2.0, 2.0, 2.0]]),
    'no_static': lambda: uniform(500, static_fraction=0.0),
    'mostly_static': lambda: uniform(500, static_fraction=0.98),
    'big_boxes': big_boxes_scene,
    'touching': touching_scene,
    'degenerate': degenerate_scene,
    'needles': needles_scene,
    'planar': planar_scene,
    'mixed_scales': mixed_scales_scene,
}


def run_worlds(scene, names, ticks, settings=None):
    """Step one World per phase name through the scene; yield (tick, {name: result})."""
    worlds = {}
    for name in names:
        world = World(broad_phase=name, **(settings or {}))
        world.set_static(scene.static_poses, scene.static_half_extents)
        worlds[name] = world
    for tick in ticks:
        dynamic_poses, dynamic_extents = scene.dynamic(tick)
        yield tick, {name: world.step(dynamic_poses, dynamic_extents)
                     for name, world in worlds.items()}


def check_candidates(phase, scene, tick):
    """Run ``phase`` alone on the scene at ``tick``: superset, once, interface order."""
    dynamic_poses, dynamic_extents = scene.dynamic(tick)
    n_static, n_dynamic = len(scene.static_poses), len(dynamic_poses)
    boxes = Boxes(n_static + n_dynamic)
    if n_static:
        set_boxes(boxes, 0, scene.static_poses, scene.static_half_extents)
    set_boxes(boxes, n_static, dynamic_poses, dynamic_extents)
    phase.set_static(boxes, n_static)
    pairs, compared = phase.find_pairs(boxes, n_static, n_dynamic)
    pairs = sorted_pairs(pairs)
    assert pairs.dtype == np.int64
    assert len(np.unique(pairs, axis=0)) == len(pairs), 'a pair was reported twice'
    if len(pairs):
        assert (pairs[:, 0] >= n_static).all() and (pairs[:, 0] < n_static + n_dynamic).all()
        dynamic_pair = pairs[:, 1] >= n_static
        assert (pairs[dynamic_pair, 1] > pairs[dynamic_pair, 0]).all()
    expected = reference_overlaps(boxes.aabbs, n_static, n_static + n_dynamic)
    found = {tuple(p) for p in pairs.tolist()}
    missing = [p for p in expected.tolist() if tuple(p) not in found]
    assert not missing, 'missed overlapping pairs %s' % missing[:5]
    assert compared >= len(pairs)
    return pairs, expected


def test_registry_knows_every_phase_and_refuses_others():
    assert set(NAMES) == {'brute_force', 'sphere', 'octree', 'kd_tree', 'sweep_and_prune',
                          'grid', 'auto'}
    with pytest.raises(ValueError, match='unknown broad phase'):
        make_broad_phase('quadtree')


@pytest.mark.parametrize('scene_name', sorted(SCENES))
@pytest.mark.parametrize('name', PHASES)
def test_same_contacts_as_brute_force(name, scene_name):
    scene = SCENES[scene_name]()
    ticks = range(0, 60, 6) if scene_name == 'flying_out' else range(3)
    for tick, results in run_worlds(scene, ['brute_force', name], ticks):
        expected = contact_ids(results['brute_force'])
        assert np.array_equal(contact_ids(results[name]), expected), (scene_name, tick)
        stats = results[name].stats
        assert stats['broad_phase'] in NAMES
        assert stats['candidate_pairs'] >= stats['sat_tests'] >= len(expected)
        assert stats['compared'] >= stats['candidate_pairs']


@pytest.mark.parametrize('scene_name', ['uniform', 'clustered', 'one_point', 'big_boxes',
                                        'touching', 'degenerate', 'mostly_static'])
@pytest.mark.parametrize('name', [name for name in PHASES if name != 'sphere'])
def test_candidates_are_exactly_the_overlapping_pairs(name, scene_name):
    # (``sphere``'s candidates are the pairs whose bounding spheres overlap, a different set.)
    phase = make_broad_phase(name, Settings())
    pairs, expected = check_candidates(phase, SCENES[scene_name](), 1)
    assert np.array_equal(pairs, expected)


def test_scenes_really_collide():
    """Guard against vacuous differential tests: the scenes have many contacts."""
    for scene_name, least in [('uniform', 100), ('clustered', 300), ('touching', 100),
                              ('one_point', 1000), ('big_boxes', 100), ('degenerate', 3),
                              ('needles', 50), ('planar', 200)]:
        (_, results), = run_worlds(SCENES[scene_name](), ['brute_force'], [1])
        assert len(results['brute_force'].contacts) >= least, scene_name


def test_no_dynamic_bodies_means_no_pairs():
    scene = uniform(200)
    for name in NAMES:
        world = World(broad_phase=name)
        world.set_static(scene.static_poses, scene.static_half_extents)
        result = world.step(np.zeros((0, 7)), np.zeros((0, 3)))
        assert len(result.contacts) == 0 and result.stats['compared'] == 0


class ChaosScene:
    """Boxes crossing cells and leaves, leaving for 1e6 m and coming back, coming and going.

    Row i is dynamic body i; the count changes every few ticks (PoseArray length changes).
    """

    def __init__(self, n_max=300, seed=5):
        rng = np.random.default_rng(seed)
        self.n_max = n_max
        self.start = rng.uniform(-4.0, 4.0, (n_max, 3))
        self.velocity = rng.uniform(-0.4, 0.4, (n_max, 3))
        self.quaternion = random_quaternions(rng, n_max)
        self.extents = rng.uniform(0.05, 0.5, (n_max, 3))
        self.extents[rng.random(n_max) < 0.02] *= 20.0  # a few huge ones
        self.counts = rng.integers(n_max // 3, n_max + 1, 1000)
        self.static_poses = poses(rng.uniform(-5.0, 5.0, (150, 3)), random_quaternions(rng, 150))
        self.static_half_extents = rng.uniform(0.05, 0.6, (150, 3))
        self.travellers = rng.permutation(n_max)[:10]

    def dynamic(self, tick):
        n = self.counts[tick // 7]
        phase = np.sin(0.05 * tick)
        position = self.start + self.velocity * 20.0 * phase  # to and fro over many cells
        far = (tick // 25) % 2 == 1  # every 25 ticks some bodies go 1e6 m away and back
        position[self.travellers] += 1e6 * far
        return poses(position[:n], self.quaternion[:n]), self.extents[:n]


@pytest.mark.parametrize('name', PHASES)
def test_many_ticks_of_moving_coming_and_going_bodies(name):
    scene = ChaosScene()
    ticks = range(200)
    for tick, results in run_worlds(scene, ['brute_force', name], ticks):
        assert np.array_equal(contact_ids(results[name]), contact_ids(results['brute_force'])), \
            (name, tick)


@pytest.fixture
def small_chunks(monkeypatch):
    """Chunks of a few items, so that the test scenes' loops are spread over threads."""
    monkeypatch.setattr(grid, 'MIN_BUCKETS_PER_CHUNK', 7)
    monkeypatch.setattr(general_path, 'MIN_PAIRS_PER_CHUNK', 5)
    monkeypatch.setattr(scene_rows, 'MIN_BODIES_PER_CHUNK', 3)
    monkeypatch.setattr(contacts_module, 'MIN_PAIRS_PER_THREAD', 2)


@pytest.mark.parametrize('scene_name', sorted(SCENES))
def test_threads_give_the_same_contacts_to_the_bit(small_chunks, scene_name):
    scene = SCENES[scene_name]()
    worlds = {}
    for threads in (1, 2, 3):
        worlds[threads] = World(broad_phase='grid', threads=threads)
        worlds[threads].set_static(scene.static_poses, scene.static_half_extents)
    for tick in (range(0, 60, 12) if scene_name == 'flying_out' else range(3)):
        dynamic = scene.dynamic(tick)  # some scenes draw new bodies at each call
        results = {threads: world.step(*dynamic) for threads, world in worlds.items()}
        expected = results[1].contacts.tobytes()
        for threads in (2, 3):
            assert results[threads].contacts.tobytes() == expected, (scene_name, tick, threads)
            assert results[threads].stats['compared'] == results[1].stats['compared']
    for world in worlds.values():
        world.close()


def test_threads_over_many_ticks_of_moving_coming_and_going_bodies(small_chunks):
    scene = ChaosScene(seed=7)
    for tick, results in run_worlds(scene, ['brute_force', 'grid', 'auto'], range(200),
                                    settings={'threads': 2}):
        for name in ('grid', 'auto'):
            assert np.array_equal(contact_ids(results[name]),
                                  contact_ids(results['brute_force'])), (name, tick)


def test_octree_cooldown_and_stay_paths_are_taken_over_many_ticks():
    scene = ChaosScene(seed=6)
    totals = {'stayed': 0, 'reinserted': 0}
    dropped = created = 0
    boxes = None
    settings = Settings(octree_max_depth=0, octree_leaf_cooldown_ticks=15)
    octree = Octree(settings)
    reference = make_broad_phase('brute_force')
    n_static = len(scene.static_poses)
    for tick in range(240):
        dynamic_poses, dynamic_extents = scene.dynamic(tick)
        n_dynamic = len(dynamic_poses)
        if boxes is None or boxes.capacity < n_static + n_dynamic:
            boxes = Boxes(n_static + scene.n_max)
            set_boxes(boxes, 0, scene.static_poses, scene.static_half_extents)
            octree.set_static(boxes, n_static)
        set_boxes(boxes, n_static, dynamic_poses, dynamic_extents)
        builds = octree.stats['builds']
        before = dict(octree.stats)
        pairs, _ = octree.find_pairs(boxes, n_static, n_dynamic)
        expected, _ = reference.find_pairs(boxes, n_static, n_dynamic)
        assert np.array_equal(
            sorted_pairs(pairs), sorted_pairs(expected)), tick
        if octree.stats['builds'] == builds and before.get('leaves_dropped') is not None:
            for key in totals:
                totals[key] += octree.stats[key] - before[key]
            dropped += octree.stats['leaves_dropped'] - before['leaves_dropped']
            created += octree.stats['leaves_created'] - before['leaves_created']
    # Counted over ticks without a rebuild: each path really ran, and often (measured with
    # this seed: 36,138 stays, 10,521 re-insertions, 6,393 leaves created, 5,258 dropped).
    assert totals['stayed'] > 20000
    assert totals['reinserted'] > 5000
    assert dropped > 2000
    assert created > 2000


def octree_tick(octree, boxes, n_static, positions, extents):
    set_boxes(boxes, n_static, axis_aligned(positions), extents)
    return octree.find_pairs(boxes, n_static, len(positions))


@pytest.mark.parametrize('cooldown', [0, 1, 15])
def test_octree_drops_an_emptied_leaf_after_exactly_the_cooldown(cooldown):
    octree = Octree(Settings(octree_max_depth=3, octree_leaf_cooldown_ticks=cooldown))
    boxes = Boxes(8)
    # Two anchors fix the root cube (0..~16 on each axis); the mover starts in one leaf.
    anchors = [[0.0, 0.0, 0.0], [8.0, 8.0, 8.0]]
    extents = np.full((3, 3), 0.01)
    octree_tick(octree, boxes, 0, anchors + [[1.0, 1.0, 1.0]], extents)
    leaves = octree.stats['leaves']
    assert octree.stats['builds'] == 1
    # Move to a far leaf: the old one empties now, one leaf is created.
    octree_tick(octree, boxes, 0, anchors + [[6.0, 1.0, 1.0]], extents)
    assert octree.stats['leaves_created'] >= 1
    assert octree.stats['builds'] == 1
    created = octree.stats['leaves_created']
    for tick in range(cooldown + 2):
        dropped_before = octree.stats['leaves_dropped']
        octree_tick(octree, boxes, 0, anchors + [[6.0, 1.0, 1.0]], extents)
        dropped_now = octree.stats['leaves_dropped'] - dropped_before
        # emptied at tick 1 (the move); dropped at the tick when cooldown ticks have passed
        expected = 1 if tick + 2 - 1 == max(cooldown, 1) else 0
        if cooldown == 0:
            expected = 0  # dropped during the move itself already
        assert dropped_now == expected, (cooldown, tick)
    assert octree.stats['leaves'] == leaves + 1 - 1  # one created, one dropped
    assert octree.stats['leaves_created'] == created


def test_octree_body_inside_its_leaf_is_not_reinserted():
    octree = Octree(Settings(octree_max_depth=3, octree_leaf_cooldown_ticks=15))
    boxes = Boxes(8)
    anchors = [[0.0, 0.0, 0.0], [8.0, 8.0, 8.0]]
    extents = np.full((3, 3), 0.01)
    octree_tick(octree, boxes, 0, anchors + [[1.0, 1.0, 1.0]], extents)
    stayed, moved = octree.stats['stayed'], octree.stats['reinserted']
    for step in range(10):  # small steps inside one leaf (leaf side is 2 m here)
        octree_tick(octree, boxes, 0, anchors + [[1.0 + 0.05 * step, 1.0, 1.0]], extents)
    assert octree.stats['stayed'] - stayed == 3 * 10
    assert octree.stats['reinserted'] == moved
    octree_tick(octree, boxes, 0, anchors + [[5.0, 1.0, 1.0]], extents)  # leaves the leaf
    assert octree.stats['reinserted'] == moved + 1


def test_octree_depth_rules():
    assert [paper_depth(n, 1.0, 1.0) for n in (8, 128, 256, 512, 1024, 10 ** 6)] == \
        [0, 3, 4, 5, 6, 6]
    # leaves of about 1.5 mean sides: root 48 m, boxes 1 m -> 32 leaves across -> depth 5
    assert size_depth(1000, 48.0, 1.0) == 5
    assert size_depth(1000, 1.0, 0.0) == 0  # points: one leaf
    octree = Octree(Settings(octree_max_depth=7, octree_leaf_cooldown_ticks=15))
    check_candidates(octree, uniform(300), 0)
    assert octree.stats['depth'] == 7


def test_octree_paper_rule_gives_the_same_pairs():
    octree = Octree(Settings(), depth_rule='paper')
    check_candidates(octree, uniform(600), 0)
    assert octree.stats['depth'] == paper_depth(600, 1.0, 1.0)


def test_sweep_axis_follows_the_spread_and_order_is_repaired_incrementally():
    rng = np.random.default_rng(3)
    n = 400
    position = rng.uniform(0.0, 1.0, (n, 3)) * [2.0, 3.0, 40.0]  # spread along z
    scene = Scene(np.zeros((0, 7)), np.zeros((0, 3)),
                  lambda tick: (axis_aligned(position + 0.01 * tick), np.full((n, 3), 0.2)))
    phase = SweepAndPrune()
    for tick in range(5):
        check_candidates(phase, scene, tick)
    assert phase.stats['axis'] == 2
    assert phase.stats['incremental_sorts'] >= 3  # coherent motion: no full sort needed
    shuffled = Scene(scene.static_poses, scene.static_half_extents,
                     lambda tick: (axis_aligned(rng.permutation(position)),
                                   np.full((n, 3), 0.2)))
    full = phase.stats['full_sorts']
    check_candidates(phase, shuffled, 0)
    assert phase.stats['full_sorts'] == full + 1  # order changed too much: full sort


@pytest.mark.parametrize('ratio, builds', [(1.0, 30), (np.inf, 1)])
def test_kd_tree_rebuild_and_refit_policies_find_the_same_pairs(ratio, builds):
    scene = flying_out(200)
    phase = KdTreePhase(rebuild_ratio=ratio)
    for tick in range(0, 30):
        check_candidates(phase, scene, tick)
    # set_static runs at each check; the dynamic tree persists across ticks
    assert phase.stats['builds'] == builds


def test_auto_does_not_flap_at_a_threshold_but_switches_at_once_when_far_off():
    scene = uniform(6000, static_fraction=0.0)
    world = World(broad_phase='auto')
    dynamic_poses, extents = scene.dynamic(0)
    names = []
    for tick in range(60):  # the count jumps across GRID_BODIES every other tick
        count = 600 if tick % 2 else 800
        shifted = dynamic_poses[:count] + [1e-6 * tick, 0, 0, 0, 0, 0, 0]
        names.append(world.step(shifted, extents[:count]).stats['broad_phase'])
    assert len(set(names)) == 1, 'flapped'
    switches = world._steps.general.phase.switches
    for tick in range(SWITCH_AFTER_TICKS):  # clearly above: switches after a few ticks
        shifted = dynamic_poses[:1200] + [1e-6 * tick, 0, 0, 0, 0, 0, 0]
        names.append(world.step(shifted, extents[:1200]).stats['broad_phase'])
    assert names[-1] == 'grid' and world._steps.general.phase.switches <= switches + 1
    small = world.step(dynamic_poses[:10], extents[:10])  # far below: at once
    assert small.stats['broad_phase'] == 'brute_force'
    large = world.step(dynamic_poses, extents)  # 6,000 bodies: no 8 ticks of brute force
    assert large.stats['broad_phase'] == 'grid'


@pytest.mark.parametrize('make_scene, expected', [
    (lambda: uniform(60), 'brute_force'), (lambda: uniform(400), 'sweep_and_prune'),
    (lambda: one_point_scene(1500), 'sweep_and_prune'), (lambda: uniform(3000), 'grid')])
def test_auto_picks_by_body_count_and_spread(make_scene, expected):
    scene = make_scene()
    world = World(broad_phase='auto')
    world.set_static(scene.static_poses, scene.static_half_extents)
    for tick in range(SWITCH_AFTER_TICKS + 2):
        dynamic_poses, extents = scene.dynamic(tick)
        shifted = dynamic_poses + [1e-6 * tick, 0, 0, 0, 0, 0, 0]  # never the same input
        result = world.step(shifted, extents)
    assert result.stats['broad_phase'] == expected


def test_auto_reports_the_phase_that_ran_with_the_same_contacts():
    scene = uniform(2000)
    results = dict(run_worlds(scene, ['auto', 'brute_force'], range(12)))
    for tick, by_name in results.items():
        assert np.array_equal(contact_ids(by_name['auto']), contact_ids(by_name['brute_force']))
    assert results[11]['auto'].stats['broad_phase'] == 'grid'
    auto = Auto(Settings())
    assert auto.name == 'brute_force'


def test_octree_settings_change_at_run_time():
    scene = uniform(400)
    world = World(broad_phase='octree')
    world.set_static(scene.static_poses, scene.static_half_extents)
    reference = World(broad_phase='brute_force')
    reference.set_static(scene.static_poses, scene.static_half_extents)
    for tick, settings in enumerate([{'octree_max_depth': 2}, {'octree_max_depth': 5},
                                     {'octree_leaf_cooldown_ticks': 0},
                                     {'broad_phase': 'grid'}]):
        world.configure(**settings)
        poses_now, extents = scene.dynamic(tick)
        assert np.array_equal(contact_ids(world.step(poses_now, extents)),
                              contact_ids(reference.step(poses_now, extents)))
    with pytest.raises(ValueError, match='max depth'):
        world.configure(octree_max_depth=11)
    with pytest.raises(ValueError, match='cooldown'):
        world.configure(octree_leaf_cooldown_ticks=-1)


@pytest.mark.slow
@pytest.mark.parametrize('name', PHASES)
def test_long_seed_scene_run(name):
    """The seed scene over 600 ticks, from packed to scattered."""
    scene = flying_out(1024)
    for tick, results in run_worlds(scene, ['brute_force', name], range(0, 600, 3)):
        assert np.array_equal(contact_ids(results[name]), contact_ids(results['brute_force']))


@pytest.mark.slow
@pytest.mark.parametrize('name', PHASES)
def test_long_chaos_run(name):
    scene = ChaosScene(n_max=800, seed=11)
    for tick, results in run_worlds(scene, ['brute_force', name], range(1000)):
        assert np.array_equal(contact_ids(results[name]), contact_ids(results['brute_force']))


@pytest.mark.parametrize('settings, message', [
    (Settings(octree_max_depth=11), 'max depth'), (Settings(octree_max_depth=-1), 'max depth'),
    (Settings(octree_max_depth=2.5), 'max depth'), (Settings(octree_max_depth=True), 'max depth'),
    (Settings(octree_leaf_cooldown_ticks=-1), 'cooldown'),
    (Settings(octree_leaf_cooldown_ticks='15'), 'cooldown')])
def test_invalid_settings_are_refused_with_a_reason(settings, message):
    with pytest.raises(ValueError, match=message):
        check_settings(settings)
    with pytest.raises(ValueError, match=message):
        make_broad_phase('octree', settings)
    assert check_settings(Settings(np.int64(10), np.int64(0))) == (10, 0)
