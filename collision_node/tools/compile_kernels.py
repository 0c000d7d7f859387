"""Compile the package's numba kernels into numba's cache now, in parallel, printing progress.

    python -m collision_node.tools.compile_kernels [--processes N]

.ci/setup-venv runs it once the package is installed, so that the first start of the node
(and of collision_demo) loads the kernels in about a second instead of compiling them. It
compiles the warm-up's sections (collision_node.pipeline.warm_up.SECTIONS) in one process a
CPU, and the clouds' kernel and the lanes' (ros/lanes.py) last, into the cache the node will
read (the same NUMBA_CACHE_DIR, if one is set); a kernel already in the
cache is loaded, not compiled. No ROS is started.
"""
import argparse
import os
import sys
import time

from collision_node.pipeline.warm_up import compile_in_processes, SECTIONS
from collision_node.ros.lanes import compile_ros_kernels


def main(args=None):
    """Compile every kernel; print a line a part done and the total."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--processes', type=int, default=os.cpu_count(),
                        help='processes that compile (default: one a CPU, %(default)s)')
    processes = max(1, parser.parse_args(args).processes)
    start = time.monotonic()
    print('compiling the numba kernels missing from its cache: %d parts in %d processes'
          % (len(SECTIONS) + 1, processes), flush=True)
    kernels = compile_in_processes(processes=processes,
                                   report=lambda line: print(line, flush=True),
                                   last=[('clouds and lanes', compile_ros_kernels)])
    print('compiled %d kernels in %.0f s' % (kernels, time.monotonic() - start), flush=True)


if __name__ == '__main__':
    sys.exit(main())
