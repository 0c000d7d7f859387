"""Scenes and a naive reference for the broad-phase tests (no code under test used here).

The reference finds the AABB-overlapping pairs with numpy broadcasting, written from the
definition (closed intervals on three axes) rather than from the kernels; the scenes are
small, seeded and self-contained, so the tests do not depend on ``collision_node.pipeline.scenes``.
"""
import numpy as np


def random_quaternions(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def log_scale_half_extents(rng, n):
    """Return (n, 3) half extents from 0.5 mm to 25 m, each drawn on a log scale."""
    return np.exp(rng.uniform(np.log(5e-4), np.log(25.0), (n, 3)))


def poses(positions, quaternions):
    return np.concatenate([positions, quaternions], axis=1)


class Scene:
    """Static boxes and a function of the tick giving the dynamic boxes."""

    def __init__(self, static_poses, static_half_extents, dynamic):
        self.static_poses = np.asarray(static_poses, float).reshape(-1, 7)
        self.static_half_extents = np.asarray(static_half_extents, float).reshape(-1, 3)
        self.dynamic = dynamic  # tick -> (poses (D, 7), half extents (D, 3))


def uniform(n, seed=0, static_fraction=0.5, clustered=False, speed=0.5):
    """Random boxes in a cube (about one colliding pair per body), moving and spinning.

    ``clustered``: 90 % of them in one corner cube of half the side.
    """
    rng = np.random.default_rng(seed)
    side = 0.62 * max(n, 1) ** (1 / 3)
    position = rng.uniform(0, side, (n, 3))
    if clustered:
        position[rng.random(n) < 0.9] *= 0.5
    quaternion = random_quaternions(rng, n)
    extents = rng.uniform(0.1, 0.3, (n, 3))
    n_static = int(n * static_fraction)
    velocity = rng.uniform(-speed, speed, (n - n_static, 3))
    spin = rng.uniform(-1, 1, (n - n_static, 3))

    def dynamic(tick):
        t = 0.1 * tick
        moved = position[n_static:] + velocity * t
        moved = np.abs((moved % (2 * side)) - side)  # bounce between the walls
        angle = np.linalg.norm(spin, axis=1) * t
        axis = spin / np.linalg.norm(spin, axis=1, keepdims=True)
        turn = np.concatenate([axis * np.sin(angle / 2)[:, None],
                               np.cos(angle / 2)[:, None]], axis=1)
        return poses(moved, _multiply(turn, quaternion[n_static:])), extents[n_static:]

    return Scene(poses(position[:n_static], quaternion[:n_static]), extents[:n_static],
                 dynamic)


def flying_out(n, seed=0, dt=0.05):
    """Return the "Discrete Collision Algorithms" scene: cubes packed at the origin fly out."""
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = 0.75 * n ** (1 / 3) * rng.random(n) ** (1 / 3)
    speed = rng.uniform(1.0, 3.0, (n, 1))
    quaternion = random_quaternions(rng, n)
    extents = np.full((n, 3), 0.5)

    def dynamic(tick):
        return poses(direction * (radius[:, None] + speed * dt * tick), quaternion), extents

    return Scene(np.zeros((0, 7)), np.zeros((0, 3)), dynamic)


def _multiply(p, q):
    """Hamilton products of quaternions (x, y, z, w)."""
    pv, pw = p[:, :3], p[:, 3:]
    qv, qw = q[:, :3], q[:, 3:]
    return np.concatenate([pw * qv + qw * pv + np.cross(pv, qv),
                           pw * qw - np.sum(pv * qv, axis=1, keepdims=True)], axis=1)


def reference_overlaps(aabbs, n_static, n_total):
    """Sorted (P, 2) rows of every AABB-overlapping pair in interface order (closed test)."""
    low = aabbs[:n_total, 0]
    high = aabbs[:n_total, 1]
    found = []
    for start in range(n_static, n_total, 512):
        rows = np.arange(start, min(start + 512, n_total))
        touch = np.all((low[rows, None, :] <= high[None, :, :])
                       & (low[None, :, :] <= high[rows, None, :]), axis=2)
        other = np.arange(n_total)[None, :]
        # dynamic a with static b, or with a dynamic b of larger row
        keep = touch & ((other < n_static) | (other > rows[:, None]))
        a, b = np.nonzero(keep)
        found.append(np.stack([rows[a], b], axis=1))
    if not found:
        return np.zeros((0, 2), np.int64)
    pairs = np.concatenate(found)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def sorted_pairs(pairs):
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def contact_ids(result):
    """Return the (id_a, type_b, id_b) rows of a World result (must match brute force)."""
    contacts = result.contacts
    return np.stack([contacts['id_a'], contacts['type_b'], contacts['id_b']], axis=1)
