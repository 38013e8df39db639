"""The image side of the engine, prepared once and shared by every candidate model: gamma-decoded
intensity, Canny edges with their directions, distance map to the nearest edge, and masks for edges
that known geometry (the table, its printed labels) explains. Pixels are OpenCV's (u right, v down)."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from app.geometry.model_edges import PreparedModel, project_points_px, visible_edge_samples
from app.geometry.transforms import transform_points


#: grey level (0-255, any colour channel) from which a pixel counts as clipped: a face brighter than the
#: sensor's top reads flat there, and the 50 % crossing of an edge beside it moves toward the dark side
#: (devset setup_006: 0.37 px on two thirds of a white part's edges, 0.8 mm of its position)
CLIP_GREY = 250


@dataclass(frozen=True, eq=False)
class EdgeImage:
    """An image prepared once for all candidate models.

    linear : (H, W) float32 intensity with the camera's gamma undone (0..1)
    edges : (H, W) uint8 Canny edge map
    dist_px : (H, W) float32 distance to the nearest edge pixel (made on first use)
    nearest : (H, W) int32 index into ``edge_uv`` of that pixel (made with ``dist_px``)
    edge_uv : (E, 2) float edge pixel positions (u, v); ``edge_angle`` (E,) gradient direction, rad
    clipped : (H, W) bool, pixels at the sensor's top (any channel at :data:`CLIP_GREY` or above),
        whose true brightness is not known; None: not known (nothing treated as clipped)
    """

    width: int
    height: int
    linear: np.ndarray
    edges: np.ndarray
    edge_uv: np.ndarray
    edge_angle: np.ndarray
    edge_mag: np.ndarray
    noise_linear: float
    gamma: float = 2.2                           # the decoding's: edge contrasts are judged at their grey level
    clipped: np.ndarray | None = None
    cache: dict = field(default_factory=dict)   # per-image intermediate results shared by models

    @property
    def dist_px(self) -> np.ndarray:
        return self._distance()[0]

    @property
    def nearest(self) -> np.ndarray:
        return self._distance()[1]

    def _distance(self) -> tuple[np.ndarray, np.ndarray]:
        # a distance transform of the whole image (30 ms at 1920 x 1200): an edge map that is masked
        # further before any search (the table's edges, then the labels') never needs its own
        if "distance" not in self.cache:
            dist_px, labels = cv2.distanceTransformWithLabels(
                np.where(self.edges > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5,
                labelType=cv2.DIST_LABEL_PIXEL)
            nearest = (labels.astype(np.int32) - 1) if len(self.edge_uv) else np.zeros_like(labels, dtype=np.int32)
            self.cache["distance"] = (dist_px.astype(np.float32), nearest)
        return self.cache["distance"]


def prepare_image(image: np.ndarray, *, gamma: float = 2.2, canny_low: float | None = None,
                  canny_high: float | None = None, smooth_sigma_px: float = 1.0) -> EdgeImage:
    """Gamma-decode the image and extract its edges (Canny), their directions and distance map.

    ``canny_low``/``canny_high`` default to 2.5x / 6x the noise of the Sobel magnitude, estimated
    from the image (median absolute deviation), with floors of 8 and 20 grey levels.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"image must be 8-bit grey or BGR, got dtype {img.dtype}")
    # a channel at the top clips the grey made from it too (a red face saturated in red only); the
    # brightest channel per pixel with OpenCV (numpy's max over the last axis: 60 ms at 1920 x 1200)
    top = img
    if img.ndim == 3:
        chans = cv2.split(img)
        top = chans[0]
        for c in chans[1:]:
            top = cv2.max(top, c)
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    clipped = top >= CLIP_GREY
    H, W = img.shape
    lin = _decode_table(float(gamma))[img]          # the same numbers as decoding each pixel
    sm = cv2.GaussianBlur(img, (0, 0), smooth_sigma_px) if smooth_sigma_px > 0 else img
    smf = sm.astype(np.float32)
    gx = cv2.Sobel(smf, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smf, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy)
    # noise: MAD of the difference between the image and its blur (flat areas dominate)
    resid = img.astype(np.float32) - smf
    noise = float(1.4826 * np.median(np.abs(resid - np.median(resid)))) + 1e-3
    sob_noise = noise * 2.0
    lo = canny_low if canny_low is not None else max(8.0, 2.5 * sob_noise)
    hi = canny_high if canny_high is not None else max(20.0, 6.0 * sob_noise)
    gx16 = np.clip(np.round(gx), -32767, 32767).astype(np.int16)
    gy16 = np.clip(np.round(gy), -32767, 32767).astype(np.int16)
    edges = cv2.Canny(gx16, gy16, lo, hi, L2gradient=True)
    noise_lin = float(noise / 255.0 * gamma * 0.5 ** (gamma - 1))  # slope of the decode at mid-grey
    return _edge_image(lin, edges, np.arctan2(gy, gx), mag, noise_lin, float(gamma), clipped)


def _decode_table(gamma: float) -> np.ndarray:
    """(256,) float32: linear light of each grey level, ``(g / 255) ** gamma`` in float32."""
    return ((np.arange(256).astype(np.float32) / 255.0) ** gamma).astype(np.float32)


def _edge_image(lin, edges, angle, mag, noise_lin, gamma, clipped=None) -> EdgeImage:
    H, W = edges.shape
    vv, uu = np.nonzero(edges)
    edge_uv = np.stack([uu, vv], axis=1).astype(float)
    full_angle = angle if angle.shape == edges.shape else None
    return EdgeImage(width=W, height=H, linear=lin, edges=edges, edge_uv=edge_uv,
                     edge_angle=full_angle[vv, uu] if full_angle is not None else angle,
                     edge_mag=mag[vv, uu] if mag.shape == edges.shape else mag, noise_linear=noise_lin,
                     gamma=gamma, clipped=clipped, cache={"angle_full": angle, "mag_full": mag})


def _with_edges(eimg: EdgeImage, edges: np.ndarray) -> EdgeImage:
    """``eimg`` with fewer edge pixels (``edges``, a subset of its own): the same image, gamma, noise
    and clipped pixels; its own caches start empty."""
    return _edge_image(eimg.linear, edges, eimg.cache.get("angle_full"), eimg.cache.get("mag_full"),
                       eimg.noise_linear, eimg.gamma, eimg.clipped)


def nearest_edge_maps(eimg: EdgeImage) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel (flattened, index ``v * width + u``): distance to the nearest edge pixel (px), and
    cos and sin of that edge pixel's gradient direction; made once per image and kept in its cache.
    The same numbers as ``cos(edge_angle[nearest[v, u]])``, looked up in one step by every scorer."""
    if "nearest_edge_maps" not in eimg.cache:
        if len(eimg.edge_angle):
            near = eimg.nearest.ravel()
            cos_a, sin_a = np.cos(eimg.edge_angle)[near], np.sin(eimg.edge_angle)[near]
        else:                           # no edges: direction 0, as the scorers took it
            cos_a = np.ones(eimg.width * eimg.height, np.float32)
            sin_a = np.zeros(eimg.width * eimg.height, np.float32)
        eimg.cache["nearest_edge_maps"] = (eimg.dist_px.ravel(), cos_a, sin_a)
    return eimg.cache["nearest_edge_maps"]


def mask_known_edges(eimg: EdgeImage, known: list[tuple[PreparedModel, np.ndarray]], K, dist,
                     width_px: float = 1.5) -> EdgeImage:
    """A copy of ``eimg`` without the edge pixels that known geometry explains.

    ``known`` holds pairs (prepared model, ``T_cam_model``), typically the table itself (its border,
    T-slots and marker-free structure) at ``T_cam_table``: corners and steps of the table otherwise
    look like small workpieces to the search. Edge pixels within ``width_px`` of a visible edge of a
    known model are removed; the grey image used for the subpixel fit is unchanged.
    """
    K = np.asarray(K, float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    mask = np.zeros(eimg.edges.shape, np.uint8)
    for model, T_cam_model in known:
        T_cam_model = np.asarray(T_cam_model, float)
        # each model's share of the mask is kept in the image's cache: the objects searched one after
        # the other in one image all mask the table (and the fixtures located before them)
        key = ("known_mask", id(model), T_cam_model.tobytes(), K.tobytes(), dist.tobytes(), float(width_px))
        if key not in eimg.cache:
            one = np.zeros(eimg.edges.shape, np.uint8)
            es = visible_edge_samples(model, T_cam_model, K, dist, eimg.width, eimg.height, max_buffer_px=1200)
            step = max(1, int(np.ceil(len(es.uv_px) / 400000)))
            for u, v in np.rint(es.uv_px[::step] * 4).astype(np.int64):
                cv2.circle(one, (int(u), int(v)), int(round(width_px * 4)), 255, -1, shift=2)
            eimg.cache[key] = (model, one)      # the model held: its id stays its own
        np.maximum(mask, eimg.cache[key][1], out=mask)
    edges = np.where(mask > 0, 0, eimg.edges).astype(np.uint8)
    return _with_edges(eimg, edges)


def mask_table_regions(eimg: EdgeImage, regions_table: list, T_cam_table: np.ndarray, K, dist,
                       dilate_px: float = 2.0) -> EdgeImage:
    """A copy of ``eimg`` without the edge pixels inside regions of the table (each a polygon (N, 3)
    in the table frame, mm), typically the printed fiducial labels: their black and white cells are
    exactly the small squares a small part looks like. A part's own edges crossing such a region
    are lost there too (a part rarely stands on a marker; it would hide it from the table pose)."""
    K = np.asarray(K, float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    mask = np.zeros(eimg.edges.shape, np.uint8)
    for poly in regions_table:
        P = transform_points(np.asarray(T_cam_table, float), np.asarray(poly, float).reshape(-1, 3))
        if np.any(P[:, 2] <= 1.0):
            continue
        uv = project_points_px(P, K, dist)
        cv2.fillPoly(mask, [np.rint(uv * 4).astype(np.int32)], 255, lineType=cv2.LINE_8, shift=2)
    if not mask.any():
        return eimg
    r = max(1, int(np.ceil(dilate_px)))
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    edges = np.where(mask > 0, 0, eimg.edges).astype(np.uint8)
    return _with_edges(eimg, edges)
