"""A stand-in table for the scene generator: a plain box with ArUco markers near its edges.

Used until the example library (``models_library/``, ``app/geometry/parts.py``) provides the
T-slot table; any table mesh with its top face at z = 0 (z up) and a DESIGN-format fiducial layout
can replace it.

Table frame: origin at the front-left corner of the top face, x along the length, y along the
width (away from the operator), z up; the top face is z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import trimesh

from app.geometry.transforms import check_pose, inv, make_pose

MARKER_WHITE = 0.85   # albedo of the printed white (quiet zone, white cells)
MARKER_BLACK = 0.04   # albedo of the printed black


def box_table_mesh(length_mm: float = 800.0, width_mm: float = 400.0,
                   height_mm: float = 60.0) -> trimesh.Trimesh:
    """Box table, table frame: x in [0, length], y in [0, width], z in [-height, 0]."""
    m = trimesh.creation.box(extents=(length_mm, width_mm, height_mm))
    m.apply_translation((length_mm / 2, width_mm / 2, -height_mm / 2))
    return m


def box_table_layout(length_mm: float = 800.0, width_mm: float = 400.0, *,
                     marker_size_mm: float = 40.0, dictionary: str = "DICT_5X5_100",
                     edge_offset_mm: float = 35.0, pitch_mm: float = 125.0,
                     first_id: int = 0) -> dict:
    """Markers along the front and back edges (and one at each end), DESIGN layout format."""
    markers = []
    n_long = max(2, int((length_mm - 2 * edge_offset_mm) // pitch_mm) + 1)
    xs = np.linspace(edge_offset_mm, length_mm - edge_offset_mm, n_long)
    mid = width_mm / 2
    positions = [(x, edge_offset_mm) for x in xs] + [(x, width_mm - edge_offset_mm) for x in xs]
    positions += [(edge_offset_mm, mid), (length_mm - edge_offset_mm, mid)]
    for k, (x, y) in enumerate(positions):
        T = make_pose(np.eye(3), (x, y, 0.0))
        markers.append({"id": first_id + k, "size_mm": float(marker_size_mm),
                        "T_table_marker": T.tolist()})
    return {"dictionary": dictionary, "markers": markers}


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV predefined dictionary by its name ("DICT_5X5_100")."""
    code = getattr(cv2.aruco, name, None)
    if not isinstance(code, int):
        raise ValueError(f"unknown ArUco dictionary {name!r}; use an OpenCV name such as DICT_5X5_100")
    return cv2.aruco.getPredefinedDictionary(code)


@dataclass(frozen=True)
class PrintedMarker:
    """One marker as printed: bit cells (True = white), size and pose on the table top."""

    id: int
    size_mm: float
    cells: np.ndarray          # (n+2, n+2) bool, row 0 = top edge (corner 0 -> corner 1)
    T_marker_table: np.ndarray
    T_table_marker: np.ndarray
    label_half_mm: float       # half side of the white label around the black square


def printed_markers(layout: dict, margin_cells: float = 1.0) -> list[PrintedMarker]:
    """The layout's markers with their bit patterns, checked to lie flat on the top face z = 0."""
    dic = aruco_dictionary(layout["dictionary"])
    n = dic.markerSize
    out = []
    for m in layout["markers"]:
        T = check_pose(m["T_table_marker"], f"T_table_marker of marker {m['id']}", tol=1e-6)
        if abs(T[2, 3]) > 1e-6 or T[2, 2] < 1 - 1e-9:
            raise ValueError(
                f"marker {m['id']}: the scene generator draws markers only flat on the table top "
                f"(z = 0, facing +z); got z = {T[2, 3]:.3f} mm, normal z = {T[2, 2]:.4f}")
        img = cv2.aruco.generateImageMarker(dic, int(m["id"]), n + 2, borderBits=1)
        s = float(m["size_mm"])
        out.append(PrintedMarker(id=int(m["id"]), size_mm=s, cells=img > 127,
                                 T_marker_table=inv(T), T_table_marker=T,
                                 label_half_mm=s / 2 * (1 + 2 * margin_cells / (n + 2))))
    return out


def marker_corners_table(marker: PrintedMarker) -> np.ndarray:
    """(4, 3) table-frame corners of the black square in OpenCV order (DESIGN marker frame)."""
    h = marker.size_mm / 2
    c = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], float)
    return c @ marker.T_table_marker[:3, :3].T + marker.T_table_marker[:3, 3]


class TableTopAlbedo:
    """Albedo of the table top at table-frame points: machined grey texture plus markers.

    The texture is a procedural grey (``base`` with low-frequency blotches, streaks along x as
    left by face milling, fine grain) at ``texel_mm``; marker cells are evaluated exactly at the
    given point (no texture resampling), so marker edges are where the layout says.
    """

    def __init__(self, bounds_xy_mm: np.ndarray, markers: list[PrintedMarker], *,
                 base: float = 0.42, seed: int = 0, texel_mm: float = 0.5) -> None:
        (x0, y0), (x1, y1) = bounds_xy_mm
        self.x0, self.y0, self.texel = float(x0), float(y0), float(texel_mm)
        nx = int(np.ceil((x1 - x0) / texel_mm)) + 2
        ny = int(np.ceil((y1 - y0) / texel_mm)) + 2
        rng = np.random.default_rng(seed)

        def smooth_noise(sx: float, sy: float) -> np.ndarray:
            # Noise blurred by (sx, sy) texels; large blurs are done on a coarser grid and resized.
            fx, fy = max(1, int(sx // 4)), max(1, int(sy // 4))
            small = rng.standard_normal((ny // fy + 2, nx // fx + 2)).astype(np.float32)
            small = cv2.GaussianBlur(small, (0, 0), sigmaX=sx / fx, sigmaY=sy / fy)
            out = cv2.resize(small, (nx, ny), interpolation=cv2.INTER_LINEAR)
            return out / max(float(out.std()), 1e-9)

        low = smooth_noise(60, 60)
        streak = smooth_noise(40, 0.8)
        grain = smooth_noise(1.0, 1.0)
        self.tex = (base * (1 + 0.06 * low + 0.03 * streak + 0.015 * grain)).astype(np.float32)
        self.markers = markers
        # Index map at 1 mm: which marker's label (dilated by 2 mm) covers a cell, -1 for none.
        self.cell_mm = 1.0
        self.imap = np.full((int(np.ceil((y1 - y0) / self.cell_mm)) + 2,
                             int(np.ceil((x1 - x0) / self.cell_mm)) + 2), -1, np.int16)
        for k, m in enumerate(markers):
            h = m.label_half_mm + 2.0
            sq = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
            pts = sq @ m.T_table_marker[:3, :3].T + m.T_table_marker[:3, 3]
            poly = np.round(((pts[:, :2] - [x0, y0]) / self.cell_mm) * 16).astype(np.int32)
            cv2.fillConvexPoly(self.imap, poly, k, lineType=cv2.LINE_8, shift=4)
            # fillConvexPoly with shift rounds; dilate to stay conservative.
        self.imap = self._dilate(self.imap)

    @staticmethod
    def _dilate(imap: np.ndarray) -> np.ndarray:
        out = imap.copy()
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                sh = np.roll(np.roll(imap, dy, 0), dx, 1)
                out = np.where((out < 0) & (sh >= 0), sh, out)
        return out

    def _remap(self, tex: np.ndarray, x_mm: np.ndarray, y_mm: np.ndarray, texel: float,
               x0: float, y0: float) -> np.ndarray:
        n = len(x_mm)
        cols = 1024                       # cv2.remap wants maps of fewer than 32767 rows
        rows = -(-n // cols)
        mx = np.zeros(rows * cols, np.float32)
        my = np.zeros(rows * cols, np.float32)
        mx[:n] = (x_mm - x0) / texel - 0.5
        my[:n] = (y_mm - y0) / texel - 0.5
        out = cv2.remap(tex, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(-1)[:n]

    def set_shadow(self, lit_fn, texel_mm: float = 1.0) -> None:
        """Precompute the lit fraction of the top face (z = 0) on a texture at ``texel_mm``;
        ``lit_fn(P_table (N, 3)) -> (N,)``."""
        (nx, ny) = (int(np.ceil(self.tex.shape[1] * self.texel / texel_mm)) + 1,
                    int(np.ceil(self.tex.shape[0] * self.texel / texel_mm)) + 1)
        gx, gy = np.meshgrid(self.x0 + (np.arange(nx) + 0.5) * texel_mm,
                             self.y0 + (np.arange(ny) + 0.5) * texel_mm)
        P = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
        self.lit_tex = lit_fn(P).reshape(ny, nx).astype(np.float32)
        self.lit_texel = texel_mm

    def lit(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Lit fraction (N,) of top-face points from :meth:`set_shadow` (1 if never set)."""
        if getattr(self, "lit_tex", None) is None:
            return np.ones(len(x_mm), np.float32)
        return self._remap(self.lit_tex, x_mm, y_mm, self.lit_texel, self.x0, self.y0)

    def __call__(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Albedo at table-frame points (x, y) on the top face; shapes (N,) -> (N,)."""
        alb = self._remap(self.tex, x_mm, y_mm, self.texel, self.x0, self.y0)
        cx = np.clip(((x_mm - self.x0) / self.cell_mm).astype(np.int64), 0, self.imap.shape[1] - 1)
        cy = np.clip(((y_mm - self.y0) / self.cell_mm).astype(np.int64), 0, self.imap.shape[0] - 1)
        mk = self.imap[cy, cx]
        for k in np.unique(mk[mk >= 0]):
            m = self.markers[int(k)]
            sel = np.nonzero(mk == k)[0]
            R = m.T_marker_table[:3, :3]
            t = m.T_marker_table[:3, 3]
            mx = R[0, 0] * x_mm[sel] + R[0, 1] * y_mm[sel] + t[0]
            my = R[1, 0] * x_mm[sel] + R[1, 1] * y_mm[sel] + t[1]
            on_label = (np.abs(mx) < m.label_half_mm) & (np.abs(my) < m.label_half_mm)
            n = m.cells.shape[0]
            cell = m.size_mm / n
            col = np.floor((mx + m.size_mm / 2) / cell).astype(np.int64)
            row = np.floor((m.size_mm / 2 - my) / cell).astype(np.int64)
            in_sq = (col >= 0) & (col < n) & (row >= 0) & (row < n)
            white = np.ones(len(sel), bool)
            white[in_sq] = m.cells[row[in_sq], col[in_sq]]
            val = np.where(white, MARKER_WHITE, MARKER_BLACK).astype(np.float32)
            alb[sel[on_label]] = val[on_label]
        return alb
