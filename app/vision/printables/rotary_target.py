"""A rotary target (:mod:`app.vision.rotary_target`) to print at true scale: SVG (1 user unit = 1 mm)
or a one-page PDF, the target's origin at the page centre, with a 100 mm check bar."""

from __future__ import annotations

import io

from app.vision.rotary_target import RotaryTarget


def paint_layers(target: RotaryTarget) -> list[tuple[float, float, float, bool]]:
    """Filled discs to paint in order: (cx_mm, cy_mm, r_mm, black) — outermost first per group."""
    out = []
    for g in target.groups:
        for k, r in enumerate(g.circle_radii_mm):
            out.append((g.center_mm[0], g.center_mm[1], r, k % 2 == 0))
    if target.mark_mm is not None:
        out.append((target.mark_mm[0], target.mark_mm[1], target.mark_radius_mm, True))
    return out


def _page_mm(target: RotaryTarget, margin_mm: float) -> float:
    return 2.0 * (target.extent_mm() + margin_mm)


def target_svg(target: RotaryTarget, margin_mm: float = 10.0) -> str:
    """SVG at true scale (width/height in mm, 1 user unit = 1 mm); target origin at the page centre.

    Print at 100 % ("actual size"), then check the 100 mm scale bar with a ruler.
    """
    side = _page_mm(target, margin_mm)
    h = side / 2.0
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{side:.3f}mm" height="{side:.3f}mm" '
             f'viewBox="{-h:.4f} {-h:.4f} {side:.4f} {side:.4f}">',
             f'<rect x="{-h:.4f}" y="{-h:.4f}" width="{side:.4f}" height="{side:.4f}" fill="white"/>',
             '<g transform="scale(1,-1)">']  # target y up, SVG y down
    if target.disc_radius_mm is not None:
        parts.append(f'<circle cx="0" cy="0" r="{target.disc_radius_mm:.4f}" fill="none" '
                     'stroke="#bbbbbb" stroke-width="0.2" stroke-dasharray="2,2"/>')
    for cx, cy, r, black in paint_layers(target):
        parts.append(f'<circle cx="{cx:.4f}" cy="{cy:.4f}" r="{r:.4f}" '
                     f'fill="{"black" if black else "white"}"/>')
    # centre cross (the axis' nominal position) and a 100 mm scale bar
    parts.append('<path d="M -3 0 L 3 0 M 0 -3 L 0 3" stroke="#bbbbbb" stroke-width="0.2"/>')
    parts.append('</g>')
    y = h - margin_mm / 2.0
    parts.append(f'<path d="M -50 {y:.3f} L 50 {y:.3f} M -50 {y - 1.5:.3f} L -50 {y + 1.5:.3f} '
                 f'M 50 {y - 1.5:.3f} L 50 {y + 1.5:.3f}" stroke="#888888" stroke-width="0.2"/>')
    parts.append(f'<text x="0" y="{y - 2:.3f}" font-size="3" text-anchor="middle" fill="#888888">'
                 'setupcam rotary target - 100 mm - print at 100 %</text>')
    parts.append('</svg>')
    return "\n".join(parts) + "\n"


def target_pdf(target: RotaryTarget, margin_mm: float = 10.0) -> bytes:
    """One-page PDF at true scale (page = layout + margin); same drawing as :func:`target_svg`."""
    from reportlab.lib.units import mm
    from reportlab.pdfgen import canvas

    side = _page_mm(target, margin_mm)
    buf = io.BytesIO()
    c = canvas.Canvas(buf, pagesize=(side * mm, side * mm))
    c.setTitle("setupcam rotary target")
    c.translate(side / 2.0 * mm, side / 2.0 * mm)  # PDF y is up like the target's
    if target.disc_radius_mm is not None:
        c.setStrokeGray(0.73)
        c.setLineWidth(0.2 * mm)
        c.setDash(2 * mm, 2 * mm)
        c.circle(0, 0, target.disc_radius_mm * mm, stroke=1, fill=0)
        c.setDash()
    for cx, cy, r, black in paint_layers(target):
        c.setFillGray(0.0 if black else 1.0)
        c.circle(cx * mm, cy * mm, r * mm, stroke=0, fill=1)
    c.setStrokeGray(0.73)
    c.setLineWidth(0.2 * mm)
    c.line(-3 * mm, 0, 3 * mm, 0)
    c.line(0, -3 * mm, 0, 3 * mm)
    y = -(side / 2.0 - margin_mm / 2.0) * mm
    c.setStrokeGray(0.53)
    c.line(-50 * mm, y, 50 * mm, y)
    c.line(-50 * mm, y - 1.5 * mm, -50 * mm, y + 1.5 * mm)
    c.line(50 * mm, y - 1.5 * mm, 50 * mm, y + 1.5 * mm)
    c.setFillGray(0.53)
    c.setFont("Helvetica", 8)
    c.drawCentredString(0, y + 2 * mm, "setupcam rotary target - 100 mm - print at 100 %")
    c.showPage()
    c.save()
    return buf.getvalue()
