"""Shared test configuration: run from the repo root without installing the package."""
import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


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
