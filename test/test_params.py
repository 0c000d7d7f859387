"""Parameters: validation without ROS, then the same through a real node and a real process."""
import math
import os
import pathlib
import random

import numpy as np
import pytest
from ros_helpers import BAD_YAML, GOOD_YAML, run_node, write_params

from collision_node.benchmarks import params_files
from collision_node.pipeline.contacts import DYNAMIC as DYNAMIC_TYPE, STATIC as STATIC_TYPE
from collision_node.ros import params
from collision_node.ros.params import ParameterError

REPO = pathlib.Path(__file__).resolve().parents[1]
DOMAIN_ID = random.Random(os.getpid()).randint(1, 200)
TABLE = {'table.pose': [0.0, 0.0, 0.4, 0.0, 0.0, 0.0, 1.0],
         'table.half_extents': [0.6, 0.4, 0.02]}
SHELF = {'shelf.pose': [1.2, 0.0, 1.0, 0.0, 0.0, 0.3826834, 0.9238795],
         'shelf.half_extents': [0.2, 0.5, 1.0], 'shelf.enabled': False}
GOOD = dict(static_colliders=['table', 'shelf'], **TABLE, **SHELF)

# Each bad set (added to GOOD) names the parameter the error must name and a word it must say.
BAD = {
    'missing pose': ({'table.pose': None}, 'table.pose', 'missing'),
    'short pose': ({'table.pose': [0.0, 0.0, 0.4, 0.0, 0.0, 1.0]}, 'table.pose', '7 values'),
    'NaN in pose': ({'table.pose': [math.nan, 0.0, 0.4, 0.0, 0.0, 0.0, 1.0]}, 'table.pose',
                    'NaN'),
    'zero quaternion': ({'shelf.pose': [0.0] * 7}, 'shelf.pose', 'unit quaternion'),
    'long quaternion': ({'shelf.pose': [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.1]}, 'shelf.pose',
                        'unit quaternion'),
    'missing extents': ({'shelf.half_extents': None}, 'shelf.half_extents', 'missing'),
    'two extents': ({'table.half_extents': [0.6, 0.4]}, 'table.half_extents', '3 values'),
    'negative extent': ({'table.half_extents': [0.6, -0.4, 0.02]}, 'table.half_extents',
                        '>= 0'),
    'NaN extent': ({'table.half_extents': [0.6, math.nan, 0.02]}, 'table.half_extents',
                   'finite'),
    # The World's bound on every body: caught here, a far collider would stop the node with a
    # traceback at start (or in the parameter callback, once a disabled one is enabled).
    'collider beyond 1e9 m': ({'shelf.pose': [2e9, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]}, 'shelf.pose',
                              'beyond'),
    'huge extent': ({'table.half_extents': [0.6, 2e9, 0.02]}, 'table.half_extents', '<= 1e+09'),
    'string enabled': ({'table.enabled': 'yes'}, 'table.enabled', 'bool'),
    'dynamic extents 4': ({'dynamic.half_extents': [0.1, 0.1, 0.1, 0.1]},
                          'dynamic.half_extents', '3 per body'),
    'dynamic extents empty': ({'dynamic.half_extents': []}, 'dynamic.half_extents', '3 values'),
    'dynamic extent inf': ({'dynamic.half_extents': [0.1, math.inf, 0.1]},
                           'dynamic.half_extents', 'finite'),
    'unknown broad phase': ({'broad_phase': 'quadtree'}, 'broad_phase', 'quadtree'),
    'octree depth': ({'octree.max_depth': -1}, 'octree.max_depth', 'depth'),
    'octree cooldown': ({'octree.leaf_cooldown_ticks': -2}, 'octree.leaf_cooldown_ticks', '>= 0'),
    'duplicate collider': ({'static_colliders': ['table', 'shelf', 'table']}, 'static_colliders',
                           'twice'),
    'reserved collider name': ({'static_colliders': ['octree']}, 'static_colliders', 'taken'),
    'dotted collider name': ({'static_colliders': ['a.b']}, 'static_colliders', 'letters'),
    'negative tick rate': ({'tick_rate_hz': -1.0}, 'tick_rate_hz', 'in [0'),
    'NaN tick rate': ({'tick_rate_hz': math.nan}, 'tick_rate_hz', 'in [0'),
    'huge tick rate': ({'tick_rate_hz': 1e6}, 'tick_rate_hz', 'in [0'),
    'negative timeout': ({'input_timeout_s': -0.5}, 'input_timeout_s', 'in [0'),
    'no bodies': ({'max_bodies': 0}, 'max_bodies', 'in [1'),
    'no threads': ({'threads': 0}, 'threads', 'in [1'),
    'thousands of threads': ({'threads': 5000}, 'threads', 'in [1'),
    'fractional threads': ({'threads': 1.5}, 'threads', 'integer'),
    'zero period': ({'diagnostic_updater.period': 0.0}, 'diagnostic_updater.period',
                    'positive'),
    'empty frame': ({'frame_id': ''}, 'frame_id', 'frame'),
    'string as double': ({'input_timeout_s': 'soon'}, 'input_timeout_s', 'double'),
    'negative margin': ({'margin': -0.01}, 'margin', 'distance in [0'),
    'NaN margin': ({'margin': math.nan}, 'margin', 'distance in [0'),
    'negative collider margin': ({'table.margin': -1.0}, 'table.margin', 'distance in [0'),
    'zero continuous tolerance': ({'continuous_tolerance': 0.0}, 'continuous_tolerance',
                                  'distance in (0'),
    'continuous as a number': ({'continuous': 1}, 'continuous', 'bool'),
    'one-body ignored pair': ({'ignored_pairs': ['d0']}, 'ignored_pairs', 'two bodies'),
    'three-body ignored pair': ({'ignored_pairs': ['d0 d1 d2']}, 'ignored_pairs', 'two bodies'),
    'unknown collider in pair': ({'ignored_pairs': ['d0 chair']}, 'ignored_pairs',
                                 "'chair' is neither"),
    'negative index in pair': ({'ignored_pairs': ['d-1 table']}, 'ignored_pairs',
                               'dynamic index -1'),
    'fractional mask': ({'table.collision_mask': 1.5}, 'table.collision_mask', 'integer'),
    'string category': ({'dynamic.collision_category': ['one']}, 'dynamic.collision_category',
                        'integer[]'),
    'empty dynamic masks': ({'dynamic.collision_mask': []}, 'dynamic.collision_mask',
                            'one value'),
    'mask beyond 64 bits': ({'table.collision_mask': 2**64}, 'table.collision_mask', '64-bit'),
    'collider named like a body': ({'static_colliders': ['d3']}, 'static_colliders',
                                   'dynamic body'),
}


def enabled_scene(parsed):
    """Return the enabled colliders' poses, sizes, ids, margins, categories and masks."""
    on = [c for c in parsed.colliders if c.enabled]
    return (np.array([c.pose for c in on]).reshape(-1, 7),
            np.array([c.half_extents for c in on]).reshape(-1, 3),
            np.array([c.static_id for c in on], np.int64),
            np.array([c.margin for c in on], np.float64),
            np.array([c.collision_category for c in on], np.int64),
            np.array([c.collision_mask for c in on], np.int64))


def test_defaults_are_the_design_table():
    parsed = params.parse({})
    assert parsed.frame_id == 'world' and parsed.broad_phase == 'auto'
    assert parsed.sphere_prefilter is True
    assert (parsed.octree_max_depth, parsed.octree_leaf_cooldown_ticks) == (0, 15)
    np.testing.assert_array_equal(parsed.dynamic_half_extents, [0.5, 0.5, 0.5])
    assert parsed.colliders == ()
    assert (parsed.tick_rate_hz, parsed.input_timeout_s, parsed.max_bodies, parsed.threads,
            parsed.diagnostic_period_s) == (0.0, 1.0, 100000, 1, 1.0)
    assert parsed.margin == 0.0 and parsed.ignored_pairs == []
    assert parsed.dynamic_collision_category == [1] and parsed.dynamic_collision_mask == [-1]
    poses, extents, ids, margins, categories, masks = enabled_scene(parsed)
    assert poses.shape == (0, 7) and extents.shape == (0, 3) and ids.shape == (0,)
    assert margins.shape == categories.shape == masks.shape == (0,)


def test_named_colliders_keep_their_list_index():
    parsed = params.parse(GOOD)
    assert [c.name for c in parsed.colliders] == ['table', 'shelf']
    np.testing.assert_array_equal(parsed.colliders[1].pose, SHELF['shelf.pose'])
    np.testing.assert_array_equal(parsed.colliders[0].half_extents, [0.6, 0.4, 0.02])
    assert [c.enabled for c in parsed.colliders] == [True, False]
    poses, extents, ids, margins, categories, masks = enabled_scene(params.parse(
        dict(GOOD, static_colliders=['shelf', 'table'], **{'shelf.enabled': True,
                                                           'table.enabled': False})))
    assert ids.tolist() == [0]  # table is disabled; the shelf keeps index 0
    assert (margins.tolist(), categories.tolist(), masks.tolist()) == ([0.0], [1], [-1])
    np.testing.assert_array_equal(poses[0], SHELF['shelf.pose'])


def test_dynamic_half_extents_one_size_or_one_per_body():
    assert params.parse({'dynamic.half_extents': [1, 2, 3]}).dynamic_half_extents.shape == (3,)
    per_body = params.parse({'dynamic.half_extents': [1, 2, 3, 4, 5, 6]}).dynamic_half_extents
    np.testing.assert_array_equal(per_body, [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize('case', sorted(BAD))
def test_bad_parameter_is_named(case):
    change, name, words = BAD[case]
    with pytest.raises(ParameterError) as raised:
        params.parse(dict(GOOD, **change))
    assert raised.value.name == name
    assert str(raised.value).startswith("parameter '%s': " % name)
    assert words in str(raised.value)


def test_each_field_is_set_by_one_table_row():
    """The table says which field a parameter sets; no name is turned into a field name."""
    fields = [spec.field for spec in params.PARAMETERS.values() if spec.field]
    assert sorted(fields) == sorted(set(params.Parameters._fields)
                                    - {'colliders', 'next_static_id'})
    assert params.PARAMETERS['check_states.bodies'].field == 'state_bodies'
    assert params.PARAMETERS['diagnostic_updater.period'].field == 'diagnostic_period_s'
    assert [name for name, spec in params.PARAMETERS.items()  # its names make the colliders
            if spec.run_time and not spec.field] == ['static_colliders']
    assert sorted(spec.field for spec in params.COLLIDER_PARAMETERS.values()) == sorted(
        set(params.Collider._fields) - {'name', 'static_id'})


def test_unknown_parameters_are_the_names_no_one_reads():
    given = ['frame_id', 'dynamic.half_extent', 'table.pose', 'tabel.pose', 'shelf.enabled',
             'qos_overrides./dynamic_poses.subscription.depth', 'use_sim_time',
             'octree.max_depth', 'octree.maxdepth']
    assert params.unknown_parameters(given, ['table', 'shelf']) == [
        'dynamic.half_extent', 'octree.maxdepth', 'tabel.pose']
    assert params.unknown_parameters(given, []) == [
        'dynamic.half_extent', 'octree.maxdepth', 'shelf.enabled', 'tabel.pose', 'table.pose']


def test_run_time_changes():
    parsed = params.parse(GOOD)
    changed = params.run_time_change(parsed, 'shelf.enabled', True)
    assert [c.enabled for c in changed.colliders] == [True, True]
    assert params.run_time_change(parsed, 'broad_phase', 'sphere').broad_phase == 'sphere'
    assert params.run_time_change(parsed, 'octree.max_depth', 4).octree_max_depth == 4
    assert params.run_time_change(parsed, 'sphere_prefilter', False).sphere_prefilter is False
    assert params.run_time_change(parsed, 'use_sim_time', True) == parsed  # not ours
    assert params.run_time_change(parsed, 'margin', 0.1).margin == 0.1
    assert parsed.continuous is False and parsed.continuous_tolerance == 1e-4
    assert params.run_time_change(parsed, 'continuous', True).continuous is True
    assert params.run_time_change(parsed, 'continuous_tolerance',
                                  1e-3).continuous_tolerance == 1e-3
    changed = params.run_time_change(parsed, 'shelf.margin', 0.2)
    assert [c.margin for c in changed.colliders] == [0.0, 0.2]
    changed = params.run_time_change(parsed, 'table.collision_mask', 6)
    assert [c.collision_mask for c in changed.colliders] == [6, -1]
    changed = params.run_time_change(parsed, 'ignored_pairs', ['d3 shelf', 'd1 d0'])
    assert changed.filters()[2].tolist() == [[3, 0, 1, 1], [1, 0, 0, 0]]
    assert params.run_time_change(parsed, 'dynamic.collision_category',
                                  [1, 2]).dynamic_collision_category == [1, 2]
    for name, value, words in (('broad_phase', 'nope', 'unknown broad phase'),
                               ('octree.max_depth', 11, 'depth'),
                               ('shelf.enabled', 1, 'bool'),
                               ('shelf.pose', [0.0] * 7, 'unit quaternion'),
                               ('shelf.half_extents', [1.0, 2.0], '3 values'),
                               ('static_colliders', ['a'], 'a.pose'),
                               ('frame_id', 'map', 'fixed at start'),
                               ('dynamic.half_extents', [1.0] * 3, 'fixed at start'),
                               ('no_such_parameter', 1.0, 'undeclared'),
                               ('shelf.colour', 'red', 'undeclared'),
                               ('margin', -0.1, 'distance'),
                               ('continuous_tolerance', math.nan, 'distance'),
                               ('continuous_tolerance', -1e-4, 'distance'),
                               ('continuous', 'yes', 'bool'),
                               ('shelf.margin', math.inf, 'distance'),
                               ('shelf.collision_category', 'all', 'integer'),
                               ('dynamic.collision_mask', [1.5], 'integer'),
                               ('ignored_pairs', ['d1 sofa'], 'neither'),
                               ('ignored_pairs', ['d1-d2'], 'two bodies')):
        with pytest.raises(ParameterError, match=words) as raised:
            params.run_time_change(parsed, name, value)
        assert raised.value.name in (name, 'a.pose')


def test_start_only_parameters_are_read_only_once_configured_and_autostart_always():
    spec = params.PARAMETERS['autostart']
    assert (spec.value_type, spec.default, spec.run_time) == (params.BOOL, True, False)
    assert params.READ_ONLY == {'autostart'}
    parsed = params.parse(GOOD)
    for name, value in (('tick_rate_hz', 5.0), ('frame_id', 'map'), ('autostart', False)):
        with pytest.raises(ParameterError, match='read-only while configured'):
            params.run_time_change(parsed, name, value)


def test_unconfigured_changes_are_checked_for_name_and_type_only():
    """Configure checks the values together; a change while unconfigured only needs its type."""
    for name, value in (('frame_id', 'map'), ('tick_rate_hz', -5.0), ('door.pose', [0.0] * 7),
                        ('static_colliders', ['a', 'a']), ('autostart', False),
                        ('qos_overrides./dynamic_poses.subscription.depth', 3)):
        params.check_unconfigured(name, value)
    for name, value, words in (('no_such_parameter', 1.0, 'undeclared'),
                               ('tick_rate_hz', 'fast', 'must be of type double'),
                               ('door.enabled', 1, 'must be of type bool'),
                               ('d3.pose', [0.0] * 7, 'names a dynamic body'),
                               ('door.colour', 'red', 'undeclared')):
        with pytest.raises(ParameterError, match=words):
            params.check_unconfigured(name, value)


def test_the_diagnostic_period_before_configure_falls_back_to_its_default():
    assert params.diagnostic_period_s(0.25) == 0.25
    for bad in (0.0, -1.0, math.inf, None, 'fast'):
        assert params.diagnostic_period_s(bad) == 1.0


def test_colliders_are_moved_added_and_removed_with_ids_for_their_lifetime():
    parsed = params.parse(dict(GOOD, ignored_pairs=['d0 shelf']))
    assert [(c.name, c.static_id) for c in parsed.colliders] == [('table', 0), ('shelf', 1)]
    moved = params.run_time_change(parsed, 'table.pose', [1.0, 0.0, 0.4, 0.0, 0.0, 0.0, 1.0])
    assert moved.colliders[0].pose[0] == 1.0 and moved.colliders[1] is parsed.colliders[1]
    resized = params.run_time_change(parsed, 'shelf.half_extents', [1, 2, 3])
    assert resized.colliders[1].half_extents.tolist() == [1.0, 2.0, 3.0]
    # A block for a name not yet listed is checked and kept aside (the node's parameters).
    door = {'door.pose': [3.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], 'door.half_extents': [0.05, 0.5, 1],
            'door.collision_mask': 2}
    for name, value in door.items():
        assert params.run_time_change(parsed, name, value) == parsed
    with pytest.raises(ParameterError, match='unit quaternion'):
        params.run_time_change(parsed, 'door.pose', [0.0] * 7)
    added = params.run_time_change(parsed, 'static_colliders', ['table', 'door', 'shelf'],
                                   door.get)
    assert [(c.name, c.static_id) for c in added.colliders] == [
        ('table', 0), ('door', 2), ('shelf', 1)]
    assert added.colliders[1].collision_mask == 2 and added.colliders[1].enabled
    assert added.filters()[2].tolist() == [[0, 0, 1, 1]]  # shelf keeps id 1
    # Removed, then added again: a new collider with a new id, never an old one's.
    removed = params.run_time_change(added, 'static_colliders', ['door', 'shelf'])
    again = params.run_time_change(removed, 'static_colliders', ['door', 'shelf', 'table'],
                                   {'table.pose': TABLE['table.pose'],
                                    'table.half_extents': [0.1, 0.1, 0.1]}.get)
    assert [c.static_id for c in again.colliders] == [2, 1, 3]
    # A collider named in ignored_pairs cannot go unless the entry goes in the same call.
    without_shelf = params.run_time_change(added, 'static_colliders', ['table', 'door'])
    with pytest.raises(ParameterError, match="'shelf' is neither") as raised:
        params.check_run_time(without_shelf)
    assert raised.value.name == 'static_colliders'
    params.check_run_time(params.run_time_change(without_shelf, 'ignored_pairs', []))
    for names, words in ((['table', 'table'], 'twice'), (['door'], 'door.pose'),
                         (['margin'], 'taken')):
        with pytest.raises(ParameterError, match=words):
            params.run_time_change(parsed, 'static_colliders', names)


def test_half_extents_file(tmp_path):
    sizes = np.random.default_rng(1).uniform(0.1, 0.3, (1000, 3))
    np.save(tmp_path / 'sizes.npy', sizes)
    parsed = params.parse({'dynamic.half_extents_file': str(tmp_path / 'sizes.npy')})
    np.testing.assert_array_equal(parsed.dynamic_half_extents, sizes)
    np.save(tmp_path / 'one.npy', np.array([0.1, 0.2, 0.3], np.float32))
    one = params.parse({'dynamic.half_extents_file': str(tmp_path / 'one.npy')})
    assert one.dynamic_half_extents.shape == (3,)
    bad = sizes.copy()
    bad[7, 1] = -1.0
    np.save(tmp_path / 'negative.npy', bad)
    np.save(tmp_path / 'flat.npy', sizes.ravel())
    np.save(tmp_path / 'objects.npy', np.array([{'a': 1}], dtype=object), allow_pickle=True)
    (tmp_path / 'text.npy').write_text('0.1 0.1 0.1')
    for name, words in (('negative.npy', r'row 7: half extents must be finite, >= 0.*-1\.0'),
                        ('flat.npy', r'shape \(3000,\)'),
                        ('objects.npy', 'cannot read'), ('text.npy', 'cannot read'),
                        ('missing.npy', 'cannot read')):
        with pytest.raises(ParameterError, match=words) as raised:
            params.parse({'dynamic.half_extents_file': str(tmp_path / name)})
        assert raised.value.name == 'dynamic.half_extents_file'


def scene_file(path, count=5, **arrays):
    rng = np.random.default_rng(2)
    poses = np.zeros((count, 7))
    poses[:, :3] = rng.uniform(-5, 5, (count, 3))
    poses[:, 6] = 1.0
    contents = {'names': np.array(['box%d' % i for i in range(count)]), 'poses': poses,
                'half_extents': rng.uniform(0.1, 1.0, (count, 3))}
    contents.update(arrays)
    np.savez(path, **{k: v for k, v in contents.items() if v is not None})
    return contents


def test_static_scene_file(tmp_path):
    path = str(tmp_path / 'scene.npz')
    contents = scene_file(path, enabled=np.array([True, False, True, True, True]),
                          margins=np.full(5, 0.1), collision_masks=np.arange(5))
    parsed = params.parse(dict(GOOD, static_scene_file=path))
    assert [c.name for c in parsed.colliders] == ['box0', 'box1', 'box2', 'box3', 'box4',
                                                  'table', 'shelf']
    assert [c.static_id for c in parsed.colliders] == list(range(7))
    poses, extents, ids, margins, categories, masks = enabled_scene(parsed)
    assert ids.tolist() == [0, 2, 3, 4, 5]  # box1 and the shelf are disabled
    np.testing.assert_array_equal(poses[:4], contents['poses'][[0, 2, 3, 4]])
    np.testing.assert_array_equal(extents[:4], contents['half_extents'][[0, 2, 3, 4]])
    assert margins.tolist() == [0.1] * 4 + [0.0] and masks.tolist() == [0, 2, 3, 4, -1]
    bad_pose = contents['poses'].copy()
    bad_pose[3, 5] = 2.0
    for arrays, words in (({'poses': bad_pose}, 'box3 \\(row 3'),
                          ({'poses': bad_pose[:, :6]}, 'poses must be numbers of shape'),
                          ({'names': None}, "no array 'names'"),
                          ({'names': np.array(['a', 'a', 'b', 'c', 'd'])}, 'twice'),
                          ({'colour': np.zeros(5)}, 'known'),
                          ({'half_extents': -contents['half_extents']}, '>= 0'),
                          ({'enabled': np.ones(5)}, 'enabled must be booleans'),
                          ({'margins': np.full(5, np.nan)}, 'box0 \\(row 0\\) margin')):
        scene_file(path, **arrays)
        with pytest.raises(ParameterError, match=words) as raised:
            params.parse({'static_scene_file': path})
        assert raised.value.name == 'static_scene_file', raised.value
    scene_file(path, names=np.array(['box0', 'table', 'b', 'c', 'd']))
    with pytest.raises(ParameterError, match="'table' appears twice"):
        params.parse(dict(GOOD, static_scene_file=path))


# Through rclpy: the same checks must hold for values that come from a params file.

@pytest.fixture
def context():
    import rclpy
    context = rclpy.Context()
    yield context
    context.try_shutdown()


def test_params_file_reaches_the_node(context, tmp_path):
    import rclpy
    from collision_node.ros.node import CollisionNode
    rclpy.init(args=['--ros-args', '--params-file', write_params(tmp_path / 'p.yaml', GOOD_YAML)],
               context=context, domain_id=DOMAIN_ID)
    node = CollisionNode(context=context)
    try:
        assert node.get_parameter('frame_id').value == 'map'
        assert list(node.get_parameter('table.half_extents').value) == [0.6, 0.4, 0.02]
        assert node.get_parameter('shelf.enabled').value is False
        assert node.get_parameter('table.enabled').value is True  # the default
        assert node.get_parameter('max_bodies').value == 100000
        assert node.get_parameter('qos_overrides./dynamic_poses.subscription.depth').value == 1
    finally:
        node.destroy_node()


def test_default_config_is_the_demo_room(context):
    import rclpy
    from collision_node.pipeline import scenes
    from collision_node.ros.node import CollisionNode
    rclpy.init(args=['--ros-args', '--params-file', str(REPO / 'config' / 'default.yaml')],
               context=context, domain_id=DOMAIN_ID)
    node = CollisionNode(context=context)
    try:
        assert node.get_parameter('static_colliders').value == list(scenes.ROOM_STATICS)
        for name, (pose, extents) in scenes.ROOM_STATICS.items():
            assert list(node.get_parameter(name + '.pose').value) == list(pose)
            assert list(node.get_parameter(name + '.half_extents').value) == list(extents)
        assert list(node.get_parameter('dynamic.half_extents').value) == list(
            scenes.ROOM_HALF_EXTENTS)
        assert node.get_parameter('broad_phase').value == 'auto'
        assert node.get_parameter('frame_id').value == 'world'
    finally:
        node.destroy_node()


def test_arm_config_is_the_arm_scene(context):
    import rclpy
    from collision_node.pipeline import scenes
    from collision_node.ros.node import CollisionNode
    rclpy.init(args=['--ros-args', '--params-file', str(REPO / 'config' / 'arm.yaml')],
               context=context, domain_id=DOMAIN_ID)
    node = CollisionNode(context=context)
    try:
        scene = scenes.make_scene('arm', scenes.ARM_LINK_COUNT)
        assert node.get_parameter('static_colliders').value == list(scenes.ARM_STATICS)
        for name, (pose, extents) in scenes.ARM_STATICS.items():
            assert list(node.get_parameter(name + '.pose').value) == list(pose)
            assert list(node.get_parameter(name + '.half_extents').value) == list(extents)
        assert list(node.get_parameter('dynamic.half_extents').value) == \
            scene.dynamic_half_extents.ravel().tolist()
        assert node.get_parameter('margin').value == 0.05
        # Every pair of neighbouring links is ignored, and the base on the floor.
        rows = params.ignored_pair_rows(node.get_parameter('ignored_pairs').value,
                                        list(scenes.ARM_STATICS))
        assert sorted(map(tuple, rows.tolist())) == sorted(
            [(link, DYNAMIC_TYPE, link + 1, DYNAMIC_TYPE)
             for link in range(scenes.ARM_LINK_COUNT - 1)] + [(0, DYNAMIC_TYPE, 0, STATIC_TYPE)])
    finally:
        node.destroy_node()


def test_input_qos_can_be_overridden(context, tmp_path):
    import rclpy
    from rclpy.qos import HistoryPolicy, ReliabilityPolicy
    from collision_node.ros.node import CollisionNode
    path = write_params(tmp_path / 'p.yaml', """
qos_overrides:
  /dynamic_poses:
    subscription:
      reliability: best_effort
      depth: 3
""")
    rclpy.init(args=['--ros-args', '--params-file', path], context=context,
               domain_id=DOMAIN_ID)
    node = CollisionNode(context=context)
    try:
        by_topic = {s.topic_name: s for s in node.subscriptions}
        dynamic, static = by_topic['/dynamic_poses'], by_topic['/static_poses']
        assert dynamic.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert dynamic.qos_profile.depth == 3
        assert dynamic.qos_profile.history == HistoryPolicy.KEEP_LAST
        # static_poses keeps the default: reliable, the newest only.
        assert static.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert static.qos_profile.depth == 1
        # check_states keeps every request: reliable, the whole queue.
        requests = by_topic['/check_states'].qos_profile
        assert requests.reliability == ReliabilityPolicy.RELIABLE
        assert requests.history == HistoryPolicy.KEEP_ALL
    finally:
        node.destroy_node()


def test_empty_collider_list_from_yaml(context, tmp_path):
    import rclpy
    from collision_node.ros.node import CollisionNode
    path = write_params(tmp_path / 'p.yaml', 'static_colliders: []\n')
    rclpy.init(args=['--ros-args', '--params-file', path], context=context,
               domain_id=DOMAIN_ID)
    node = CollisionNode(context=context)  # an empty YAML list arrives untyped: still valid
    node.destroy_node()


@pytest.mark.parametrize('name', sorted(BAD_YAML))
def test_bad_params_file_stops_the_node(context, tmp_path, name):
    import rclpy
    from collision_node.ros.node import CollisionNode
    path = write_params(tmp_path / 'p.yaml', BAD_YAML[name])
    rclpy.init(args=['--ros-args', '--params-file', path], context=context,
               domain_id=DOMAIN_ID)
    with pytest.raises(ParameterError) as raised:
        CollisionNode(context=context)
    assert raised.value.name == name
    if name == 'input_timeout_s':
        assert str(raised.value) == ("parameter 'input_timeout_s': must be of type double "
                                     '(write 1.0, not 1), got integer')


def test_misspelt_parameter_is_warned_at_start(context, capfd):
    import rclpy
    from rclpy.parameter import Parameter
    from collision_node.ros.node import CollisionNode
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = CollisionNode(context=context, parameter_overrides=[
        Parameter('dynamic.half_extent', value=[0.1, 0.1, 0.1])])
    try:
        assert list(node.get_parameter('dynamic.half_extents').value) == [0.5, 0.5, 0.5]
    finally:
        node.destroy_node()
    log = capfd.readouterr().err
    assert 'ignored 1 parameter(s)' in log and "'dynamic.half_extent'" in log


def test_bad_overrides_stop_the_node(context):
    import rclpy
    from rclpy.parameter import Parameter
    from collision_node.ros.node import CollisionNode
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    with pytest.raises(ParameterError, match="parameter 'box.pose': quaternion"):
        CollisionNode(context=context, parameter_overrides=[
            Parameter('static_colliders', value=['box']),
            Parameter('box.pose', value=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0]),
            Parameter('box.half_extents', value=[1.0, 1.0, 1.0])])


def test_process_exits_with_the_parameter_named(tmp_path):
    done = run_node(DOMAIN_ID, write_params(tmp_path / 'bad.yaml', BAD_YAML['shelf.half_extents']))
    assert done.returncode == 2
    assert "parameter 'shelf.half_extents'" in done.stderr
    assert 'Traceback' not in done.stderr


def test_process_exits_on_an_unparsable_params_file(tmp_path):
    # rcl itself refuses a list mixing integers and doubles, before any node exists.
    done = run_node(DOMAIN_ID, write_params(tmp_path / 'bad.yaml',
                                            'dynamic:\n  half_extents: [1, 0.5, 1]'))
    assert done.returncode == 2
    assert 'Sequence should be of same type' in done.stderr
    assert 'Traceback' not in done.stderr


def test_scene_parameters_parse_back_to_the_scene(tmp_path):
    rng = np.random.default_rng(3)
    poses = np.concatenate([rng.normal(size=(4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))], 1)
    extents = rng.uniform(0.1, 0.5, (4, 3))
    values = params_files.scene_parameters(poses, extents, [0.2, 0.2, 0.2], broad_phase='grid',
                                           **{'diagnostic_updater.period': 0.5})
    parsed = params.parse(values)
    assert [c.name for c in parsed.colliders] == ['s0', 's1', 's2', 's3']
    np.testing.assert_array_equal([c.pose for c in parsed.colliders], poses)
    np.testing.assert_array_equal([c.half_extents for c in parsed.colliders], extents)
    assert (parsed.broad_phase, parsed.diagnostic_period_s) == ('grid', 0.5)
    path = tmp_path / 'scene.yaml'
    params_files.write_params_file(path, params_files.scene_parameters(poses[:0], extents[:0],
                                                                       [0.1] * 3))
    assert 'static_colliders' not in path.read_text()  # an empty list has no type
