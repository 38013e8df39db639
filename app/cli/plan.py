"""``setupcam plan``: plan a collision-safe travel path from a JSON request (see app/planning/request.py)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plan",
        help="plan a safe probe/sensor travel path from a JSON file",
        description="Reads points (mm, focal-plane heights), probe (working_distance_mm, clearance_mm, ...) "
        "and obstacles (per_move_mm | part_top_mm | regions | meshes) and prints the path as JSON. "
        "Format: app/planning/request.py.",
    )
    p.add_argument("request", help="JSON request file, or - for stdin")
    p.add_argument("--method", choices=["reference", "profile"], help="override the request's method")
    p.add_argument("--indent", type=int, default=2, help="JSON indent (0: one line)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.planning.request import plan_request

    try:
        if args.request == "-":
            req, base = json.load(sys.stdin), Path.cwd()
        else:
            path = Path(args.request)
            req, base = json.loads(path.read_text()), path.parent
    except (OSError, json.JSONDecodeError) as exc:
        print(f"cannot read the request {args.request}: {exc}", file=sys.stderr)
        return 2
    if args.method:
        req["method"] = args.method
    try:
        out = plan_request(req, base_dir=base)
    except (ValueError, TypeError) as exc:
        print(f"plan: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=args.indent or None))
    if "collision" in out and not out["collision"]["ok"]:
        print(f"plan: collision check failed: {out['collision']['reason']}", file=sys.stderr)
        return 1
    return 0
