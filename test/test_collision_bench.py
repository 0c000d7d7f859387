"""collision_bench on its tiny plan: the files, their columns, and properties that must hold."""
import itertools
import json
import pathlib
import sys

import numpy as np
import pytest
from rclpy.parameter import parameter_dict_from_yaml_file, parameter_value_to_python

from collision_node.benchmarks import collision_bench as bench
from collision_node.benchmarks import report, robot, robot_model
from collision_node.benchmarks.accuracy import (
    AABBS_ONLY, BROAD_ONLY, CLASSIC, contact_keys, MODES, pair_errors, pair_keys, row_keys,
    SAT_FLOAT32, SAT_FLOAT64, SPHERES_ONLY)
from collision_node.benchmarks.runs import all_pairs
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.scenes import make_scene
from collision_node.pipeline.world import CONTACT_DTYPE, DYNAMIC, Result, STATIC, World

REPO = pathlib.Path(__file__).resolve().parent.parent


@pytest.fixture(scope='module')
def tiny_run(tmp_path_factory):
    output = tmp_path_factory.mktemp('bench')
    status = bench.main(['--tiny', '--output', str(output)])
    with open(output / 'results.json') as results:
        return status, output, json.load(results)


def test_tiny_run_succeeds_and_names_its_command(tiny_run):
    status, output, results = tiny_run
    assert status == 0, results['meta']['errors']
    assert results['meta']['errors'] == []
    assert results['meta']['command'] == 'collision_bench --tiny --seed 0 --output %s' % output
    assert results['meta']['command'] in (output / 'results.md').read_text()


def test_writes_the_report_files(tiny_run):
    _, output, _ = tiny_run
    markdown = (output / 'results.md').read_text()
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        assert 'matplotlib is not installed' in markdown
    else:
        assert (output / 'time_vs_error.png').stat().st_size > 0
        assert '![run time against error](time_vs_error.png)' in markdown


def _header_of_table_after(markdown, heading):
    lines = markdown[markdown.index(heading):].splitlines()
    return next(line for line in lines if line.startswith('| '))


def test_markdown_tables_have_the_named_columns(tiny_run):
    _, output, _ = tiny_run
    markdown = (output / 'results.md').read_text()
    accuracy = [cell.strip() for cell in
                _header_of_table_after(markdown, '## Run time against error').split('|')]
    for column in ('broad phase', 'mode', 'compared', 'false positives', 'false negatives',
                   'median ms', 'p99 ms'):
        assert column in accuracy
    paper = _header_of_table_after(markdown, '## "Discrete Collision Algorithms"')
    for column in ('slowest ticks/s', 'quickest ticks/s', 'average ticks/s', 'least compared',
                   'most compared'):
        assert column in paper
    for heading in ('## Targets', '## "Engine Algorithms"', '## python-fcl side by side',
                    '## Where a tick goes', '## Threads', '## Margins and filters'):
        assert heading in markdown


def test_the_committed_results_page_is_the_generators_page(tiny_run):
    """doc/benchmark_results.md is results.md of a run: the same sections, no commit named."""
    _, output, _ = tiny_run

    def headings(text):
        return [line for line in text.splitlines() if line.startswith('#')]
    committed = (REPO / 'doc' / 'benchmark_results.md').read_text()
    assert headings(committed) == headings((output / 'results.md').read_text())
    assert 'commit' not in committed.split('\n## ')[0]


def test_threads_section_finds_the_same_contacts_with_each_thread_count(tiny_run):
    _, _, results = tiny_run
    rows = results['threads']
    assert [row['threads'] for row in rows] == list(bench.THREAD_COUNTS)
    assert all('median_ms' in row for row in rows)
    assert len({(row['colliding_min'], row['colliding_max']) for row in rows}) == 1


def test_margins_section_reports_more_pairs_for_larger_margins(tiny_run):
    _, _, results = tiny_run
    rows = results['margins']
    assert [row['configuration'] for row in rows] == [
        'margin 0 %', 'margin 2 %', 'margin 10 %', 'half masked']
    plain, small, large, masked = rows
    assert plain['near_pairs'] == masked['near_pairs'] == 0 < small['near_pairs']
    assert small['near_pairs'] < large['near_pairs']
    # A margin adds near pairs and keeps the colliding ones; masks only remove pairs.
    assert plain['reported_pairs'] < small['reported_pairs'] < large['reported_pairs']
    assert masked['filtered_pairs'] > 0 and masked['reported_pairs'] < plain['reported_pairs']
    assert plain['vs_margin_0'] == 1.0


def test_continuous_section_times_off_and_on(tiny_run):
    _, _, results = tiny_run
    rows = results['continuous']
    assert [(row['rate_hz'], row['continuous']) for row in rows] == [
        (60.0, False), (60.0, True), (15.0, False), (15.0, True)]
    for off, on in (rows[:2], rows[2:]):
        assert off['vs_off'] == 1.0 and on['vs_off'] > 0.0
        assert off['swept_pairs'] == off['advance_steps'] == 0 < on['advance_steps']
        assert on['reported_pairs'] >= off['reported_pairs'] and on['unresolved_pairs'] == 0
    assert rows[3]['swept_pairs'] > 0  # 4x the motion: pairs that touch only in between


def test_every_broad_phase_runs_in_every_mode(tiny_run):
    _, _, results = tiny_run
    scenes = {(row['scene'], row['bodies']) for row in results['accuracy']}
    for scene in scenes:
        measured = {(row['broad_phase'], row['mode']) for row in results['accuracy']
                    if (row['scene'], row['bodies']) == scene}
        assert measured == set(itertools.product(NAMES, MODES))


def test_sat_float64_matches_ground_truth_exactly(tiny_run):
    _, _, results = tiny_run
    rows = [row for row in results['accuracy'] if row['mode'] == SAT_FLOAT64]
    assert rows
    for row in rows:
        assert (row['false_positives'], row['false_negatives']) == (0, 0), row


def test_bounding_volume_modes_never_miss_a_collision(tiny_run):
    _, _, results = tiny_run
    by_key = {(row['scene'], row['bodies'], row['broad_phase'], row['mode']): row
              for row in results['accuracy']}
    for (scene, bodies, phase, mode), row in by_key.items():
        if mode in (CLASSIC, BROAD_ONLY, SPHERES_ONLY, AABBS_ONLY):
            assert row['false_negatives'] == 0, row
            assert row['false_positives'] >= 0
        if mode == BROAD_ONLY:
            # The candidates are some of the compared pairs.
            classic = by_key[(scene, bodies, phase, CLASSIC)]
            assert row['false_positives'] <= classic['false_positives']
        if mode in (SPHERES_ONLY, AABBS_ONLY):
            # A filter on the broad phase's candidates can only drop pairs.
            broad = by_key[(scene, bodies, phase, BROAD_ONLY)]
            assert row['false_positives'] <= broad['false_positives']
        if mode == SAT_FLOAT32:
            assert row['false_positives'] >= 0 and row['false_negatives'] >= 0
    # The scenes do have near misses: bounding volumes alone report pairs that do not touch.
    assert any(row['false_positives'] > 0 for row in results['accuracy']
               if row['mode'] == BROAD_ONLY)


def test_brute_force_compares_every_pair(tiny_run):
    _, _, results = tiny_run
    for row in results['paper001']:
        if row['broad_phase'] == 'brute_force':
            n = row['bodies']  # flying out: every body is dynamic
            assert row['compared_min'] == row['compared_max'] == n * (n - 1) // 2
    baseline = results['paper000'][0]
    dynamic = results['meta']['plan_settings']['paper000_bodies'] // 2
    static = results['meta']['plan_settings']['paper000_bodies'] - dynamic
    assert baseline['compared_max'] == dynamic * static + dynamic * (dynamic - 1) // 2


def test_compared_sums_every_pair_for_brute_force(tiny_run):
    _, _, results = tiny_run
    rows = [row for row in results['accuracy'] if row['broad_phase'] == 'brute_force']
    assert rows
    for row in rows:
        scene = make_scene(row['scene'], row['bodies'])
        static, dynamic = len(scene.static_poses), scene.dynamic_count
        per_tick = dynamic * static + dynamic * (dynamic - 1) // 2
        assert row['compared'] == row['ticks'] * per_tick
        if row['mode'] == CLASSIC:  # every pair compared, minus the true ones
            assert row['false_positives'] == row['compared'] - row['true_pairs']


def test_ticks_per_second_are_ordered(tiny_run):
    _, _, results = tiny_run
    rows = [row for section in ('paper001', 'paper000', 'scenes') for row in results[section]
            if 'average_tps' in row]
    assert rows
    for row in rows:
        assert row['slowest_tps'] <= row['average_tps'] <= row['quickest_tps']
        assert row['compared_min'] <= row['compared_max']


def test_python_fcl_finds_the_same_pairs(tiny_run):
    _, _, results = tiny_run
    rows = [row for row in results['fcl'] if 'ratio' in row]
    assert {row['broad_phase'] for row in rows} == set(NAMES)
    for row in rows:
        assert row['pairs_per_tick'] > 0
        assert (row['only_ours'], row['only_fcl']) == (0, 0), row


def test_every_target_is_listed(tiny_run):
    _, _, results = tiny_run
    assert len(results['targets']) == 15
    for target in results['targets']:
        assert target['passed'] in (True, False, None)


def test_unknown_section_is_refused(capsys):
    with pytest.raises(SystemExit):
        bench.main(['--tiny', '--only', 'paper001,nonsense'])
    assert 'nonsense' in capsys.readouterr().err


def test_all_pairs_lists_each_pair_with_a_dynamic_body_once():
    n_static, n_dynamic = 3, 4
    expected = {frozenset(pair) for pair in itertools.combinations(range(7), 2)
                if max(pair) >= n_static}
    pairs = all_pairs(n_static, n_dynamic)
    assert len(pairs) == len(expected)
    assert {frozenset(pair) for pair in pairs.tolist()} == expected
    assert np.all(pairs[:, 0] >= n_static)


def test_pair_keys_ignore_order_and_duplicates():
    keys = pair_keys(np.array([[5, 2], [2, 5], [7, 1]]), 10)
    assert keys.tolist() == [17, 25]
    assert pair_errors(np.array([1, 2, 3]), np.array([2, 3, 4])) == (1, 1)


def test_contact_keys_map_ids_back_to_rows():
    contacts = np.zeros(2, CONTACT_DTYPE)
    contacts['id_a'] = [0, 1]
    contacts['id_b'] = [2, 2]
    contacts['type_b'] = [STATIC, DYNAMIC]
    # 3 static rows, then dynamic rows: dynamic 0 -> row 3; static 2 -> row 2.
    assert contact_keys(contacts, 3, 10).tolist() == [2 * 10 + 3, 4 * 10 + 5]


def test_row_keys_key_broad_phase_rows_as_contact_keys():
    world = World(broad_phase='brute_force')
    world.set_static([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]], [0.5, 0.5, 0.5])
    poses = [[0.6, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], [0.0, 0.7, 0.0, 0.0, 0.0, 0.0, 1.0]]
    broad = world.broad_phase_pairs(poses, [0.5, 0.5, 0.5])
    contacts = world.step(poses, [0.5, 0.5, 0.5]).contacts
    assert row_keys(broad.pairs, broad, 1, 3).tolist() == contact_keys(contacts, 1, 3).tolist()


def test_slow_runs_are_skipped_by_extrapolation():
    slow = bench.SlowRunFilter(max_tick_s=1.0)
    assert slow.reason_to_skip('run', 1000) is None  # nothing known yet
    slow.record('run', 1000, 20.0)                   # 20 ms at 1,000 bodies: n² assumed
    assert slow.reason_to_skip('run', 5000) is None  # 0.5 s expected
    assert slow.reason_to_skip('run', 10000).startswith('skipped: ~2 s per tick')
    assert slow.reason_to_skip('other run', 10000) is None
    slow.record('run', 10000, 200.0)                 # linear from 1,000 to 10,000
    assert slow.reason_to_skip('run', 40000) is None  # 0.8 s expected
    assert 'n^1' in slow.reason_to_skip('run', 100000)  # 2 s expected
    slow.record('quadratic', 1000, 1.0)
    slow.record('quadratic', 10000, 100.0)
    assert slow.reason_to_skip('quadratic', 20000) is None  # 0.4 s
    assert 'n^2' in slow.reason_to_skip('quadratic', 40000)  # 1.6 s
    # Fixed costs hide quadratic work in the times; the comparisons reveal it.
    slow.record('brute', 1000, 10.0, compared=10 ** 6)
    slow.record('brute', 10000, 100.0, compared=10 ** 8)
    assert 'n^2' in slow.reason_to_skip('brute', 40000)  # 1.6 s, not 0.4 s


def test_a_skipped_row_keeps_its_name_and_says_why():
    columns = [('scene', lambda row: row['scene']), ('ms', lambda row: row['median_ms']),
               ('ticks', lambda row: row['ticks'])]
    lines = report.table(columns, [{'scene': 'uniform', 'skipped': 'too slow'},
                                   {'scene': 'uniform', 'median_ms': 1.5, 'ticks': 3}])
    assert lines.splitlines()[2:] == ['| uniform | too slow |  |', '| uniform | 1.5 | 3 |']


def test_static_moves_section_times_every_configuration(tiny_run):
    _, _, results = tiny_run
    rows = results['static_moves']
    assert [row['configuration'] for row in rows] == [
        'statics still', '10 statics moved (the same)', '10 statics moved (others each tick)',
        '10 statics jump 1 m (others each tick)', 'all statics moved', 'all bodies dynamic']
    assert rows[0]['vs_still'] == 1.0 and rows[-1]['vs_dynamic'] == 1.0
    assert all(row['median_ms'] > 0 and row['ticks'] == rows[0]['ticks'] for row in rows)
    # The same scene: the statics given as dynamic bodies add their pairs with each other.
    assert rows[-1]['colliding_pairs'] >= rows[0]['colliding_pairs'] > 0


# --- the robot section ---------------------------------------------------------------------

PEERS = {robot.FCL: robot.FCL_HINT, robot.COAL: robot.COAL_HINT,
         robot.MUJOCO_MESH: robot.MUJOCO_HINT, robot.MUJOCO_BOX: robot.MUJOCO_HINT}


def test_robot_section_times_every_method_and_compares_its_answers(tiny_run):
    _, output, results = tiny_run
    rows = {row['method']: row for row in results['robot']}
    assert list(rows) == [robot.OURS_STEP, robot.OURS_BATCH, robot.FCL, robot.COAL,
                          robot.MUJOCO_MESH, robot.MUJOCO_BOX]
    plan = bench.PLANS['tiny']
    ours = rows[robot.OURS_STEP]
    assert ours['states'] == plan.robot_states * plan.robot_rounds
    assert ours['per_state_us'] > 0 and ours['pairs_per_state'] > 0
    batch = rows[robot.OURS_BATCH]
    assert batch['states_per_call'] == plan.robot_batch_states
    assert batch['compared_states'] == batch['states'] == (plan.robot_batch_states
                                                           * plan.robot_rounds)
    assert batch['same_answers']
    for name, hint in PEERS.items():
        row = rows[name]
        if 'skipped' in row:
            assert row['skipped'] == hint
            continue
        assert row['compared_states'] == row['states'] == ours['states']
        assert row['states_differing'] == 0 or not row['same_answers']
        assert row['vs_mujoco'] > 0
        if name != robot.MUJOCO_BOX:  # MuJoCo's box-box collider approximates near pairs
            assert row['same_answers'] or row['boundary_only'], row
    markdown = (output / 'results.md').read_text()
    assert '## Robot arm' in markdown
    assert sum(row.get('mujoco_reference', False) for row in rows.values()) <= 1


def test_robot_section_skips_each_peer_not_installed(monkeypatch):
    for module in ('fcl', 'coal', 'mujoco'):
        monkeypatch.setitem(sys.modules, module, None)  # import raises ImportError
    rows = robot.robot_rows(3, 5, 1, progress=lambda message: None)
    by_method = {row['method']: row for row in rows}
    for name, hint in PEERS.items():
        assert by_method[name] == {'method': name, 'skipped': hint}
    assert 'vs_mujoco' not in by_method[robot.OURS_STEP]
    assert by_method[robot.OURS_STEP]['per_state_us'] > 0
    for target in report.robot_targets(rows):
        assert target['passed'] is None
        assert target['measured'] == 'not measured: ' + robot.MUJOCO_HINT
    settings = bench.PLANS['tiny']._asdict()
    assert robot.MUJOCO_HINT in '\n'.join(report._robot_markdown(rows, settings))


def _check_states_by_steps(drop_first=False):
    """Return a World.check_states keeping the contract by calling step (for these tests)."""
    dtype = np.dtype(CONTACT_DTYPE.descr + [('state', np.uint32)])

    def check_states(world, states, half_extents):
        parts = []
        for state, poses in enumerate(states):
            contacts = world.step(poses, half_extents).contacts[1 if drop_first else 0:]
            part = np.zeros(len(contacts), dtype)
            for name in CONTACT_DTYPE.names:
                part[name] = contacts[name]
            part['state'] = state
            parts.append(part)
        return Result(np.concatenate(parts), {})
    return check_states


@pytest.mark.parametrize('drop_first', [False, True])
def test_robot_section_compares_check_states_state_by_state(monkeypatch, drop_first):
    monkeypatch.setattr(World, 'check_states', _check_states_by_steps(drop_first),
                        raising=False)
    rows = {row['method']: row for row in robot.robot_rows(3, 40, 1,
                                                           progress=lambda message: None)}
    batch = rows[robot.OURS_BATCH]
    assert batch['states_per_call'] == batch['compared_states'] == 40
    assert batch['per_state_us'] > 0
    if drop_first:  # a pair missing is a difference, and not one on the margin's boundary
        assert batch['states_differing'] > 0 and batch['only_ours'] > 0
        assert batch['only_peer'] == 0 and not batch['same_answers']
        assert not batch['boundary_only']
    else:
        assert batch['same_answers'] and batch['states_differing'] == 0


def test_robot_differences_on_the_margin_are_told_apart():
    poses = robot.arm_states(1)[0]
    near = poses.copy()
    # The flange (half height 0.02 m) level, 0.05 m + 1e-7 above the floor's top (z = 0).
    near[6] = [1.2, 1.2, 0.02 + robot.ARM_MARGIN + 1e-7, 0.0, 0.0, 0.0, 1.0]
    floor_pair = (6, STATIC, robot.STATIC_NAMES.index('floor'))
    found = robot.compare([near], [set()], [{floor_pair}])
    assert found['states_differing'] == 1 and found['only_peer'] == 1
    assert found['boundary_only'] and found['worst_gap_m'] == pytest.approx(1e-7, abs=1e-9)
    far = near.copy()
    far[6, 2] += 0.5
    found = robot.compare([far], [{floor_pair}], [set()])
    assert not found['boundary_only'] and found['worst_gap_m'] == pytest.approx(0.5, abs=1e-6)
    assert robot.compare([near], [{floor_pair}], [{floor_pair}])['same_answers']


def test_robot_targets_are_judged_on_the_measured_numbers():
    mujoco = {'method': robot.MUJOCO_MESH, 'per_state_us': 10.0, 'mujoco_reference': True}
    rows = [{'method': robot.OURS_STEP, 'per_state_us': 6.0, 'states_per_call': 1},
            {'method': robot.OURS_BATCH, 'per_state_us': 2.0, 'states_per_call': 4000},
            mujoco]
    step, batch = report.robot_targets(rows)
    assert (step['passed'], batch['passed']) == (True, False)
    assert step['measured'].startswith('0.6x')
    rows[1]['states_per_call'] = 50
    assert report.robot_targets(rows)[1]['passed'] is None
    assert [target['passed'] for target in report.robot_targets(None)] == [None, None]


def test_robot_world_is_set_up_as_config_arm_yaml():
    parameters = {name: parameter_value_to_python(parameter.value) for name, parameter in
                  parameter_dict_from_yaml_file(str(REPO / 'config' / 'arm.yaml')).items()}
    assert parameters['broad_phase'] == robot.ARM_BROAD_PHASE
    assert parameters['margin'] == robot.ARM_MARGIN
    assert tuple(parameters['ignored_pairs']) == robot.ARM_IGNORED_PAIRS
    assert tuple(parameters['static_colliders']) == robot.STATIC_NAMES
    for name in robot.STATIC_NAMES:
        assert parameters.get(name + '.margin', 0.0) == robot.ARM_COLLIDER_MARGINS[name]
    assert len(robot.allowed_pairs()) == 21 + 21 - len(robot.ARM_IGNORED_PAIRS)


def test_robot_mujoco_model_gives_each_pair_the_worlds_margin():
    mujoco = pytest.importorskip('mujoco')
    for meshes in (True, False):
        model, bodies = robot.mujoco_model(mujoco, meshes)
        geom = {body: geom_id for geom_id, body in bodies.items()}
        for id_a, type_b, id_b in robot.allowed_pairs():
            margins = model.geom_margin[[geom[(DYNAMIC, id_a)], geom[(type_b, id_b)]]]
            assert margins.sum() == pytest.approx(robot.pair_margin((id_a, type_b, id_b)),
                                                  abs=1e-15)
        assert model.nexclude == len(robot.ARM_IGNORED_PAIRS)


# --- the robot_model section (the Panda) ---------------------------------------------------

PANDA_PEERS = {robot_model.MUJOCO_MESH: robot.MUJOCO_HINT, robot_model.MUJOCO_BOX:
               robot.MUJOCO_HINT, robot_model.PIN_COAL: robot_model.PIN_HINT}


def test_robot_model_section_gives_every_peer_the_same_answers(tiny_run):
    _, output, results = tiny_run
    rows = {row['method']: row for row in results['robot_model']}
    if 'skipped' in rows[robot_model.OURS_JOINTS]:  # example-robot-data not installed
        assert rows[robot_model.OURS_JOINTS]['skipped'] == robot_model.PANDA_HINT
        return
    assert list(rows) == [robot_model.OURS_JOINTS, robot_model.OURS_BATCH,
                          robot_model.OURS_EVERY_CORE, robot_model.MUJOCO_MESH,
                          robot_model.MUJOCO_BOX, robot_model.PIN_COAL, robot_model.TRAJECTORY,
                          robot_model.WAYPOINTS, robot_model.FALSE_ALARMS]
    plan = bench.PLANS['tiny']
    ours = rows[robot_model.OURS_JOINTS]
    assert (ours['boxes'], ours['dof'], ours['allowed_pairs']) == (17, 8, 44)
    assert ours['states'] == plan.panda_states * plan.panda_rounds
    assert 0 < ours['colliding_states'] < 1  # a mix of colliding and free states
    for name in (robot_model.OURS_BATCH, robot_model.OURS_EVERY_CORE):
        batch = rows[name]
        assert batch['states_per_call'] == plan.panda_batch_states
        assert batch['compared_states'] == plan.panda_batch_states * plan.panda_rounds
        assert batch['same_answers'] and batch['states_differing'] == 0
    for name, hint in PANDA_PEERS.items():
        row = rows[name]
        if 'skipped' in row:
            assert row['skipped'] == hint
            continue
        assert row['compared_states'] == row['states'] == ours['states']
        assert row['same_answers'] and row['states_differing'] == 0, row
        assert row['vs_mujoco'] > 0
    if 'per_state_us' in rows[robot_model.PIN_COAL]:
        assert rows[robot_model.PIN_COAL]['placement_error'] < 1e-9
    path, alone = rows[robot_model.TRAJECTORY], rows[robot_model.WAYPOINTS]
    assert path['waypoints'] == alone['waypoints'] == robot_model.TRAJECTORY_WAYPOINTS
    assert path['reported_pairs'] == 0 and path['per_call_ms'] > 0
    assert path['vs_waypoints'] == path['per_call_ms'] / alone['per_call_ms']
    alarms = rows[robot_model.FALSE_ALARMS]
    assert alarms['segments'] == plan.panda_segments and alarms['misses'] == 0
    assert 0 <= alarms['false_alarms'] <= alarms['reports']
    markdown = (output / 'results.md').read_text()
    assert '## Panda from its URDF' in markdown
    targets = [t for t in results['targets'] if t['target'].startswith('Panda')]
    assert len(targets) == 4
    assert targets[3]['passed'] == (path['vs_waypoints'] <= report.PANDA_TRAJECTORY_MAX_RATIO)


def test_robot_model_section_skips_each_peer_not_installed(monkeypatch):
    for module in ('mujoco', 'pinocchio', 'coal'):
        monkeypatch.setitem(sys.modules, module, None)  # import raises ImportError
    rows = robot_model.robot_model_rows(3, 5, 1, 2, progress=lambda message: None)
    by_method = {row['method']: row for row in rows}
    for name, hint in PANDA_PEERS.items():
        assert by_method[name] == {'method': name, 'skipped': hint}
    assert 'vs_mujoco' not in by_method[robot_model.OURS_JOINTS]
    assert by_method[robot_model.OURS_BATCH]['same_answers']
    one, batch, every_core, path = report.robot_model_targets(rows)
    assert one['passed'] is batch['passed'] is every_core['passed'] is None
    assert one['measured'] == 'not measured: ' + robot.MUJOCO_HINT
    assert path['passed'] in (True, False)  # ours alone
    settings = bench.PLANS['tiny']._asdict()
    assert robot.MUJOCO_HINT in '\n'.join(report._robot_model_markdown(rows, settings))


def test_robot_model_section_without_the_panda_says_why(monkeypatch):
    def missing():
        raise robot.Unavailable(robot_model.PANDA_HINT)
    monkeypatch.setattr(robot_model, 'panda_files', missing)
    rows = robot_model.robot_model_rows(3, 5, 1, 2, progress=lambda message: None)
    assert rows == [{'method': robot_model.OURS_JOINTS, 'skipped': robot_model.PANDA_HINT}]
    assert all(target['passed'] is None for target in report.robot_model_targets(rows))
    settings = bench.PLANS['tiny']._asdict()
    assert robot_model.PANDA_HINT in '\n'.join(report._robot_model_markdown(rows, settings))


def test_robot_model_compare_counts_a_differing_state():
    panda = robot_model.load_panda()
    q = np.zeros((1, panda.dof))
    table = (0, STATIC, robot_model.STATIC_NAMES.index('table'))
    found = robot.compare(q, [set()], [{table}], robot_model._distance(panda),
                          robot_model._margin)
    assert found['states_differing'] == 1 and found['only_peer'] == 1
    assert not found['boundary_only'] and found['colliding_pairs_differing'] == 0


def test_robot_model_targets_are_judged_on_the_measured_numbers():
    mujoco = {'method': robot.MUJOCO_BOX, 'per_state_us': 10.0, 'mujoco_reference': True}
    same = {'same_answers': True, 'states_differing': 0, 'compared_states': 10}
    rows = [dict(same, method=robot_model.OURS_JOINTS, per_state_us=6.0, states_per_call=1),
            dict(same, method=robot_model.OURS_BATCH, per_state_us=2.0, states_per_call=4000),
            dict(same, method=robot_model.OURS_EVERY_CORE, per_state_us=0.9,
                 states_per_call=4000),
            mujoco,
            {'method': robot_model.TRAJECTORY, 'kind': 'trajectory', 'waypoints': 100,
             'per_call_ms': 2.0, 'vs_waypoints': 2.5},
            {'method': robot_model.WAYPOINTS, 'kind': 'trajectory', 'waypoints': 100,
             'per_call_ms': 0.8, 'vs_waypoints': 1.0}]
    one, batch, every_core, path = report.robot_model_targets(rows)
    assert (one['passed'], batch['passed'], every_core['passed'], path['passed']) == \
        (True, False, True, True)
    assert one['measured'].startswith('0.6x') and path['measured'].startswith('2.5x')
    rows[0].update(same_answers=False, states_differing=1, only_ours=1, only_peer=0,
                   colliding_pairs_differing=1, boundary_only=False,
                   worst_gap_m=0.01)  # quick but wrong: not met
    assert report.robot_model_targets(rows)[0]['passed'] is False
    rows[4]['vs_waypoints'] = 3.5
    assert report.robot_model_targets(rows)[3]['passed'] is False
    assert [t['passed'] for t in report.robot_model_targets(None)] == [None] * 4


def test_robot_model_mujoco_tree_places_the_boxes_as_ours():
    mujoco = pytest.importorskip('mujoco')
    panda = robot_model.load_panda()
    _, urdf_path, _ = robot_model.panda_files()
    model, geoms, (qpos_map, qpos_offset) = robot_model.mujoco_model(
        mujoco, panda, urdf_path, meshes=False)
    data = mujoco.MjData(model)
    assert model.nexclude == len(panda.disabled_link_pairs)
    for q in robot_model.random_states(panda, 5, np.random.default_rng(4)):
        data.qpos[:] = qpos_map @ q + qpos_offset
        mujoco.mj_kinematics(model, data)
        poses = panda.box_poses(q)
        for geom, (kind, index) in geoms.items():
            if kind == DYNAMIC:
                np.testing.assert_allclose(data.geom_xpos[geom], poses[index, :3], atol=1e-12)
                np.testing.assert_allclose(data.geom_xmat[geom].reshape(3, 3),
                                           robot.rotation(poses[index, 3:]), atol=1e-12)
