"""The engine's numba loops made ready before the first job needs them.

numba compiles a loop on its first call (about 3 s for the plane search's and the z-buffer's on a
fresh checkout), or loads it from its cache beside the source (about 0.2 s). Either way Python's lock
is held meanwhile: inside a job, the watchdog's heartbeats wait, and a short stall limit takes the job
for dead. :func:`warm_up` runs each loop once on a tiny scene through the engine's own calls, so it
is compiled for exactly the argument types the engine passes; the job runner calls it once per
process before it claims a job, and the bootstrap once after installing (the cache it writes serves
every later process).
"""

from __future__ import annotations

import threading
import time

import numpy as np

_lock = threading.Lock()
_ready = False


def warm_up() -> float:
    """Compile or load the plane search's and the z-buffer's loops (once per process; later calls
    return at once). Returns the seconds it took here (0 when already done)."""
    global _ready
    if _ready:
        return 0.0
    with _lock:
        if _ready:
            return 0.0
        t = time.perf_counter()
        _run_each_loop()
        _ready = True
        return time.perf_counter() - t


def _run_each_loop() -> None:
    import cv2
    import trimesh

    from app.geometry.model_edges import render_depth
    from app.geometry.transforms import inv, pose_from_xyz_euler, transform_points
    from app.vision.object_pose.edge_image import prepare_image
    from app.vision.object_pose.search import _image_scorer
    from app.vision.object_pose.search_kernels import conj_product_sum

    # a bright square on grey seen from 300 mm straight above, a lens with some distortion
    img = np.full((96, 96), 90, np.uint8)
    cv2.rectangle(img, (30, 30), (66, 66), 200, -1)
    K = np.array([[120.0, 0.0, 48.0], [0.0, 120.0, 48.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])
    T_cam_table = inv(pose_from_xyz_euler(0.0, 0.0, 300.0, 180.0, 0.0, 0.0))
    score = _image_scorer(prepare_image(img), K, dist, T_cam_table)
    P = np.array([[-15.0, -15.0, 0.0], [15.0, -15.0, 0.0], [15.0, 15.0, 0.0], [-15.0, 15.0, 0.0]])
    D = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    up = np.tile([0.0, 0.0, 1.0], (4, 1))
    hx, hy, ht = np.zeros(3), np.zeros(3), np.array([0.0, 0.1, 0.2])
    score(hx, hy, ht, P, D, np.ones(4))
    score(hx, hy, ht, P, D, np.ones(4), normals=(up, -up, np.zeros(4, bool)))
    spectra = np.ones((2, 4, 3), np.complex64)
    conj_product_sum(spectra, spectra)
    box = trimesh.creation.box(extents=(20.0, 20.0, 20.0))
    render_depth([(transform_points(pose_from_xyz_euler(0.0, 0.0, 300.0, 170.0, 5.0, 0.0), box.vertices),
                   box.faces)], K, 96, 96)
