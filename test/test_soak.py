"""The soak tool: its memory-trend arithmetic, then a soak of 10,000 ticks asserting flat memory.

Flat memory, as collision_soak defines it: from the node's first answer on, the least-squares
RSS trend over the second half of the run adds up to less than MAX_GROWTH_MB over that half
(the first half is left to the warm-up). At 500 ticks/s, the 5,000 ticks of the second half
would have to leak less than about 400 bytes each to pass.
"""
import os
import random

import numpy as np
import pytest
from ros_helpers import run_soak

from collision_node.benchmarks.collision_soak import (memory_trend, parse_arguments,
                                                      percentiles_ms, RSS_PERIOD_S)

DOMAIN_ID = random.Random(os.getpid() + 3).randint(1, 200)
SOAK_TICKS = 10_000
SOAK_RATE_HZ = 500.0
SOAK_BODIES = 100
MAX_GROWTH_MB = 2.0


def test_memory_trend_sees_growth_in_the_second_half_only():
    rng = np.random.default_rng(0)
    times = np.arange(0.0, 100.0, 0.25)
    warm_up = np.minimum(times, 20.0) * 2.0  # +40 MB in the first 20 s, then flat
    noise = rng.normal(0.0, 0.2, len(times))
    flat = memory_trend(times, 200.0 + warm_up + noise)
    assert abs(flat['growth_mb']) < 0.3 and flat['rss_end_mb'] == pytest.approx(240.0, abs=1.0)
    leaking = memory_trend(times, 200.0 + warm_up + noise + 0.1 * times)  # 0.1 MB/s
    assert leaking['growth_mb'] == pytest.approx(0.1 * 49.75, rel=0.1)
    assert leaking['slope_mb_per_min'] == pytest.approx(6.0, rel=0.1)
    assert memory_trend([0.0, 1.0], [1.0, 2.0]) == {'samples': 2}


def test_percentiles_are_samples_in_milliseconds():
    stats = percentiles_ms(np.arange(1, 101) * 1e-3)  # 1 ms .. 100 ms
    assert stats == pytest.approx({'p50_ms': 51.0, 'p99_ms': 100.0, 'max_ms': 100.0})
    assert percentiles_ms([]) == {'p50_ms': 0.0, 'p99_ms': 0.0, 'max_ms': 0.0}


def test_soak_of_ten_thousand_ticks_keeps_memory_flat(tmp_path):
    done, summary = run_soak(
        DOMAIN_ID, tmp_path / 'soak.json', '--ticks', str(SOAK_TICKS), '--rate',
        str(SOAK_RATE_HZ), '--bodies', str(SOAK_BODIES), '--interval', '5', '--duration', '120',
        '--max-growth-mb', str(MAX_GROWTH_MB))
    print(done.stdout)
    assert done.returncode == 0, done.stdout + done.stderr
    assert summary['ticks'] >= SOAK_TICKS and summary['node_exit_code'] is None
    assert summary['accounted'] and summary['rejected'] == 0
    assert summary['answers_in_order'] and summary['error_statuses'] == 0
    memory = summary['memory']
    assert memory['samples'] >= 10.0 / RSS_PERIOD_S  # 10 s at least
    assert memory['growth_mb'] < MAX_GROWTH_MB, memory


def test_a_named_scene_brings_its_own_body_count():
    assert parse_arguments(['--scene', 'arm']).bodies == 7
    assert parse_arguments(['--scene', 'room']).bodies == 40
    assert parse_arguments(['--scene', 'uniform']).bodies == 1000
    assert parse_arguments(['--scene', 'uniform', '--bodies', '64']).bodies == 64


@pytest.mark.parametrize('arguments, complaint', [
    (['--rate', '0'], '--rate must be positive'),
    (['--duration', '-1'], '--duration must be positive'),
    (['--ticks', '0'], '--ticks must be at least 1'),
    (['--bodies', '0'], '--bodies must be at least 1'),
    (['--scene', 'nowhere'], "invalid choice: 'nowhere'"),
    (['--scene', 'arm', '--bodies', '5'], '--bodies: the arm scene has 7 bodies, not 5'),
])
def test_soak_refuses_bad_arguments(capsys, arguments, complaint):
    with pytest.raises(SystemExit) as raised:
        parse_arguments(arguments)
    assert raised.value.code == 2 and complaint in capsys.readouterr().err
