"""The import rule of the package's folders (doc/design.md, Code map).

``pipeline`` imports nothing of ``collision_node`` outside itself and nothing of ROS;
``ros`` imports ``pipeline`` and itself only; ``cluster`` (Ray, optional) imports
``pipeline`` and itself only, and is the one folder that imports Ray; ``benchmarks`` and
``tools`` sit on top. Every import is
read from the source (function-level imports too), so a crossing fails here, not in a review.
"""
import ast
import pathlib
import subprocess
import sys

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / 'collision_node'
LAYERS = ('pipeline', 'ros', 'cluster', 'benchmarks', 'tools')
ALLOWED = {
    'pipeline': {'pipeline'},
    'ros': {'pipeline', 'ros'},
    'cluster': {'pipeline', 'cluster'},
    'benchmarks': set(LAYERS),
    'tools': set(LAYERS),
}
# Third-party packages of ROS: the pipeline must run where none of them is installed.
ROS_PACKAGES = ('rclpy', 'rcl_interfaces', 'ament_index_python', 'builtin_interfaces')


def imported_modules(source):
    """Every absolute module name a source file imports (``from a import b`` gives a and a.b)."""
    names = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, 'relative import'
            names.append(node.module)
            names.extend(node.module + '.' + alias.name for alias in node.names)
    return names


def crossings(layer, source):
    """Return the imports of a module in ``layer`` that break the rule."""
    bad = []
    for name in imported_modules(source):
        parts = name.split('.')
        if parts[0] == 'collision_node' and len(parts) > 1 and parts[1] in LAYERS:
            if parts[1] not in ALLOWED[layer]:
                bad.append(name)
        elif layer == 'pipeline' and (parts[0] in ROS_PACKAGES or parts[0].endswith('_msgs')):
            bad.append(name)
        elif parts[0] == 'ray' and layer != 'cluster':  # an optional extra: one folder needs it
            bad.append(name)
    return bad


def modules():
    return sorted(PACKAGE.glob('*/**/*.py'))


def test_every_module_sits_in_a_layer():
    top_level = sorted(path.name for path in PACKAGE.glob('*.py'))
    assert top_level == ['__init__.py']
    assert {path.relative_to(PACKAGE).parts[0] for path in modules()} == set(LAYERS)


@pytest.mark.parametrize('path', modules(), ids=lambda path: str(path.relative_to(PACKAGE)))
def test_imports_follow_the_layers(path):
    layer = path.relative_to(PACKAGE).parts[0]
    assert crossings(layer, path.read_text()) == []


def test_the_rule_catches_a_crossing():
    assert crossings('pipeline', 'from collision_node.ros.cdr import parse_pose_array') == [
        'collision_node.ros.cdr', 'collision_node.ros.cdr.parse_pose_array']
    assert crossings('pipeline', 'def f():\n    import rclpy\n') == ['rclpy']
    assert crossings('pipeline', 'from sensor_msgs.msg import PointCloud2') == [
        'sensor_msgs.msg', 'sensor_msgs.msg.PointCloud2']
    assert crossings('ros', 'from collision_node.tools import demo') == [
        'collision_node.tools', 'collision_node.tools.demo']
    assert crossings('ros', 'from collision_node.pipeline.world import World') == []
    assert crossings('tools', 'from collision_node.benchmarks import runs') == []
    assert crossings('tools', 'import ray') == ['ray']
    assert crossings('cluster', 'import ray\nfrom collision_node.pipeline import world') == []
    assert crossings('cluster', 'from collision_node.ros import node') == [
        'collision_node.ros', 'collision_node.ros.node']


def test_the_pipeline_runs_without_ros():
    """Importing the public World (and every pipeline module) loads no ROS package."""
    names = ['collision_node.pipeline.' + '.'.join(path.relative_to(PACKAGE / 'pipeline')
                                                   .with_suffix('').parts)
             for path in sorted((PACKAGE / 'pipeline').glob('**/*.py'))]
    script = ('import sys, importlib\n'
              'from collision_node import World, warm_up\n'
              'for name in %r: importlib.import_module(name.removesuffix(".__init__"))\n'
              'loaded = [m for m in sys.modules if m.split(".")[0] in %r '
              'or m.split(".")[0].endswith("_msgs")]\n'
              'print(loaded)\n' % (names, ROS_PACKAGES))
    done = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == '[]'


def test_the_core_does_not_import_the_test_scenes():
    """Only benchmarks, tools and tests use pipeline/scenes.py; the pipeline's own code never."""
    users = [path.name for path in sorted((PACKAGE / 'pipeline').glob('**/*.py'))
             if 'collision_node.pipeline.scenes' in imported_modules(path.read_text())]
    assert users == []


def test_public_names():
    import collision_node
    from collision_node.pipeline.warm_up import warm_up
    from collision_node.pipeline.world import World
    from collision_node.ros.cdr import serialize_pose_array
    from collision_node.ros.messages import cloud_to_contacts
    assert collision_node.World is World and collision_node.warm_up is warm_up
    assert collision_node.cloud_to_contacts is cloud_to_contacts
    assert collision_node.serialize_pose_array is serialize_pose_array
    assert set(collision_node.__all__) >= {'World', 'warm_up', 'cloud_to_contacts',
                                           'serialize_pose_array'}
    with pytest.raises(AttributeError):
        collision_node.no_such_name
