"""``/api/subjects``: subjects, their latest pose frame and the skeleton to draw."""
from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query

from limbstream import wire

from ..deps import LiveDep, SubjectPath
from ..models import Pose, PoseKind, Skeleton, Subject

router = APIRouter(prefix="/api", tags=["subjects"])


@router.get("/subjects", response_model=list[Subject])
async def list_subjects(live: LiveDep) -> list[dict]:
    """Every subject with device counts, total data rate and its latest frame's age."""
    return live.subject_views()


@router.get("/subjects/{subject}/pose", response_model=Pose,
            responses={404: {"description": "no frame of this subject yet"}})
async def latest_pose(subject: SubjectPath, live: LiveDep,
                kind: Annotated[PoseKind, Query(description="auto: exact if recent, else live")] = "auto") -> dict:
    """The latest pose frame of a subject (joint positions in metres, Y up)."""
    entry = live.latest_pose(subject, kind)
    if entry is None:
        raise HTTPException(404, f"no {'' if kind == 'auto' else kind + ' '}pose frame of subject {subject!r} yet")
    return entry.as_dict(subject)


@router.get("/skeleton", response_model=Skeleton)
async def skeleton() -> dict:
    """Joint names (order of pose frames) and the bones to draw between them."""
    return {"joints": list(wire.JOINTS), "bones": [list(b) for b in wire.BONES]}
