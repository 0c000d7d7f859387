"""The README's "Publishing poses from a script", run as written through real pub/sub.

The node and the monitor start from the README's own command lines (``.venv/bin/`` being this
Python's venv), the script is the README's snippet saved as ``my_poses.py``, and the monitor
must print the README's lines. Masked are only what a clock decides: the stamp, and the level
and message of the status (``1 ticks at 1.0 Hz`` measures the period the tick fell in). The two
scripts of doc/changing-scene.md and the manager script of doc/lifecycle.md run against the
node the same way.
"""
import os
import random
import re
import shlex
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.executors import SingleThreadedExecutor
from ros_helpers import make_context, node_environment, REPO
from test_readme import code_blocks, DOC, python_snippets

from collision_node.tools.processes import stop_process

DOMAIN_ID = random.Random(os.getpid() + 23).randint(1, 200)
SECTION = 'Publishing poses from a script'
START_TIMEOUT_S = 120.0  # the node compiles its kernels first when numba's cache is empty
STOP_TIMEOUT_S = 10.0
MASKS = [(r'^collisions at [0-9.]+ ', 'collisions at <stamp> '),
         (r'^(diagnostics) \w+ (.*: collision_check): .*$', r'\1 <level> \2: <message>')]


def command(line):
    """Split a README command line; take its ``.venv/bin/`` program from this Python's venv."""
    words = shlex.split(line)
    if words[0].startswith('.venv/bin/'):
        words[0] = os.path.join(os.path.dirname(sys.executable), os.path.basename(words[0]))
    return words


def masked(text):
    for pattern, replacement in MASKS:
        text = re.sub(pattern, replacement, text, flags=re.MULTILINE)
    return text


def shown_as(expected):
    """Return a regular expression for the README's output; a ``...`` line is any lines."""
    return ''.join(r'(?:.*\n)*' if line.strip() == '...' else re.escape(line) + '\n'
                   for line in masked(expected).splitlines())


def test_the_script_gets_its_answer_to_the_monitor(tmp_path):
    node_line, monitor_line, script_line = code_blocks('bash')[SECTION][0].splitlines()
    snippet, = python_snippets()[SECTION]
    expected, = code_blocks('')[SECTION]
    (tmp_path / 'my_poses.py').write_text(snippet)
    env = node_environment(DOMAIN_ID)
    with open(tmp_path / 'node.log', 'w') as node_log:
        node = subprocess.Popen(command(node_line), cwd=REPO, env=env, stdout=node_log,
                                stderr=subprocess.STDOUT)
    with open(tmp_path / 'monitor.err', 'w') as monitor_errors:
        monitor = subprocess.Popen(command(monitor_line), cwd=REPO, env=env,
                                   stdout=subprocess.PIPE, stderr=monitor_errors, text=True)
    started = time.monotonic()
    try:
        # As the README has it, the monitor listens before the script publishes: it says so
        # once it has matched the node's `collisions` publisher (made after the warm-up).
        while 'listening' not in (tmp_path / 'monitor.err').read_text():
            assert node.poll() is None and monitor.poll() is None, 'the node or monitor ended'
            assert time.monotonic() < started + START_TIMEOUT_S, 'the node did not start'
            time.sleep(0.1)
        matched = time.monotonic()
        script = subprocess.run(command(script_line), cwd=tmp_path, env=env,
                                capture_output=True, text=True, timeout=START_TIMEOUT_S)
        assert script.returncode == 0, script.stderr
        published = time.monotonic()
        output, _ = monitor.communicate(timeout=START_TIMEOUT_S)
    finally:
        monitor.kill()
        stop_process(node, STOP_TIMEOUT_S)
    assert monitor.returncode == 0, \
        'monitor matched after %.1f s, script done %.1f s later, at %.3f (wall clock):\n%s\n' \
        'node log:\n%s' % (matched - started, published - matched,
                           time.time() - time.monotonic() + published,
                           (tmp_path / 'monitor.err').read_text(),
                           (tmp_path / 'node.log').read_text())
    assert re.fullmatch(shown_as(expected), masked(output)), output


CHANGING = DOC / 'changing-scene.md'


def test_the_scene_changing_scripts_change_the_nodes_scene(tmp_path):
    """Both scripts of the page, run as written against the node on the demo room."""
    node_line = code_blocks('bash')[SECTION][0].splitlines()[0]
    move_script, = python_snippets(CHANGING)['Moving colliders with static_poses']
    change_script, = python_snippets(CHANGING)[
        'Adding, removing, resizing, enabling with parameters']
    (tmp_path / 'move.py').write_text(move_script)
    (tmp_path / 'change.py').write_text(change_script)
    env = node_environment(DOMAIN_ID)
    context = make_context(DOMAIN_ID)
    observer = rclpy.create_node('observer', context=context)
    statuses = []
    observer.create_subscription(DiagnosticArray, '/diagnostics',
                                 lambda message: statuses.extend(message.status), 10)
    with open(tmp_path / 'node.log', 'w') as node_log:
        node = subprocess.Popen(command(node_line), cwd=REPO, env=env, stdout=node_log,
                                stderr=subprocess.STDOUT)

    def wait_for_status(condition):
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            assert node.poll() is None, (tmp_path / 'node.log').read_text()
            assert time.monotonic() < deadline, 'no such status'
            executor.spin_once(timeout_sec=0.1)
            while statuses:
                found = {item.key: item.value for item in statuses.pop(0).values}
                if condition(found):
                    return found

    executor = SingleThreadedExecutor(context=context)
    executor.add_node(observer)
    try:
        wait_for_status(lambda found: found['scene_version'] == '0')
        moved = subprocess.run([sys.executable, 'move.py'], cwd=tmp_path, env=env,
                               capture_output=True, text=True, timeout=START_TIMEOUT_S)
        assert moved.returncode == 0, moved.stderr
        wait_for_status(lambda found: found['scene_version'] == '1')
        changed = subprocess.run([sys.executable, 'change.py'], cwd=tmp_path, env=env,
                                 capture_output=True, text=True, timeout=START_TIMEOUT_S)
        assert changed.returncode == 0, changed.stderr
        assert changed.stdout == 'True \n'
        found = wait_for_status(lambda found: found['scene_version'] == '2')
        assert found['static_ids'] == \
            'floor:0 wall_north:1 wall_south:2 table:3 shelf_left:4 door:6'
    finally:
        stop_process(node, STOP_TIMEOUT_S)
        executor.shutdown()
        observer.destroy_node()
        context.try_shutdown()


LIFECYCLE = DOC / 'lifecycle.md'


def test_the_lifecycle_script_configures_and_activates_a_waiting_node(tmp_path):
    """The page's script against the node started by the page's command, as it prints."""
    node_line = code_blocks('bash', LIFECYCLE)['From the command line'][0].splitlines()[0]
    words = shlex.split(node_line)
    assert words[:4] == ['ros2', 'run', 'collision_node', 'collision_node']  # no ros2 here
    script, = python_snippets(LIFECYCLE)['From code']
    expected, = code_blocks('', LIFECYCLE)['From code']
    (tmp_path / 'manager.py').write_text(script)
    env = node_environment(DOMAIN_ID)
    with open(tmp_path / 'node.log', 'w') as node_log:
        node = subprocess.Popen(command('.venv/bin/collision_node') + words[4:], cwd=REPO,
                                env=env, stdout=node_log, stderr=subprocess.STDOUT)
    try:
        done = subprocess.run([sys.executable, 'manager.py'], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=START_TIMEOUT_S)
    except subprocess.TimeoutExpired as timeout:  # say how far it came
        done = timeout
    finally:
        stopped = stop_process(node, STOP_TIMEOUT_S)
    log = (tmp_path / 'node.log').read_text()
    assert not isinstance(done, subprocess.TimeoutExpired), \
        'the script printed %r, then waited %d s; node log:\n%s' % (
            done.stdout, START_TIMEOUT_S, log)
    assert done.returncode == 0, done.stderr + log
    assert done.stdout == expected
    assert stopped == 0 and 'Traceback' not in log, log
