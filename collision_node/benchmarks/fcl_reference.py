"""python-fcl driven from the same numpy arrays as the World: the outside reference.

Two DynamicAABBTreeCollisionManagers, one for the static boxes (built once) and one for the
dynamic boxes (transforms set from the (D, 7) pose array each tick, then ``update()``);
dynamic-dynamic pairs from ``collide`` on the dynamic manager, dynamic-static pairs from
``collide`` between the managers, both with python-fcl's own ``defaultCollisionCallback``
(a Python call per AABB-overlapping pair: that is how python-fcl is used, and where most of
its time goes). python-fcl is an optional dependency (the ``bench`` extra).
"""
import math
import time

import numpy as np

INSTALL_HINT = 'python-fcl is not installed: pip install python-fcl (the "bench" extra)'

# Box-box collision without contact details yields one contact per colliding pair; the
# request's limit only has to exceed the number of pairs in a tick.
MAX_CONTACTS = 2 ** 31 - 1


def fcl_available():
    try:
        import fcl  # noqa: F401
    except ImportError:
        return False
    return True


class FclWorld:
    """Static and dynamic boxes in python-fcl, with pairs reported as World box rows.

    Rows follow :class:`~collision_node.pipeline.obb.Boxes`' layout: static boxes first, then
    dynamic.
    """

    def __init__(self, static_poses, static_half_extents, dynamic_half_extents, first_poses):
        import fcl
        self._fcl = fcl
        self.n_static = len(static_poses)
        self._row_of_geometry = {}  # id(fcl.Box) -> box row: contacts name geometries
        self._geometries = []       # kept alive, so their ids stay unique
        statics = self._objects(static_poses, static_half_extents, 0)
        self._dynamic = self._objects(first_poses, dynamic_half_extents, self.n_static)
        self._static_manager = fcl.DynamicAABBTreeCollisionManager()
        self._static_manager.registerObjects(statics)
        self._static_manager.setup()
        self._dynamic_manager = fcl.DynamicAABBTreeCollisionManager()
        self._dynamic_manager.registerObjects(self._dynamic)
        self._dynamic_manager.setup()
        self._statics = statics
        self._request = fcl.CollisionRequest(num_max_contacts=MAX_CONTACTS)

    def _objects(self, poses, half_extents, first_row):
        fcl = self._fcl
        objects = []
        for row, (pose, half) in enumerate(zip(poses, half_extents), first_row):
            box = fcl.Box(*(2.0 * half))  # fcl takes full side lengths
            # fcl's quaternions are (w, x, y, z); ours are ROS's (x, y, z, w).
            transform = fcl.Transform(pose[[6, 3, 4, 5]], pose[:3])
            objects.append(fcl.CollisionObject(box, transform))
            self._geometries.append(box)
            self._row_of_geometry[id(box)] = row
        return objects

    def step(self, poses):
        """Move the dynamic boxes to ``poses`` (D, 7) and collide.

        Returns (pairs (P, 2) of box rows, update_ms, collide_ms).
        """
        fcl = self._fcl
        before = time.perf_counter()
        translations = np.ascontiguousarray(poses[:, :3])
        quaternions = poses[:, [6, 3, 4, 5]].tolist()  # the quickest form fcl accepts here
        for body, translation, quaternion in zip(self._dynamic, translations, quaternions):
            body.setTranslation(translation)
            body.setQuatRotation(quaternion)
        self._dynamic_manager.update()
        updated = time.perf_counter()
        data = fcl.CollisionData(request=self._request)
        self._dynamic_manager.collide(data, fcl.defaultCollisionCallback)
        if self.n_static:
            self._dynamic_manager.collide(self._static_manager, data,
                                          fcl.defaultCollisionCallback)
        collided = time.perf_counter()
        rows = self._row_of_geometry
        pairs = np.array([(rows[id(c.o1)], rows[id(c.o2)]) for c in data.result.contacts],
                         dtype=np.int64).reshape(-1, 2)
        return pairs, 1e3 * (updated - before), 1e3 * (collided - updated)


def compare_with_fcl(scene, ticks, dt, phase_names, limits):
    """Ticks of python-fcl and of a World per broad phase on the same poses.

    Returns (python-fcl's numbers, one row per broad phase with both and their ratio over
    the ticks that phase ran). fcl's time is update + collide (its output is its list of
    contacts; turning that into rows for the comparison is not timed); the World's is its
    whole ``step``. The time budget stops the run; a phase whose tick exceeds the tick limit
    stops stepping, the others go on.
    """
    from collision_node.benchmarks.accuracy import contact_keys, pair_errors, pair_keys
    from collision_node.benchmarks.runs import tick_poses
    from collision_node.pipeline.world import World

    n_static = len(scene.static_poses)
    n_total = n_static + scene.dynamic_count
    reference = FclWorld(scene.static_poses, scene.static_half_extents,
                         scene.dynamic_half_extents, scene.dynamic_poses(0.0))
    worlds = {}
    for name in phase_names:
        worlds[name] = World(broad_phase=name)
        worlds[name].set_static(scene.static_poses, scene.static_half_extents)
    fcl_ms = {'update': [], 'collide': []}
    ours = {name: {'ms': [], 'only_ours': 0, 'only_fcl': 0, 'stopped': None}
            for name in phase_names}
    fcl_pairs = 0
    started = time.perf_counter()
    stopped = None
    for _, poses in tick_poses(scene, ticks, dt):
        pairs, update_ms, collide_ms = reference.step(poses)
        fcl_ms['update'].append(update_ms)
        fcl_ms['collide'].append(collide_ms)
        fcl_keys = pair_keys(pairs, n_total)
        fcl_pairs += len(fcl_keys)
        for name, world in worlds.items():
            if ours[name]['stopped']:
                continue
            before = time.perf_counter()
            contacts = world.step(poses, scene.dynamic_half_extents).contacts
            tick_s = time.perf_counter() - before
            ours[name]['ms'].append(1e3 * tick_s)
            only_ours, only_fcl = pair_errors(contact_keys(contacts, n_static, n_total),
                                              fcl_keys)
            ours[name]['only_ours'] += only_ours
            ours[name]['only_fcl'] += only_fcl
            if tick_s > limits.tick_s:
                ours[name]['stopped'] = limits.reason_to_stop(started, tick_s)
        stopped = limits._replace(tick_s=math.inf).reason_to_stop(started, 0.0)
        if stopped:
            break
    ticks_done = len(fcl_ms['update'])
    fcl_total = np.add(fcl_ms['update'], fcl_ms['collide'])
    reference = {'scene': scene.name, 'bodies': n_total, 'ticks': ticks_done,
                 'stopped': stopped if ticks_done < ticks else None,
                 'fcl_median_ms': float(np.median(fcl_total)),
                 'fcl_update_ms': float(np.median(fcl_ms['update'])),
                 'fcl_collide_ms': float(np.median(fcl_ms['collide'])),
                 'pairs_per_tick': fcl_pairs / ticks_done}
    rows = []
    for name in phase_names:
        ran = len(ours[name]['ms'])
        median = float(np.median(ours[name]['ms']))
        fcl_median = float(np.median(fcl_total[:ran]))  # python-fcl on the same ticks
        rows.append(dict(reference, broad_phase=name, ticks=ran,
                         stopped=ours[name]['stopped'] or reference['stopped'],
                         median_ms=median, fcl_median_ms=fcl_median,
                         ratio=fcl_median / median, only_ours=ours[name]['only_ours'],
                         only_fcl=ours[name]['only_fcl']))
    return reference, rows
