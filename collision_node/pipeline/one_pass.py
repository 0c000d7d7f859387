"""The one pass: small scenes' steps, and batches of states, each in one compiled call.

:class:`OnePass` checks a step of a small scene with small_scene.check_scene. What the pass
reads besides its input (the scene's static rows copied into boxes of its own, with room for
the bodies; the filter table; the margins) is gathered once per version of the scene rows and
body count (:class:`Gathered`), with the last input checked and its answer: an identical
input returns that answer again. Its rows are its own, so it keeps nothing of the general
path's and changes nothing of it.

:class:`Batches` checks K states of D bodies for ``check_states`` (and the robot's
``check_joints`` in scenes too large for the robot's pass): small ones in one pass over the
threads, each chunk of states with rows of its own (kept per version and body count), larger
ones state after state by a discrete general path of their own over the same scene rows, made
for the batch. Both key what they keep on the scene rows' version (scene_rows.py), so a new
option reaches them on their next call.
"""
import time

import numpy as np

from collision_node.pipeline.contacts import CONTACT_DTYPE, joined, STATE_CONTACT_DTYPE
from collision_node.pipeline.general_path import GeneralPath
from collision_node.pipeline.obb import InvalidBox, REASONS
from collision_node.pipeline.small_scene import check_scene, check_states
from collision_node.pipeline.stats import COUNTS, one_pass_stats, Result, reused

# Least states in a chunk when check_states spreads them over threads (~1 µs a state).
MIN_STATES_PER_CHUNK = 256


class Gathered:
    """What one-pass steps read besides their input, for one version and body count."""

    __slots__ = ('version', 'n_static', 'arguments', 'last_poses', 'last_half_extents',
                 'half_extents_shape', 'last_valid', 'result')

    def __init__(self, version, n_static, arguments, last_poses, last_half_extents, last_valid,
                 half_extents_shape):
        self.version = version
        self.n_static = n_static
        self.arguments = arguments  # check_scene's after the input's: (last, statics, rows,
        # options), last made of the three arrays below
        self.last_poses = last_poses  # the last input checked, while last_valid[0] is 1
        self.last_half_extents = last_half_extents  # (1, 3) or (D, 3)
        self.half_extents_shape = half_extents_shape  # as the caller gives them
        self.last_valid = last_valid
        self.result = None  # its answer

    def answer(self, contacts, counters, same, start, end=None):
        """Return the Result of a check_scene call on these arguments, and keep it.

        ``same``: the input was the last one, whose answer is returned again; else
        ``contacts`` and ``counters`` are the check's (which found every box valid).
        ``start``, ``end``: perf_counter when the input came and when the check was done
        (None: now).
        """
        if same:
            return Result(self.result.contacts, reused(self.result.record))
        contacts.flags.writeable = False
        end = time.perf_counter() if end is None else end
        self.result = Result(contacts, one_pass_stats(
            len(self.last_poses), self.n_static, counters, 1e3 * (end - start), None))
        return self.result


class OnePass:
    """Steps of small scenes in one compiled pass (module docstring)."""

    def __init__(self, scene):
        """Read ``scene`` (scene_rows.SceneRows), never write it."""
        self._scene = scene
        self.gathered = None  # Gathered of the last step

    def step(self, poses, half_extents, previous, start):
        """Check ``poses`` (D, 7) with ``half_extents`` as World.step does, in one pass.

        The general path's interface: ``previous``, a continuous step's motion start, is
        not read (the pass is discrete); ``start`` the step's perf_counter at its call.
        """
        gathered = self.gathered
        extents = per_body_extents(half_extents, len(poses))
        if gathered is None or gathered.version != self._scene.version \
                or gathered.last_poses.shape != poses.shape \
                or gathered.half_extents_shape != half_extents.shape:
            gathered = self.gathered = self._gather(len(poses), extents, half_extents.shape)
        return self._step_gathered(poses, extents, gathered, start)

    def step_as_before(self, poses, half_extents, start):
        """Check as :meth:`step` if the input is as the last one was, else return None.

        As before: the scene rows at the same version, the poses and half extents writable
        C-contiguous float64 arrays of the last step's shapes (a robot's tick). Then nothing
        is converted or gathered again: World.step tries this first.
        """
        if type(poses) is np.ndarray and poses.ndim == 2 and poses.shape[1] == 7 \
                and poses.dtype == np.float64 and _writable_c_array(poses):
            gathered = self.as_before(len(poses), half_extents)
            if gathered is not None:
                return self._step_gathered(poses, half_extents, gathered, start)
        return None

    def as_before(self, count, half_extents):
        """Return what the last step gathered if ``count`` bodies of ``half_extents`` read it.

        That is: the scene rows at the same version, as many bodies, and ``half_extents`` a
        writable C-contiguous float64 array of the last step's shape. Else None.
        """
        gathered = self.gathered
        if gathered is not None and gathered.version == self._scene.version \
                and count == len(gathered.last_poses) \
                and type(half_extents) is np.ndarray \
                and half_extents.shape == gathered.half_extents_shape \
                and half_extents.dtype == np.float64 and _writable_c_array(half_extents):
            return gathered
        return None

    def _step_gathered(self, poses, half_extents, gathered, start):
        """Check as :meth:`step`, with what was ``gathered`` for this version and input shape.

        ``half_extents`` C-contiguous float64 of the gathered shape.
        """
        if half_extents.ndim == 1:
            half_extents = half_extents.reshape(1, 3)
        contacts, counters, bad, code, invalid, same = check_scene(poses, half_extents,
                                                                   *gathered.arguments)
        if not same:
            if bad >= 0:
                raise InvalidBox(int(bad), REASONS[code])
            if invalid:
                raise RuntimeError('the SAT met NaN, Inf or overflow on validated input')
        return gathered.answer(contacts, counters, same, start)

    @property
    def last_poses(self):
        """Return the last input checked (the motion's start for a continuous step)."""
        return self.gathered.last_poses

    def _gather(self, count, extents, given_shape):
        """Gather what one-pass steps of ``count`` bodies read besides their input."""
        scene = self._scene
        scene.filter.check_count(count)
        last = (np.empty((count, 7)), np.empty(extents.shape), np.zeros(1, np.int64))
        return Gathered(scene.version, scene.count, (last, scene.rows.by_id,
                                                     scene.pass_rows(count),
                                                     scene.pass_options(count)), *last,
                        given_shape)


class _StatesPass:
    """What batches of states read besides their input, for one version and body count."""

    __slots__ = ('version', 'bodies', 'statics', 'options', 'chunk_rows')

    def __init__(self, version, bodies, statics, options, chunks):
        self.version = version
        self.bodies = bodies
        self.statics = statics  # small_scene's statics and options
        self.options = options
        self.chunk_rows = [None] * chunks  # per chunk: small_scene's rows, then scratch


class Batches:
    """Batches of independent states against the static rows (module docstring)."""

    def __init__(self, scene):
        """Read ``scene`` (scene_rows.SceneRows), never write it."""
        self._scene = scene
        self._states_pass = None  # _StatesPass of the last batch

    def check(self, states, half_extents, one_pass_pairs):
        """Check ``states`` as World.check_states does; one pass up to ``one_pass_pairs``."""
        start = time.perf_counter()
        states = np.require(states, np.float64, ['C', 'A', 'W'])
        if states.ndim != 3 or states.shape[2] != 7:
            raise ValueError('states must have shape (K, D, 7): K states of D poses '
                             'x y z qx qy qz qw, got %s' % (states.shape,))
        count, bodies = states.shape[:2]
        extents = per_body_extents(np.asarray(half_extents, np.float64), bodies)
        scene = self._scene
        scene.filter.check_count(bodies)
        if bodies * (bodies - 1) // 2 + bodies * scene.count > one_pass_pairs:
            contacts, counters = self._one_by_one(states, extents)
        else:
            poses = states.reshape(-1, 7)
            contacts, counters = self._in_one_pass(
                count, bodies, lambda *arguments: check_states(poses, bodies, extents,
                                                               *arguments))
        contacts.flags.writeable = False
        return Result(contacts, one_pass_stats(bodies, scene.count, counters,
                                               1e3 * (time.perf_counter() - start), count))

    def _in_one_pass(self, count, bodies, check):
        """Return the contacts and counters of ``count`` small states, chunks over threads.

        ``check(*arguments)`` runs small_scene.check_states on its static arguments, a
        chunk's box rows and the chunk's range of states.
        """
        scene = self._scene
        states_pass = self._states_pass
        if states_pass is None or states_pass.version != scene.version \
                or states_pass.bodies != bodies:
            states_pass = self._states_pass = _StatesPass(
                scene.version, bodies, scene.rows.by_id, scene.pass_options(bodies),
                scene.workers.max_chunks)

        def chunk(index, first, stop):
            # Each chunk writes its states' boxes to rows of its own, after a copy of the
            # static rows (kept for the next batch of this version).
            rows = states_pass.chunk_rows[index]
            if rows is None:
                rows = states_pass.chunk_rows[index] = scene.pass_rows(bodies)
            return check(states_pass.statics, rows, states_pass.options, first, stop)

        parts = scene.workers.map_ranges(chunk, count, MIN_STATES_PER_CHUNK)
        for contacts, _, state, body, code, invalid in parts:
            if state >= 0 and body >= 0:
                raise ValueError('state %d: dynamic body %d: %s' % (state, body, REASONS[code]))
            if invalid:
                raise RuntimeError('the SAT met NaN, Inf or overflow on validated input')
        contacts = parts[0][0] if len(parts) == 1 else joined([part[0] for part in parts])
        return contacts, sum(part[1] for part in parts)

    def _one_by_one(self, states, extents):
        """Return the contacts and counters of large ``states``, stepped by a general path.

        A discrete general path of its own over the same scene rows, made for this batch:
        consecutive states keep what did not change between them, as ticks do, and no step
        of the World's is read or changed.
        """
        path = GeneralPath(self._scene, continuous=False)
        extents = extents if len(extents) > 1 else extents[0]
        found, counters = [], np.zeros(4, np.int64)
        for state, poses in enumerate(states):
            try:
                result = path.step(poses, extents, None, time.perf_counter())
            except InvalidBox as error:
                raise ValueError('state %d: dynamic body %d: %s'
                                 % (state, error.body, error.reason)) from None
            rows = np.empty(len(result.contacts), STATE_CONTACT_DTYPE)
            for name in CONTACT_DTYPE.names:
                rows[name] = result.contacts[name]
            rows['state'] = state
            found.append(rows)
            counters += result.record[COUNTS]
        contacts = np.concatenate(found) if found else np.zeros(0, STATE_CONTACT_DTYPE)
        return contacts, counters


def _writable_c_array(array):
    """Whether ``array`` (an ndarray) is C-contiguous and writable, as kernels take it."""
    flags = array.flags  # a new object at each read
    return flags.c_contiguous and flags.writeable


def per_body_extents(half_extents, count):
    """Return half extents (3,) as one row (1, 3), or (count, 3) as they are; else refuse."""
    if half_extents.shape == (3,):
        return np.require(half_extents, np.float64, ['C', 'A', 'W']).reshape(1, 3)
    if half_extents.shape != (count, 3):
        raise ValueError('half extents must have shape (3,) or (%d, 3), got %s'
                         % (count, half_extents.shape))
    return np.require(half_extents, np.float64, ['C', 'A', 'W'])
