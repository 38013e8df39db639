"""A top view of the table where it sits on the machine (SVG): its outline and markers, its frame
(origin, x and y arrows), the machine's X and Y directions, and the jogged points.

Drawn in machine coordinates seen from +Z (machine X to the right, Y up), so the picture looks like the
table seen from above the spindle. Elements carry classes (``table-outline``, ``marker``, ``axis-x``,
``axis-y``, ``machine-axes``, ``jog-point``) and the jogged points ``data-point``, ``data-x-mm`` and
``data-y-mm`` so a test can read the picture back.
"""

from __future__ import annotations

from xml.sax.saxutils import escape, quoteattr

import numpy as np

WIDTH_PX = 640
PAD_PX = 48
MAX_HEIGHT_PX = 480


def table_figure_svg(bbox_min_mm, bbox_max_mm, T_machine_table, *, markers=(), points=(), title: str = "") -> str:
    """SVG text of the table at ``T_machine_table`` (4x4, mm).

    bbox_min_mm, bbox_max_mm : the table model's extent in its own frame (x, y used), mm
    markers : (id, (x, y) centre in the table frame, size in mm) for each fiducial marker
    points : (label, (x, y) in machine coordinates, mm) for each jogged point
    """
    T = np.asarray(T_machine_table, dtype=float)
    lo, hi = np.asarray(bbox_min_mm, float)[:2], np.asarray(bbox_max_mm, float)[:2]

    def to_machine(xy_table) -> np.ndarray:
        p = np.atleast_2d(np.asarray(xy_table, float))
        return p @ T[:2, :2].T + T[:2, 3]

    outline = to_machine([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    jogged = [(str(label), np.asarray(xy, float)[:2]) for label, xy in points]
    every = np.vstack([outline, T[:2, 3]] + [xy[None] for _, xy in jogged])
    mn, mx = every.min(axis=0), every.max(axis=0)
    k = min((WIDTH_PX - 2 * PAD_PX) / max(float(mx[0] - mn[0]), 1.0),
            (MAX_HEIGHT_PX - 2 * PAD_PX) / max(float(mx[1] - mn[1]), 1.0))
    height = int(round((mx[1] - mn[1]) * k + 2 * PAD_PX + 24))  # + a strip below for the legend

    def px(p) -> tuple[float, float]:  # machine mm -> SVG px (y down)
        return round((p[0] - mn[0]) * k + PAD_PX, 2), round((mx[1] - p[1]) * k + PAD_PX, 2)

    def poly(pts) -> str:
        return " ".join(f"{x},{y}" for x, y in (px(p) for p in pts))

    arrow = 0.25 * float(max(hi - lo))
    o = T[:2, 3]
    ex, ey = to_machine([[arrow, 0.0]])[0], to_machine([[0.0, arrow]])[0]
    c_deg = float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH_PX}" height="{height}" '
        f'viewBox="0 0 {WIDTH_PX} {height}" font-family="sans-serif" font-size="13">',
        f"<title>{escape(title or 'Table on the machine, seen from above')}</title>",
        '<defs><marker id="head" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" markerHeight="7" '
        'orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" fill="context-stroke"/></marker></defs>',
        f'<rect width="{WIDTH_PX}" height="{height}" fill="#ffffff"/>',
        f'<polygon class="table-outline" points="{poly(outline)}" fill="#e4e7eb" stroke="#444" stroke-width="2"/>',
    ]
    for marker_id, centre, size in markers:
        h = float(size) / 2
        c = np.asarray(centre, float)[:2]
        sq = to_machine([c + [-h, -h], c + [h, -h], c + [h, h], c + [-h, h]])
        parts.append(f'<polygon class="marker" data-id="{int(marker_id)}" points="{poly(sq)}" fill="#222"/>')
    for cls, tip, name, colour in (("axis-x", ex, "x", "#d62728"), ("axis-y", ey, "y", "#2ca02c")):
        (x0, y0), (x1, y1) = px(o), px(tip)
        parts.append(f'<line class="{cls}" x1="{x0}" y1="{y0}" x2="{x1}" y2="{y1}" stroke="{colour}" '
                     'stroke-width="3" marker-end="url(#head)"/>')
        parts.append(f'<text x="{x1 + 6}" y="{y1 - 6}" fill="{colour}" font-weight="bold">table {name}</text>')
    ox, oy = px(o)
    parts.append(f'<circle class="table-origin" cx="{ox}" cy="{oy}" r="5" fill="#1f77b4"/>')
    # the machine's own directions, bottom left, so the turn C reads against them
    bx, by = 14, height - 10
    parts.append(f'<g class="machine-axes" stroke="#555" stroke-width="2">'
                 f'<line x1="{bx}" y1="{by}" x2="{bx + 30}" y2="{by}" marker-end="url(#head)"/>'
                 f'<line x1="{bx}" y1="{by}" x2="{bx}" y2="{by - 30}" marker-end="url(#head)"/></g>'
                 f'<text x="{bx + 34}" y="{by + 4}" fill="#555">machine X</text>'
                 f'<text x="{bx + 6}" y="{by - 24}" fill="#555">Y</text>')
    for label, xy in jogged:
        x, y = px(xy)
        parts.append(f'<g class="jog-point" data-point={quoteattr(label)} data-x-mm="{xy[0]:.4f}" '
                     f'data-y-mm="{xy[1]:.4f}"><circle cx="{x}" cy="{y}" r="7" fill="none" stroke="#ff7f0e" '
                     f'stroke-width="3"/><text x="{x + 9}" y="{y + 18}" fill="#b35900" '
                     f'font-weight="bold">{escape(label)}</text></g>')
    parts.append(f'<text class="caption" x="{WIDTH_PX - 8}" y="{height - 10}" text-anchor="end" fill="#222">'
                 f'table origin X {T[0, 3]:.3f} Y {T[1, 3]:.3f} Z {T[2, 3]:.3f} mm, C {c_deg:.4f}°</text>')
    parts.append("</svg>")
    return "\n".join(parts)
