"""Sine and cosine of one angle together, in plain arithmetic a loop over states can vectorize.

The robot's forward kinematics takes a sine and a cosine per turning joint. libm's ``sin``
and ``cos`` cost about 20 ns a pair on the AMD EPYC VM (numba calls them one value at a
time, and without Intel's SVML no loop that calls them vectorizes): a third of the Panda's
forward kinematics. :func:`reduced_sincos` is fdlibm's: the angle reduced by the nearest
multiple of pi/2 (Cody and Waite, pi/2 in three parts: the first's 33 bits times any
multiple below 2**20 are exact), then fdlibm's ``__kernel_sin`` and ``__kernel_cos``
polynomials on [-pi/4, pi/4] and the quadrant's swap and signs as selects, no branch: about
1.5 ns a pair in a loop LLVM vectorizes. Within 1 ulp of glibc's ``sin`` and ``cos`` on
every one of 2.5 million random angles (|x| < 8e5) when it was written; test/test_trig.py
checks 250,000 of them and every multiple of pi/4 up to 10 pi.

:func:`sincos` is the one every caller uses for one angle: :func:`reduced_sincos` within
REDUCED_LIMIT, libm beyond it (a multiple of pi/2 past 2**19 no longer reduces exactly) and
for NaN and Inf. A loop over many angles tests its block against REDUCED_LIMIT once and then
calls :func:`reduced_sincos` alone: the same values, bit for bit, as :func:`sincos` gives.
"""
import math

import numpy as np

from collision_node.pipeline._jit import inlined_kernel

TWO_OVER_PI = 6.36619772367581382433e-01
# pi/2 = PIO2_1 + PIO2_2 + PIO2_2T to about 2**-140: the first two hold 33 bits each.
PIO2_1 = 1.57079632673412561417e+00
PIO2_2 = 6.07710050630396597660e-11
PIO2_2T = 2.02226624879595063154e-21
# fdlibm's k_sin.c and k_cos.c (FreeBSD msun): minimax on [-pi/4, pi/4].
S1, S2, S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
S4, S5, S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
C1, C2, C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
C4, C5, C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11
# |x| within which reduced_sincos reduces exactly: the multiple n of pi/2 stays below 2**19.
REDUCED_LIMIT = 823549.0


@inlined_kernel
def reduced_sincos(x):
    """Return (sin x, cos x) for |x| <= REDUCED_LIMIT (module docstring), branch free."""
    n = np.rint(x * TWO_OVER_PI)
    # x - n pi/2 as fdlibm's __ieee754_rem_pio2 takes it, both parts of pi/2's tail kept.
    high = x - n * PIO2_1
    tail = n * PIO2_2
    y = high - tail
    tail = n * PIO2_2T - ((high - y) - tail)
    y = y - tail
    z = y * y
    sine = y + z * y * (S1 + z * (S2 + z * (S3 + z * (S4 + z * (S5 + z * S6)))))
    w = z * z
    r = z * (C1 + z * (C2 + z * C3)) + w * w * (C4 + z * (C5 + z * C6))
    half = 0.5 * z
    one = 1.0 - half
    cosine = one + (((1.0 - one) - half) + z * r)
    quadrant = np.int64(n) & 3
    odd = (quadrant & 1) != 0
    s = cosine if odd else sine
    c = sine if odd else cosine
    s = -s if (quadrant & 2) != 0 else s
    c = -c if ((quadrant + 1) & 2) != 0 else c
    return s, c


@inlined_kernel
def sincos(x):
    """Return (sin x, cos x) for any x: reduced_sincos within REDUCED_LIMIT, else libm."""
    if abs(x) <= REDUCED_LIMIT:
        return reduced_sincos(x)
    return math.sin(x), math.cos(x)
