"""collision_bench: the seed papers' tables, run time against error, and python-fcl side by side.

    collision_bench --quick --output bench_results     # a subset, under a minute
    collision_bench --output bench_results             # every scene (long; prints progress)

Writes OUTPUT/results.json (every number), OUTPUT/results.md (the tables, the performance
targets with pass/fail, the command that reproduces them) and OUTPUT/time_vs_error.png.
python-fcl, coal, MuJoCo, pinocchio and matplotlib are optional (the ``bench`` extra,
benchmark-only), and example-robot-data (the ``test`` extra): without them the fcl table, the
robot sections' peers (or the Panda) and the plot are left out and say why.
Scenes come from :mod:`collision_node.pipeline.scenes`, seeded.
"""
import argparse
from importlib import metadata
import math
import os
import platform
import shlex
import subprocess
import sys
import time
from typing import NamedTuple

import numpy as np

from collision_node.benchmarks import report
from collision_node.benchmarks.accuracy import accuracy_rows
from collision_node.benchmarks.fcl_reference import compare_with_fcl, fcl_available, INSTALL_HINT
from collision_node.benchmarks.robot import robot_rows
from collision_node.benchmarks.robot_model import robot_model_rows
from collision_node.benchmarks.runs import (
    Limits, run_all_pairs_sat, run_world, WARM_UP_BODIES, WARM_UP_TICKS, warmed)
from collision_node.benchmarks.stages import profile_stages
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.scenes import make_scene
from collision_node.pipeline.warm_up import warm_up
from collision_node.pipeline.world import World

OCTREE_DEPTHS = tuple(range(1, 10))  # Table 1 of "Discrete Collision Algorithms"
PAPER000_OCTREE_DEPTH = 4            # the octree of "Engine Algorithms" ran at depth 4
DEFAULT_PHASE = 'auto'               # what the node uses unless told otherwise
SECTIONS = ('paper001', 'octree_depths', 'paper000', 'scenes', 'accuracy', 'fcl', 'profile',
            'threads', 'margins', 'continuous', 'static_moves', 'robot', 'robot_model')
THREAD_COUNTS = (1, 2)  # the World's threads: one, and both cores of a 2-core machine
# The margins section: margins as fractions of the mean box size (its full side), and one run
# with half the dynamic pairs masked out (categories 1 and 2 in turn, each accepting its own).
MARGIN_FRACTIONS = (0.0, 0.02, 0.1)
MARGIN_ROUNDS = 5  # the configurations take turns, a few ticks each, so noise hits all alike
# The continuous section: the uniform scene's inputs at 60 Hz (its usual speed, up to ~1.4 cm
# and 0.03 rad a tick) and at 15 Hz (4x the motion per tick).
CONTINUOUS_RATES_HZ = (60.0, 15.0)

# The static_moves section: static colliders moved every tick (World.move_static), by up to this
# much along x (m, a sine per collider: within their cells), or by STATIC_JUMP_M (into other
# cells), against the same scene with them still and with every body dynamic.
STATIC_MOVE_M = 0.02
STATIC_JUMP_M = 1.0
STATIC_MOVES_PER_TICK = 10


class Plan(NamedTuple):
    """What one benchmark run covers. Sizes are total body counts."""

    flying_out_sizes: tuple    # "Discrete Collision Algorithms" scene, every broad phase
    flying_out_ticks: int
    flying_out_dt: float       # s; ticks * dt simulated seconds, dense at first, then sparse
    depth_sizes: tuple         # the same scene, octree depths 1-9
    paper000_bodies: int
    paper000_ticks: int
    scene_sizes: tuple         # (scene, bodies): uniform and clustered, every broad phase
    scene_ticks: int
    accuracy_scenes: tuple     # (scene, bodies, ticks, dt)
    fcl_sizes: tuple           # (bodies, ticks) on the uniform scene
    profile_sizes: tuple       # (scene, bodies, ticks, dt): the targets' scenes
    thread_sizes: tuple        # (bodies, ticks): uniform scene, default phase, 1 and 2 threads
    margin_sizes: tuple        # (bodies, ticks per configuration): uniform scene, margins
    continuous_sizes: tuple    # (bodies, ticks per configuration): uniform scene, continuous
    static_move_sizes: tuple   # (bodies, ticks per configuration): uniform scene, statics moving
    robot_states: int          # the arm (config/arm.yaml): states per round, one per call,
    robot_batch_states: int    # and K, the states of one World.check_states call,
    robot_rounds: int          # in this many rounds (each on states a little later)
    panda_states: int          # the Panda (robot_model.py): random states per round, one per
    panda_batch_states: int    # call, and K, the states of one World.check_joints call,
    panda_rounds: int          # in this many rounds,
    panda_segments: int        # then this many random short segments for the false alarms
    budget_s: float            # a run stops early (marked truncated) after this wall time
    # A run expected to take longer per tick is skipped; one stops after a tick that took
    # longer. Keep it >= 1 s: then a skipped run misses every performance target even if its
    # phase scales linearly (the report counts a skipped default phase as failing).
    max_tick_s: float


DT = 1.0 / 60.0  # s
PLANS = {
    'full': Plan(
        flying_out_sizes=(128, 256, 512, 1024), flying_out_ticks=300, flying_out_dt=DT,
        depth_sizes=(128, 256, 512, 1024), paper000_bodies=1000, paper000_ticks=300,
        scene_sizes=(('uniform', 64),) + tuple((scene, n) for scene in ('uniform', 'clustered')
                                               for n in (1000, 10000, 100000)),
        scene_ticks=120,
        accuracy_scenes=(('flying_out', 128, 300, DT), ('flying_out', 256, 300, DT),
                         ('flying_out', 512, 300, DT), ('flying_out', 1024, 300, DT),
                         ('paper000', 1000, 120, DT),
                         ('uniform', 1000, 120, DT), ('uniform', 10000, 20, DT),
                         ('uniform', 100000, 3, DT),
                         ('clustered', 1000, 120, DT), ('clustered', 10000, 20, DT),
                         ('clustered', 100000, 3, DT)),
        fcl_sizes=((1000, 60), (5000, 30), (10000, 20), (20000, 20)),
        profile_sizes=(('uniform', 64, 2000, DT), ('flying_out', 1024, 300, DT),
                       ('uniform', 10000, 120, DT), ('uniform', 100000, 30, DT)),
        thread_sizes=((10000, 120), (100000, 30)),
        margin_sizes=((1000, 200), (10000, 100)),
        continuous_sizes=((1000, 200), (10000, 100)),
        static_move_sizes=((10000, 200), (100000, 20)),
        robot_states=400, robot_batch_states=4000, robot_rounds=40,
        panda_states=400, panda_batch_states=4000, panda_rounds=40, panda_segments=2000,
        budget_s=120.0, max_tick_s=5.0),
    # Every section and table, on sizes that take a few seconds each (under a minute in all
    # with a warm cache), but the targets' sizes (20,000 against python-fcl, 100,000).
    'quick': Plan(
        flying_out_sizes=(128, 256, 512, 1024), flying_out_ticks=60, flying_out_dt=5.0 / 60,
        depth_sizes=(512, 1024), paper000_bodies=1000, paper000_ticks=30,
        scene_sizes=(('uniform', 64), ('uniform', 1000), ('uniform', 10000),
                     ('uniform', 100000), ('clustered', 1000)),
        scene_ticks=10,
        accuracy_scenes=(('flying_out', 1024, 20, 0.25), ('paper000', 1000, 10, DT),
                         ('uniform', 1000, 10, DT), ('clustered', 1000, 10, DT)),
        fcl_sizes=((1000, 10), (5000, 5), (20000, 3)),
        profile_sizes=(('uniform', 64, 500, DT), ('flying_out', 1024, 60, 5.0 / 60),
                       ('uniform', 10000, 10, DT), ('uniform', 100000, 5, DT)),
        thread_sizes=((10000, 40), (100000, 10)),
        margin_sizes=((1000, 100), (10000, 40)),
        continuous_sizes=((1000, 100), (10000, 40)),
        static_move_sizes=((10000, 30),),
        robot_states=400, robot_batch_states=4000, robot_rounds=5,
        panda_states=200, panda_batch_states=4000, panda_rounds=8, panda_segments=200,
        budget_s=3.0, max_tick_s=1.0),
    # For the tests: every section on small scenes, in seconds.
    'tiny': Plan(
        flying_out_sizes=(64, 128), flying_out_ticks=10, flying_out_dt=0.5,
        depth_sizes=(128,), paper000_bodies=200, paper000_ticks=5,
        scene_sizes=(('uniform', 300), ('clustered', 300)), scene_ticks=5,
        accuracy_scenes=(('flying_out', 128, 8, 0.5), ('paper000', 200, 5, DT),
                         ('uniform', 300, 5, DT), ('clustered', 300, 5, DT)),
        fcl_sizes=((300, 3),),
        profile_sizes=(('flying_out', 128, 5, 0.5), ('uniform', 1000, 3, DT)),
        thread_sizes=((1000, 3),),
        margin_sizes=((300, 5),),
        continuous_sizes=((300, 5),),
        static_move_sizes=((300, 10),),
        robot_states=20, robot_batch_states=50, robot_rounds=2,
        panda_states=20, panda_batch_states=50, panda_rounds=2, panda_segments=20,
        budget_s=5.0, max_tick_s=1.0),
}


class Progress:
    """Progress lines on stderr, stamped with the seconds since the start."""

    def __init__(self, stream=sys.stderr):
        self._start = time.perf_counter()
        self._stream = stream

    def __call__(self, message):
        print('[%7.1f s] %s' % (time.perf_counter() - self._start, message), file=self._stream,
              flush=True)


class SlowRunFilter:
    """Skips a run whose tick, extrapolated from the smaller sizes measured, would be too long.

    The tick time is scaled as n^p from the last size, p fitted to the last two sizes and
    clamped to [1, 2] (every broad phase scales between linear and brute force's n²), or 2
    with only one size. p is the larger of the fits to the tick times and to the pairs
    compared: fixed costs make small sizes look cheap, and the comparisons tell how the work
    grows. Brute force at 100,000 bodies (~3.75e9 comparisons, ~15 s a tick) is skipped; a
    phase whose work grew linearly from 1,000 to 10,000 bodies is run.
    """

    def __init__(self, max_tick_s):
        self._max_tick_s = max_tick_s
        self._sizes = {}  # key -> [(bodies, ms per tick, compared or None), ...]

    def reason_to_skip(self, key, bodies, max_tick_s=None):
        """Why the run ``key`` at ``bodies`` should be skipped, or None to run it."""
        sizes = [size for size in self._sizes.get(key, []) if size[0] <= bodies]
        if not sizes:
            return None
        last_bodies, last_ms, last_compared = sizes[-1]
        power = 2.0
        smaller = [size for size in sizes if size[0] < last_bodies]
        if smaller:
            first_bodies, first_ms, first_compared = smaller[-1]
            growth = math.log(last_bodies / first_bodies)
            power = math.log(last_ms / first_ms) / growth
            if first_compared and last_compared:
                power = max(power, math.log(last_compared / first_compared) / growth)
            power = min(2.0, max(1.0, power))
        expected_s = 1e-3 * last_ms * (bodies / last_bodies) ** power
        if expected_s <= (max_tick_s or self._max_tick_s):
            return None
        return ('skipped: ~%.3g s per tick expected (%.3g ms at %d bodies, scaled as n^%.2g)'
                % (expected_s, last_ms, last_bodies, power))

    def record(self, key, bodies, ms, compared=None):
        """Remember that run ``key`` took ``ms`` per tick at ``bodies`` (and ``compared``)."""
        self._sizes.setdefault(key, []).append((bodies, ms, compared))


class Bench:
    """Runs the sections of a plan and collects their rows."""

    def __init__(self, plan, seed, progress):
        self.plan = plan
        self.seed = seed
        self.progress = progress
        self.slow = SlowRunFilter(plan.max_tick_s)
        self.limits = Limits(plan.budget_s, plan.max_tick_s)
        self.errors = []
        self.results = {}  # section -> rows, filled as the sections finish

    def scene(self, name, bodies):
        return make_scene(name, bodies, self.seed)

    def _guarded(self, label, run, *args, **kwargs):
        """``run(*args, **kwargs)``; an exception becomes an error row instead of a crash."""
        try:
            return run(*args, **kwargs)
        except Exception as error:  # one broken phase must not hide the others' numbers
            message = '%s: %s: %s' % (label, type(error).__name__, error)
            self.errors.append(message)
            self.progress('ERROR ' + message)
            return {'error': '%s: %s' % (type(error).__name__, error)}

    def _world_row(self, scene, ticks, dt, label, ids, skip_key=None, **world_options):
        bodies = ids['bodies']
        reason = skip_key and self.slow.reason_to_skip(skip_key, bodies)
        if reason:
            self.progress('%s: %s' % (label, reason))
            return dict(ids, skipped=reason)
        before = time.perf_counter()
        row = self._guarded(label, warmed, run_world, scene, ticks, dt, self.limits,
                            **world_options)
        if 'error' not in row:
            if skip_key:
                self.slow.record(skip_key, bodies, row['median_ms'], row.get('compared_max'))
            self.progress('%s: %d ticks in %.1f s, median %.3f ms'
                          % (label, row['ticks'], time.perf_counter() - before,
                             row['median_ms']))
        return dict(ids, **row)

    def paper001(self):
        plan = self.plan
        rows = []
        for bodies in plan.flying_out_sizes:
            scene = self.scene('flying_out', bodies)
            for name in NAMES:
                rows.append(self._world_row(
                    scene, plan.flying_out_ticks, plan.flying_out_dt,
                    'paper001 n=%d %s' % (bodies, name),
                    {'scene': 'flying_out', 'bodies': bodies, 'broad_phase': name},
                    skip_key=('scenes', 'flying_out', name), broad_phase=name))
        return rows

    def octree_depths(self):
        if 'octree' not in NAMES:
            return [{'skipped': 'no octree broad phase in this build'}]
        plan = self.plan
        rows = []
        for bodies in plan.depth_sizes:
            scene = self.scene('flying_out', bodies)
            for depth in OCTREE_DEPTHS:
                rows.append(self._world_row(
                    scene, plan.flying_out_ticks, plan.flying_out_dt,
                    'octree depth %d n=%d' % (depth, bodies),
                    {'scene': 'flying_out', 'bodies': bodies, 'broad_phase': 'octree',
                     'depth': depth},
                    broad_phase='octree', octree_max_depth=depth))
        return rows

    def paper000(self):
        plan = self.plan
        bodies = plan.paper000_bodies
        scene = self.scene('paper000', bodies)
        ticks = plan.paper000_ticks
        rows = []

        def ids(method):
            return {'scene': 'paper000', 'bodies': bodies, 'method': method}

        before = time.perf_counter()
        row = self._guarded('paper000 baseline', warmed, run_all_pairs_sat, scene, ticks, DT,
                            self.limits)
        self.progress('paper000 baseline (SAT on all pairs): %.1f s'
                      % (time.perf_counter() - before))
        rows.append(dict(ids('baseline: SAT on all pairs'), **row))
        methods = [('sphere test', {'broad_phase': 'sphere', 'sphere_prefilter': False}),
                   ('brute force AABBs + SAT', {'broad_phase': 'brute_force',
                                                'sphere_prefilter': False})]
        if 'octree' in NAMES:
            octree = {'broad_phase': 'octree', 'octree_max_depth': PAPER000_OCTREE_DEPTH}
            methods += [('octree depth %d' % PAPER000_OCTREE_DEPTH,
                         dict(octree, sphere_prefilter=False)),
                        ('sphere + octree depth %d' % PAPER000_OCTREE_DEPTH,
                         dict(octree, sphere_prefilter=True))]
        methods.append(('World default (%s, sphere prefilter)' % DEFAULT_PHASE,
                        {'broad_phase': DEFAULT_PHASE, 'sphere_prefilter': True}))
        for method, options in methods:
            rows.append(self._world_row(scene, ticks, DT, 'paper000 ' + method, ids(method),
                                        **options))
        return rows

    def scenes(self):
        plan = self.plan
        rows = []
        for scene_name, bodies in plan.scene_sizes:
            scene = self.scene(scene_name, bodies)
            for name in NAMES:
                rows.append(self._world_row(
                    scene, plan.scene_ticks, DT, '%s n=%d %s' % (scene_name, bodies, name),
                    {'scene': scene_name, 'bodies': bodies, 'broad_phase': name},
                    skip_key=('scenes', scene_name, name), broad_phase=name))
        return rows

    def accuracy(self):
        rows = []
        warm = self.scene('uniform', WARM_UP_BODIES)
        accuracy_rows(warm, WARM_UP_TICKS, DT, NAMES, self.plan.budget_s)
        for scene_name, bodies, ticks, dt in self.plan.accuracy_scenes:
            before = time.perf_counter()
            self.progress('accuracy %s n=%d: ground truth and %d broad phases, %d ticks'
                          % (scene_name, bodies, len(NAMES), ticks))
            found = self._guarded('accuracy %s n=%d' % (scene_name, bodies), accuracy_rows,
                                  self.scene(scene_name, bodies), ticks, dt, NAMES,
                                  self.plan.budget_s, self.progress,
                                  # hopeless in the timing sections: hopeless here too
                                  lambda name, scene_name=scene_name, bodies=bodies:
                                  self.slow.reason_to_skip(('scenes', scene_name, name),
                                                           bodies))
            if isinstance(found, dict):
                rows.append(dict(found, scene=scene_name, bodies=bodies))
                continue
            for row in found:
                if 'error' in row:
                    self.errors.append('accuracy %s n=%d %s: %s' % (
                        scene_name, bodies, row['broad_phase'], row['error']))
            rows.extend(found)
            self.progress('accuracy %s n=%d: %.1f s'
                          % (scene_name, bodies, time.perf_counter() - before))
        return rows

    def fcl(self):
        if not fcl_available():
            return [{'skipped': INSTALL_HINT}]
        rows = []
        compare_with_fcl(self.scene('uniform', WARM_UP_BODIES), WARM_UP_TICKS, DT, NAMES,
                         self.limits)  # warm
        for bodies, ticks in self.plan.fcl_sizes:
            skipped = {}
            for name in NAMES:
                reason = self.slow.reason_to_skip(('fcl', name), bodies)
                if reason:
                    skipped[name] = reason
            before = time.perf_counter()
            found = self._guarded('fcl n=%d' % bodies, compare_with_fcl,
                                  self.scene('uniform', bodies), ticks, DT,
                                  [name for name in NAMES if name not in skipped],
                                  self.limits._replace(budget_s=4 * self.plan.budget_s))
            if isinstance(found, dict):
                rows.append(dict(found, scene='uniform', bodies=bodies))
                continue
            reference, measured = found
            for row in measured:
                self.slow.record(('fcl', row['broad_phase']), bodies, row['median_ms'])
            rows.extend(measured)
            rows.extend(dict(reference, broad_phase=name, skipped=reason)
                        for name, reason in skipped.items())
            self.progress('fcl n=%d: %d ticks in %.1f s, python-fcl median %.1f ms'
                          % (bodies, reference['ticks'], time.perf_counter() - before,
                             reference['fcl_median_ms']))
        return rows

    def profile(self):
        """Stage timings of the default phase and of the quickest one measured so far."""
        rows = []
        for scene_name, bodies, ticks, dt in self.plan.profile_sizes:
            phases = [DEFAULT_PHASE]
            quickest = self._quickest_phase(scene_name, bodies)
            if quickest and quickest != DEFAULT_PHASE:
                phases.append(quickest)
            for name in phases:
                rows.append(self._profile_row(scene_name, bodies, ticks, dt, name))
        return rows

    def _profile_row(self, scene_name, bodies, ticks, dt, name):
        # The scenes section ran the same configuration before: its tick times count. A
        # profile takes few ticks, so it may try sizes ten times slower than a timing run.
        key = ('scenes', scene_name, name)
        label = 'profile %s n=%d %s' % (scene_name, bodies, name)
        ids = {'scene': scene_name, 'bodies': bodies, 'broad_phase': name}
        reason = self.slow.reason_to_skip(key, bodies, 10 * self.plan.max_tick_s)
        if reason:
            self.progress('%s: %s' % (label, reason))
            return dict(ids, skipped=reason)
        limits = self.limits._replace(tick_s=10 * self.plan.max_tick_s)
        row = self._guarded(label, warmed, profile_stages, self.scene(scene_name, bodies),
                            ticks, dt, limits, phase_name=name)
        if 'tick_ms' in row:
            self.slow.record(key, bodies, row['tick_ms'])
            self.progress('%s: tick %.3f ms' % (label, row['tick_ms']))
        return dict(ids, **row)

    def threads(self):
        """Time the default phase on the uniform scene, its World on 1 and on 2 threads."""
        rows = []
        for bodies, ticks in self.plan.thread_sizes:
            scene = self.scene('uniform', bodies)
            for threads in THREAD_COUNTS:
                rows.append(self._world_row(
                    scene, ticks, DT, 'threads uniform n=%d threads=%d' % (bodies, threads),
                    {'scene': 'uniform', 'bodies': bodies, 'broad_phase': DEFAULT_PHASE,
                     'threads': threads}, broad_phase=DEFAULT_PHASE, threads=threads))
        return rows

    def margins(self):
        """Time margins of 0, 2 % and 10 % of the box size, and half the pairs masked out.

        The configurations take turns in rounds on the same ticks of the uniform scene (half
        static, default phase), so that a slow minute of the machine hits them all alike.
        """
        rows = []
        for bodies, ticks in self.plan.margin_sizes:
            scene = self.scene('uniform', bodies)
            size = 2.0 * float(np.mean(scene.dynamic_half_extents))  # the mean box side
            half = np.arange(scene.dynamic_count) % 2 + 1
            configurations = [('margin %g %%' % (100 * f), {'margin': f * size}, None)
                              for f in MARGIN_FRACTIONS]
            configurations.append(('half masked', {'margin': 0.0}, half))
            worlds = []
            for _, options, categories in configurations:
                world = World(broad_phase=DEFAULT_PHASE, **options)
                world.set_static(scene.static_poses, scene.static_half_extents)
                if categories is not None:
                    world.set_filters(categories=categories, masks=categories)
                worlds.append(world)
            samples = _in_rounds(ticks, [(_scene_inputs(scene, DT), world.step)
                                         for world in worlds])
            for (label, options, _), times in zip(configurations, samples):
                stats = [s for _, s in times]
                rows.append({
                    'scene': 'uniform', 'bodies': bodies, 'configuration': label,
                    'margin_m': options['margin'], 'ticks': len(times),
                    'median_ms': float(np.median([ms for ms, _ in times])),
                    'reported_pairs': float(np.mean([s['colliding_pairs'] + s['near_pairs']
                                                     for s in stats])),
                    'near_pairs': float(np.mean([s['near_pairs'] for s in stats])),
                    'filtered_pairs': float(np.mean([s['filtered_pairs'] for s in stats])),
                    'sat_tests': float(np.mean([s['sat_tests'] for s in stats]))})
                self.progress('margins n=%d %s: %.3f ms' % (bodies, label,
                                                            rows[-1]['median_ms']))
            base = rows[-len(configurations)]['median_ms']
            for row in rows[-len(configurations):]:
                row['vs_margin_0'] = row['median_ms'] / base
            for world in worlds:
                world.close()
        return rows

    def continuous(self):
        """Time continuous checking off and on, at the scene's usual speed and 4x faster.

        The uniform scene (half static, default phase), its inputs 1/60 s apart and 1/15 s
        apart; off and on take turns in rounds on the same inputs.
        """
        rows = []
        for bodies, ticks in self.plan.continuous_sizes:
            scene = self.scene('uniform', bodies)
            for rate in CONTINUOUS_RATES_HZ:
                worlds = []
                for continuous in (False, True):
                    world = World(broad_phase=DEFAULT_PHASE, continuous=continuous)
                    world.set_static(scene.static_poses, scene.static_half_extents)
                    worlds.append(world)
                samples = _in_rounds(ticks, [(_scene_inputs(scene, 1.0 / rate), world.step)
                                             for world in worlds])
                for world, times in zip(worlds, samples):
                    stats = [s for _, s in times[1:]]  # the first tick has no motion yet
                    rows.append({
                        'scene': 'uniform', 'bodies': bodies, 'rate_hz': rate,
                        'continuous': world.continuous, 'ticks': len(stats),
                        'median_ms': float(np.median([ms for ms, _ in times[1:]])),
                        'reported_pairs': float(np.mean([s['colliding_pairs'] + s['near_pairs']
                                                         for s in stats])),
                        'swept_pairs': float(np.mean([s['swept_pairs'] for s in stats])),
                        'candidate_pairs': float(np.mean([s['candidate_pairs'] for s in stats])),
                        'advance_steps': float(np.mean([s['advance_steps'] for s in stats])),
                        'unresolved_pairs': int(sum(s['unresolved_pairs'] for s in stats))})
                    rows[-1]['vs_off'] = rows[-1]['median_ms'] / rows[-1 - world.continuous][
                        'median_ms']
                    self.progress('continuous n=%d %g Hz %s: %.3f ms' % (
                        bodies, rate, 'on' if world.continuous else 'off',
                        rows[-1]['median_ms']))
                    world.close()
        return rows

    def static_moves(self):
        """Time static colliders that move every tick against the same scene without.

        The uniform scene, half static, default phase, its dynamic bodies moving: statics
        still; 10 moved per tick (the same 10, and 10 others each tick; by 2 cm, and by 1 m:
        into other cells); all of them moved per tick; and all of them given as dynamic bodies
        instead, moving alike. The
        configurations take turns in rounds, as in :meth:`margins`; the time of a tick is
        move_static's and step's together.
        """
        rows = []
        for bodies, ticks in self.plan.static_move_sizes:
            scene = self.scene('uniform', bodies)
            statics = len(scene.static_poses)
            moves = STATIC_MOVES_PER_TICK

            def others(tick, moves=moves, statics=statics):
                return (np.arange(moves) + moves * tick) % statics

            configurations = [  # (label, the statics moved at a tick, by up to m)
                ('statics still', None, 0.0),
                ('%d statics moved (the same)' % moves, lambda tick: np.arange(moves),
                 STATIC_MOVE_M),
                ('%d statics moved (others each tick)' % moves, others, STATIC_MOVE_M),
                ('%d statics jump %g m (others each tick)' % (moves, STATIC_JUMP_M), others,
                 STATIC_JUMP_M),
                ('all statics moved', lambda tick: np.arange(statics), STATIC_MOVE_M),
                ('all bodies dynamic', lambda tick: np.arange(statics), STATIC_MOVE_M)]
            all_extents = np.concatenate([scene.static_half_extents,
                                          scene.dynamic_half_extents])
            worlds, runs = [], []
            for label, moving, amplitude in configurations:
                world = World(broad_phase=DEFAULT_PHASE)
                worlds.append(world)
                if label == 'all bodies dynamic':
                    def inputs(k, moving=moving, amplitude=amplitude):
                        moved = _moved_statics(scene, moving(k), amplitude, k)
                        return (np.concatenate([moved, scene.dynamic_poses(k * DT)]),
                                all_extents)
                    runs.append((inputs, world.step))
                    continue
                world.set_static(scene.static_poses, scene.static_half_extents)
                if moving is None:
                    runs.append((_scene_inputs(scene, DT), world.step))
                    continue

                def inputs(k, moving=moving, amplitude=amplitude):
                    return (_moved_statics(scene, moving(k), amplitude, k),
                            scene.dynamic_poses(k * DT), scene.dynamic_half_extents)
                runs.append((inputs, _move_static_and_step(world)))
            samples = _in_rounds(ticks, runs)
            for (label, _, _), times in zip(configurations, samples):
                rows.append({
                    'scene': 'uniform', 'bodies': bodies, 'static_bodies': statics,
                    'configuration': label, 'ticks': len(times),
                    'median_ms': float(np.median([ms for ms, _ in times])),
                    'colliding_pairs': float(np.mean([s['colliding_pairs'] for _, s in times])),
                    'broad_phase': times[-1][1]['broad_phase']})
                self.progress('static_moves n=%d %s: %.3f ms'
                              % (bodies, label, rows[-1]['median_ms']))
            these = rows[-len(configurations):]
            for row in these:
                row['vs_still'] = row['median_ms'] / these[0]['median_ms']
                row['vs_dynamic'] = row['median_ms'] / these[-1]['median_ms']
            for world in worlds:
                world.close()
        return rows

    def robot(self):
        """Time the arm of config/arm.yaml: ours, python-fcl, coal and MuJoCo (robot.py)."""
        plan = self.plan
        rows = self._guarded('robot', robot_rows, plan.robot_states, plan.robot_batch_states,
                             plan.robot_rounds, self.progress)
        if isinstance(rows, dict):
            return [rows]
        for row in rows:
            if 'error' in row:
                self.errors.append('robot %s: %s' % (row['method'], row['error']))
        for target in report.robot_targets(rows):
            self.progress('robot target: %s: %s: %s' % (
                target['target'], target['measured'],
                {True: 'PASS', False: 'FAIL', None: 'n/a'}[target['passed']]))
        return rows

    def robot_model(self):
        """Time the Panda of example-robot-data: ours, MuJoCo, pinocchio + coal (robot_model)."""
        plan = self.plan
        rows = self._guarded('robot_model', robot_model_rows, plan.panda_states,
                             plan.panda_batch_states, plan.panda_rounds, plan.panda_segments,
                             self.seed, self.progress)
        if isinstance(rows, dict):
            return [rows]
        for row in rows:
            if 'error' in row:
                self.errors.append('robot_model %s: %s' % (row['method'], row['error']))
        for target in report.robot_model_targets(rows):
            self.progress('robot_model target: %s: %s: %s' % (
                target['target'], target['measured'],
                {True: 'PASS', False: 'FAIL', None: 'n/a'}[target['passed']]))
        return rows

    def _quickest_phase(self, scene_name, bodies):
        """Name the phase with the lowest median tick at the largest size <= bodies."""
        rows = [row for section in ('paper001', 'scenes') for row in self.results.get(section, [])
                if row.get('scene') == scene_name and row.get('bodies', 0) <= bodies
                and 'median_ms' in row and row['broad_phase'] != 'auto']
        if not rows:
            return None
        largest = max(row['bodies'] for row in rows)
        return min((row for row in rows if row['bodies'] == largest),
                   key=lambda row: row['median_ms'])['broad_phase']


def _in_rounds(ticks, runs):
    """Time ``ticks`` ticks of each (inputs, tick) in ``runs``, the runs taking turns.

    ``inputs(k)`` returns the arguments of tick k (untimed), ``tick(*arguments)`` is timed and
    returns the World's Result. The runs take turns in MARGIN_ROUNDS rounds of a few ticks
    each, so that a slow minute of the machine hits them all alike. Returns per run its
    [(ms, stats)] in tick order.
    """
    samples = [[] for _ in runs]
    per_round = max(1, ticks // MARGIN_ROUNDS)
    for first in range(0, per_round * MARGIN_ROUNDS, per_round):
        for (inputs, tick), times in zip(runs, samples):
            for k in range(first, first + per_round):
                arguments = inputs(k)
                before = time.perf_counter()
                result = tick(*arguments)
                times.append((1e3 * (time.perf_counter() - before), result.stats))
    return samples


def _scene_inputs(scene, dt):
    """Return the inputs of World.step at tick k: the scene's poses at k·dt and its sizes."""
    return lambda k: (scene.dynamic_poses(k * dt), scene.dynamic_half_extents)


def _moved_statics(scene, rows, amplitude, k):
    """Return the scene's static poses with ``rows`` moved along x at tick k (a sine each)."""
    poses = scene.static_poses.copy()
    poses[rows, 0] += amplitude * np.sin(0.3 * k + rows)
    return poses


def _move_static_and_step(world):
    """Return a tick that moves ``world``'s static boxes, then steps it."""
    def tick(static_poses, poses, half_extents):
        world.move_static(np.arange(len(static_poses)), static_poses)
        return world.step(poses, half_extents)
    return tick


def reproduce_command(args):
    """Return the command line that reproduces this run's numbers."""
    words = ['collision_bench']
    if args.plan != 'full':
        words.append('--' + args.plan)
    words += ['--seed', str(args.seed), '--output', args.output]
    if args.only:
        words += ['--only', ','.join(args.only)]
    return ' '.join(shlex.quote(word) for word in words)


def machine():
    """Describe the machine and software the numbers were measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open('/proc/cpuinfo') as cpuinfo:
            cpu = next(line.split(':', 1)[1].strip() for line in cpuinfo
                       if line.startswith('model name'))
    except (OSError, StopIteration):
        pass
    versions = {'python': platform.python_version(), 'numpy': np.__version__}
    import numba
    versions['numba'] = numba.__version__
    try:
        from fcl.version import __version__ as fcl_version
        versions['python-fcl'] = fcl_version
    except ImportError:
        versions['python-fcl'] = None
    for name in ('coal', 'mujoco', 'pin', 'example-robot-data'):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    try:
        here = os.path.dirname(os.path.abspath(__file__))
        commit = subprocess.run(['git', 'describe', '--always', '--dirty'], cwd=here,
                                capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ''
    return {'cpu': cpu, 'cores': os.cpu_count(), 'versions': versions,
            'commit': commit or None, 'date': time.strftime('%Y-%m-%d %H:%M:%S UTC',
                                                            time.gmtime())}


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog='collision_bench', description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter)
    size = parser.add_mutually_exclusive_group()
    size.add_argument('--quick', dest='plan', action='store_const', const='quick',
                      default='full', help='a subset of every section, under 2 minutes')
    size.add_argument('--tiny', dest='plan', action='store_const', const='tiny',
                      help='every section on small scenes, for tests (seconds)')
    parser.add_argument('--output', default='bench_results',
                        help='directory for results.json, results.md, time_vs_error.png')
    parser.add_argument('--seed', type=int, default=0, help='scene seed (default 0)')
    parser.add_argument('--only', type=lambda text: text.split(','), default=None,
                        help='comma-separated sections to run: %s' % ','.join(SECTIONS))
    args = parser.parse_args(argv)
    unknown = set(args.only or ()) - set(SECTIONS)
    if unknown:
        parser.error('unknown section(s) %s; choose from %s'
                     % (', '.join(sorted(unknown)), ', '.join(SECTIONS)))
    return args


def main(argv=None):
    """Run the benchmark; return 0, or 1 when a run failed (its error is in the report)."""
    args = parse_args(argv)
    plan = PLANS[args.plan]
    progress = Progress()
    command = reproduce_command(args)
    progress('collision_bench (%s plan); reproduce with: %s' % (args.plan, command))
    # Compile (or load from numba's cache) every kernel first: a cold compile inside a timed
    # tick would count as that phase's time and could get the phase skipped as too slow.
    warm_up()
    progress('kernels ready')
    bench = Bench(plan, args.seed, progress)
    results = {'meta': dict(machine(), plan=args.plan, plan_settings=plan._asdict(),
                            seed=args.seed, command=command, broad_phases=list(NAMES),
                            default_phase=DEFAULT_PHASE)}
    started = time.perf_counter()
    for section in args.only or SECTIONS:
        progress('section %s' % section)
        results[section] = bench.results[section] = getattr(bench, section)()
    results['meta']['seconds'] = time.perf_counter() - started
    results['meta']['errors'] = bench.errors
    paths = report.write(args.output, results)
    progress('wrote %s' % ', '.join(paths))
    print('Every number above comes from: %s' % command)
    return 1 if bench.errors else 0


if __name__ == '__main__':
    sys.exit(main())
