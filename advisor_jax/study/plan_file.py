"""The plan on disk: ``DIR/plan.json``, made by a sweep's first call and kept for the later
calls and cluster tasks, which must cut the study into the same pieces."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from advisor_jax.fileio import atomic_write_json
from advisor_jax.study.plan import Device, Piece, Plan
from advisor_jax.study.spec import Study, StudyError


def save_plan(out: Path, study: Study, plan: Plan) -> None:
    record = {
        "study": str(study.path),
        "name": study.name,
        "digest": plan.digest,
        "device": dataclasses.asdict(plan.device),
        "devices": plan.devices,
        "caps": plan.caps,
        "explained": plan.explained,
        "max_agents": plan.max_agents,
        "pieces": [{**dataclasses.asdict(p), "agents": p.agents} for p in plan.pieces],
    }
    atomic_write_json(out / "plan.json", record)


def load_plan(out: Path, study: Study) -> Plan | None:
    """The plan kept in ``out`` (None if there is none); a plan of another study is an
    error, since its pieces would not be this study's."""
    path = out / "plan.json"
    if not path.is_file():
        return None
    record = json.loads(path.read_text())
    if record["digest"] != study.digest:
        raise StudyError(
            f"{out} holds a sweep of another study or of another version of {study.path} "
            f"({path} was made from {record['study']}); choose another --out"
        )
    fields = {f.name for f in dataclasses.fields(Piece)}
    pieces = tuple(
        Piece(**{k: tuple(v) if isinstance(v, list) else v for k, v in p.items() if k in fields})
        for p in record["pieces"]
    )
    return Plan(
        record["digest"],
        Device(**record["device"]),
        record["devices"],
        tuple(record["caps"]),
        pieces,
        tuple(record["explained"]),
        record.get("max_agents"),
    )
