"""One teach or search picture with what locates it (:class:`View`), and the camera-image mask of the
edges that known geometry explains (:func:`known_edge_mask`: the table's slots and border, the
printed marker labels)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from app.geometry.model_edges import (
    PreparedModel,
    project_points_px,
    visible_edge_samples,
)
from app.geometry.transforms import transform_points


@dataclass(frozen=True)
class View:
    """One teach or search picture with what locates it: image as taken, intrinsics, the table pose,
    an optional camera-image mask (uint8, > 0) of edges known to be something else, and the table
    pose's covariance (rotation about the table axes rad, shift along them mm at
    ``table_centroid_mm``: :class:`~app.vision.fiducials.TablePose`'s convention). Without it the
    table pose is taken as exact (synthetic tests with the true pose)."""

    image: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    T_cam_table: np.ndarray
    ignore: np.ndarray | None = None
    table_cov: np.ndarray | None = None          # (6, 6) of T_cam_table as locate_table's TablePose.covariance
    table_centroid_mm: np.ndarray | None = None  # its centroid_table_mm (where that covariance's shift is)

    @staticmethod
    def of(image: np.ndarray, K: np.ndarray, dist, table, ignore: np.ndarray | None = None) -> View:
        """A view located by :func:`app.vision.fiducials.locate_table`'s ``TablePose`` (its pose and its
        covariance, so that the pose's error enters every sigma found in this picture)."""
        return View(image, K, dist, table.T_cam_table, ignore, np.asarray(table.covariance, float),
                    np.asarray(table.centroid_table_mm, float))


def known_edge_mask(shape: tuple[int, int], K, dist, T_cam_table, known: list[tuple[PreparedModel, np.ndarray]] = (),
                    regions_table: list = (), width_px: float = 1.5) -> np.ndarray:
    """Camera-image mask (uint8) of edges that known geometry explains: the visible edges of
    ``known`` models (pairs of prepared model and ``T_table_model``, e.g. the table's slots and
    border) drawn ``width_px`` wide, and ``regions_table`` polygons (table frame, (N, 3) mm, e.g. the
    printed marker labels) filled. The same geometry as the engine's
    :func:`~app.vision.object_pose.edge_image.mask_known_edges` and ``mask_table_regions``."""
    H, W = shape
    K = np.asarray(K, float)
    d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    T_cam_table = np.asarray(T_cam_table, float)
    mask = np.zeros((H, W), np.uint8)
    for model, T_table_model in known:
        es = visible_edge_samples(model, T_cam_table @ np.asarray(T_table_model, float), K, d, W, H,
                                  max_buffer_px=1200)
        for u, v in np.rint(es.uv_px * 4).astype(np.int64):
            cv2.circle(mask, (int(u), int(v)), round(width_px * 4), 255, -1, shift=2)
    for poly in regions_table:
        P = transform_points(T_cam_table, np.asarray(poly, float).reshape(-1, 3))
        if np.any(P[:, 2] <= 1.0):
            continue
        uv = project_points_px(P, K, d)
        cv2.fillPoly(mask, [np.rint(uv * 4).astype(np.int32)], 255, shift=2)
    return mask
