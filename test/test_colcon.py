"""colcon builds the package in a fresh workspace, and the installed node answers a PoseArray.

colcon runs from this Python's environment (colcon-core, colcon-ros, colcon-python-setup-py,
colcon-library-path, colcon-bash from PyPI, next to the ROS wheels), as a user would after
``pip install``: ``colcon build``, ``source install/setup.bash``, then what ``ros2 run
collision_node collision_node`` starts, ``lib/collision_node/collision_node``.
"""
import glob
import os
import random
import shutil
import signal
import subprocess
import sys
import time

from geometry_msgs.msg import PoseArray
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from collision_node.pipeline.warm_up import warm_up
from collision_node.ros.cdr import serialize_pose_array
from collision_node.ros.messages import cloud_to_contacts

PACKAGE = 'collision_node'
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COLCON = os.path.join(sys.prefix, 'bin', 'colcon')
DOMAIN_ID = random.randint(1, 200)  # this module's own DDS domain: no cross-talk
BUILD_TIMEOUT_S = 120.0
# The node loads its kernels before it answers; compiling them instead (a stale cache) takes
# a minute or two on a busy 2-core machine. A bound for a hang, not a speed goal.
ANSWER_TIMEOUT_S = 180.0
# Not part of the package: VCS data, virtualenvs, caches (the numba cache too), old builds.
NOT_SOURCES = shutil.ignore_patterns(
    '.*', '__pycache__', '*.egg-info', 'build', 'install', 'log')
RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE)

# Two dynamic boxes (the default config's 0.1 m half extents) in the free air of the room, the
# second 0.1 m along +x from the first: they overlap by 0.2 - 0.1 = 0.1 m along x, and touch
# nothing static (the table top is at z 0.42, the shelves and walls are metres away).
POSES = np.array([[0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 1.0],
                  [0.1, 0.0, 1.5, 0.0, 0.0, 0.0, 1.0]])


def build_workspace(root, *options):
    """Build a copy of this package in a new colcon workspace at ``root``."""
    shutil.copytree(REPO, root / 'src' / PACKAGE, ignore=NOT_SOURCES)
    result = subprocess.run(
        [COLCON, 'build', '--base-paths', 'src', '--event-handlers', 'console_direct-',
         *options],
        cwd=root, env=colcon_environment(), capture_output=True, text=True,
        timeout=BUILD_TIMEOUT_S)
    assert result.returncode == 0, result.stdout + result.stderr
    return root


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    """Return a workspace built the default way (installed copies, no symlinks)."""
    root = build_workspace(tmp_path_factory.mktemp('colcon_ws'))
    seed_numba_cache(root)
    return root


def seed_numba_cache(workspace):
    """Copy the source tree's numba cache beside the installed modules.

    A fresh install compiles its kernels once, at the node's first start: a minute or more
    on a busy 2-core machine. numba keys its cache by the content hash of the source file,
    which the installed copy shares, so the copied cache is valid there and the node loads
    its kernels instead. The warm-up fills the source tree's cache first (loading what is
    there; later tests load what it compiles).
    """
    warm_up()
    installed, = glob.glob(str(workspace / 'install' / PACKAGE / 'lib' / 'python*' /
                               'site-packages' / PACKAGE))
    source = os.path.join(REPO, PACKAGE)
    for path in glob.glob(os.path.join(source, '**', '__pycache__', '*.nb[ic]'),
                          recursive=True):
        target = os.path.join(installed, os.path.relpath(path, source))
        if os.path.isdir(os.path.dirname(os.path.dirname(target))):
            os.makedirs(os.path.dirname(target), exist_ok=True)
            shutil.copyfile(path, target)


def colcon_environment():
    """Return this environment with this Python's bin first, free of any sourced workspace."""
    env = {key: value for key, value in os.environ.items()
           if key not in ('AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'CMAKE_PREFIX_PATH',
                          'PYTHONPATH')}
    env['PATH'] = os.pathsep.join([os.path.dirname(COLCON), env.get('PATH', '')])
    env['ROS_DOMAIN_ID'] = str(DOMAIN_ID)
    return env


def sourced(workspace, command):
    """Return the argv that runs the shell ``command`` after ``source install/setup.bash``."""
    return ['bash', '-c', 'source "%s" && %s' % (workspace / 'install' / 'setup.bash', command)]


def test_build_installs_the_executables_config_manifest_and_index_marker(workspace):
    prefix = workspace / 'install' / PACKAGE
    for script in ('collision_node', 'pose_publisher', 'collision_monitor', 'collision_demo'):
        path = prefix / 'lib' / PACKAGE / script
        assert path.is_file() and os.access(path, os.X_OK), path
    share = prefix / 'share' / PACKAGE
    assert (share / 'config' / 'default.yaml').read_text() == \
        (workspace / 'src' / PACKAGE / 'config' / 'default.yaml').read_text()
    assert (share / 'package.xml').is_file()
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()


def package_as_sourced(workspace):
    """Return the package prefix in the ament index and the collision_node module's file."""
    # Run from the workspace: python -c puts the working directory first on sys.path.
    script = ('from ament_index_python.packages import get_package_prefix; '
              'import collision_node; print(get_package_prefix("collision_node")); '
              'print(collision_node.__file__)')
    result = subprocess.run(sourced(workspace, '"%s" -c \'%s\'' % (sys.executable, script)),
                            cwd=workspace, env=colcon_environment(), capture_output=True,
                            text=True, timeout=60.0)
    assert result.returncode == 0, result.stderr
    return result.stdout.split()


def test_sourced_workspace_finds_the_installed_package(workspace):
    # What ros2 run looks up (the ament index) and what the node imports: the installed copy,
    # not the source nor an editable install in the venv.
    prefix, module = package_as_sourced(workspace)
    install = workspace / 'install' / PACKAGE
    assert prefix == str(install)
    assert module.startswith(str(install / 'lib')), module


@pytest.mark.parametrize('tool', ['pose_publisher', 'collision_monitor', 'collision_demo'])
def test_installed_tools_start(workspace, tool):
    script = workspace / 'install' / PACKAGE / 'lib' / PACKAGE / tool
    result = subprocess.run(sourced(workspace, '"%s" --help' % script), cwd=workspace,
                            env=colcon_environment(), capture_output=True, text=True,
                            timeout=60.0)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith('usage: %s' % tool), result.stdout


def test_symlink_install_builds_too(tmp_path):
    # setup.cfg's [develop] script_dir puts the scripts where ros2 run looks, as [install]
    # install_scripts does for the default build.
    workspace = build_workspace(tmp_path, '--symlink-install')
    prefix = workspace / 'install' / PACKAGE
    assert (prefix / 'lib' / PACKAGE / PACKAGE).is_file()
    assert (prefix / 'share' / PACKAGE / 'config' / 'default.yaml').is_symlink()
    index_prefix, module = package_as_sourced(workspace)
    assert index_prefix == str(prefix)
    assert module == str(workspace / 'build' / PACKAGE / PACKAGE / '__init__.py')


def test_installed_node_answers_a_pose_array(workspace):
    prefix = workspace / 'install' / PACKAGE
    node_process = subprocess.Popen(
        sourced(workspace, 'exec "%s" --ros-args --params-file "%s"' % (
            prefix / 'lib' / PACKAGE / PACKAGE,
            prefix / 'share' / PACKAGE / 'config' / 'default.yaml')),
        cwd=workspace, env=colcon_environment(), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('test_colcon', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    clouds = []
    node.create_subscription(PointCloud2, 'collisions', clouds.append, RELIABLE)
    publisher = node.create_publisher(PoseArray, 'dynamic_poses', RELIABLE)
    try:
        started = time.monotonic()
        last_sent = -1.0
        # Sent again and again: the node reads no input before its kernels are compiled.
        while not clouds and time.monotonic() - started < ANSWER_TIMEOUT_S \
                and node_process.poll() is None:
            if time.monotonic() - last_sent > 0.5:
                publisher.publish(serialize_pose_array(7, 0, 'world', POSES))
                last_sent = time.monotonic()
            executor.spin_once(timeout_sec=0.1)
        answered_after_s = time.monotonic() - started
    finally:
        if node_process.poll() is None:
            node_process.send_signal(signal.SIGINT)
        try:
            output, _ = node_process.communicate(timeout=30.0)
        finally:
            node_process.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)

    assert clouds, 'no collisions after %.0f s; the node said:\n%s' % (answered_after_s, output)
    print('installed node answered %.1f s after its start' % answered_after_s)
    cloud = clouds[0]
    assert (cloud.header.stamp.sec, cloud.header.stamp.nanosec) == (7, 0)
    assert cloud.header.frame_id == 'world'
    contacts = cloud_to_contacts(cloud)
    assert len(contacts) == 1, contacts
    contact = contacts[0]
    assert (contact['id_a'], contact['type_a'], contact['id_b'], contact['type_b']) == \
        (0, 0, 1, 0)
    np.testing.assert_allclose(contact['depth'], 0.1, atol=1e-6)
    np.testing.assert_allclose([contact['normal_x'], contact['normal_y'], contact['normal_z']],
                               [1.0, 0.0, 0.0], atol=1e-6)
    assert node_process.returncode == 0, output  # SIGINT is a clean shutdown
