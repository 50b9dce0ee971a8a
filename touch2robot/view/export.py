"""Sharing a replay: the demonstration and one robot trajectory as a Rerun recording (``.rrd``), opened with
``rerun file.rrd``: the human skeleton and glove regions, the task scene with the LEAP Hand posed by the
trajectory and its tactile pads coloured by contact, and per-region contact timelines (human vs robot), all
on the reference clock ``t_ref``."""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np

from schemas.tables import HUMAN_REGIONS, ROBOT_REGIONS
from touch2robot.view.demonstration import Demonstration, RobotTrajectory
from touch2robot.view.pose import (
    CONTACT_RGB,
    IDLE_REGION_RGB,
    REGION_PAD_GEOMS,
    SKELETON_EDGES,
    ScenePoser,
    glove_region_points,
)

EXPORT_RATE_HZ = 20.0
TIMELINE = "t_ref"


def write_rrd(
    demo: Demonstration, trajectory: RobotTrajectory | None, path: Path, rate_hz: float = EXPORT_RATE_HZ
) -> Path:
    """Write ``path`` (temp + rename) sampled at ``rate_hz`` over the demonstration; returns the path."""
    import rerun as rr

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")  # two exports to one path never share it
    rec = rr.RecordingStream(application_id="touch2robot_view", recording_id=demo.recording_id)
    rec.save(str(tmp))
    poser = ScenePoser(demo.task)
    pads = {geom: region for region, geom in REGION_PAD_GEOMS.items()}
    for mesh in poser.meshes:
        if mesh.name not in pads:
            rec.log(
                f"robot/{mesh.body}/{mesh.name}",
                rr.Mesh3D(vertex_positions=mesh.vertices, triangle_indices=mesh.faces, albedo_factor=mesh.color),
                static=True,
            )
    pad_meshes = {pads[m.name]: m for m in poser.meshes if m.name in pads}
    last: dict[str, bool] = {}
    for t in np.arange(demo.t[0], demo.t[-1], 1.0 / rate_hz):
        rec.set_time(TIMELINE, duration=float(t))
        if trajectory is not None:
            xpos, xquat = poser.pose(*trajectory.at(float(t)))
            robot = trajectory.contacts_at(float(t))
        else:
            xpos, xquat = poser.pose()
            robot = np.zeros(len(ROBOT_REGIONS), bool)
        for k, body in enumerate(poser.bodies):
            w, x, y, z = xquat[k]
            rec.log(f"robot/{body}", rr.Transform3D(translation=xpos[k], quaternion=rr.Quaternion(xyzw=[x, y, z, w])))
        for k, region in enumerate(ROBOT_REGIONS):
            on = bool(robot[k])
            if last.get(region) != on:
                mesh = pad_meshes[region]
                rec.log(
                    f"robot/{mesh.body}/{mesh.name}",
                    rr.Mesh3D(
                        vertex_positions=mesh.vertices,
                        triangle_indices=mesh.faces,
                        albedo_factor=CONTACT_RGB if on else mesh.color,
                    ),
                )
                last[region] = on
            rec.log(f"contacts/robot/{region}", rr.Scalars(float(on)))
        human = demo.contacts_at(float(t))
        keypoints = demo.keypoints_at(float(t))
        rec.log("human/skeleton", rr.LineStrips3D([[keypoints[a], keypoints[b]] for a, b in SKELETON_EDGES]))
        points = glove_region_points(keypoints)
        rec.log(
            "human/glove",
            rr.Points3D(
                [points[r] for r in HUMAN_REGIONS],
                radii=0.008,
                colors=[CONTACT_RGB if human[k] else IDLE_REGION_RGB for k in range(len(HUMAN_REGIONS))],
                labels=list(HUMAN_REGIONS),
            ),
        )
        for k, region in enumerate(HUMAN_REGIONS):
            rec.log(f"contacts/human/{region}", rr.Scalars(float(human[k])))
    rec.flush()
    rec.disconnect()
    tmp.replace(path)
    return path
