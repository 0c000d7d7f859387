"""The per-period tick statistics behind /diagnostics, without ROS."""
import math
import pathlib
import subprocess
import sys

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest

from collision_node.pipeline.world import Result
from collision_node.ros.diagnostics import ERROR, Monitor, OK, STAGES, WARN

REPO = pathlib.Path(__file__).resolve().parents[1]
WORLD_STATS = {'broad_phase': 'sphere', 'dynamic_bodies': 5, 'static_bodies': 2,
               'still_bodies': 1, 'compared': 17, 'candidate_pairs': 4, 'sat_tests': 3,
               'colliding_pairs': 2, 'reused': False, 'filtered_pairs': 6, 'near_pairs': 1,
               'min_distance': -0.0125, 'min_distance_pair': (3, 0, 1, 1), 'continuous': 'on',
               'swept_pairs': 1, 'unresolved_pairs': 0}
WORLD = Result(None, WORLD_STATS)  # a general-path step's result: its stats given
REQUIRED_KEYS = ['broad_phase', 'dynamic_bodies', 'static_bodies', 'still_bodies',
                 'candidate_pairs', 'sat_tests', 'colliding_pairs', 'compared', 'ticks', 'rate_hz',
                 'dropped_inputs', 'rejected_inputs', 'last_rejection', 'filtered_pairs',
                 'near_pairs', 'min_distance', 'min_distance_pair', 'continuous', 'swept_pairs',
                 'unresolved_pairs', 'continuous_discrete_ticks'] + [
    '%s_ms_%s' % (stage, statistic)
    for stage in ('parse', 'broad', 'narrow', 'output', 'publish', 'total')
    for statistic in ('last', 'median', 'p99', 'max')]


def test_continuous_fallbacks_are_counted_and_said():
    monitor = Monitor(0.0)
    reason = 'discrete (pose count changed from 5 to 6)'
    for mode in ('on', reason, 'on', 'discrete (no previous input)', 'off'):
        monitor.tick(0.5, [1.0] * 6, Result(None, dict(WORLD_STATS, continuous=mode)))
        if mode == reason:
            values = dict(monitor.report(0.6, input_timeout_s=5.0)[2])
            assert values['continuous'] == reason
    values = dict(monitor.report(1.0, input_timeout_s=5.0)[2])
    assert values['continuous'] == 'off' and values['continuous_discrete_ticks'] == '2'
    assert (values['swept_pairs'], values['unresolved_pairs']) == ('1', '0')


def nearest_rank(values, fraction):
    """Return the conservative percentile: the smallest sample at or above the fraction's rank."""
    ordered = sorted(values)
    return ordered[math.ceil(fraction * (len(ordered) - 1))]


def test_levels_are_the_message_constants():
    assert bytes([OK]) == DiagnosticStatus.OK
    assert bytes([WARN]) == DiagnosticStatus.WARN
    assert bytes([ERROR]) == DiagnosticStatus.ERROR


def test_report_has_every_key_and_the_world_stats():
    monitor = Monitor(0.0)
    monitor.received()
    monitor.tick(0.5, [1.0, 2.0, 3.0, 0.5, 3.5, 10.0],
                 Result(None, dict(WORLD_STATS, broad_phase_stats={'builds': 1})))
    level, message, values = monitor.report(1.0, input_timeout_s=5.0)
    values = dict(values)
    assert set(REQUIRED_KEYS) <= set(values)
    assert level == OK, message
    assert values['broad_phase'] == 'sphere'
    assert (values['dynamic_bodies'], values['static_bodies'], values['compared'],
            values['candidate_pairs'], values['sat_tests'], values['colliding_pairs']) == (
        '5', '2', '17', '4', '3', '2')
    assert values['ticks'] == '1' and float(values['rate_hz']) == 1.0
    assert values['reused_result'] == 'false'
    assert float(values['narrow_ms_last']) == 3.0 and float(values['total_ms_max']) == 10.0
    assert float(values['output_ms_last']) == 0.5 and float(values['publish_ms_last']) == 3.5
    assert values['sphere.builds'] == '1'  # the broad phase's own counters, named after it
    assert (values['filtered_pairs'], values['near_pairs']) == ('6', '1')
    assert (values['min_distance'], values['min_distance_pair']) == ('-0.0125', 'd3-s1')
    monitor.tick(0.7, [1.0] * 6,
                 Result(None, dict(WORLD_STATS, min_distance=float('nan'),
                                   min_distance_pair=None)))
    values = dict(monitor.report(1.0, input_timeout_s=5.0)[2])
    assert values['min_distance'] == values['min_distance_pair'] == ''  # nothing reported


def test_stage_statistics_over_the_period():
    rng = np.random.default_rng(3)
    times = rng.exponential(2.0, (300, len(STAGES)))
    monitor = Monitor(0.0)
    for row in times:
        monitor.received()
        monitor.tick(1.0, row, WORLD)
    values = dict(monitor.report(10.0, input_timeout_s=0.0)[2])
    for column, stage in enumerate(STAGES):
        samples = times[:, column].tolist()
        assert float(values['%s_ms_last' % stage]) == pytest.approx(samples[-1], abs=1e-3)
        assert float(values['%s_ms_median' % stage]) == pytest.approx(
            nearest_rank(samples, 0.5), abs=1e-3)
        assert float(values['%s_ms_p99' % stage]) == pytest.approx(
            nearest_rank(samples, 0.99), abs=1e-3)
        assert float(values['%s_ms_max' % stage]) == pytest.approx(max(samples), abs=1e-3)
    assert values['ticks'] == '300' and float(values['rate_hz']) == 30.0


def test_more_ticks_than_samples_keeps_the_newest_and_the_true_max():
    monitor = Monitor(0.0, samples=8)
    totals = [100.0] + [float(i) for i in range(1, 20)]  # the slow one is pushed out
    for total in totals:
        monitor.tick(0.0, [0.0, 0.0, 0.0, 0.0, 0.0, total], WORLD)
    values = dict(monitor.report(1.0, input_timeout_s=0.0)[2])
    newest = totals[-8:]
    assert float(values['total_ms_median']) == nearest_rank(newest, 0.5)
    assert float(values['total_ms_p99']) == max(newest)
    assert float(values['total_ms_max']) == 100.0
    assert values['ticks'] == '20'


def test_a_new_period_starts_after_each_report():
    monitor = Monitor(0.0)
    monitor.tick(0.1, [5.0] * len(STAGES), WORLD)
    monitor.report(1.0, input_timeout_s=0.0)
    values = dict(monitor.report(2.0, input_timeout_s=0.0)[2])
    assert values['ticks'] == '0' and float(values['total_ms_max']) == 0.0
    assert float(values['total_ms_last']) == 5.0  # the last tick stays visible
    assert values['dynamic_bodies'] == '5'


def test_rejection_warns_for_one_period_and_is_remembered():
    monitor = Monitor(0.0)
    monitor.rejected('input frame_id map is not world')
    monitor.tick(0.5, [1.0] * len(STAGES), WORLD)
    level, message, values = monitor.report(1.0, input_timeout_s=5.0)
    assert level == WARN and 'frame_id map' in message
    assert dict(values)['rejected_inputs'] == '1'
    monitor.tick(1.5, [1.0] * len(STAGES), WORLD)
    level, _, values = monitor.report(2.0, input_timeout_s=5.0)
    assert level == OK
    assert dict(values)['rejected_inputs'] == '1'  # a total since the start
    assert dict(values)['last_rejection'] == 'input frame_id map is not world'


def test_tick_slower_than_the_input_period_warns():
    monitor = Monitor(0.0)
    for _ in range(10):  # 10 inputs in 1 s: a 100 ms input period
        monitor.received()
        monitor.tick(0.9, [0.0, 0.0, 0.0, 0.0, 0.0, 50.0], WORLD)
    assert monitor.report(1.0, input_timeout_s=5.0)[0] == OK
    for total in (50.0, 150.0):  # 2 inputs in 1 s: a 500 ms input period
        monitor.received()
        monitor.tick(1.9, [0.0, 0.0, 0.0, 0.0, 0.0, total], WORLD)
    assert monitor.report(2.0, input_timeout_s=5.0)[0] == OK
    for _ in range(20):
        monitor.received()
    monitor.tick(2.9, [0.0, 0.0, 0.0, 0.0, 0.0, 60.0], WORLD)  # 20 inputs in 1 s: 50 ms
    level, message, _ = monitor.report(3.0, input_timeout_s=5.0)
    assert level == WARN and 'longer than the input period' in message
    monitor.received()
    monitor.received()
    monitor.dropped(18)  # 20 inputs sent in 1 s, 18 of them overwritten before a tick
    monitor.tick(3.9, [0.0, 0.0, 0.0, 0.0, 0.0, 60.0], WORLD)
    level, message, _ = monitor.report(4.0, input_timeout_s=5.0)
    assert level == WARN and 'input period 50 ms' in message
    monitor.tick(4.5, [0.0, 0.0, 0.0, 0.0, 0.0, 150.0], WORLD)  # a timer ticking at 10 Hz
    level, message, _ = monitor.report(5.0, input_timeout_s=5.0, tick_period_s=0.1)
    assert level == WARN and 'longer than the input period' in message


def test_no_valid_input_is_an_error_unless_disabled():
    monitor = Monitor(10.0)
    assert monitor.report(10.5, input_timeout_s=1.0)[0] == OK
    level, message, _ = monitor.report(11.2, input_timeout_s=1.0)
    assert level == ERROR and 'no valid input' in message
    monitor.rejected('garbage')  # a rejected input is not a valid one
    assert monitor.report(11.5, input_timeout_s=1.0)[0] == ERROR
    monitor.tick(11.6, [1.0] * len(STAGES), WORLD)
    assert monitor.report(12.0, input_timeout_s=1.0)[0] == OK
    assert monitor.report(60.0, input_timeout_s=0.0)[0] == OK


def test_no_valid_input_names_the_rejected_ones():
    monitor = Monitor(0.0)
    monitor.rejected('frame_id map')
    monitor.tick(0.5, [1.0] * len(STAGES), WORLD)  # a valid input: the count restarts
    assert monitor.report(1.0, input_timeout_s=5.0)[:2] == (
        WARN, '1 inputs rejected, last: frame_id map')
    for body in (3, 1, 1):
        monitor.rejected('dynamic body %d: pose has a NaN or Inf value' % body)
    assert monitor.report(6.5, input_timeout_s=5.0)[:2] == (
        ERROR, 'no valid input for 6 s; 3 inputs rejected, last: dynamic body 1: pose has a NaN '
        'or Inf value')
    monitor.tick(7.0, [1.0] * len(STAGES), WORLD)
    assert monitor.report(13.0, input_timeout_s=5.0)[:2] == (ERROR, 'no valid input for 6 s')


def test_dropped_inputs_are_a_total():
    monitor = Monitor(0.0)
    monitor.dropped()
    monitor.dropped(4)
    assert dict(monitor.report(1.0, 0.0)[2])['dropped_inputs'] == '5'
    monitor.dropped()
    assert dict(monitor.report(2.0, 0.0)[2])['dropped_inputs'] == '6'


def test_no_ticks_reports_zeros():
    values = dict(Monitor(0.0).report(1.0, 0.0)[2])
    assert values['ticks'] == '0' and values['total_ms_median'] == '0.000'
    assert values['broad_phase'] == ''


def test_pure_modules_do_not_import_rclpy():
    check = ('import sys, collision_node.ros.diagnostics, collision_node.ros.params; '
             'sys.exit(" ".join(m for m in sys.modules if m.startswith("rclpy")) or None)')
    done = subprocess.run([sys.executable, '-c', check], cwd=REPO, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_a_node_that_is_not_active_is_never_ok():
    monitor = Monitor(0.0)
    monitor.lifecycle(0.0, 'unconfigured')
    level, message, values = monitor.report(0.5, input_timeout_s=0.1)
    assert (level, message) == (WARN, 'unconfigured: not checking collisions')
    assert (dict(values)['lifecycle_state'], dict(values)['ignored_inputs']) == (
        'unconfigured', '0')
    monitor.lifecycle(1.0, 'unconfigured', "configure failed: parameter 'x': bad")
    level, message, _ = monitor.report(1.5, input_timeout_s=0.1)
    assert level == ERROR
    assert message == "unconfigured: not checking collisions; configure failed: parameter 'x': bad"
    monitor.lifecycle(2.0, 'inactive')
    monitor.ignored()
    monitor.ignored(2)
    level, message, values = monitor.report(2.5, input_timeout_s=0.1)
    assert (level, message) == (WARN, 'inactive: not checking collisions, 3 inputs ignored')
    assert dict(values)['lifecycle_state'] == 'inactive' and dict(values)['ignored_inputs'] == '3'
    level, message, values = monitor.report(3.0, input_timeout_s=0.1)  # none this period
    assert message == 'inactive: not checking collisions' and dict(values)['ignored_inputs'] == '3'
    # Active at 10 s, long after any valid input: the input timeout counts from the activate.
    monitor.lifecycle(10.0, 'active')
    level, _, values = monitor.report(10.05, input_timeout_s=0.1)
    assert level == OK and dict(values)['lifecycle_state'] == 'active'
    level, message, _ = monitor.report(10.2, input_timeout_s=0.1)
    assert (level, message) == (ERROR, 'no valid input for 0.2 s')


def test_the_lifecycle_keys_leave_the_first_and_last_keys_in_place():
    """collision_monitor prints the keys in order; the README shows its first and last lines."""
    keys = [key for key, _ in Monitor(0.0).report(1.0, input_timeout_s=0.0)[2]]
    assert keys[:3] == ['broad_phase', 'dynamic_bodies', 'static_bodies']
    assert keys[-2:] == ['rejected_inputs', 'last_rejection']
    assert {'lifecycle_state', 'ignored_inputs'} <= set(keys)
