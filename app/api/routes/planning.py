"""/api/v1/planning: collision-safe travel paths; /api/v1/setups/{id}/probing-program."""

from __future__ import annotations

from typing import Any
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Query, Request, Response
from starlette.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from app.api.deps import FilesDep, OperatorPrincipal, SessionDep, SettingsDep, get_principal
from app.services import planning as svc
from app.services.errors import Invalid

router = APIRouter(tags=["planning"], dependencies=[Depends(get_principal)])

EXAMPLE = {"points": [[0, 0, 0], [20, 10, -6], [40, 20, -23]],
           "probe": {"working_distance_mm": 30, "clearance_mm": 5},
           "obstacles": {"part_top_mm": 6}, "method": "reference"}


class PlanBody(BaseModel):
    points: list[list[float]] = Field(description="Focal-plane positions [x, y, z] in the table frame, mm")
    probe: dict[str, float] = Field(description="working_distance_mm, clearance_mm, radius_mm, length_mm")
    obstacles: dict[str, Any] = Field(description="One of: per_move_mm, part_top_mm, regions (+ priority), "
                                                  "setup_id (the located scene, inflated by its uncertainty)")
    method: str = Field(default="reference", description="reference | profile")
    options: dict[str, Any] = Field(default_factory=dict)
    speeds: dict[str, float] = Field(default_factory=dict, description="x_mm_min, y_mm_min, z_mm_min")

    model_config = {"json_schema_extra": {"examples": [EXAMPLE]}}


@router.post("/planning/paths", summary="Plan a collision-safe path between measuring points")
def plan_path(session: SessionDep, files: FilesDep, body: PlanBody) -> dict:
    return svc.plan(session, files, body.model_dump())


def _closed_parameters(request: Request, allowed: tuple[str, ...]) -> None:
    """Unknown or repeated query parameters are refused (422 with a code): every parameter is data."""
    keys = [k for k, _ in request.query_params.multi_items()]
    unknown = sorted({k for k in keys if k not in allowed})
    if unknown:
        raise Invalid(f"unknown query parameter(s) {', '.join(repr(k[:40]) for k in unknown)}; use "
                      f"{', '.join(allowed)}", code="unknown_parameter")
    if len(keys) != len(set(keys)):
        raise Invalid("a query parameter is given twice", code="repeated_parameter")


@router.get("/setups/{setup_id}/probing-options", summary="What a probing program of this setup can be made with",
            description="Dialects, the controller's work-offset slots, the clearance range, and the slot a verified "
                        "export of the current revision was written to (the frame the program should run in).")
def probing_options(session: SessionDep, files: FilesDep, setup_id: int) -> dict:
    from app.services import probing_summary

    return probing_summary.probing_options(session, files, setup_id)


@router.get("/setups/{setup_id}/probing-plan", summary="The probing program as data, for the probing page",
            description="The same gates and parameters as probing-program (refused with the same 409/422 and "
                        "reason `code`): the frame it runs in, the obstacles with their source (located, assumed, "
                        "drawn), the touches and the travel (table frame, mm), and the program's URL.")
def probing_plan(request: Request, session: SessionDep, files: FilesDep, settings: SettingsDep, setup_id: int,
                 wcs: str = Query(default="G54", max_length=8), dialect: str = Query(default="linuxcnc", max_length=16),
                 clearance_mm: float = Query(default=5.0),
                 no_go: str | None = Query(default=None, max_length=2000),
                 detour: str = Query(default="straight", max_length=16)) -> dict:
    from app.services import probing_summary

    _closed_parameters(request, tuple(p for p in svc.PROGRAM_PARAMS if p != "dry_run"))
    out = probing_summary.plan_summary(session, files, settings, setup_id, wcs=wcs, dialect=dialect,
                                       clearance_mm=clearance_mm, no_go=no_go, detour=detour)
    query = urlencode(out.pop("program_query"))
    out["program_url"] = f"{request.app.url_path_for('probing_program', setup_id=str(setup_id))}?{query}"
    return out


@router.get("/setups/{setup_id}/probing-program", response_class=Response,
            summary="Probing program for the confirmed workpiece (touch moves; dry_run: plain moves)",
            description="Refused (409/422 with a reason `code`) unless the setup passes the export's gates, every "
                        "object asked for is located, and every move stays inside the machine's travel. Every "
                        "parameter is checked against a closed set; unknown or repeated parameters are refused. "
                        "`detour=subroutine`: the travel is one call per move of a subroutine the controller "
                        "evaluates (reference safe-height method, obstacles baked in), in any of the dialects "
                        "linuxcnc, heidenhain, fanuc, siemens (docs/controller-conventions.md).",
            responses={200: {"content": {"text/plain": {}}}})
def probing_program(request: Request, session: SessionDep, files: FilesDep, settings: SettingsDep, setup_id: int,
                    dry_run: bool = False,
                    wcs: str = Query(default="G54", max_length=8, description="work-offset slot of the controller"),
                    dialect: str = Query(default="linuxcnc", max_length=16,
                                         description="linuxcnc; with detour=subroutine also heidenhain, fanuc, "
                                                     "siemens"),
                    clearance_mm: float = Query(default=5.0, description="travel clearance, mm (1..20)"),
                    no_go: str | None = Query(default=None, max_length=2000,
                                              description="no-go zones the operator drew, table frame: "
                                                          "x0,y0,x1,y1,top_mm;... (objects asked for but not "
                                                          "located are taken to be inside them)"),
                    detour: str = Query(default="straight", max_length=16,
                                        description="straight (every move written out) | subroutine (the "
                                                    "controller evaluates the detour per move)")) -> Response:
    _closed_parameters(request, svc.PROGRAM_PARAMS)
    text = svc.probing_program(session, files, settings, setup_id, dry_run=dry_run, wcs=wcs, dialect=dialect,
                               clearance_mm=clearance_mm, no_go=no_go, detour=detour)
    suffix = svc.program_suffix(dialect)
    return Response(text, media_type="text/plain",
                    headers={"Content-Disposition": f'attachment; filename="setup{setup_id}-probe{suffix}"'})


@router.post("/setups/{setup_id}/probe-results", summary="Refine the confirmed pose from probing results",
             description="Body: the LinuxCNC PROBEOPEN log (lines 'X Y Z [A B C U V W]') or JSON [[x, y, z], ...] "
                         "as text/plain. Answers the setup with a new result revision (confirm it, then export).",
             openapi_extra={"requestBody": {"content": {"text/plain": {"schema": {"type": "string"}}}}})
async def probe_results(request: Request, session: SessionDep, files: FilesDep, settings: SettingsDep,
                        who: OperatorPrincipal, setup_id: int) -> dict:
    from app.api.routes.setups import to_public

    text = (await request.body()).decode("utf-8", errors="replace")
    s = await run_in_threadpool(svc.apply_probe_results, session, files, settings, setup_id, text, who.label())
    return to_public(s).model_dump(mode="json")
