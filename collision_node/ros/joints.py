"""A robot's current joint values, merged from partial joint_states, and trajectory requests.

Plain Python and numpy (no rclpy): the node hands over a message's names and positions, this
module keeps the values and says what is wrong. ``joint_states`` publishers often publish part
of a robot each (an arm's driver, a gripper's): every message sets the joints it names, the
others keep their values, names the robot does not have are ignored. Until every joint of
the robot has had a value there is no complete q, and :attr:`JointValues.missing` names the
joints still without one.

    joints = JointValues(robot.joint_names)
    joints.merge(message.name, message.position)   # JointInputError: the message is refused
    if not joints.missing:
        q = joints.q()
"""
import numpy as np


class JointInputError(ValueError):
    """A joint_states message or a trajectory request refused; the text says why."""


class JointValues:
    """The value of every joint of a robot that has had one, by name."""

    def __init__(self, joint_names, previous=None):
        """Hold no value yet, or those of ``previous`` (a JointValues) for the joints it shares.

        Keeping them is what makes a new model of the same robot (the same joint names)
        answer at once, not only after the next message of every publisher.
        """
        self.names = tuple(joint_names)
        self._index = {name: i for i, name in enumerate(self.names)}
        self._values = np.zeros(len(self.names))
        self._known = np.zeros(len(self.names), np.bool_)
        # The last message's names, and which of its entries (the last one of a name given
        # twice) go to which joints: a publisher sends the same names every time.
        self._merged_names, self._entries, self._joints = None, None, None
        if previous is not None:
            for i, name in enumerate(previous.names):
                j = self._index.get(name)
                if j is not None and previous._known[i]:
                    self._values[j], self._known[j] = previous._values[i], True

    @property
    def missing(self):
        """Return the names of the joints that have had no value yet, in q's order."""
        return [name for name, known in zip(self.names, self._known) if not known]

    def merge(self, names, positions):
        """Set the joints named by a joint_states message; ignore names the robot does not have.

        ``positions`` may be empty (sensor_msgs/JointState: a message of velocities or efforts
        only), and then nothing changes. Raises JointInputError, and changes nothing, when it
        has another length than ``names`` or a NaN or Inf value.
        """
        positions = np.asarray(positions, np.float64)
        if len(positions) == 0:
            return
        if len(positions) != len(names):
            raise JointInputError('%d names but %d positions (each position belongs to the name '
                                  'at its index)' % (len(names), len(positions)))
        bad = np.flatnonzero(~np.isfinite(positions))
        if len(bad):
            raise JointInputError('joint %r: position %r'
                                  % (names[bad[0]], float(positions[bad[0]])))
        if names is not self._merged_names and names != self._merged_names:
            last = {self._index[name]: k for k, name in enumerate(names) if name in self._index}
            self._entries = np.array(list(last.values()), np.int64)
            self._joints = np.array(list(last), np.int64)
            self._merged_names = names
        self._values[self._joints] = positions[self._entries]
        self._known[self._joints] = True

    @property
    def merged_names(self):
        """Return the names of the last message merged (None before one)."""
        return self._merged_names

    def merge_arrays(self):
        """Return (entries, joints, values, known) for a kernel that merges as :meth:`merge`.

        A message of :attr:`merged_names` sets ``values[joints] = positions[entries]`` and
        ``known[joints] = True``; ``values`` and ``known`` are this object's own (the node's
        joint_states lane merges in place).
        """
        return self._entries, self._joints, self._values, self._known

    def q(self):
        """Return a copy of the values (dof,); JointInputError if a joint has none yet."""
        if not self._known.all():
            raise JointInputError('no joint_states value yet for %s' % ', '.join(self.missing))
        return self._values.copy()

    def waypoints(self, joint_names, points):
        """Return a trajectory request as the whole robot's waypoints, (W, dof).

        ``joint_names`` name the entries of each of ``points`` (sequences of positions, as in
        trajectory_msgs/JointTrajectory); a joint it does not name keeps its current value.
        Raises JointInputError naming the joint (and the waypoint) at fault: a name the robot
        does not have or given twice, a point of another length, a NaN or Inf position, or a
        joint left out that has no value yet.
        """
        columns = []
        for number, name in enumerate(joint_names):
            if name not in self._index:
                raise JointInputError('joint_names[%d] %r is not a joint of the robot (%s)'
                                      % (number, name, ', '.join(self.names)))
            if name in joint_names[:number]:
                raise JointInputError('joint_names[%d] %r is given twice' % (number, name))
            columns.append(self._index[name])
        kept = np.ones(len(self.names), np.bool_)
        kept[columns] = False
        unknown = [name for name, keep, known in zip(self.names, kept, self._known)
                   if keep and not known]
        if unknown:
            raise JointInputError('joint %r is not in joint_names and has no joint_states value '
                                  'yet' % unknown[0])
        waypoints = np.tile(self._values, (len(points), 1))
        for number, positions in enumerate(points):
            positions = np.asarray(positions, np.float64)
            if len(positions) != len(columns):
                raise JointInputError('waypoint %d: %d positions for %d joint_names'
                                      % (number, len(positions), len(columns)))
            bad = np.flatnonzero(~np.isfinite(positions))
            if len(bad):
                raise JointInputError('waypoint %d: joint %r: position %r'
                                      % (number, joint_names[bad[0]], float(positions[bad[0]])))
            waypoints[number, columns] = positions
        return waypoints
