"""Two boxes seen from box A: the relative pose, and the tuple arithmetic of per-pair kernels.

Also the tuple arithmetic of frames: quaternion products and rotations (the robot's forward
kinematics, a pose's box), and a point's distance outside a box (the robot's culls and bounds).

Per-pair kernels (sat.py, distance.py) work in the frame of a pair's first box A: R = AᵀB as a
row-major 9-tuple, R[3i + j] = a_i·b_j (column j is B's axis j in A's frame), and
t = Aᵀ(c_B − c_A), B's centre in A's frame. Working relative to A keeps the numbers as small
as the pair, not as large as its distance from the world origin.

Speed notes. The helpers take and return tuples of floats, never arrays: numba
reference-counts every array handed to a function it does not inline (two atomic operations
per array per call), which cost more than the whole SAT. And each helper that indexes a tuple
is called with constant indices, so that it is inlined and the indexing resolved at compile
time; a tuple indexed at run time compiles to a branch per element.
"""
from collision_node.pipeline._jit import inlined_kernel, kernel

# Two edges whose cross product is shorter than this are parallel: their axis is the zero
# vector and the face axes already decide the pair. Any longer cross product is a valid axis,
# however noisy its direction (SAT holds for every direction).
MIN_EDGE_AXIS_LENGTH = 1e-150


@kernel
def matrix(rotations, a):
    """Return box ``a``'s rotation matrix as a row-major 9-tuple."""
    return (rotations[a, 0, 0], rotations[a, 0, 1], rotations[a, 0, 2],
            rotations[a, 1, 0], rotations[a, 1, 1], rotations[a, 1, 2],
            rotations[a, 2, 0], rotations[a, 2, 1], rotations[a, 2, 2])


@kernel
def rotation_from_quaternion(x, y, z, w):
    """Return the rotation matrix of a unit quaternion, row-major (9-tuple)."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w),
            2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w),
            2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y))


@kernel
def quaternion_product(p, q):
    """Return the Hamilton product p q of two quaternions (x, y, z, w): q's turn, then p's."""
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return (pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz)


@kernel
def relative_pose(ra, rb, d):
    """R = AᵀB and t = Aᵀd from the world rotations (row-major) and d = c_B − c_A."""
    rel = (column_dot(ra, 0, rb, 0), column_dot(ra, 0, rb, 1), column_dot(ra, 0, rb, 2),
           column_dot(ra, 1, rb, 0), column_dot(ra, 1, rb, 1), column_dot(ra, 1, rb, 2),
           column_dot(ra, 2, rb, 0), column_dot(ra, 2, rb, 1), column_dot(ra, 2, rb, 2))
    return rel, transposed_times(ra, d)


@kernel
def transposed_times(matrix, v):
    """Return ``matrix`` (a row-major 9-tuple) transposed times ``v``: v in its frame."""
    return (matrix[0] * v[0] + matrix[3] * v[1] + matrix[6] * v[2],
            matrix[1] * v[0] + matrix[4] * v[1] + matrix[7] * v[2],
            matrix[2] * v[0] + matrix[5] * v[1] + matrix[8] * v[2])


@kernel
def column_dot(ra, i, rb, j):
    """Return column i of ``ra`` dotted with column j of ``rb`` (row-major 9-tuples)."""
    return ra[i] * rb[j] + ra[3 + i] * rb[3 + j] + ra[6 + i] * rb[6 + j]


@kernel
def column(rel, j):
    """Return B's axis j in A's frame."""
    return rel[j], rel[3 + j], rel[6 + j]


@kernel
def rotate(matrix, v):
    """Return ``matrix`` (a row-major 9-tuple) times ``v``."""
    return (matrix[0] * v[0] + matrix[1] * v[1] + matrix[2] * v[2],
            matrix[3] * v[0] + matrix[4] * v[1] + matrix[5] * v[2],
            matrix[6] * v[0] + matrix[7] * v[1] + matrix[8] * v[2])


@inlined_kernel
def placed(r, t, p):
    """Return the point ``p`` of a frame (rotation ``r`` row-major, origin ``t``) outside it.

    t + r p, the origin added first and the products one by one (not t + :func:`rotate`):
    the order the forward kinematics' frames and box centres have always been summed in,
    which the robot's kernels share to the bit. Inlined by numba, so that the robot's loops
    over states vectorize.
    """
    return (t[0] + r[0] * p[0] + r[1] * p[1] + r[2] * p[2],
            t[1] + r[3] * p[0] + r[4] * p[1] + r[5] * p[2],
            t[2] + r[6] * p[0] + r[7] * p[1] + r[8] * p[2])


@inlined_kernel
def turned(r, m):
    """Return the rotation r m (row-major 9-tuples): m's axes turned by r (inlined as placed)."""
    return (r[0] * m[0] + r[1] * m[3] + r[2] * m[6], r[0] * m[1] + r[1] * m[4] + r[2] * m[7],
            r[0] * m[2] + r[1] * m[5] + r[2] * m[8], r[3] * m[0] + r[4] * m[3] + r[5] * m[6],
            r[3] * m[1] + r[4] * m[4] + r[5] * m[7], r[3] * m[2] + r[4] * m[5] + r[5] * m[8],
            r[6] * m[0] + r[7] * m[3] + r[8] * m[6], r[6] * m[1] + r[7] * m[4] + r[8] * m[7],
            r[6] * m[2] + r[7] * m[5] + r[8] * m[8])


@kernel
def dot(u, v):
    """Return the dot product of two 3-tuples."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


@kernel
def cross(u, v):
    """Return the cross product of two 3-tuples."""
    return u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]


@kernel
def squared_distance_outside(d, r, e):
    """Return the squared distance from a box to the point ``d`` from its centre (0 inside).

    ``r`` the box's rotation (row-major 9-tuple), ``e`` its half extents, ``d`` in the world's
    axes: the part of each coordinate in the box's frame beyond the half extent. A sign of d
    changes nothing (the box is symmetric).
    """
    x = max(abs(r[0] * d[0] + r[3] * d[1] + r[6] * d[2]) - e[0], 0.0)
    y = max(abs(r[1] * d[0] + r[4] * d[1] + r[7] * d[2]) - e[1], 0.0)
    z = max(abs(r[2] * d[0] + r[5] * d[1] + r[8] * d[2]) - e[2], 0.0)
    return x * x + y * y + z * z


@kernel
def sum_abs(v):
    """Return the sum of the absolute values of a 3-tuple."""
    return abs(v[0]) + abs(v[1]) + abs(v[2])


@kernel
def zero_if_finite(v):
    """Return 0 when the 3-tuple ``v`` is finite, else NaN (x · 0 is NaN for NaN and ±Inf).

    Written out, not looped: a loop over a tuple compiles to an indirect jump per element
    (measured: 15 % of the whole SAT), and a sum of x · 0 cannot overflow.
    """
    return v[0] * 0.0 + v[1] * 0.0 + v[2] * 0.0


@kernel
def zero_if_finite_matrix(m):
    """:func:`zero_if_finite` for a row-major 9-tuple."""
    return zero_if_finite(m[0:3]) + zero_if_finite(m[3:6]) + zero_if_finite(m[6:9])


# The overlap of the two boxes' projections on each of the 15 SAT axes (< 0: a gap).

@kernel
def face_a_overlap(rel, t, ea, eb, i):
    radius_b = eb[0] * abs(rel[3 * i]) + eb[1] * abs(rel[3 * i + 1]) + eb[2] * abs(rel[3 * i + 2])
    return ea[i] + radius_b - abs(t[i])


@kernel
def face_b_overlap(rel, t, ea, eb, j):
    b_j = column(rel, j)
    radius_a = ea[0] * abs(b_j[0]) + ea[1] * abs(b_j[1]) + ea[2] * abs(b_j[2])
    return radius_a + eb[j] - abs(dot(t, b_j))


@kernel
def edge_overlap(rel, t, ea, eb, i, j):
    """Return (overlap × |L|, |L|²) on the axis L = e_i × b_j, not normalised.

    In A's frame L = (0, −R[i2, j], R[i1, j]) in the order (i, i1, i2) = (i, i+1, i+2 mod 3):
    straight from R, so the cross product adds no rounding.
    """
    i1 = (i + 1) % 3
    i2 = (i + 2) % 3
    u1 = -rel[3 * i2 + j]
    u2 = rel[3 * i1 + j]
    radius_a = ea[i1] * abs(u1) + ea[i2] * abs(u2)
    # B's radius from the full dot products L·b_m, not from the cofactor identity
    # (e_i × b_j)·b_m = ±R[i, k]: that identity needs an exactly orthonormal B and is off by
    # eps/|L| for near-parallel edges. The term m = j is exactly 0 (u1·u2 − u2·u1).
    radius_b = 0.0
    for m in range(3):
        if m != j:
            radius_b += eb[m] * abs(u1 * rel[3 * i1 + m] + u2 * rel[3 * i2 + m])
    return radius_a + radius_b - abs(u1 * t[i1] + u2 * t[i2]), u1 * u1 + u2 * u2


@kernel
def projection_gap(rel, t, ea, eb, n):
    """Return the gap (< 0: overlap) between the boxes' projections on the direction n.

    n in A's frame, unit: the distance is at least this gap, equal to it along the closest
    direction.
    """
    nb = (dot(column(rel, 0), n), dot(column(rel, 1), n), dot(column(rel, 2), n))
    return (dot(t, n) - (ea[0] * abs(n[0]) + ea[1] * abs(n[1]) + ea[2] * abs(n[2]))
            - (eb[0] * abs(nb[0]) + eb[1] * abs(nb[1]) + eb[2] * abs(nb[2])))
