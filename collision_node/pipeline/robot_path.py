"""The robot path: a robot's joint values in, its contacts out, states and trajectories.

The World's robot methods live here (World keeps thin delegations): ``set_robot`` makes the
robot's boxes the dynamic bodies (robot_bodies.RobotBodies) and its self-collision pairs join
the World's ignored pairs; ``check_joints`` runs the robot's pass (robot_pass.py: forward
kinematics and the check in one compiled call per chunk of states, over the threads), or
checks the robot's box poses through ``check_states`` when the scene is too large for one
pass; ``check_trajectory`` checks the waypoints so and the segments between them
(robot_bodies.first_uncleared_pieces). The pairs both read (robot_pass.RobotRows) are kept per
version of the scene rows and robot (scene_rows.py), as every path keys what it keeps.
"""
import time

import numpy as np

from collision_node.pipeline.contacts import joined
from collision_node.pipeline.obb import REASONS
from collision_node.pipeline.one_pass import MIN_STATES_PER_CHUNK
from collision_node.pipeline.robot_bodies import (DEFAULT_RESOLUTION, first_uncleared_pieces,
                                                  segment_contacts)
from collision_node.pipeline.robot_pass import NON_FINITE_JOINT, RobotRows
from collision_node.pipeline.stats import Result

FLOAT64 = np.dtype(np.float64)


class RobotPath:
    """A robot at a base pose, checked against the scene rows (module docstring)."""

    def __init__(self, scene, batches):
        """Read ``scene`` (scene_rows.SceneRows); check large scenes with ``batches``."""
        self._scene = scene
        self._batches = batches
        self.bodies = None  # robot_bodies.RobotBodies once set_robot gave one
        self._rows = None  # robot_pass.RobotRows of the bodies at a scene version

    def set_bodies(self, bodies):
        """Take ``bodies`` (robot_bodies.RobotBodies) as the robot; the World set its filter."""
        self.bodies = bodies

    def check_joints(self, q, one_pass_pairs):
        """Check the robot at joint values ``q`` as World.check_joints does."""
        start = time.perf_counter()
        rows = self._rows
        if rows is None or rows.version != self._scene.version or rows.bodies is not self.bodies:
            rows = self._robot_rows(self._robot_bodies())
        # One state as a planner hands it goes in as it is, with no more Python than the pass
        # needs: for a robot's few boxes, the Python around the pass costs as much as the pass.
        # A state that fails is checked again the full way below, which says why.
        if type(q) is np.ndarray and q.shape == rows.one_state and q.dtype is FLOAT64 \
                and q.flags.carray and rows.all_pairs <= one_pass_pairs:
            result = rows.check_one(q, start)
            if result is not None:
                return result
        return self._check_states(rows, rows.bodies.robot._states(q), one_pass_pairs, start)

    def _check_states(self, rows, states, one_pass_pairs, start, kept=None):
        """Check ``states`` (K, dof), as Robot._states returns them, against ``rows``.

        ``kept``: where the robot's pass keeps each state's robot boxes and pairs'
        separations (robot_pass.RobotRows.check); left unwritten when the scene is too large
        for it.
        """
        if rows.all_pairs > one_pass_pairs:
            return self._batches.check(rows.bodies.poses(states), rows.bodies.robot.half_extents,
                                       one_pass_pairs)
        if len(states) == 1:
            parts = [rows.check(states, 0, 1, kept)]
        else:
            workers = self._scene.workers
            rows.reserve(workers.max_chunks)
            parts = workers.map_ranges(
                lambda chunk, first, stop: rows.check(states, first, stop, kept, chunk),
                len(states), MIN_STATES_PER_CHUNK)
        passed = sat_tests = 0
        for _, (part_passed, part_sat_tests), state, box, code, invalid in parts:
            if invalid:
                raise RuntimeError('the SAT met NaN, Inf or overflow on validated input')
            if state >= 0:
                if box == NON_FINITE_JOINT:
                    rows.bodies.robot._states(states[state])  # raises, naming the joint
                raise ValueError('state %d: dynamic body %d: %s' % (state, box, REASONS[code]))
            passed += part_passed
            sat_tests += part_sat_tests
        contacts = parts[0][0] if len(parts) == 1 else joined([part[0] for part in parts])
        return rows.result(contacts, passed, sat_tests, 1e3 * (time.perf_counter() - start),
                           len(states))

    def robot_pass(self, one_pass_pairs):
        """Return the RobotRows check_joints runs now, or None (no robot, or past one pass)."""
        if self.bodies is None:
            return None
        rows = self._robot_rows(self.bodies)
        return rows if rows.all_pairs <= one_pass_pairs else None

    def robot_poses(self, q):
        """Return the robot's box poses at joint values ``q``: (K, B, 7), the World's frame."""
        return self._robot_bodies().poses(q)

    def check_trajectory(self, world, waypoints, one_pass_pairs,
                         resolution=DEFAULT_RESOLUTION):
        """Check a joint-space path as World.check_trajectory does (``world`` checks joints)."""
        start = time.perf_counter()
        bodies = self._robot_bodies()
        waypoints = bodies.robot._states(waypoints)
        rows = self._robot_rows(bodies)
        # The waypoints' robot boxes and pairs' separations, kept by their exact check for the
        # segments' ends: their forward kinematics runs once. Not kept (left empty) beyond the
        # robot's pass.
        boxes = bodies.count
        small = rows.all_pairs <= one_pass_pairs
        states = len(waypoints) if small else 0
        kept = (np.empty((boxes, 3, states)), np.empty((boxes, 9, states)),
                np.empty((len(rows.pairs), states)))
        exact = self._check_states(rows, waypoints, one_pass_pairs, start, kept).contacts
        found, reports = (None, 0) if len(waypoints) < 2 else first_uncleared_pieces(
            *bodies.packed_model, bodies.base_pose, waypoints, kept, rows.pairs,
            rows.motion_radii, rows.margins, rows.boxes, bodies.robot.chord_turns,
            bodies.robot.chord_reach, max(resolution, 1e-12))
        return Result(segment_contacts(world, bodies, waypoints, exact, found, reports,
                                       rows.keys), {})

    def _robot_bodies(self):
        if self.bodies is None:
            raise ValueError('no robot: call set_robot(robot) first')
        return self.bodies

    def _robot_rows(self, bodies):
        """Return the RobotRows of ``bodies``, kept while the scene rows and robot stay."""
        rows = self._rows
        if rows is None or rows.version != self._scene.version or rows.bodies is not bodies:
            rows = self._rows = RobotRows(self._scene, bodies)
        return rows
