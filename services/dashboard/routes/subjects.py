"""``/api/subjects``: subjects, their latest pose frame and joint angles, and the skeleton to draw."""
from __future__ import annotations

import asyncio
from typing import Annotated, Literal

from fastapi import APIRouter, HTTPException, Query, Request

from limbstream import wire
from limbstream.body import LAYOUTS, PAPER10

from ..deps import LiveDep, SubjectPath, TokenDep, ViewsDep
from ..entries import ANGLES_HISTORY_S
from ..models import (AngleName, CalibrateRequest, CalibrateResult, Pose, PoseKind, Skeleton, Subject, SubjectDetail,
                      SubjectJoints)
from ..views import layout_view
from ..zenoh_io import ConfigError, query_calibrate

router = APIRouter(prefix="/api", tags=["subjects"])


@router.get("/subjects", response_model=list[Subject])
async def list_subjects(views: ViewsDep) -> list[dict]:
    """Every subject with device counts, total data rate and its latest frame's age."""
    return views.subject_views()


@router.get("/subjects/{subject}", response_model=SubjectDetail, responses={404: {"description": "unknown subject"}})
async def get_subject(subject: SubjectPath, views: ViewsDep) -> dict:
    """One subject as in the list, with each of its devices and the body's segments it has no
    device for."""
    if subject not in views.subject_names():
        raise HTTPException(404, f"unknown subject {subject!r}")
    return views.subject_view(subject, with_devices=True)


@router.get("/subjects/{subject}/pose", response_model=Pose,
            responses={404: {"description": "no frame of this subject yet"}})
async def latest_pose(subject: SubjectPath, live: LiveDep,
                kind: Annotated[PoseKind, Query(description="auto: exact if recent, else live")] = "auto") -> dict:
    """The latest pose frame of a subject (joint positions in metres, Y up)."""
    entry = live.latest_pose(subject, kind)
    if entry is None:
        raise HTTPException(404, f"no {'' if kind == 'auto' else kind + ' '}pose frame of subject {subject!r} yet")
    return entry.as_dict(subject)


@router.get("/subjects/{subject}/joints", response_model=SubjectJoints,
            responses={404: {"description": "no joint angles of this subject (of that kind) yet"}})
async def joint_angles(subject: SubjectPath, views: ViewsDep,
                       seconds: Annotated[float, Query(gt=0, le=ANGLES_HISTORY_S,
                                                       description="history window, s")] = 10.0,
                       kind: Annotated[PoseKind, Query(description="the pose frames they come from; auto: live while "
                                                                   "they come, else exact")] = "auto",
                       angle: Annotated[list[AngleName] | None, Query(
                           description="the angles of the history (repeat it; default: all)")] = None) -> dict:
    """The subject's newest joint angles (OpenSim's names, degrees; each flagged angle's flags; the
    calibration they rest on, and why there are none if so) and the last ``seconds`` of them."""
    joints = views.joint_angles(subject, seconds, kind, angle)
    if joints is None:
        raise HTTPException(404, f"no {'' if kind == 'auto' else kind + ' '}joint angles of subject {subject!r} yet")
    return joints


@router.get("/skeleton", response_model=Skeleton)
async def skeleton(layout: Annotated[Literal[tuple(LAYOUTS)], Query(  # type: ignore[valid-type]
        description="a built-in body layout (docs/body.md)")] = PAPER10.name) -> dict:
    """A layout's segments and joints (the order of pose frames) and the bones to draw between them."""
    return layout_view(LAYOUTS[layout])


@router.get("/layouts", response_model=dict[str, Skeleton])
async def layouts() -> dict:
    """Every built-in layout by name, as ``/api/skeleton`` gives it: what a page needs to draw any
    subject's frames (a frame's ``layout`` names its own)."""
    return {name: layout_view(lay) for name, lay in LAYOUTS.items()}


@router.post("/subjects/{subject}/calibrate", response_model=CalibrateResult, dependencies=[TokenDep],
             responses={400: {"description": "the body is not decodable JSON"}, 401: {"description": "no bearer token"},
                        403: {"description": "bad token or control disabled"}, 404: {"description": "unknown subject"},
                        409: {"description": "refused: the reason (not still, a device missing, ...)"},
                        502: {"description": "the aggregator failed"},
                        503: {"description": "not connected to Zenoh yet"}, 504: {"description": "no aggregator answered"}})
async def calibrate(subject: SubjectPath, body: CalibrateRequest, request: Request, live: LiveDep) -> dict:
    """Calibrate every streaming device of a subject from the pose it holds for the next second
    (hold it still). All of them or none; the previous calibrations stay when refused. A partial
    body calibrates the devices it has (``absent``: the segments it lacks)."""
    if subject not in {e.subject for e in live.devices.values()}:
        raise HTTPException(404, f"unknown subject {subject!r}")
    bridge = request.app.state.bridge
    if bridge is None:
        raise HTTPException(503, "not connected to Zenoh yet")
    try:
        answer = await asyncio.to_thread(query_calibrate, bridge.session, subject, body.pose,
                                          wire.CALIBRATION_ANSWER_TIMEOUT_S)
    except ConfigError as exc:
        raise HTTPException(exc.status, exc.message) from None
    if not answer.ok:
        raise HTTPException(409, answer.reason)
    return {"subject": subject, "pose": body.pose, "devices": answer.devices, "absent": answer.absent}
