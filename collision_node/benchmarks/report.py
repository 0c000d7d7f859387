"""results.json, results.md and time_vs_error.png from the rows the benchmark collected."""
import json
import math
import os

from collision_node.benchmarks import robot, robot_model
from collision_node.benchmarks.stages import SETTLE_TICKS

# The performance targets, in the order doc/benchmarks.md lists them.
FCL_TARGET_BODIES = 20000
FCL_TARGET_RATIO = 40.0
TICK_TARGETS_MS = ((10000, 2.0), (100000, 30.0))   # uniform scene, bodies: median ms
STATIC_MOVES_BODIES = 10000  # 10 of 5,000 statics moved per tick, and all of them
STATIC_MOVES_MAX_RATIO = 1.1   # × the tick with none moved
STATIC_MOVES_ALL_MAX_RATIO = 1.0  # × the tick with all of them dynamic
SEED_SCENE_BODIES = 1024
SEED_SCENE_TARGET_TPS = 1000.0
ROBOT_STEP_MAX_VS_MUJOCO = 0.7    # the arm, one World.step per state: x MuJoCo's time per state
ROBOT_BATCH_MAX_VS_MUJOCO = 0.15  # World.check_states, per state
ROBOT_BATCH_STATES = 4000         # ... with this many states per call
PANDA_ONE_MAX_VS_MUJOCO = 0.7     # the Panda, check_joints one state per call, FK included
PANDA_BATCH_MAX_VS_MUJOCO = 0.1   # ... K states per call, per state
PANDA_BATCH_STATES = 4000         # ... with this many states per call
PANDA_TRAJECTORY_MAX_RATIO = 3.0  # check_trajectory: x check_joints on its waypoints alone
PANDA_WAYPOINTS = 100


def write(directory, results):
    """Write the three files into ``directory`` (created if needed); return their paths."""
    os.makedirs(directory, exist_ok=True)
    results = dict(results, targets=targets(results))
    paths = [os.path.join(directory, 'results.json'), os.path.join(directory, 'results.md')]
    with open(paths[0], 'w') as out:
        json.dump(results, out, indent=1, default=_plain)
    plot_note = plot_time_vs_error(results.get('accuracy', []),
                                   os.path.join(directory, 'time_vs_error.png'))
    if plot_note is None:
        paths.append(os.path.join(directory, 'time_vs_error.png'))
    with open(paths[1], 'w') as out:
        out.write(markdown(results, plot_note))
    return paths


def _plain(value):
    """Turn numpy scalars and arrays into plain JSON values."""
    if hasattr(value, 'tolist'):
        return value.tolist()
    raise TypeError('cannot store %r in JSON' % (value,))


# --- targets -----------------------------------------------------------------------------


def targets(results):
    """Each performance target: what was measured (default phase, and the best phase), pass/fail.

    ``passed`` is None when this run did not measure the target.
    """
    default = results['meta']['default_phase']
    found = []

    fcl_rows = [row for row in results.get('fcl', [])
                if row.get('bodies') == FCL_TARGET_BODIES and 'broad_phase' in row]
    found.append(_target(
        '%d bodies (uniform, half static): >= %gx python-fcl, identical pairs'
        % (FCL_TARGET_BODIES, FCL_TARGET_RATIO), fcl_rows, default,
        value=lambda row: row['ratio'], better=max,
        passes=lambda row: (row['ratio'] >= FCL_TARGET_RATIO
                            and row['only_ours'] + row['only_fcl'] == 0),
        describe=lambda row: '%.1fx (%.3g ms vs python-fcl %.3g ms), %d pair mismatches' % (
            row['ratio'], row['median_ms'], row['fcl_median_ms'],
            row['only_ours'] + row['only_fcl'])))

    for bodies, limit_ms in TICK_TARGETS_MS:
        rows = [row for row in results.get('scenes', [])
                if row.get('scene') == 'uniform' and row.get('bodies') == bodies]
        found.append(_target(
            '%d bodies (uniform, half static): <= %g ms per tick (median)' % (bodies, limit_ms),
            rows, default, value=lambda row: -row['median_ms'], better=max,
            passes=lambda row, limit_ms=limit_ms: row['median_ms'] <= limit_ms,
            describe=lambda row: '%.3g ms median, %.3g ms p99' % (row['median_ms'],
                                                                  row['p99_ms'])))

    rows = [row for row in results.get('paper001', [])
            if row.get('bodies') == SEED_SCENE_BODIES]
    found.append(_target(
        'seed scene, %d bodies flying out: >= %g ticks/s'
        % (SEED_SCENE_BODIES, SEED_SCENE_TARGET_TPS),
        rows, default, value=lambda row: row['average_tps'], better=max,
        passes=lambda row: row['average_tps'] >= SEED_SCENE_TARGET_TPS,
        describe=lambda row: '%.0f ticks/s average (slowest tick %.0f ticks/s)' % (
            row['average_tps'], row['slowest_tps'])))

    moves = {row['configuration']: row for row in results.get('static_moves', [])
             if row.get('bodies') == STATIC_MOVES_BODIES}
    for what, configuration, key, limit in (
            ('moving 10 of 5,000 statics per tick: <= %g x the tick with none moved'
             % STATIC_MOVES_MAX_RATIO, '10 statics moved (others each tick)', 'vs_still',
             STATIC_MOVES_MAX_RATIO),
            ('moving all 5,000 statics per tick: <= %g x the same bodies all dynamic'
             % STATIC_MOVES_ALL_MAX_RATIO, 'all statics moved', 'vs_dynamic',
             STATIC_MOVES_ALL_MAX_RATIO)):
        row = moves.get(configuration)
        found.append({'target': what, 'measured': 'not measured in this run', 'passed': None}
                     if row is None else
                     {'target': what, 'phase': row['broad_phase'], 'passed': row[key] <= limit,
                      'measured': '%.3g x (%.3g ms)' % (row[key], row['median_ms'])})

    found += robot_targets(results.get('robot'))
    found += robot_model_targets(results.get('robot_model'))

    for what in ('PoseArray in -> collisions out through ROS, 10,000 bodies: <= 5 ms median',
                 'JIT: nothing compiles during a tick; node ready <= 5 s with a warm cache',
                 '100,000 dynamic sizes + 10,000 statics loaded: node ready <= 5 s (warm)'):
        found.append({'target': what, 'measured': 'not measured by collision_bench '
                      '(needs the ROS node; see its own benchmark)', 'passed': None})
    return found


def robot_targets(rows):
    """Judge the arm's two targets, each against the MuJoCo row the ratios use (robot.py).

    Not measured (``passed`` None) when the section did not run, MuJoCo or our method did
    not, or the batch had another K than the target's.
    """
    targets = [
        ('arm (config/arm.yaml), one World.step per state: <= %g x MuJoCo per state'
         % ROBOT_STEP_MAX_VS_MUJOCO, robot.OURS_STEP, ROBOT_STEP_MAX_VS_MUJOCO, 1),
        ('arm, World.check_states with K = {:,} states per call: <= {:g} x MuJoCo per state, '
         'per state'.format(ROBOT_BATCH_STATES, ROBOT_BATCH_MAX_VS_MUJOCO), robot.OURS_BATCH,
         ROBOT_BATCH_MAX_VS_MUJOCO, ROBOT_BATCH_STATES)]
    if rows is None:
        return [{'target': what, 'measured': 'not measured in this run', 'passed': None}
                for what, _, _, _ in targets]
    by_method = {row.get('method'): row for row in rows}
    reference = next((row for row in rows if row.get('mujoco_reference')), None)
    found = []
    for what, method, limit, states_per_call in targets:
        ours = by_method.get(method, {'skipped': 'not run'})
        if reference is None:
            why = '; '.join(sorted({by_method[name].get('skipped') or by_method[name].get(
                'error', 'not run') for name in (robot.MUJOCO_MESH, robot.MUJOCO_BOX)
                if name in by_method})) or 'MuJoCo not run'
            measured = 'not measured: %s' % why
        elif 'per_state_us' not in ours:
            measured = 'not measured: %s' % (ours.get('skipped') or ours.get('error'))
        elif ours['states_per_call'] != states_per_call:
            measured = 'not measured in this run (%d states per call)' % ours[
                'states_per_call']
        else:
            ratio = ours['per_state_us'] / reference['per_state_us']
            measured = '%.3gx: %.3g us per state against %s %.3g us%s' % (
                ratio, ours['per_state_us'], reference['method'], reference['per_state_us'],
                ' (its answers differ)' if reference.get('mujoco_answers_differ') else '')
            for other in rows:  # a quicker MuJoCo whose answers differ: its ratio too
                if (other.get('method') in (robot.MUJOCO_MESH, robot.MUJOCO_BOX)
                        and other.get('per_state_us', math.inf) < reference['per_state_us']):
                    measured += '; %.3gx against %s %.3g us (different pairs)' % (
                        ours['per_state_us'] / other['per_state_us'], other['method'],
                        other['per_state_us'])
            found.append({'target': what, 'passed': bool(ratio <= limit), 'measured': measured})
            continue
        found.append({'target': what, 'measured': measured, 'passed': None})
    return found


def robot_model_targets(rows):
    """Judge the Panda's targets (robot_model.py); ``passed`` None when not measured.

    The per-state targets divide by the MuJoCo row the ratios use (MuJoCo on one thread, also
    against ours on every core, as its line says); the trajectory target divides
    check_trajectory's median call by check_joints' on the same waypoints.
    """
    states = [
        ('Panda, one joint state per call (World.check_joints), FK included: <= %g x MuJoCo '
         'per state' % PANDA_ONE_MAX_VS_MUJOCO, robot_model.OURS_JOINTS,
         PANDA_ONE_MAX_VS_MUJOCO, 1),
        ('Panda, K = {:,} joint states per call (World.check_joints): <= {:g} x MuJoCo per '
         'state, per state'.format(PANDA_BATCH_STATES, PANDA_BATCH_MAX_VS_MUJOCO),
         robot_model.OURS_BATCH, PANDA_BATCH_MAX_VS_MUJOCO, PANDA_BATCH_STATES),
        ('Panda, K = {:,} joint states per call (World.check_joints), a thread a core: <= {:g} '
         'x MuJoCo per state (one thread), per state'.format(
             PANDA_BATCH_STATES, PANDA_BATCH_MAX_VS_MUJOCO),
         robot_model.OURS_EVERY_CORE, PANDA_BATCH_MAX_VS_MUJOCO, PANDA_BATCH_STATES)]
    trajectory = ('Panda, a %d-waypoint collision-free trajectory (World.check_trajectory), '
                  'segments included: <= %g x the time of its %d waypoints alone'
                  % (PANDA_WAYPOINTS, PANDA_TRAJECTORY_MAX_RATIO, PANDA_WAYPOINTS))
    if rows is None:
        return [{'target': what, 'measured': 'not measured in this run', 'passed': None}
                for what in [target[0] for target in states] + [trajectory]]
    by_method = {row.get('method'): row for row in rows}
    reference = next((row for row in rows if row.get('mujoco_reference')), None)
    found = []
    for what, method, limit, states_per_call in states:
        ours = by_method.get(method, {'skipped': 'not run'})
        if 'per_state_us' not in ours:
            measured = 'not measured: %s' % (ours.get('skipped') or ours.get('error'))
        elif reference is None:
            measured = 'not measured: %s' % ('; '.join(sorted({
                by_method[name].get('skipped') or by_method[name].get('error', 'not run')
                for name in (robot.MUJOCO_MESH, robot.MUJOCO_BOX) if name in by_method}))
                or 'MuJoCo not run')
        elif ours['states_per_call'] != states_per_call:
            measured = 'not measured in this run (%d states per call)' % ours[
                'states_per_call']
        else:
            ratio = ours['per_state_us'] / reference['per_state_us']
            found.append({'target': what, 'passed': bool(ratio <= limit and ours[
                'same_answers']), 'measured': '%.3gx: %.3g us per state against %s %.3g us, '
                '%s' % (ratio, ours['per_state_us'], reference['method'],
                        reference['per_state_us'], robot.answers_text(ours))})
            continue
        found.append({'target': what, 'measured': measured, 'passed': None})
    path, alone = (by_method.get(robot_model.TRAJECTORY, {}),
                   by_method.get(robot_model.WAYPOINTS, {}))
    if 'per_call_ms' in path and 'per_call_ms' in alone and path['waypoints'] == \
            PANDA_WAYPOINTS:
        found.append({'target': trajectory, 'passed': bool(
            path['vs_waypoints'] <= PANDA_TRAJECTORY_MAX_RATIO), 'measured': (
            '%.3gx: %.3g ms against %.3g ms' % (path['vs_waypoints'], path['per_call_ms'],
                                                alone['per_call_ms']))})
    else:
        found.append({'target': trajectory, 'passed': None, 'measured': 'not measured: %s' % (
            path.get('skipped') or path.get('error') or by_method.get(
                robot_model.OURS_JOINTS, {}).get('skipped') or 'not run')})
    return found


def _target(what, rows, default, value, better, passes, describe):
    """Judge the default phase's row, and the best measured phase's.

    A run skipped as hopeless fails: the skip threshold (``max_tick_s``) lies far beyond
    every target, even for a phase that scales linearly from the size it was judged on.
    """
    by_phase = {row['broad_phase']: row for row in rows}
    if default not in by_phase or 'error' in by_phase[default]:
        return {'target': what, 'measured': 'not measured in this run', 'passed': None}
    row = by_phase[default]
    judged = {'target': what, 'phase': default}
    if 'skipped' in row:
        judged.update(measured='not run, ' + row['skipped'], passed=False)
    else:
        judged.update(measured=describe(row), passed=bool(passes(row)))
    measured = [row for row in by_phase.values() if 'skipped' not in row and 'error' not in row]
    if measured:
        best = better(measured, key=value)
        judged.update(best_phase=best['broad_phase'], best_measured=describe(best),
                      best_passed=bool(passes(best)))
    return judged


# --- markdown ----------------------------------------------------------------------------


def _number(value, digits=3):
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ''
    if isinstance(value, bool):
        return 'yes' if value else 'no'
    if isinstance(value, int):
        return '{:,}'.format(value)
    if isinstance(value, float):
        if value >= 10 ** digits:
            return '{:,.0f}'.format(value)
        return '%.*g' % (digits, value)
    return str(value)


def table(columns, rows):
    """Format a markdown table; ``columns`` are (header, function of the row)."""
    lines = ['| ' + ' | '.join(header for header, _ in columns) + ' |',
             '|' + '|'.join('---' for _ in columns) + '|']
    for row in rows:
        cells = []
        for _, cell in columns:
            try:
                cells.append(_number(cell(row)))
            except KeyError:  # a skipped or failed run: no numbers
                cells.append(None)
        if None in cells:
            # Say why in the first empty cell, after the columns that name the run.
            cells[cells.index(None)] = row.get('skipped') or 'ERROR ' + row.get('error', '?')
        lines.append('| ' + ' | '.join(cell or '' for cell in cells) + ' |')
    return '\n'.join(lines)


def _get(key):
    return lambda row: row[key]


def _phase_label(row):
    """Name the broad phase, and what ``auto`` picked."""
    name = row['broad_phase']
    used = row.get('phases_used')
    if used and used != [name]:
        return '%s (ran %s)' % (name, ', '.join(used))
    return name


def _ticks(row):
    """Give the ticks run, and why the run stopped early if it did."""
    if row.get('stopped'):
        return '%d (%s)' % (row['ticks'], row['stopped'])
    return row['ticks']


TICK_COLUMNS = [
    ('ticks', _ticks),
    ('slowest ticks/s', _get('slowest_tps')),
    ('quickest ticks/s', _get('quickest_tps')),
    ('average ticks/s', _get('average_tps')),
    ('least compared', _get('compared_min')),
    ('most compared', _get('compared_max')),
    ('median ms', _get('median_ms')),
    ('p99 ms', _get('p99_ms')),
    ('colliding pairs (max)', _get('colliding_max')),
]


def markdown(results, plot_note):
    meta = results['meta']
    settings = meta['plan_settings']
    out = ['# collision_bench results', '',
           'Reproduce every number below with `%s` (run from the repository, `pip install '
           '-e .[bench]`).' % meta['command'], '',
           '- machine: %s, %s cores; %s' % (meta['cpu'], meta['cores'], ', '.join(
               '%s %s' % item for item in meta['versions'].items())),
           # The commit stays in results.json: the page describes the numbers, not a history.
           '- %s; plan `%s`, seed %d, %.0f s'
           % (meta['date'], meta['plan'], meta['seed'], meta['seconds']),
           '- broad phases: %s; the World default is `%s` with the sphere prefilter'
           % (', '.join(meta['broad_phases']), meta['default_phase']),
           '- a tick is one `World.step` (poses in, sorted contacts out) timed from outside; '
           'ticks/s = 1 / tick time: slowest = 1 / longest tick, quickest = 1 / shortest, '
           'average = ticks / total time. "compared" is `Result.stats["compared"]`, the pair '
           'comparisons the broad phase made (the papers\' "pairs compared").', '']
    if meta['errors']:
        out += ['**Errors** (their rows say ERROR):', ''] + [
            '- %s' % error for error in meta['errors']] + ['']

    out += ['## Targets', '',
            table([('target', _get('target')), ('default phase', lambda r: r.get('phase')),
                   ('measured', _get('measured')),
                   ('pass', lambda r: {True: 'PASS', False: 'FAIL', None: 'n/a'}[r['passed']]),
                   ('best phase', lambda r: r.get('best_phase')),
                   ('best measured', lambda r: r.get('best_measured')),
                   ('best pass', lambda r: {True: 'PASS', False: 'FAIL', None: ''}[
                       r.get('best_passed')])],
                  results['targets']), '']

    if 'paper001' in results:
        out += ['## "Discrete Collision Algorithms": bodies flying out from the origin (its '
                'Table 2, every broad phase)', '',
                'Cubes of half extent 0.5 m start packed around the origin and fly outward at '
                '1-3 m/s: dense first, sparse later; no static bodies. %d ticks of %.4g s '
                '(%.3g s simulated).' % (settings['flying_out_ticks'],
                                         settings['flying_out_dt'],
                                         settings['flying_out_ticks']
                                         * settings['flying_out_dt']), '',
                table([('broad phase', _phase_label), ('bodies', _get('bodies'))] + TICK_COLUMNS,
                      results['paper001']), '']
    if 'octree_depths' in results:
        out += ['## "Discrete Collision Algorithms": octree depth (its Table 1)', '',
                table([('octree depth', _get('depth')), ('bodies', _get('bodies'))]
                      + TICK_COLUMNS, results['octree_depths']), '']
    if 'paper000' in results:
        rows = results['paper000']
        baseline = rows[0].get('average_tps') if rows else None
        out += ['## "Engine Algorithms": 500 static + 500 dynamic boxes', '',
                'Baseline = the SAT on every dynamic-static and dynamic-dynamic pair, as in '
                'the paper; "sphere test" = bounding spheres, then the SAT; the octree at '
                'depth 4, as in the paper.', '',
                table([('method', _get('method'))] + TICK_COLUMNS + [
                    ('speed-up vs baseline (average)',
                     lambda row: (row['average_tps'] / baseline) if baseline else None),
                    ('SAT tests (max)', _get('sat_tests_max'))], rows), '']
    if 'scenes' in results:
        out += ['## Uniform and clustered scenes', '',
                'Half the bodies static; uniform: about one colliding pair per body; '
                'clustered: 90 % of the bodies in one corner cube of half the side.', '',
                table([('scene', _get('scene')), ('bodies', _get('bodies')),
                       ('broad phase', _phase_label)] + TICK_COLUMNS
                      + [('candidates (max)', _get('candidate_pairs_max'))],
                      results['scenes']), '']
    if 'accuracy' in results:
        out += ['## Run time against error', '',
                'Errors are pair-set differences against the float64 SAT on all pairs, summed '
                'over the ticks. Modes: "every compared pair (classic)" calls every pair the '
                'broad phase compared a collision (the classic octree of "Discrete Collision '
                'Algorithms": every pair sharing a leaf; counted as compared - true pairs); '
                '"broad phase only" every candidate pair it returns (ours already drop pairs '
                'whose AABBs are '
                'apart); "spheres only" / "AABBs only" the candidates whose bounding volumes '
                'overlap; "SAT float32 boxes" the SAT on the boxes rounded to float32; "SAT '
                'float64" the World as shipped. "compared", "true pairs" and the errors are sums '
                'over the ticks.', '',
                table([('scene', _get('scene')), ('bodies', _get('bodies')),
                       ('broad phase', _get('broad_phase')), ('mode', _get('mode')),
                       ('ticks', _ticks), ('compared', _get('compared')),
                       ('true pairs', _get('true_pairs')),
                       ('false positives', _get('false_positives')),
                       ('false negatives', _get('false_negatives')),
                       ('median ms', _get('median_ms')), ('p99 ms', _get('p99_ms'))],
                      results['accuracy']), '',
                plot_note or '![run time against error](time_vs_error.png)', '']
    if 'fcl' in results:
        out += ['## python-fcl side by side', '',
                'Uniform scene, half the bodies static. python-fcl: two '
                'DynamicAABBTreeCollisionManagers (static built once; dynamic transforms set '
                'from the same pose array each tick, then `update()`), `collide` with '
                'the `defaultCollisionCallback` of python-fcl; its time is update + collide. '
                'Mismatches: pairs only one side reports, summed over the ticks.', '',
                table([('bodies', _get('bodies')), ('broad phase', _get('broad_phase')),
                       ('ticks', _ticks), ('ours median ms', _get('median_ms')),
                       ('python-fcl median ms', _get('fcl_median_ms')),
                       ('fcl update ms', _get('fcl_update_ms')),
                       ('fcl collide ms', _get('fcl_collide_ms')),
                       ('python-fcl / ours', _get('ratio')),
                       ('pairs per tick', _get('pairs_per_tick')),
                       ('only ours', _get('only_ours')), ('only fcl', _get('only_fcl'))],
                      results['fcl']), '']
    if 'profile' in results:
        out += ['## Where a tick goes (median ms)', '',
                'The stages World.step reports (prepare = input checks + set_boxes, narrow = '
                'SAT + contact assembly, other = the rest of the call), then the same pipeline '
                'timed stage by stage from the public pieces, with the boxes in input order '
                '(the World keeps its rows in Z-order, which makes its SAT faster at 100,000 '
                'bodies than the SAT column here). Steady state: the ticks timed '
                'follow up to %d untimed ones ("settled").' % SETTLE_TICKS, '',
                table([('scene', _get('scene')), ('bodies', _get('bodies')),
                       ('broad phase', _phase_label), ('ticks', _ticks),
                       ('settled', _get('settling_ticks')), ('tick', _get('tick_ms')),
                       ('prepare', _get('prepare_ms')),
                       ('broad', _get('broad_ms')), ('narrow', _get('narrow_ms')),
                       ('other', _get('other_ms')), ('set_boxes', _get('set_boxes_ms')),
                       ('find_pairs', _get('find_pairs_ms')), ('SAT', _get('sat_ms')),
                       ('contacts', _get('contacts_ms'))],
                      results['profile']), '']
    if 'threads' in results:
        out += ['## Threads (the `threads` parameter; median ms per tick)', '',
                'The default phase on the uniform scene, half static, its World on 1 and 2 '
                'threads, ticks back to back. Through ROS, with idle time between inputs, '
                'see collision_latency --threads.', '',
                table([('bodies', _get('bodies')), ('threads', _get('threads')),
                       ('broad phase', _phase_label), ('ticks', _ticks),
                       ('median ms', _get('median_ms')), ('p99 ms', _get('p99_ms'))],
                      results['threads']), '']
    if 'margins' in results:
        out += ['## Margins and filters (median ms per tick)', '',
                'The uniform scene, half static, default phase: margins of 0, 2 % and 10 % of '
                'the mean box side (exact distance for the pairs within them), and margin 0 '
                'with half the dynamic pairs masked out (categories 1 and 2 in turn). The '
                'configurations take turns in rounds; counts are means per tick.', '',
                table([('bodies', _get('bodies')), ('configuration', _get('configuration')),
                       ('ticks', _get('ticks')), ('median ms', _get('median_ms')),
                       ('× margin 0', _get('vs_margin_0')),
                       ('reported', _get('reported_pairs')), ('near', _get('near_pairs')),
                       ('filtered', _get('filtered_pairs')), ('SAT tests', _get('sat_tests'))],
                      results['margins']), '']
    if 'continuous' in results:
        out += ['## Continuous checking (median ms per tick)', '',
                'The uniform scene, half static, default phase, its inputs 1/60 s apart (its '
                'usual speed) and 1/15 s apart; `continuous` off and on take turns in rounds '
                'on the same inputs; counts are means per tick.', '',
                table([('bodies', _get('bodies')), ('input Hz', _get('rate_hz')),
                       ('continuous', _get('continuous')), ('ticks', _get('ticks')),
                       ('median ms', _get('median_ms')), ('× off', _get('vs_off')),
                       ('candidates', _get('candidate_pairs')),
                       ('reported', _get('reported_pairs')),
                       ('touched only in between', _get('swept_pairs')),
                       ('advancement steps', _get('advance_steps')),
                       ('undecided', _get('unresolved_pairs'))],
                      results['continuous']), '']
    if 'static_moves' in results:
        out += ['## Static colliders that move (median ms per tick)', '',
                'The uniform scene, half static, default phase, its dynamic bodies moving: '
                'static colliders still, 10 moved per tick by World.move_static (the same 10, '
                'or 10 others each tick; by up to 2 cm, or 1 m: into other cells), all of them '
                'moved per tick, and all of them given as dynamic bodies instead. A tick is '
                'move_static and step. The configurations take turns in rounds.', '',
                table([('bodies', _get('bodies')), ('configuration', _get('configuration')),
                       ('ticks', _get('ticks')), ('median ms', _get('median_ms')),
                       ('× still', _get('vs_still')), ('× all dynamic', _get('vs_dynamic')),
                       ('colliding', _get('colliding_pairs')), ('phase', _get('broad_phase'))],
                      results['static_moves']), '']
    if 'robot' in results:
        out += _robot_markdown(results['robot'], settings)
    if 'robot_model' in results:
        out += _robot_model_markdown(results['robot_model'], settings)
    return '\n'.join(out)


def _robot_answers(row):
    """Say how a timed row's answers compare with ours (KeyError for a row not timed)."""
    row['per_state_us']
    return robot.answers_text(row)


def _robot_markdown(rows, settings):
    """Return the robot section's lines: the arm of config/arm.yaml, ours and its peers."""
    return [
        '## Robot arm: ours against python-fcl, coal and MuJoCo (µs per state)', '',
        'The arm of config/arm.yaml: 7 box links over 3 static boxes (floor, table, shelf), '
        'adjacent links and base-floor ignored, {} allowed pairs, each reported when it '
        'collides or lies within its margin (0.05 m; 0.10 m from the shelf). States over one '
        "period of the arm's trajectory: {:,} per round one per call, and {:,} in one "
        '`World.check_states` call; {} rounds, the methods taking turns, each round on states '
        'a little later. Per state: the median call (one per call) or the call / K. Each '
        'method gets its input in its own form, prepared outside the clock. Same answers: '
        "every state's set of pairs against ours; a differing pair within {:g} m of its "
        'margin would be a boundary case. python-fcl, coal and MuJoCo are benchmark-only '
        'dependencies (the `bench` extra); one not installed is skipped.'.format(
            len(robot.allowed_pairs()), settings['robot_states'],
            settings['robot_batch_states'], settings['robot_rounds'], robot.BOUNDARY_M), '',
        table([('method', _get('method')), ('states per call', _get('states_per_call')),
               ('states', _get('states')), ('µs per state', _get('per_state_us')),
               ('mean µs', _get('mean_us')), ('× MuJoCo', _get('vs_mujoco')),
               ('pairs per state', _get('pairs_per_state')),
               ('same answers', _robot_answers)], rows), '',
        '× MuJoCo divides by the row marked MuJoCo reference below: the quickest MuJoCo '
        'configuration whose answers agree with ours.', ''] + [
        '- %s%s: %s' % (row['method'], ' (MuJoCo reference)' if row.get('mujoco_reference')
                        else '', row['setup']) for row in rows if 'setup' in row] + ['']


def _robot_model_markdown(rows, settings):
    """Return the robot_model section's lines: the Panda from its URDF, ours and its peers."""
    states = [row for row in rows if row.get('kind', 'state') == 'state']
    paths = [row for row in rows if row.get('kind') == 'trajectory']
    alarms = [row for row in rows if row.get('kind') == 'false_alarms']
    panda = next((row for row in states if 'boxes' in row), {})
    lines = [
        '## Panda from its URDF: ours against MuJoCo and pinocchio + coal (µs per state)', '',
        "The Panda of example-robot-data (URDF and SRDF, its meshes as boxes: {} boxes, {} "
        'joints, the second finger a mimic) over a table under its base, a wall and a shelf '
        'within reach; same-link, adjacent and SRDF pairs skipped ({} box pairs left, and '
        'every robot-static pair). Random joint states '
        'within the limits (seeded): {:,} per round one per call, and {:,} in one '
        '`World.check_joints` call; {} rounds, the methods taking turns, each round on new '
        'states. Every method is given q and places the boxes itself (forward kinematics '
        "inside the clock). Same answers: every state's set of colliding pairs against "
        "ours.".format(panda.get('boxes', '?'), panda.get('dof', '?'),
                       panda.get('allowed_pairs', '?'), settings['panda_states'],
                       settings['panda_batch_states'], settings['panda_rounds']), '',
        table([('method', _get('method')), ('states per call', _get('states_per_call')),
               ('states', _get('states')), ('µs per state', _get('per_state_us')),
               ('mean µs', _get('mean_us')), ('× MuJoCo', _get('vs_mujoco')),
               ('share of states colliding', _get('colliding_states')),
               ('pairs per state', _get('pairs_per_state')),
               ('same answers', _robot_answers)], states), '',
        '× MuJoCo divides by the row marked MuJoCo reference below: the quickest MuJoCo '
        'configuration whose answers agree with ours.', ''] + [
        '- %s%s: %s' % (row['method'], ' (MuJoCo reference)' if row.get('mujoco_reference')
                        else '', row['setup']) for row in states if 'setup' in row]
    for row in states:
        if 'placement_error' in row:
            lines.append("- pinocchio's box placements against our forward kinematics, 20 "
                         'random states: largest difference %.2g (m, and rotation matrix '
                         'entries)' % row['placement_error'])
    lines += ['', 'The trajectory: a smooth path of {} waypoints (two sines per joint, the '
              'first of random paths whose {} states a segment are all free), '
              '`World.check_trajectory(waypoints)` (waypoints exactly, segments '
              'conservatively) against `World.check_joints(waypoints)` alone, {} calls '
              'each a round in the same rounds, the two taking turns call by call (the '
              'first going first in alternate rounds). False alarms: on random short '
              'segments (each joint moved by up to {:g} rad, a finger by up to {:g} m), the '
              '(segment, pair) '
              'reports of a two-waypoint `check_trajectory` that a referee checking {} states '
              'of the segment finds never colliding.'.format(
                  robot_model.TRAJECTORY_WAYPOINTS, robot_model.SAMPLES_PER_SEGMENT,
                  robot_model.TRAJECTORY_REPEATS, robot_model.SHORT_SEGMENT_RAD,
                  robot_model.SHORT_SEGMENT_M, robot_model.REFEREE_SAMPLES), '',
              table([('check', _get('method')), ('waypoints', _get('waypoints')),
                     ('calls', _get('calls')), ('median ms per call', _get('per_call_ms')),
                     ('mean ms', _get('mean_ms')),
                     ('× the waypoints alone', _get('vs_waypoints')),
                     ('pairs reported', _get('reported_pairs'))], paths), '']
    lines += ['- %s' % robot_model.false_alarm_text(row) for row in alarms
              if 'reports' in row]
    return lines + ['']


# --- plot --------------------------------------------------------------------------------


def plot_time_vs_error(rows, path):
    """Median tick time against errors per tick, one panel per scene; None, or why not."""
    rows = [row for row in rows if 'false_positives' in row]
    if not rows:
        return 'No accuracy rows in this run: no time_vs_error.png.'
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        from matplotlib import ticker
    except ImportError:
        return ('matplotlib is not installed (pip install matplotlib, the "bench" extra): '
                'no time_vs_error.png.')
    panels = sorted({(row['scene'], row['bodies']) for row in rows})
    modes = list(dict.fromkeys(row['mode'] for row in rows))
    phases = list(dict.fromkeys(row['broad_phase'] for row in rows))
    markers = 'osD^v<>phX*'
    colours = plt.get_cmap('tab10')
    columns = min(3, len(panels))
    lines = math.ceil(len(panels) / columns)
    figure, axes = plt.subplots(lines, columns, figsize=(5 * columns, 4 * lines),
                                squeeze=False)
    for ax, (scene, bodies) in zip(axes.flat, panels):
        most = 1.0
        for row in rows:
            if (row['scene'], row['bodies']) != (scene, bodies):
                continue
            errors = (row['false_positives'] + row['false_negatives']) / row['ticks']
            most = max(most, errors)
            ax.scatter(row['median_ms'], errors, color=colours(modes.index(row['mode'])),
                       marker=markers[phases.index(row['broad_phase']) % len(markers)])
        ax.set_xscale('log')
        ax.xaxis.set_major_formatter(ticker.FormatStrFormatter('%g'))
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_yscale('symlog', linthresh=1.0)  # 0 errors stays on the plot
        ax.set_ylim(-0.3, 3.0 * most)
        ax.set_title('%s, %d bodies' % (scene, bodies))
        ax.set_xlabel('median tick time (ms)')
        ax.set_ylabel('wrong pairs per tick (FP + FN)')
        ax.grid(True, which='both', alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis('off')
    handles = [plt.Line2D([], [], color=colours(i), marker='o', linestyle='', label=mode)
               for i, mode in enumerate(modes)]
    handles += [plt.Line2D([], [], color='grey', marker=markers[i % len(markers)],
                           linestyle='', label=phase) for i, phase in enumerate(phases)]
    figure.legend(handles=handles, loc='lower center', ncol=min(6, len(handles)))
    figure.tight_layout(rect=(0, 0.08, 1, 1))
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return None
