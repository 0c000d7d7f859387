"""collision_node.cluster: Ray actors answer exactly what one World in one process answers.

One local Ray (2 CPUs) serves the module's first sections; the last section shuts it down
and runs a two-node ray.cluster_utils.Cluster instead (the sections run in file order). Every
answer is compared with np.array_equal to the World's own, after the same scene verbs,
with workers killed mid-batch or loaded with another scene.
"""
import os
import pathlib
import subprocess
import sys
import time

import numpy as np
import pytest
import ray  # the 'test' extra has it, and CI installs it: no cluster test is skipped
from test_robot_world import panda_world, random_states

from collision_node import World
from collision_node.cluster import ClusterChecker, ClusterError
from collision_node.tools import label

REPO = pathlib.Path(__file__).resolve().parent.parent


def with_repo_on_path():
    """Let Ray's worker processes import the package as this process does."""
    paths = [str(REPO)] + [p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep) if p]
    os.environ['PYTHONPATH'] = os.pathsep.join(dict.fromkeys(paths))


@pytest.fixture(scope='module')
def local_ray():
    with_repo_on_path()
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def killed(worker):
    """Kill ``worker`` and return once it is dead.

    ray.kill only asks: an actor answers the chunks queued on it until the kill lands, and a
    chunk of a few states takes microseconds, so a test that did not wait would race it.
    """
    ray.kill(worker)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            ray.get(worker.where.remote(), timeout=30)
        except ray.exceptions.RayActorError:
            return
        time.sleep(0.01)
    raise AssertionError('the worker still answers 60 s after ray.kill')


def box_world(dynamic=6, static=10, seed=0, **settings):
    """Return (world, states (12, D, 7), half extents (D, 3)): random boxes in a 2 m cube."""
    rng = np.random.default_rng(seed)

    def poses(*shape):
        quaternions = rng.normal(size=shape + (4,))
        quaternions /= np.linalg.norm(quaternions, axis=-1, keepdims=True)
        return np.concatenate([rng.uniform(-1, 1, shape + (3,)), quaternions], axis=-1)
    world = World(**settings)
    world.set_static(poses(static), rng.uniform(0.05, 0.4, (static, 3)),
                     ids=np.arange(static) * 3 + 1, margins=rng.uniform(0, 0.05, static))
    return world, poses(12, dynamic), rng.uniform(0.05, 0.4, (dynamic, 3))


@pytest.mark.parametrize('settings', [
    {'broad_phase': 'brute_force'},
    {'broad_phase': 'grid', 'margin': 0.05},
    {'broad_phase': 'sweep_and_prune', 'sphere_prefilter': False},
    {'broad_phase': 'octree', 'filtered': True},
    {'broad_phase': 'kd_tree', 'dynamic': 200, 'static': 100},   # beyond the one pass
], ids=lambda settings: '-'.join('%s' % value for value in settings.values()))
def test_check_states_equals_one_world(local_ray, settings):
    settings = dict(settings)
    filtered = settings.pop('filtered', False)
    sizes = {key: settings.pop(key) for key in ('dynamic', 'static') if key in settings}
    world, states, half_extents = box_world(**sizes, **settings)
    if filtered:
        world.set_filters(categories=[1, 2, 1, 2, 1, 2], masks=[-1, 1, -1, -1, 2, -1],
                          ignored_pairs=[(0, 0, 1, 0), (2, 0, 4, 1)])
    expected = world.check_states(states, half_extents).contacts
    assert len(expected) > 0
    with ClusterChecker(world, workers=2, chunk=5) as checker:
        assert len(checker.workers) == 2
        found = checker.check_states(states, half_extents)
        assert np.array_equal(found.contacts, expected)
        assert found.stats['chunks'] == 3 and found.stats['states'] == 12


def test_check_joints_equals_one_world(local_ray, panda):
    world = panda_world(panda, margin=0.02)
    world.set_filters(ignored_pairs=[(5, 0, 1, 1)])
    q = random_states(panda, 60, seed=1)
    expected = world.check_joints(q).contacts
    assert len(np.unique(expected['state'])) > 10
    with ClusterChecker(world, workers=2, chunk=16) as checker:
        assert np.array_equal(checker.check_joints(q).contacts, expected)
    with ClusterChecker(box_world()[0], workers=1) as checker:
        with pytest.raises(ValueError, match='no robot'):
            checker.check_joints(q)


def test_scene_changes_between_batches(local_ray):
    world, states, half_extents = box_world(margin=0.02)
    with ClusterChecker(world, workers=2, chunk=4) as checker:
        moved = world.static_colliders.poses[:2] + [0.2, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0]
        verbs = [('move_static', [1, 4], moved),
                 ('add_static', [100], [[0, 0, 0, 0, 0, 0, 1]], [[0.5, 0.5, 0.5]]),
                 ('move_static', [100], None, [[0.2, 0.3, 0.4]]),
                 ('remove_static', [7, 100]),
                 ('enable_static', [1], False)]
        for verb, *arguments in verbs:
            getattr(world, verb)(*arguments)
            getattr(checker, verb)(*arguments)
            assert np.array_equal(checker.check_states(states, half_extents).contacts,
                                  world.check_states(states, half_extents).contacts), verb
        assert checker.version == len(verbs)
        with pytest.raises(ValueError, match='static id 55'):
            checker.move_static([55], world.static_colliders.poses[:1])
        assert checker.version == len(verbs)  # refused in the caller: nothing sent


def test_a_worker_at_another_version_is_loaded_again(local_ray):
    world, states, half_extents = box_world()
    other, _, _ = box_world(seed=5)
    with ClusterChecker(world, workers=2, chunk=3) as checker:
        ray.get(checker.workers[0].load.remote(other.describe(), 999))
        assert np.array_equal(checker.check_states(states, half_extents).contacts,
                              world.check_states(states, half_extents).contacts)
        assert checker.reruns > 0


def test_a_worker_killed_mid_batch(local_ray):
    world, states, half_extents = box_world(margin=0.05)
    expected = world.check_states(states, half_extents).contacts
    with ClusterChecker(world, workers=2, chunk=1, in_flight=3) as checker:
        parts = []
        blocks = [states[:6], states[6:]]
        for first, count, contacts in checker.stream_states(blocks, half_extents):
            if not parts:
                killed(checker.workers[0])
            parts.append(contacts)
        assert np.array_equal(np.concatenate(parts), expected)
        assert checker.restarts == 1 and checker.reruns > 0
        assert np.array_equal(checker.check_states(states, half_extents).contacts, expected)


def test_bad_input_raises_before_anything_is_sent(local_ray, panda):
    world, states, half_extents = box_world()
    with ClusterChecker(world, workers=1, restarts=0) as checker:
        killed(checker.workers[0])  # a chunk sent would end in ClusterError
        bad = states.copy()
        bad[7, 2, 4] = np.nan
        with pytest.raises(ValueError) as refused:
            world.check_states(bad, half_extents)
        with pytest.raises(ValueError, match='state 7: dynamic body 2') as error:
            checker.check_states(bad, half_extents)
        assert str(error.value) == str(refused.value)
        with pytest.raises(ValueError, match='half extents'):
            checker.check_states(states, half_extents[:2])
        with pytest.raises(ValueError, match='shape'):
            checker.check_states(states[0], half_extents)
        with pytest.raises(ClusterError, match='0 of 12 states answered'):
            checker.check_states(states, half_extents)
    with ClusterChecker(panda_world(panda), workers=1, restarts=0) as checker:
        killed(checker.workers[0])
        q = random_states(panda, 5, seed=0)
        q[3, 1] = np.inf
        with pytest.raises(ValueError, match="state 3, joint 'panda_joint2'"):
            checker.check_joints(q)
        with pytest.raises(ValueError, match='q must have shape'):
            checker.check_joints(q[:, :3])


def test_every_worker_lost_mid_batch_says_how_many_were_answered(local_ray):
    world, states, half_extents = box_world()
    with ClusterChecker(world, workers=2, chunk=2, in_flight=1, restarts=0) as checker:
        stream = checker.stream_states([states], half_extents)
        first = next(stream)
        for worker in checker.workers:
            killed(worker)
        with pytest.raises(ClusterError, match=r'\d+ states answered: every worker is lost'):
            list(stream)
        assert first[0] == 0 and first[1] == 2
        with pytest.raises(ClusterError, match='0 of 12 states answered'):
            checker.check_states(states, half_extents)


def test_without_ray_the_import_names_the_extra_and_nothing_else_imports_ray():
    hidden = subprocess.run(
        [sys.executable, '-c', 'import sys; sys.modules["ray"] = None\n'
         'import collision_node.cluster'], capture_output=True, text=True, timeout=120,
        cwd=REPO)
    assert hidden.returncode != 0
    assert "ImportError: collision_node.cluster needs Ray: install the 'ray' extra" \
        in hidden.stderr
    names = sorted('.'.join(path.relative_to(REPO).with_suffix('').parts).removesuffix(
        '.__init__') for path in (REPO / 'collision_node').glob('**/*.py')
        if path.relative_to(REPO / 'collision_node').parts[0] != 'cluster')
    script = ('import sys, importlib\n'
              'for name in %r: importlib.import_module(name)\n'
              'print(sorted(m for m in sys.modules if m.split(".")[0] == "ray"))\n' % names)
    done = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                          timeout=300, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == '[]'


def expected_labels(contacts, count):
    """Labels by hand: per state the row of smallest distance (first on a tie)."""
    rows = {}
    for row in contacts:
        state = int(row['state'])
        if state not in rows or row['distance'] < rows[state]['distance']:
            rows[state] = row
    labels = np.zeros(count, label.label_dtype())
    for name in ('id_a', 'type_b', 'id_b'):
        labels[name] = -1
    labels['depth'] = labels['distance'] = np.nan
    for state, row in rows.items():
        labels[state] = (row['distance'] <= 0.0, row['id_a'], row['type_b'], row['id_b'],
                         row['depth'], row['distance'])
    return labels


def test_the_docs_snippet(local_ray, panda):
    from test_readme import python_snippets
    from test_robot_world import STATIC_HALF_EXTENTS, STATIC_POSES
    snippet, = python_snippets(REPO / 'doc' / 'cluster.md')['The checker']
    q = random_states(panda, 30, seed=2)
    namespace = {'robot': panda, 'static_poses': np.array(STATIC_POSES),
                 'static_half_extents': np.array(STATIC_HALF_EXTENTS), 'q': q,
                 'states': panda.box_poses(q), 'half_extents': panda.half_extents,
                 'ids': [0], 'poses': np.array(STATIC_POSES[:1]) + [0.1, 0, 0, 0, 0, 0, 0],
                 'blocks_of_q': [q[:10], q[10:]]}
    exec(snippet, namespace)
    world = namespace['world']
    assert np.array_equal(namespace['result'].contacts, world.check_joints(q).contacts)
    assert len(namespace['contacts']) > 0  # the stream's last chunk, after the move


def assert_labels_equal(found, expected):
    for name, kind in label.LABEL_FIELDS:
        assert np.array_equal(found[name], expected[name], equal_nan=kind is np.float64), name


def test_collision_label_writes_the_worlds_labels(local_ray, panda, tmp_path):
    from conftest import PANDA, PREFIX
    from test_robot_world import STATIC_HALF_EXTENTS, STATIC_POSES
    statics = [str(value) for pose, half in zip(STATIC_POSES, STATIC_HALF_EXTENTS)
               for value in ['--static'] + pose + half]
    output = tmp_path / 'labels.npy'
    previous = os.environ.get('AMENT_PREFIX_PATH')
    os.environ['AMENT_PREFIX_PATH'] = PREFIX
    try:
        assert label.main(['--urdf', os.path.join(PANDA, 'urdf', 'panda.urdf'),
                           '--srdf', os.path.join(PANDA, 'srdf', 'panda.srdf'),
                           '--count', '250', '--seed', '3', '--margin', '0.03',
                           '--chunk', '40', '--output', str(output), '--quiet']
                          + statics) == 0
    finally:
        if previous is None:
            del os.environ['AMENT_PREFIX_PATH']
        else:
            os.environ['AMENT_PREFIX_PATH'] = previous
    labels = np.load(output)
    q = random_states(panda, 250, seed=3)
    assert np.array_equal(labels['q'], q)
    world = panda_world(panda, margin=0.03)
    contacts = world.check_joints(q).contacts
    expected = expected_labels(contacts, 250)
    assert_labels_equal(labels, expected)
    assert 0 < labels['collides'].sum() < 250
    assert not (tmp_path / 'labels.npy.part').exists()


def test_collision_label_without_a_robot(local_ray, tmp_path):
    world, states, half_extents = box_world(margin=0.01)
    poses = tmp_path / 'poses.npy'
    np.save(poses, states)
    output = tmp_path / 'labels.npy'
    colliders = world.static_colliders
    statics = []
    for pose, half in zip(colliders.poses, colliders.half_extents):
        statics += ['--static'] + [repr(float(value)) for value in list(pose) + list(half)]
    assert label.main(['--poses', str(poses), '--half-extents', '0.2', '0.1', '0.3',
                       '--margin', '0.01', '--chunk', '5', '--output', str(output), '--quiet']
                      + statics) == 0
    one = World(margin=0.01)
    one.set_static(colliders.poses, colliders.half_extents)
    expected = expected_labels(one.check_states(states, [0.2, 0.1, 0.3]).contacts, 12)
    assert_labels_equal(np.load(output), expected)


# ---------------------------------------------------------------------- two nodes

@pytest.fixture(scope='module')
def two_nodes(local_ray):
    """Start a head and a second node, two CPUs each (the local Ray is shut down first)."""
    from ray.cluster_utils import Cluster
    ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={'num_cpus': 2,
                                                            'include_dashboard': False})
    second = cluster.add_node(num_cpus=2)
    ray.init(address=cluster.address, log_to_driver=False)
    cluster.wait_for_nodes()
    yield cluster, second
    ray.shutdown()
    cluster.shutdown()


def test_two_nodes_one_lost_mid_batch(two_nodes):
    cluster, second = two_nodes
    world, states, half_extents = box_world(margin=0.03)
    states = np.tile(states, (40, 1, 1))  # 480 states, 240 chunks: the loss lands mid-batch
    expected = world.check_states(states, half_extents).contacts
    with ClusterChecker(world, workers=2, chunk=2, in_flight=1) as checker:
        nodes = {ray.get(worker.where.remote())[0] for worker in checker.workers}
        assert len(nodes) == 2
        assert np.array_equal(checker.check_states(states, half_extents).contacts, expected)
        parts = []
        for _, _, contacts in checker.stream_states([states], half_extents):
            if not parts:
                cluster.remove_node(second)
            parts.append(contacts)
        assert np.array_equal(np.concatenate(parts), expected)
        # The lost actor is replaced on the head node, at the latest by the next batch.
        assert np.array_equal(checker.check_states(states, half_extents).contacts, expected)
        assert checker.restarts == 1
        assert {ray.get(worker.where.remote())[0] for worker in checker.workers} == \
            {ray.get_runtime_context().get_node_id()}
