"""The engine's entry points run with one BLAS thread and give the setting back."""

from threadpoolctl import threadpool_info

from app.vision.blas_threads import available_cores, one_blas_thread


def _blas_threads() -> list[int]:
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_one_blas_thread_inside_and_restored_after():
    import numpy as np

    np.ones((4, 4)) @ np.ones((4, 4))          # BLAS loaded
    before = _blas_threads()
    seen = one_blas_thread(_blas_threads)()
    assert seen and all(n == 1 for n in seen)
    assert _blas_threads() == before


def test_the_engine_entry_points_are_limited():
    from app.vision import localize, object_pose

    for fn in (localize.localize, object_pose.locate_object, object_pose.recognise):
        assert getattr(fn, "__wrapped__", None) is not None, fn.__name__


def test_the_cores_a_process_may_use_are_its_affinity_else_all(monkeypatch):
    import os

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {2, 5, 7}, raising=False)
    assert available_cores() == 3           # pinned by taskset or a container's cpuset
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert available_cores() == 1           # nothing known: one
