"""Objects known from photographs instead of CAD: a 2.5-D edge template in the table plane.

A fixture, clamp or repeat part without a CAD model is taught from the machine's own camera. With
the table located by its markers (``T_cam_table``), every picture is *rectified* onto the plane
``z = height`` of the table frame, so one rectified pixel is a fixed square of that plane in
millimetres. Seen so, the object's top face keeps its true shape and size from any camera pose, while
its side walls, its shadow and the table's own edges (all below the plane) do not line up between
views. The package follows the stages (docs/photo-models.md):

* :mod:`.plane` - :class:`PlaneGrid`, :func:`plane_homography` and :func:`rectify` (a picture ->
  the table plane at the object's height, ``FINE_MM_PER_PX``), :func:`~.plane.camera_mm_per_px`;
* :mod:`.edges` - subpixel edges of a rectified picture, the known edges left out;
* :mod:`.view` - :class:`View` (a picture, its intrinsics and table pose with its covariance) and
  :func:`known_edge_mask`;
* :mod:`.model` - :class:`PhotoModel` (template points and normals, height, outline, holes,
  symmetries, the teach placement; ``to_dict`` / ``from_dict``), ``TEMPLATE_SPACING_MM``,
  ``CLUSTER_MM``, the template placed at a pose;
* :mod:`.template` - :func:`teach` (outline, inner edges, agreement of several pictures, the top face,
  symmetries, ``teach_cov``) and :class:`TeachError`; :mod:`.height` - :func:`measure_height`;
* locating, :func:`locate` in :mod:`.locating`: :mod:`.search` (coarse x, y, turn), :mod:`.fit`
  (least squares, ``SUPPORT_MM``, the score), :mod:`.verify` (unexplained and missing edges,
  distinctiveness, edge IoU, ``EXPLAINED_MM``), :mod:`.uncertainty` (sigma: the fit's scatter, the
  table-pose propagation, :data:`EDGE_BIAS_PX`);
* :mod:`.lookalikes` - :func:`decide_lookalikes` among photo models at one place.

The answer of :func:`locate` is the CAD engine's :class:`~app.vision.object_pose.results.ObjectPose`
or :class:`~app.vision.object_pose.results.ObjectFailure`.

Frames and units: docs/design.md (``T_a_b``, mm, degrees at the boundary, radians inside). The
object is taken to rest on the table top (z = 0) with its top face at ``height_mm``.
"""

from app.vision.photo_model.height import measure_height
from app.vision.photo_model.locating import locate, locate_near
from app.vision.photo_model.lookalikes import decide_lookalikes
from app.vision.photo_model.model import TEMPLATE_SPACING_MM, PhotoModel
from app.vision.photo_model.plane import PlaneGrid, plane_homography, rectify
from app.vision.photo_model.template import TeachError, teach
from app.vision.photo_model.uncertainty import EDGE_BIAS_PX
from app.vision.photo_model.view import View, known_edge_mask

__all__ = [
    "EDGE_BIAS_PX",
    "TEMPLATE_SPACING_MM",
    "PhotoModel",
    "PlaneGrid",
    "TeachError",
    "View",
    "decide_lookalikes",
    "known_edge_mask",
    "locate",
    "locate_near",
    "measure_height",
    "plane_homography",
    "rectify",
    "teach",
]
