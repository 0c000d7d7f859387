"""Every Python snippet of the README and of doc/, run as written.

Each snippet is found by its page and the heading it stands under, so an edit that breaks one
fails here. The snippets that publish through ROS are run by test_readme_ros.py.
"""
import contextlib
import io
import pathlib
import re
import sysconfig

import numpy as np
from std_msgs.msg import Header

from collision_node import World
from collision_node.pipeline import scenes

REPO = pathlib.Path(__file__).resolve().parent.parent
README = REPO / 'README.md'
DOC = REPO / 'doc'
# Every page with ```python blocks, and the headings they stand under: each has a test here,
# in test_readme_ros.py or (doc/cluster.md, with Ray) in test_cluster.py.
SNIPPETS = {
    'README.md': ['Point it at your robot', 'Publishing poses from a script',
                  'The collisions cloud'],
    'doc/design.md': ['Static collider ids'],
    'doc/python-api.md': ['Python API', "The broad phase's pairs"],
    'doc/changing-scene.md': ['Moving colliders with static_poses',
                              'Adding, removing, resizing, enabling with parameters'],
    'doc/lifecycle.md': ['From code'],
    'doc/robot.md': ['The robot model', 'In the World: joint states and whole trajectories'],
    'doc/cluster.md': ['The checker'],
}


def code_blocks(language, page=README):
    """{heading: [code, ...]} for every ```language block of a page ('': no language)."""
    blocks, heading = {}, None
    for match in re.finditer(r'^(#+ [^\n]*)$|^```(\w*)\n(.*?)^```', page.read_text(),
                             re.MULTILINE | re.DOTALL):
        if match.group(1):
            heading = match.group(1).lstrip('#').strip()
        elif match.group(2) == language:
            blocks.setdefault(heading, []).append(match.group(3))
    return blocks


def python_snippets(page=README):
    """{heading: [code, ...]} for every ```python block of a page."""
    return code_blocks('python', page)


def test_every_snippet_has_a_test():
    pages = [README] + sorted(DOC.glob('*.md'))
    found = {page.relative_to(REPO).as_posix(): sorted(python_snippets(page)) for page in pages}
    assert {name: headings for name, headings in found.items() if headings} == {
        name: sorted(headings) for name, headings in SNIPPETS.items()}


def test_python_api_snippet():
    scene = scenes.make_scene('room', 40, 0)
    namespace = {'static_poses': scene.static_poses,
                 'static_half_extents': scene.static_half_extents,
                 'dynamic_poses': scene.dynamic_poses(0.0),
                 'dynamic_half_extents': scene.dynamic_half_extents}
    snippet, = python_snippets(DOC / 'python-api.md')['Python API']
    exec(snippet, namespace)
    result = namespace['result']
    assert result.stats['dynamic_bodies'] == 40
    assert len(result.contacts) == result.stats['colliding_pairs'] > 0
    # The snippet's first state is the step's input: the same rows, with 'state' 0 first.
    batch = namespace['batch'].contacts
    assert batch.dtype.names == ('state',) + result.contacts.dtype.names
    first = batch[batch['state'] == 0]
    for name in result.contacts.dtype.names:
        np.testing.assert_array_equal(first[name], result.contacts[name])


def test_broad_phase_pairs_snippet():
    scene = scenes.make_scene('room', 40, 0)
    world = World(broad_phase='brute_force')
    world.set_static(scene.static_poses, scene.static_half_extents)
    namespace = {'world': world, 'dynamic_poses': scene.dynamic_poses(0.0),
                 'dynamic_half_extents': scene.dynamic_half_extents}
    snippet, = python_snippets(DOC / 'python-api.md')["The broad phase's pairs"]
    exec(snippet, namespace)
    broad = namespace['broad']
    contacts = world.step(namespace['dynamic_poses'], scene.dynamic_half_extents).contacts
    keys = {(int(broad.ids[a]), int(broad.types[b]), int(broad.ids[b])) for a, b in broad.pairs}
    assert {(int(c['id_a']), int(c['type_b']), int(c['id_b'])) for c in contacts} <= keys
    assert broad.compared >= broad.candidates >= len(broad.pairs) >= len(contacts) > 0


def test_robot_snippets(monkeypatch):
    """The robot page's snippets on the Panda of example-robot-data, and the README's two lines."""
    prefix = pathlib.Path(sysconfig.get_paths()['purelib']) / 'cmeel.prefix'
    panda = prefix / 'share' / 'example-robot-data' / 'robots' / 'panda_description'
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    scene = scenes.make_scene('room', 40, 0)
    namespace = {'urdf_path': str(panda / 'urdf' / 'panda.urdf'),
                 'srdf_path': str(panda / 'srdf' / 'panda.srdf'),
                 'static_poses': scene.static_poses,
                 'static_half_extents': scene.static_half_extents,
                 'q': np.zeros((3, 8)), 'waypoints': np.linspace(0.0, 0.5, 24).reshape(3, 8)}
    model, world = python_snippets(DOC / 'robot.md').values()
    exec(model[0] + world[0], namespace)
    assert len(namespace['robot'].box_links) == 17
    assert namespace['path'].dtype.names[0] == 'state'
    readme, = python_snippets()['Point it at your robot']
    exec(readme, namespace)  # a World of its own, without the obstacles
    robot_only = namespace['world']
    robot_only.set_robot(namespace['robot'])
    assert np.array_equal(namespace['contacts'],
                          robot_only.check_trajectory(namespace['waypoints']).contacts)


def test_cloud_snippet_reads_a_real_cloud():
    from collision_node import World
    from collision_node.ros.messages import contacts_to_cloud
    scene = scenes.make_scene('room', 40, 0)
    world = World()
    world.set_static(scene.static_poses, scene.static_half_extents)
    contacts = world.step(scene.dynamic_poses(0.0), scene.dynamic_half_extents).contacts
    assert len(contacts) > 0
    namespace = {}
    snippet, = python_snippets()['The collisions cloud']
    exec(snippet, namespace)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        namespace['on_collisions'](contacts_to_cloud(contacts, Header()))
    rows = [line.split() for line in printed.getvalue().splitlines()]
    assert [[int(a), int(t), int(b)] for a, t, b, _ in rows] == [
        [int(c['id_a']), int(c['type_b']), int(c['id_b'])] for c in contacts]
    np.testing.assert_allclose([float(depth) for *_, depth in rows], contacts['depth'],
                               rtol=1e-6)


def test_static_names_snippet_reads_the_diagnostics():
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    snippet, = python_snippets(DOC / 'design.md')['Static collider ids']
    namespace = {}
    exec(snippet, namespace)
    status = DiagnosticStatus(values=[KeyValue(key='scene_version', value='3'),
                                      KeyValue(key='static_ids', value='floor:0 crate:2 door:3')])
    assert namespace['static_names'](status) == {0: 'floor', 2: 'crate', 3: 'door'}
