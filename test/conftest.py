"""Shared test configuration: run from the repo root without installing the package."""
import os
import sys
import sysconfig

import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# example-robot-data's robots, for the robot tests (a test-only dependency).
PREFIX = os.path.join(sysconfig.get_paths()['purelib'], 'cmeel.prefix')
PANDA = os.path.join(PREFIX, 'share', 'example-robot-data', 'robots', 'panda_description')


@pytest.fixture(scope='module')
def context(request):
    """Start an rclpy context on the test module's own DDS domain (its DOMAIN_ID)."""
    from ros_helpers import make_context
    context = make_context(request.module.DOMAIN_ID)
    yield context
    context.try_shutdown()


@pytest.fixture
def harness(context):
    """Make a node-and-tester Harness in the demo room (closed after the test)."""
    from ros_helpers import Harness, room_overrides
    made = []

    def make(input_depth=None, **overrides):
        made.append(Harness(context, input_depth, **room_overrides(**overrides)))
        return made[-1]
    yield make
    for harness in made:
        harness.close()


@pytest.fixture(scope='module')
def panda():
    """Return the Panda of example-robot-data (URDF and SRDF), its meshes as boxes."""
    from collision_node import Robot
    previous = os.environ.get('AMENT_PREFIX_PATH')
    os.environ['AMENT_PREFIX_PATH'] = PREFIX
    try:
        return Robot.from_urdf(os.path.join(PANDA, 'urdf', 'panda.urdf'),
                               os.path.join(PANDA, 'srdf', 'panda.srdf'))
    finally:
        if previous is None:
            del os.environ['AMENT_PREFIX_PATH']
        else:
            os.environ['AMENT_PREFIX_PATH'] = previous
