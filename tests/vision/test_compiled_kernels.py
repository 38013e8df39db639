"""The warm-up compiles the engine's numba loops for the argument types the engine really passes:
after it, a whole localisation adds no compiled version of any loop (each new one would be compiled
inside a job, holding Python's lock while the job's heartbeats wait)."""

from __future__ import annotations

from app.geometry import raster_kernels
from app.vision import compiled_kernels
from app.vision.object_pose import locate_object, search_kernels
from tests.vision.object_pose.test_search import _bracket_scene

LOOPS = (search_kernels.planar_scores, search_kernels.conj_product_sum, raster_kernels.raster_min_depth,
         raster_kernels.span_pixel_count)


def test_after_the_warm_up_a_localisation_compiles_nothing_more():
    compiled_kernels.warm_up()
    assert compiled_kernels.warm_up() == 0.0               # once per process
    before = {f.__name__: list(f.signatures) for f in LOOPS}
    assert all(before.values())
    model, T_true, scene, eimg = _bracket_scene()
    pose = locate_object(None, scene.K, scene.dist, scene.T_cam_table, model, edge_image=eimg)
    assert pose.model_name == "bracket_140" and hasattr(pose, "T_table_obj")
    assert {f.__name__: list(f.signatures) for f in LOOPS} == before
