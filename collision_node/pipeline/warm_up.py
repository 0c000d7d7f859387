"""Compile every kernel a tick can run, before the first tick.

numba compiles a kernel (or loads it from its cache) on its first call with each type
signature. :func:`warm_up` runs every broad phase and every mode of the World (still bodies,
margins, filters, continuous checks, moving colliders, threads, the robot) on small random
scenes of its own, in SECTIONS that are independent of each other; the benchmarks call it
before they time.

Every section on a cold cache is about 100 s of CPU (2-vCPU Intel Xeon of the README), much of
it the SAT and exact distances that every World runs; :func:`compile_in_processes` spreads the
sections over processes (.ci/setup-venv does so through collision_node.tools.compile_kernels).
The node needs less: :func:`warm_up_like` runs a copy of its configured World on its own
bodies, so it subscribes once those kernels are ready, and :func:`warm_up_in_background`
readies the rest while it answers (doc/design.md, JIT).
"""
import atexit
import functools
import glob
import hashlib
import itertools
import multiprocessing
import os
import pathlib
import sys
import threading
import time

import numba
import numpy as np

from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.broadphase.auto import GRID_BODIES
from collision_node.pipeline.contacts import (assemble_contacts, DYNAMIC, MIN_PAIRS_PER_THREAD,
                                              orient_pairs, STATIC)
from collision_node.pipeline.distance import box_distance
from collision_node.pipeline.jit_progress import compile_progress, REPORT_PERIOD_S
from collision_node.pipeline.robot import Robot
from collision_node.pipeline.sat import COLLIDING, empty_output
from collision_node.pipeline.stats import distance_stats
from collision_node.pipeline.workers import Workers
from collision_node.pipeline.world import ONE_PASS_PAIRS, ONE_PASS_PHASES, World

BACKGROUND_NICENESS = 10  # the background compile yields the CPUs to the node's ticks
STOP_POLL_S = 0.2  # how often the parts' compile looks whether it is asked to stop
BACKGROUND_READY = 'every other kernel ready'  # warm_up_in_background's report, once done
COMPLETE_MARKER = 'collision_node-complete-'  # + the sources' stamp: see cache_complete
WARM_UP_BODIES = 64  # half static: enough for every broad phase to run its full code path
AUTO_SPREAD_BODIES = 2 * GRID_BODIES  # auto measures the boxes' spread from this many bodies
# Half static, half dynamic (n/2 · (n/2 - 1) / 2 + n²/4 pairs): past ONE_PASS_PAIRS.
ONE_PASS_BODIES = 2 * int(np.sqrt(4.0 * ONE_PASS_PAIRS / 3.0)) + 8
# A robot with one joint of each kind the forward kinematics branches on (fixed, revolute,
# prismatic) and a box on each link: its kernels compile for any robot (same types).
WARM_UP_ROBOT = """<robot name="warm_up">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="arm"><collision><geometry><cylinder radius="0.05" length="0.4"/></geometry>
    </collision></link>
  <link name="tool"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <link name="tip"/>
  <joint name="turn" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3"/></joint>
  <joint name="slide" type="prismatic"><parent link="arm"/><child link="tool"/>
    <origin xyz="0 0 0.4"/><axis xyz="0 0 1"/><limit lower="0" upper="0.1"/></joint>
  <joint name="end" type="fixed"><parent link="tool"/><child link="tip"/></joint>
</robot>"""


class _Scene:
    """``n`` random boxes in a cube, half static; the others drift and turn with time."""

    def __init__(self, n, seed=1):
        rng = np.random.default_rng(seed)
        side = 0.62 * n ** (1.0 / 3.0)  # about one contact per body, as scenes.uniform
        quaternions = rng.normal(size=(n, 4))
        quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
        poses = np.concatenate([rng.uniform(0.0, side, (n, 3)), quaternions], axis=1)
        extents = rng.uniform(0.1, 0.3, (n, 3))
        half = n // 2
        self.static_poses, self.static_half_extents = poses[:half], extents[:half]
        self._start, self.dynamic_half_extents = poses[half:], extents[half:]
        self._velocity = rng.uniform(-0.5, 0.5, (n - half, 3))

    def dynamic_poses(self, time_s):
        """Return the dynamic poses ``time_s`` seconds after the start."""
        poses = self._start.copy()
        poses[:, :3] += self._velocity * time_s
        # A turn about z by time_s rad, composed with each start orientation.
        turn = np.array([0.0, 0.0, np.sin(0.5 * time_s), np.cos(0.5 * time_s)])
        x, y, z, w = poses[:, 3:].T
        tz, tw = turn[2], turn[3]
        poses[:, 3:] = np.stack([tw * x - tz * y, tw * y + tz * x, tw * z + tz * w,
                                 tw * w - tz * z], axis=1)
        return poses

    def half_moved(self, time_s):
        """Return the poses at ``time_s``, every other body still where it was at 0 s."""
        poses = self.dynamic_poses(time_s)
        poses[::2] = self.dynamic_poses(0.0)[::2]
        return poses


def warm_up(sections=None):
    """Run ``sections`` (names of SECTIONS; None: all), so that no later tick compiles."""
    for name in SECTIONS if sections is None else sections:
        SECTIONS[name]()


def warm_up_like(world, half_extents, robot=None):
    """Run a copy of ``world`` on bodies of ``half_extents``, as its first ticks will be run.

    The copy has the World's settings, static colliders, filters and robot (or ``robot``);
    its bodies ((D, 3): D bodies, (3,): WARM_UP_BODIES / 2) sit on the colliders, so that
    every stage of a step runs: boxes, pairs, SAT and contacts, a step again with half of them
    moved, the same input again, and both as a batch of states; with a robot, its joint
    states and a trajectory too. Compiles what a World so configured runs for inputs of that
    many bodies, and nothing else.
    """
    sizes = np.asarray(half_extents, float)
    count = len(sizes) if sizes.ndim == 2 else WARM_UP_BODIES // 2
    description = world.describe()
    twin = World.from_description(description)
    try:
        poses = _Scene(2 * count).dynamic_poses(0.0)
        colliders = description.colliders[1]
        if len(colliders):  # on the colliders, one after another
            poses[:, :3] = colliders[np.arange(count) % len(colliders), :3]
        poses[:, :3] += 0.05 * np.arange(count)[:, None]  # apart a little: every pair differs
        moved = poses.copy()
        moved[::2, 0] += 0.01
        for step_poses in (poses, moved, moved):  # the same input again: the answer reused
            result = twin.step(step_poses, sizes)
        distance_stats(result.contacts)  # what the diagnostics read of a tick: a kernel too
        twin.check_states(np.array([poses, moved]), sizes)
        robot = description.robot if robot is None else robot
        if robot is not None:
            twin.set_robot(robot)
            still = np.zeros(robot.dof)
            twin.check_joints(still)
            twin.step(twin.robot_poses(still), robot.half_extents)  # a continuous node's
            twin.check_trajectory(np.array([still, still + 0.1]))
    finally:
        twin.close()


def compile_in_processes(sections=None, processes=None, report=print, niceness=0,
                         stop=None, last=()):
    """Compile (or load) the kernels of ``sections`` (None: all) into numba's cache.

    The sections run in ``processes`` new processes (None: one a CPU), in two waves: first the
    SHARED_FIRST sections, which compile the kernels every other section calls, then the rest,
    heaviest first, a process taking the next section when it is done with one, and ``last``:
    (name, function) pairs of the caller's own, module functions that compile kernels. They
    call the sections' kernels (the ROS lanes call the one pass and the robot's pass): taken
    last, they load those from the cache rather than compile them again beside the section
    that does (the lanes in the first wave made a first start 11 s longer).
    In one wave two processes would compile those shared kernels twice (the SAT under every
    section): numba writes whole files, and _jit serializes the writes to one kernel's index,
    so that is safe, only slower (84 s against 69 s for every section, Intel Xeon). The
    kernels end up in numba's cache, not in this process. ``report(line)`` hears a line as
    each section is done; the processes run ``niceness`` below this one's priority; ``stop``
    (a threading.Event), once set, ends them within STOP_POLL_S. Returns how many kernels
    compiled (a kernel compiled by two processes counts twice).
    """
    tasks = [(name, SECTIONS[name]) for name in (SECTIONS if sections is None else sections)]
    waves = [[task for task in tasks if task[0] in SHARED_FIRST],
             [task for task in tasks if task[0] not in SHARED_FIRST] + list(last)]
    count = len(tasks) + len(last)
    processes = max(1, min(count, processes or os.cpu_count()))
    start = reported = time.monotonic()
    kernels = done = 0

    def waiting():  # a line a period while no part finishes, as in a start's compile
        nonlocal reported
        if time.monotonic() - reported >= REPORT_PERIOD_S:
            reported = time.monotonic()
            report('%d of %d parts compiled, %.0f s so far' % (done, count, reported - start))

    # spawn, not fork: a fork of a process that compiled (LLVM, numba's threads) is not safe.
    with multiprocessing.get_context('spawn').Pool(processes, os.nice, (niceness,)) as pool:
        for wave in waves:
            finished = pool.imap_unordered(_compile_task, wave)
            for _ in wave:
                answer = _next_answer(finished, stop, waiting)
                if answer is None:  # stopped
                    return kernels
                name, compiled, seconds = answer
                done += 1
                kernels += compiled
                report('compiled part %d of %d (%s: %d kernels, %.1f s), %.0f s so far' % (
                    done, count, name, compiled, seconds, time.monotonic() - start))
    if sections is None:
        _mark_complete()
    return kernels


def cache_complete():
    """Whether every section's kernels were compiled into numba's cache for these sources.

    :func:`compile_in_processes` leaves a marker once it compiled every section; a start whose
    own kernels all loaded may still find others missing (an earlier start stopped during its
    background compile), and then has them compiled in other processes too.
    """
    return os.path.exists(_marker_path())


def _mark_complete():
    """Leave the marker of :func:`cache_complete`, and remove those of other sources."""
    marker = _marker_path()
    for stale in glob.glob(os.path.join(os.path.dirname(marker), COMPLETE_MARKER + '*')):
        if stale != marker:
            os.remove(stale)
    pathlib.Path(marker).touch()


def _marker_path():
    """Return the marker's path: in this module's kernels' cache, named by :func:`source_stamp`."""
    cache = box_distance._cache._cache_path  # numba's cache directory for the pipeline's kernels
    package = pathlib.Path(__file__).resolve().parent.parent
    return os.path.join(cache, COMPLETE_MARKER + source_stamp(package))


def source_stamp(package):
    """Return a digest of what numba checks before it loads a cached kernel, for ``package``.

    Each source file's time and size (numba's own test), numba's and Python's versions, and
    what numba keys its cached code on besides (the target, this CPU and its features): an
    edited or updated package, or another machine, gets another stamp.
    """
    digest = hashlib.sha1()
    for path in sorted(pathlib.Path(package).rglob('*.py')):
        status = path.stat()
        line = '%s %d %d\n' % (path.relative_to(package), status.st_mtime_ns, status.st_size)
        digest.update(line.encode())
    digest.update(('%s %s %s' % (numba.__version__, sys.version,
                                 box_distance.targetctx.codegen().magic_tuple())).encode())
    return digest.hexdigest()[:16]


def _next_answer(finished, stop, waiting):
    """Return the next answer of ``finished`` (imap), or None once ``stop`` is set.

    Polls every STOP_POLL_S, calling ``waiting()`` at each poll without an answer.
    """
    while not (stop is not None and stop.is_set()):
        try:
            return finished.next(timeout=STOP_POLL_S)
        except multiprocessing.TimeoutError:
            waiting()
    return None


def _compile_task(task):
    """Run ``task`` (name, function); return its name, the kernels it compiled, its time in s."""
    name, function = task
    start = time.monotonic()
    with compile_progress(lambda line: None) as progress:
        function()
    return name, progress.compiled, time.monotonic() - start


def warm_up_in_background(compile_first, report=None, also=None):
    """Ready every kernel in a thread of its own, while the process goes on; return the thread.

    ``compile_first``: the cache is probably cold (a start just compiled, or it is not
    :func:`cache_complete`): the kernels are
    first compiled in other processes (:func:`compile_in_processes`, at a lower priority), so
    that the compile holds neither this process's interpreter lock nor its CPU time. Then
    :func:`warm_up` in this process loads every kernel from numba's cache (about a second), so
    that no later tick waits for one. A tick that needs a kernel before that compiles or loads
    it itself, as numba does on a first call. ``report(line)``, if given, hears when every
    kernel is ready. ``also``: (name, function) of the caller's own that compiles kernels
    (a module function: the processes import it), readied with the sections. Kernels are the
    process's: a second call returns the first call's thread.
    """
    global _background
    with _background_lock:
        if _background is None:
            def run():
                start = time.monotonic()
                extra = [] if also is None else [also]
                if compile_first:
                    compile_in_processes(report=lambda line: None, niceness=BACKGROUND_NICENESS,
                                         stop=_stopping, last=extra)
                for _, function in list(SECTIONS.items()) + extra:
                    if _stopping.is_set():
                        return
                    try:
                        function()
                    except RuntimeError:
                        # The program is ending (a signal): its thread pools refuse new work
                        # before the atexit hook stops this thread. Nothing is left to ready.
                        if threading.main_thread().is_alive():
                            raise
                        return
                if report is not None:
                    report('%s, in the background in %.1f s'
                           % (BACKGROUND_READY, time.monotonic() - start))

            _background = threading.Thread(target=run, name='warm_up', daemon=True)
            _background.start()
            atexit.register(_stop_background)
        return _background


def _stop_background():
    """Stop the background warm-up at the end of the process, and wait for it.

    A thread left inside numba or LLVM while the interpreter tears down can crash the process
    (status 139 instead of 0): the warm-up stops between sections (a second or so), the
    compile processes are ended.
    """
    _stopping.set()
    _background.join()


_background = None  # the process's background warm-up thread, once one started
_background_lock = threading.Lock()
_stopping = threading.Event()  # set at the process's end: the background stops


def _broad_phase(name):
    """Run broad phase ``name`` in every mode on the small scene, then past the one pass."""
    scene = _Scene(WARM_UP_BODIES)
    extents = scene.dynamic_half_extents
    for statics in (True, False):
        world = World(broad_phase=name)
        if statics:
            world.set_static(scene.static_poses, scene.static_half_extents)
        for sphere_prefilter in (True, False):
            world.sphere_prefilter = sphere_prefilter
            # Bodies move between steps so that update paths (bodies leaving their cell or
            # leaf) run too, and half of them only, so that still bodies keep their
            # contacts; one size per body, then one size for all, one body, none.
            world.step(scene.dynamic_poses(0.0), extents)
            world.step(scene.half_moved(0.5), extents)
            world.step(scene.dynamic_poses(1.0), extents[0])
            world.step(scene.half_moved(1.0), extents[0])
            world.step(scene.dynamic_poses(1.5)[:1], extents[0])
            world.step(np.zeros((0, 7)), extents[0])
    # Colliders that moved under still bodies: a little (kept in every phase's structure),
    # then far (loose in the grid and the octree: paired by the World itself).
    ids = np.arange(len(scene.static_poses))
    world = World(broad_phase=name)
    world.set_static(scene.static_poses, scene.static_half_extents)
    world.step(scene.dynamic_poses(0.0), extents)
    moved = scene.static_poses.copy()
    for shift in (1e-3, 2.0):
        moved[:2, 0] += shift
        world.move_static(ids, moved)
        world.step(scene.half_moved(0.5), extents)
    # Brute force and auto past the one-pass pairs (their general path), and auto measuring
    # the boxes' spread (from AUTO_SPREAD_BODIES bodies on).
    sizes = (ONE_PASS_BODIES,) if name in ONE_PASS_PHASES else ()
    for bodies in sizes + ((AUTO_SPREAD_BODIES,) if name == 'auto' else ()):
        large = _Scene(bodies)
        world = World(broad_phase=name)
        world.set_static(large.static_poses, large.static_half_extents)
        world.step(large.dynamic_poses(0.0), large.dynamic_half_extents)
        world.step(large.half_moved(0.5), large.dynamic_half_extents)


def _margins():
    """Run margins (padded bounds, exact distances) and filters, in one pass and past it."""
    # The World's margin alone, then with the colliders' own, and filters (masks per body,
    # ignored pairs).
    for margins in (_Scene(WARM_UP_BODIES), _Scene(ONE_PASS_BODIES)):
        sizes = margins.dynamic_half_extents
        world = World(broad_phase='brute_force', margin=0.1)
        world.set_static(margins.static_poses, margins.static_half_extents)
        world.step(margins.dynamic_poses(0.0), sizes)
        world = World(broad_phase='brute_force', margin=0.1)
        world.set_static(margins.static_poses, margins.static_half_extents, margins=0.05,
                         masks=3)
        world.set_filters(categories=np.arange(len(sizes)) % 2 + 1,
                          ignored_pairs=[(0, DYNAMIC, 1, DYNAMIC), (0, DYNAMIC, 0, STATIC)])
        world.step(margins.dynamic_poses(0.0), sizes)
        world.step(margins.half_moved(0.5), sizes)


def _one_pass(margins, batches):
    """Run the one pass at each World margin of ``margins`` (0: none at all), and batches."""
    # Two compiled variants: no margin at all, and margins (the World's, the colliders' own or
    # both: the same types); filters or none are the same types too (SceneRows.filter_table).
    # ``batches``: check_states too (its own kernels), as a step is checked first.
    scene = _Scene(WARM_UP_BODIES)
    extents = scene.dynamic_half_extents
    states = np.array([scene.dynamic_poses(t) for t in (0.0, 0.5)])
    for margin in margins:
        world = World(broad_phase='brute_force', margin=margin)
        world.set_static(scene.static_poses, scene.static_half_extents)
        for sizes in (extents, extents[0]):
            world.step(states[0], sizes)
            if batches:
                world.check_states(states, sizes)


def _distances():
    """Run the exact distance of two boxes (margins' pairs), as the SAT calls it."""
    # Two boxes apart along a face normal, then turned so that edges and corners are closest:
    # each of its searches runs. Called with the SAT's types (tuples of floats).
    turned = (0.36, -0.48, 0.8, 0.8, 0.6, 0.0, -0.48, 0.64, 0.6)
    for rel, offset in (((1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), (3.0, 0.0, 0.0)),
                        (turned, (2.5, 1.5, 1.0)), (turned, (0.1, 0.0, 0.0))):
        box_distance(rel, offset, (0.5, 0.4, 0.3), (0.6, 0.2, 0.1))


def _continuous():
    """Run continuous checks (swept bounds, advancement, pairs touching only in between)."""
    # With and without margins: a bullet through a wall besides the scene.
    scene = _Scene(WARM_UP_BODIES)
    bullet = np.array([[0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 1.0]])
    poses = [np.concatenate([scene.dynamic_poses(t), bullet + [[0.0, 0.0, 4.0 * t] + [0.0] * 4]])
             for t in (0.0, 0.5, 1.0)]
    for margin in (0.0, 0.1):
        world = World(broad_phase='brute_force', margin=margin, continuous=True)
        world.set_static(np.concatenate([scene.static_poses, [[0.0] * 6 + [1.0]]]),
                         np.concatenate([scene.static_half_extents, [[1.0, 1.0, 0.01]]]),
                         margins=margin)
        for step_poses in poses:
            world.step(step_poses, [0.05, 0.05, 0.05])


def _large_ticks():
    """Sort candidate pairs and list contacts over threads, as only large ticks do."""
    # Candidate pairs sorted by row, which only scenes of SORT_PAIRS_ROWS boxes are.
    pairs = np.array([[0, 1]])
    orient_pairs(pairs, 0, np.arange(2), np.zeros(3, np.int64), pairs.copy())
    # Contacts listed by ranges of bodies for threads (discrete and swept ticks alike), which
    # only ticks of MIN_PAIRS_PER_THREAD candidate pairs a thread are: two bodies against one
    # static box, many times over.
    pairs = np.tile([[1, 0], [2, 0]], (MIN_PAIRS_PER_THREAD, 1))
    status, depth, normal, point = empty_output(len(pairs))
    status[:] = COLLIDING
    depth[:] = normal[:] = point[:] = 0.0
    workers = Workers(2)
    assemble_contacts(pairs, status, depth, normal, point, 1, 2, np.zeros(1, np.int64),
                      np.arange(2), workers=workers)
    workers.close()


def _robot_model():
    """Run the robot model's forward kinematics: one state, a batch, the link frames."""
    robot = Robot.from_urdf(WARM_UP_ROBOT)
    robot.box_poses(np.zeros(robot.dof))
    robot.box_poses(np.zeros((2, robot.dof)))
    robot.link_poses(np.zeros(robot.dof))


def _robot():
    """Run the robot in a World: joint states and trajectories."""
    # With and without margins (the World's or the colliders' own: the same types), a robot
    # with pairs to leave out and one with none. A step of the robot's boxes is the one pass's,
    # compiled by its sections (the same types): run here too, it would compile them again
    # beside them.
    scene = _Scene(WARM_UP_BODIES)
    robot = Robot.from_urdf(WARM_UP_ROBOT)
    lone_box = Robot.from_urdf(WARM_UP_ROBOT.split('<link name="arm">')[0] + '</robot>')
    for margin, arm in itertools.product((0.0, 0.1), (robot, lone_box)):
        world = World(margin=margin)
        world.set_static(scene.static_poses, scene.static_half_extents)
        world.set_robot(arm)
        world.check_joints(np.zeros(arm.dof))
        world.check_trajectory(np.linspace(0.0, 0.1, 2 * arm.dof).reshape(2, arm.dof))


# Every part of the warm-up by name, each independent of the others; heaviest first (CPU s
# on a cold cache, Intel Xeon, after the SHARED_FIRST ones), so that processes taking them in
# turn end together.
SECTIONS = {
    'one_pass': functools.partial(_one_pass, (0.0,), False),  # 20, the SAT's without margins
    'distances': _distances,  # 8
    'robot_model': _robot_model,  # 4
    'robot': _robot,  # 16
    # 12 after the two above: margins, and the batches of states with and without
    'one_pass_margins': functools.partial(_one_pass, (0.1, 0.0), True),
    'octree': functools.partial(_broad_phase, 'octree'),  # 14
    'continuous': _continuous,  # 9
    'margins': _margins,  # 5
    **{name: functools.partial(_broad_phase, name) for name in NAMES},  # 0.1-5 each
    'large_ticks': _large_ticks,  # 0.6
}
# The sections that compile what every other one calls (the one pass and the SAT without
# margins; the exact distance that margins add): compile_in_processes compiles them first,
# beside each other, and the robot's forward kinematics, which calls none of them, beside
# them (it fills the wait for the one pass, the longest).
SHARED_FIRST = ('one_pass', 'distances', 'robot_model')
