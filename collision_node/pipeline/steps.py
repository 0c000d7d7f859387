"""World.step's room: which path checks a step, and the last accepted input.

A step goes down one of two paths over the same scene rows (scene_rows.py): the one pass
(one_pass.py) when it has at most ``ONE_PASS_PAIRS`` pairs to test, the broad phase is one of
``ONE_PASS_PHASES`` and ``continuous`` is off; the general path (general_path.py) otherwise.
An input as the last one was (a robot's tick) is tried in the one pass first, before anything
is converted. A continuous step's motion starts at the last accepted input, whichever path
took it: :class:`Steps` keeps it.
"""
import time

import numpy as np

from collision_node.pipeline.general_path import GeneralPath
from collision_node.pipeline.one_pass import OnePass
from collision_node.pipeline.scene_rows import as_poses

# Small scenes are checked in one pass when the broad phase is one of these (the pass is brute
# force) and a tick has at most this many pairs to test, ~25 µs of AABB tests: the general
# path's stages cost ~60 µs of calls however few the bodies, and its broad phases catch up
# with testing every pair at about 4x this many (doc/benchmarks.md).
ONE_PASS_PHASES = ('auto', 'brute_force')
ONE_PASS_PAIRS = 16384


class Steps:
    """The paths of World.step over one set of scene rows (module docstring)."""

    def __init__(self, rows):
        """Step over ``rows`` (scene_rows.SceneRows); raise ValueError on an unknown phase."""
        self._rows = rows
        self.general = GeneralPath(rows)
        self._one_pass = OnePass(rows)
        self._probe = None  # broad_phase_pairs' own GeneralPath, made at its first call
        self._previous = None  # the poses of the last accepted input (the motion's start)

    def step(self, poses, half_extents):
        """Check a step as World.step does (its docstring)."""
        start = time.perf_counter()
        result = self._one_pass.step_as_before(poses, half_extents, start)  # a robot's tick
        if result is not None:
            self._previous = self._one_pass.last_poses
            return result
        poses = as_poses(poses)
        half_extents = np.asarray(half_extents, dtype=np.float64)
        n, options = len(poses), self._rows.options
        small = n * (n - 1) // 2 + n * self._rows.count <= ONE_PASS_PAIRS
        in_one_pass = small and not options.continuous and options.broad_phase in ONE_PASS_PHASES
        path = self._one_pass if in_one_pass else self.general
        result = path.step(poses, half_extents, self._previous, start)
        self._previous = path.last_poses
        return result

    def pass_as_before(self, count, half_extents):
        """Return the one pass's gathering a step of these bodies would check with, or None.

        See World.pass_as_before. Its input becomes the last accepted one (the pass updates
        it in place once the check accepts the input).
        """
        gathered = self._one_pass.as_before(count, half_extents)
        if gathered is not None:
            self._previous = gathered.last_poses
        return gathered

    def broad_phase_pairs(self, poses, half_extents):
        """Return a discrete general step's BroadPhasePairs at these poses; changes no step."""
        self._probe = self._probe or GeneralPath(self._rows, continuous=False)
        return self._probe.broad_phase_pairs(poses, half_extents)
