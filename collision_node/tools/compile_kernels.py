"""Compile the node's numba kernels into numba's cache now, printing the progress.

    python -m collision_node.tools.compile_kernels

.ci/setup-venv runs it once the package is installed, so that the first start of the node
(and of collision_demo) loads the kernels in about a second instead of compiling them for
about 30. It compiles what the node's warm-up does, into the cache the node will read (the
same NUMBA_CACHE_DIR, if one is set); a kernel already in the cache is loaded, not compiled.
"""
import sys

from collision_node.pipeline.jit_progress import compile_progress
from collision_node.ros.node import compile_kernels


def main():
    with compile_progress(lambda line: print(line, flush=True)):
        compile_kernels()


if __name__ == '__main__':
    sys.exit(main())
