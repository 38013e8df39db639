"""Safe travel paths for probes and sensors, and probing programs (issue 8). Pure: numbers in, numbers out.

* ``path``       types (ProbeParams, AxisSpeeds, PlannedMove, PlannedPath), length and time.
* ``obstacles``  obstacle heights: per move, part top, region map with priority rules, from meshes, raster.
* ``reference``  the reference safe-height method (four patterns, two shortening variants, orthogonal).
* ``profile``    the profile planner: taut path over the real height profile of each move's corridor.
* ``collision``  independent swept-body check against the scene meshes (python-fcl).
* ``probing``    touch points, LinuxCNC G-code (G38.2 / dry run), probe-log parser, offset refinement.
* ``probing_safety`` what a probing program may assume (located / assumed obstacles), where touches
                 may go, retract height, machine travel; the gated planner ``plan_probing_program``.
* ``program_check``  independent check of a program: parsed back, exact distances to true primitives.
* ``request``    a JSON request -> planned path answer (CLI ``setupcam plan`` and REST).
"""

from __future__ import annotations

from numpy.typing import ArrayLike

from app.planning.obstacles import ObstacleSource
from app.planning.path import AxisSpeeds, PlannedMove, PlannedPath, ProbeParams, path_length_mm, path_time_s
from app.planning.profile import ProfileOptions, plan_path_profile
from app.planning.reference import ReferenceOptions, plan_path_reference


def plan_path(
    points: ArrayLike,
    obstacles: ObstacleSource,
    probe: ProbeParams,
    method: str = "reference",
    options: ReferenceOptions | ProfileOptions | None = None,
) -> PlannedPath:
    """Plan the travel through ``points`` (N, 3; mm; focal-plane heights; table frame) in order.

    method "reference": :func:`plan_path_reference` (``options``: ReferenceOptions);
    method "profile": :func:`plan_path_profile` (``options``: ProfileOptions).
    """
    if method == "reference":
        return plan_path_reference(points, obstacles, probe, options or ReferenceOptions())
    if method == "profile":
        return plan_path_profile(points, obstacles, probe, options or ProfileOptions())
    raise ValueError(f"unknown planning method {method!r}; use 'reference' or 'profile'")


__all__ = [
    "AxisSpeeds",
    "PlannedMove",
    "PlannedPath",
    "ProbeParams",
    "ProfileOptions",
    "ReferenceOptions",
    "path_length_mm",
    "path_time_s",
    "plan_path",
    "plan_path_profile",
    "plan_path_reference",
]
