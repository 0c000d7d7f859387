"""JIT: no tick compiles, and numba's cache works when the package is installed read-only.

test_node.py's fresh-process check runs every broad phase on moving input; the check here runs
the node's other tick paths (static colliders, no dynamic body, one size for all bodies, an
unchanged input, sphere prefilter off, a collider disabled at run time, margins and collision
filters set at run time) after the warm-up.

Read-only installs are copies of the package that the test process cannot write to (for root,
which ignores file modes, the child drops CAP_DAC_OVERRIDE before it starts).

Processes filling one cache (compile_kernels' parallel parts) add to a kernel's index one at a
time: a compile waits while another process holds the cache's lock.
"""
import ctypes
import fcntl
import os
import random
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from collision_node.pipeline import warm_up
from collision_node.pipeline._jit import CACHE_LOCK, compiled_for
from collision_node.pipeline.frames import sum_abs

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOMAIN_ID = random.Random(os.getpid() + 11).randint(1, 200)
# linux/prctl.h, linux/capability.h
PR_CAPBSET_DROP = 24
CAP_DAC_OVERRIDE = 1
CAP_DAC_READ_SEARCH = 2

NO_COMPILE_CHECK = """
import sys
import numpy as np
import rclpy
from rclpy.parameter import Parameter
from collision_node.pipeline import scenes
from collision_node.pipeline._jit import KERNELS
from collision_node.pipeline.broadphase import NAMES
from collision_node.ros.cdr import serialize_pose_array
from collision_node.ros.node import CollisionNode


def compiled():  # every kernel of the package (pipeline._jit.KERNELS): its compiled types
    return {(kernel.py_func.__module__, kernel.py_func.__name__): len(kernel.overloads)
            for kernel in KERNELS}


rclpy.init(domain_id=%d)
room = scenes.room(300, seed=3)
names = ['c%%d' %% i for i in range(len(room.static_poses))]
colliders = [Parameter('static_colliders', value=names)]
for name, pose, extents in zip(names, room.static_poses, room.static_half_extents):
    colliders += [Parameter(name + '.pose', value=pose.tolist()),
                  Parameter(name + '.half_extents', value=extents.tolist())]
one_size = [0.1, 0.1, 0.1]
per_body = room.dynamic_half_extents.ravel().tolist()
nodes = [CollisionNode(parameter_overrides=colliders + [
             Parameter('dynamic.half_extents', value=sizes), Parameter('threads', value=threads)])
         for sizes, threads in ((one_size, 1), (per_body, 1), (one_size, 2))]
for node in nodes:  # the kernels other settings need load in the background meanwhile
    node._background_warm_up.join()
before = compiled()
for node in nodes:
    for name in NAMES:
        assert node.set_parameters([Parameter('broad_phase', value=name)])[0].successful
        for sphere in (True, False):
            assert node.set_parameters([Parameter('sphere_prefilter', value=sphere)])[0].successful
            for enabled in (True, False):
                assert node.set_parameters([Parameter('c0.enabled', value=enabled)])[0].successful
                for t in (0.0, 0.5, 0.5, 1.0):  # 0.5 twice: the World reuses its answer
                    node._check(serialize_pose_array(1, 0, '', room.dynamic_poses(t)))
    # Margins and filters: the World's own, a collider's, masks per body and ignored pairs.
    for change in ([Parameter('margin', value=0.05)], [Parameter('c1.margin', value=0.1)],
                   [Parameter('c2.collision_mask', value=6)],
                   [Parameter('dynamic.collision_category', value=[1, 2] * 150)],
                   [Parameter('ignored_pairs', value=['d0 d1', 'd3 c1'])],
                   [Parameter('continuous', value=True)]):
        assert node.set_parameters(change)[0].successful
        for t in (0.0, 0.5, 0.5):
            node._check(serialize_pose_array(1, 0, '', room.dynamic_poses(t)))
        bad = room.dynamic_poses(0.0)
        bad[7, 2] = np.nan
        node._check(serialize_pose_array(1, 0, '', bad))
    node._check(serialize_pose_array(1, 0, '', np.zeros((0, 7))))
    # Static colliders that change: a few moved by static_poses (loose) under still bodies,
    # then all of them (a rebuild), one moved and resized by parameters, one removed.
    statics = room.static_poses.copy()
    for moving in (slice(0, 2), slice(None)):
        statics[moving, 0] += 0.05
        node._on_static_poses(serialize_pose_array(0, 0, '', statics))
        for t in (0.5, 0.5, 1.0):
            node._check(serialize_pose_array(1, 0, '', room.dynamic_poses(t)))
    for change in ([Parameter('c1.pose', value=(statics[1] + [0.1, 0, 0, 0, 0, 0, 0]).tolist()),
                    Parameter('c1.half_extents', value=[0.3, 0.2, 0.1])],
                   [Parameter('static_colliders', value=names[1:])]):
        assert node.set_parameters_atomically(change).successful
        for t in (1.0, 1.0, 0.5):
            node._check(serialize_pose_array(1, 0, '', room.dynamic_poses(t)))
# auto past GRID_BODIES: it measures the boxes' spread to choose between its phases.
assert nodes[0].set_parameters([Parameter('broad_phase', value='auto'),
                                 Parameter('dynamic.collision_category', value=[1])])[0].successful
crowd = scenes.room(1500, seed=5)
for t in (0.0, 0.5):
    nodes[0]._check(serialize_pose_array(1, 0, '', crowd.dynamic_poses(t)))
# Past SORT_PAIRS_ROWS boxes the World sorts the candidate pairs by row (1 and 2 threads);
# past MIN_PAIRS_PER_THREAD pairs a thread it assembles the contacts over threads (nodes[2],
# still continuous: discrete, then swept).
assert nodes[2].set_parameters([Parameter('dynamic.collision_category',
                                          value=[1])])[0].successful
big = scenes.room(17000, seed=6)
for node in (nodes[0], nodes[2]):
    for t in (0.0, 0.5):
        node._check(serialize_pose_array(1, 0, '', big.dynamic_poses(t)))
after = compiled()
assert len(before) > 5, before
changed = {key: (before.get(key), count) for key, count in after.items()
           if before.get(key) != count}
sys.exit('compiled during ticks: %%s' %% changed if changed else None)
""" % DOMAIN_ID

# A World readied by warm_up_like alone (no background warm-up): what the node does before
# it subscribes. Its ticks and what the diagnostics read of them (the stats) add no type.
WARM_UP_LIKE_CHECK = """
import sys
from collision_node.pipeline import scenes
from collision_node.pipeline._jit import KERNELS
from collision_node.pipeline.warm_up import warm_up_like
from collision_node.pipeline.world import World


def compiled():
    return {kernel: len(kernel.overloads) for kernel in KERNELS}


arm = scenes.arm()
world = World()
world.set_static(arm.static_poses, arm.static_half_extents)
warm_up_like(world, arm.dynamic_half_extents)
before = compiled()
for t in (0.0, 0.1):
    world.step(arm.dynamic_poses(t), arm.dynamic_half_extents).stats
changed = [kernel.py_func.__name__ for kernel, count in compiled().items()
           if before.get(kernel) != count]
sys.exit('compiled or loaded after warm_up_like: %s' % changed if changed else None)
"""

# Decorates every kernel (import), then runs one small one, and says where numba put it.
CACHE_CHECK = """
import os
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from collision_node.pipeline import obb, sat
assert obb.__file__.startswith(sys.argv[1]), obb.__file__
obb.spheres_apart(np.zeros((2, 3)), np.ones(2), 0, 1)
print(obb.spheres_apart._cache._cache_path)
print(sum(obb.spheres_apart.stats.cache_hits.values()))
print(sat.collide_pair_rows._cache._cache_path)
"""


def test_nothing_compiles_during_a_tick():
    """In a fresh process: after the node's warm-up, no tick path adds compiled code.

    Every broad phase, sphere prefilter on and off, a static collider enabled and disabled,
    one size for all bodies and one per body, reused answers, a rejected and an empty input,
    static colliders moved, resized and removed.
    """
    done = subprocess.run([sys.executable, '-c', NO_COMPILE_CHECK], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]


def test_warm_up_like_readies_a_tick_and_the_stats_the_diagnostics_read():
    """A node's first diagnostics report once loaded a kernel (34 ms, the executor held)."""
    done = subprocess.run([sys.executable, '-c', WARM_UP_LIKE_CHECK], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]


def _without_write_permission():
    """Drop root's power to ignore file modes in the child (no-op for other users)."""
    if os.geteuid() == 0:
        libc = ctypes.CDLL(None, use_errno=True)
        for capability in (CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH):
            if libc.prctl(PR_CAPBSET_DROP, capability, 0, 0, 0) != 0:
                raise OSError(ctypes.get_errno(), 'prctl(PR_CAPBSET_DROP) failed')


@pytest.fixture
def read_only_install(tmp_path):
    """Copy the package without caches, read-only, and make a writable home beside it."""
    install = tmp_path / 'site-packages'
    shutil.copytree(os.path.join(REPO, 'collision_node'), install / 'collision_node',
                    ignore=shutil.ignore_patterns('__pycache__'))
    for root, _, files in os.walk(install):
        for name in files:
            os.chmod(os.path.join(root, name), 0o444)
        os.chmod(root, 0o555)
    home = tmp_path / 'home'
    home.mkdir()
    yield install, home
    for root, _, _ in os.walk(install):
        os.chmod(root, 0o755)


def run_cache_check(install, home, **environment):
    env = {key: value for key, value in os.environ.items()
           if key not in ('NUMBA_CACHE_DIR', 'XDG_CACHE_HOME', 'PYTHONPATH')}
    env.update(HOME=str(home), **environment)
    done = subprocess.run([sys.executable, '-c', CACHE_CHECK, str(install)], cwd=str(home),
                          env=env, capture_output=True, text=True, timeout=300,
                          preexec_fn=_without_write_permission)
    assert done.returncode == 0, done.stderr[-3000:]
    cache_path, hits, sat_cache_path = done.stdout.split()
    return cache_path, int(hits), sat_cache_path


def cache_files(directory):
    return sorted(name for _, _, files in os.walk(directory) for name in files
                  if name.endswith(('.nbi', '.nbc')))


def test_read_only_install_caches_in_the_user_cache(read_only_install):
    install, home = read_only_install
    cache_path, hits, sat_cache_path = run_cache_check(install, home)
    assert cache_path.startswith(str(home / '.cache' / 'numba'))
    assert sat_cache_path == cache_path  # every kernel, not only the one that ran
    assert hits == 0 and any(f.startswith('obb.spheres_apart') for f in cache_files(home))
    assert not cache_files(install)
    # A second process loads the kernel from there instead of compiling it.
    assert run_cache_check(install, home)[1] == 1


def test_numba_cache_dir_overrides_the_user_cache(read_only_install, tmp_path):
    install, home = read_only_install
    chosen = tmp_path / 'chosen'
    cache_path, _, _ = run_cache_check(install, home, NUMBA_CACHE_DIR=str(chosen))
    assert cache_path.startswith(str(chosen))
    assert any(f.startswith('obb.spheres_apart') for f in cache_files(chosen))
    assert not cache_files(home) and not cache_files(install)


def test_read_only_install_without_a_writable_home_still_caches(read_only_install, tmp_path):
    install, _ = read_only_install
    home = tmp_path / 'read_only_home'
    home.mkdir()
    os.chmod(home, 0o555)
    cache_path, _, sat_cache_path = run_cache_check(install, home)
    assert sat_cache_path == cache_path and not cache_path.startswith(str(home))
    assert any(f.startswith('obb.spheres_apart') for f in cache_files(cache_path))
    assert run_cache_check(install, home)[1] == 1  # loaded, not compiled, the second time


# Compiles add_one for the type of sys.argv[2] (int or float) into NUMBA_CACHE_DIR.
ADD_ONE = """
import sys
sys.path.insert(0, sys.argv[1])
from add_one import add_one
add_one(eval(sys.argv[2]))
"""


def test_a_compile_waits_to_add_to_an_index_another_process_holds(tmp_path):
    """Two types of one kernel from two processes: the second waits, both end in the index."""
    (tmp_path / 'add_one.py').write_text('from collision_node.pipeline._jit import kernel\n'
                                         '@kernel\ndef add_one(x):\n    return x + 1\n')
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / 'cache'))

    def compile_for(value):
        return subprocess.Popen([sys.executable, '-c', ADD_ONE, str(tmp_path), value], cwd=REPO,
                                env=env)

    assert compile_for('1').wait(120) == 0
    [index] = (tmp_path / 'cache').rglob('*.nbi')
    with open(index.parent / CACHE_LOCK, 'a') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # as another process adding to an index
        waiting = compile_for('1.5')
        time.sleep(10.0)  # the float type compiles in about a second, then waits for the lock
        assert waiting.poll() is None, 'saved without the lock'
        assert len(cache_files(tmp_path / 'cache')) == 2  # the int type's index and data
    assert waiting.wait(120) == 0
    assert len(cache_files(tmp_path / 'cache')) == 3  # and the float type's data
    # Both types load from the one index: nothing compiles again.
    for value in ('1', '1.5'):
        done = subprocess.run(
            [sys.executable, '-c', ADD_ONE + 'print(sum(add_one.stats.cache_hits.values()), '
             'sum(add_one.stats.cache_misses.values()))', str(tmp_path), value],
            cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout.split() == ['1', '0']  # loaded, not compiled


def test_the_complete_cache_marker_follows_the_sources(tmp_path, monkeypatch):
    """A start compiles in other processes unless a full compile marked these sources done."""
    package = tmp_path / 'package'
    (package / 'sub').mkdir(parents=True)
    (package / 'a.py').write_text('x = 1\n')
    (package / 'sub' / 'b.py').write_text('y = 2\n')
    stamp = warm_up.source_stamp(package)
    assert warm_up.source_stamp(package) == stamp
    later = os.stat(package / 'sub' / 'b.py').st_mtime_ns + 10 ** 9
    os.utime(package / 'sub' / 'b.py', ns=(later, later))  # an edit of the same size
    assert warm_up.source_stamp(package) != stamp

    cache = tmp_path / 'cache'
    cache.mkdir()
    (cache / (warm_up.COMPLETE_MARKER + 'other')).touch()  # another version's marker
    marker = str(cache / (warm_up.COMPLETE_MARKER + stamp))
    monkeypatch.setattr(warm_up, '_marker_path', lambda: marker)
    assert not warm_up.cache_complete()
    warm_up._mark_complete()
    assert warm_up.cache_complete()
    assert os.listdir(cache) == [os.path.basename(marker)]


def test_compiled_for_returns_the_dispatchers_own_compiled_function():
    """The lanes' typed calls: the same answer as through the dispatcher, compiled if need be."""
    arguments = ((np.float64(-1.5), np.float64(2.0), np.float64(-0.25)),)
    compiled = compiled_for(sum_abs, arguments)
    assert compiled(*arguments) == sum_abs(*arguments) == 3.75
    integers = ((np.int64(-1), np.int64(2), np.int64(3)),)  # a type never compiled before
    assert compiled_for(sum_abs, integers)(*integers) == 6
