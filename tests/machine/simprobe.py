"""A simulated touch probe for the LinuxCNC test sim: a HAL user-space component ``simprobe``.

    loadusr -Wn simprobe /usr/bin/python3 simprobe.py PART.json   (-Wn: wait for the component by name)
    net J0:pos-fb => simprobe.x   (and y, z)       net simprobe-trip simprobe.probe => motion.probe-input
    net J3:pos-fb => simprobe.r   (XYZC sim only: the C axis, degrees)

It watches the machine position of the controlled point (the probe tip, the ball's lowest point)
and sets ``probe`` while the ball (radius from the file) meets the true part: boxes turned about
machine Z, in machine coordinates (mm). PART.json is re-read whenever it changes:

    {"ball_radius_mm": 1.5, "boxes": [{"centre_xy": [x, y], "half_xy": [hx, hy], "yaw_deg": c,
                                       "z0": z0, "z1": z1}],
     "rotary": {"centre_xy": [cx, cy]}}        # optional: the boxes sit on a C table (see below)

With ``rotary`` the boxes are given as they lie at C = 0 and turn with the table: at C = r degrees (pin
``r``) they are turned by r about the machine Z line through ``centre_xy``, counter-clockwise seen from
+Z (the XYZC sim's table turns right-handed about +Z for positive C).

A missing or empty file means nothing to touch (``probe`` stays false), so the sim runs every other
test unchanged. Polled from user space, the probe trips a little late on a loaded machine: at every
trip it appends how far the ball already was inside the part (mm) when it read the position, and how
far when it read it again just after setting ``probe``, to ``simprobe_trips.txt`` beside PART.json
(``x y z depth depth_after``): the controller latched its position between the two, so that a test
can tell the sim's own lateness from a program's error. Runs
under the system Python that has LinuxCNC's ``hal`` module; standard library only.
"""

import json
import math
import os
import sys
import time

import hal


def load(path):
    try:
        with open(path) as f:
            d = json.load(f)
        return float(d.get("ball_radius_mm", 1.5)), list(d.get("boxes", [])), d.get("rotary")
    except (OSError, ValueError):
        return 1.5, [], None


def turned(boxes, rotary, r_deg):
    """The boxes with the table turned to ``r_deg`` about the rotary centre (unchanged without one)."""
    if not rotary or not r_deg:
        return boxes
    cx, cy = rotary["centre_xy"]
    c, s = math.cos(math.radians(r_deg)), math.sin(math.radians(r_deg))
    out = []
    for b in boxes:
        dx, dy = b["centre_xy"][0] - cx, b["centre_xy"][1] - cy
        out.append({**b, "centre_xy": [cx + c * dx - s * dy, cy + s * dx + c * dy], "yaw_deg": b["yaw_deg"] + r_deg})
    return out


def depth(x, y, z, r, boxes):
    """How far (mm) the ball of radius ``r`` whose lowest point is at (x, y, z) reaches into the
    nearest box (r minus the distance from its centre to the box), or None when it touches none."""
    cz = z + r  # ball centre
    best = None
    for b in boxes:
        c, s = math.cos(math.radians(b["yaw_deg"])), math.sin(math.radians(b["yaw_deg"]))
        dx, dy = x - b["centre_xy"][0], y - b["centre_xy"][1]
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        qx = max(abs(lx) - b["half_xy"][0], 0.0)
        qy = max(abs(ly) - b["half_xy"][1], 0.0)
        qz = max(b["z0"] - cz, cz - b["z1"], 0.0)
        d2 = qx * qx + qy * qy + qz * qz
        if d2 <= r * r:
            best = max(best or 0.0, r - math.sqrt(d2))
    return best


def main():
    path = sys.argv[1]
    h = hal.component("simprobe")
    for axis in "xyzr":
        h.newpin(axis, hal.HAL_FLOAT, hal.HAL_IN)
    h.newpin("probe", hal.HAL_BIT, hal.HAL_OUT)
    h.ready()
    trips = os.path.join(os.path.dirname(os.path.abspath(path)), "simprobe_trips.txt")
    stamp, r, boxes, rotary = None, 1.5, [], None
    try:
        while True:
            try:
                st = os.stat(path).st_mtime_ns
            except OSError:
                st = None
            if st != stamp:
                stamp = st
                r, boxes, rotary = load(path) if st is not None else (1.5, [], None)
            x, y, z = h["x"], h["y"], h["z"]
            d = depth(x, y, z, r, turned(boxes, rotary, h["r"])) if boxes else None
            tripped = d is not None and not h["probe"]
            h["probe"] = d is not None
            if tripped:  # after the pin: the log costs the trip no time
                # the controller latches its position when it sees the pin, at the latest by now
                after = depth(h["x"], h["y"], h["z"], r, turned(boxes, rotary, h["r"])) or 0.0
                with open(trips, "a") as f:
                    f.write(f"{x:.6f} {y:.6f} {z:.6f} {d:.6f} {max(after, d):.6f}\n")
            time.sleep(0.0005)
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
