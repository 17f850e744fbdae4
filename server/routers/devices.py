"""A user's devices (foot sensor, phone, watch)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, status

from server import crud
from server.deps import CurrentUser, PathId, SessionDep
from server.schemas import DeviceCreate, DeviceOut

__all__ = ["router"]

router = APIRouter(prefix="/devices", tags=["devices"])


@router.post("", response_model=DeviceOut, status_code=status.HTTP_201_CREATED)
def create_device(body: DeviceCreate, db: SessionDep, user: CurrentUser) -> Any:
    dev = crud.create_device(db, user, body.kind, body.name)
    db.commit()
    return dev


@router.get("", response_model=list[DeviceOut])
def list_devices(db: SessionDep, user: CurrentUser) -> Any:
    return crud.list_devices(db, user)


@router.get("/{device_id}", response_model=DeviceOut)
def get_device(device_id: PathId, db: SessionDep, user: CurrentUser) -> Any:
    dev = crud.get_device(db, user, device_id)
    if dev is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"device {device_id} not found")
    return dev
