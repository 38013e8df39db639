"""Pose of a CAD part on the machine table from one image, without markers on the part.

Given the table's pose ``T_cam_table`` (from its fiducials), the intrinsics and a prepared model
(:func:`app.geometry.model_edges.prepare_model`), :func:`locate_object` finds ``T_cam_obj`` and
``T_table_obj = inv(T_cam_table) @ T_cam_obj``. The package follows the engine's stages:

* :mod:`.edge_image` - the image prepared once for all models (edges, directions, distance map);
* :mod:`.search` - stage 1: the part rests on a horizontal surface, so a pose is a resting state, a
  position and a turn about the table normal; an oriented chamfer correlation of the model's
  horizontal edges with the image edges cast onto each plane gives the starts;
* :mod:`.planar_fit` - stage 2: each start aligned in the table plane (oriented chamfer ICP);
* :mod:`.refine` - stage 3: subpixel edges along the model's edge normals and the least-squares fit;
* :mod:`.verify` and :mod:`.datum` - stage 4: support, distinctiveness, rival poses, symmetries;
* :mod:`.uncertainty` - the contact prior and the posterior covariance (the export gate's sigma);
* :mod:`.locate` - :func:`locate_object`, which reads as these stages; :mod:`.recognise` - which
  library models are in the image; :mod:`.options` - :class:`LocateOptions`, one frozen object;
* :mod:`.results` - :class:`ObjectPose`, :class:`ObjectFailure`, :class:`Recognition`, :class:`Progress`.

A fit that is not good enough, or not clearly better than a different pose, is returned as an
:class:`ObjectFailure` with the reason; it is never returned as a pose.

Conventions: docs/design.md (``T_a_b``, mm, degrees at the boundary); pixels are OpenCV's (u right, v
down, centres at integers); ``image`` is 8-bit grey (a colour image is converted).
"""

from app.vision.object_pose.draw import draw_object
from app.vision.object_pose.edge_image import EdgeImage, mask_known_edges, mask_table_regions, prepare_image
from app.vision.object_pose.locate import locate_object
from app.vision.object_pose.options import LocateOptions
from app.vision.object_pose.recognise import recognise
from app.vision.object_pose.results import ObjectFailure, ObjectPose, Progress, Recognition
from app.vision.object_pose.uncertainty import SIGMA_SCALE

__all__ = [
    "EdgeImage",
    "LocateOptions",
    "ObjectFailure",
    "ObjectPose",
    "Progress",
    "Recognition",
    "SIGMA_SCALE",
    "draw_object",
    "locate_object",
    "mask_known_edges",
    "mask_table_regions",
    "prepare_image",
    "recognise",
]
