"""The task scene's geometry posed by MuJoCo's kinematics: each body's world pose for a hand configuration,
wrist pose and object pose, and each visible geom as a mesh in its body's frame (what a 3D view draws)."""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import mujoco
import numpy as np
import trimesh

from schemas.tables import HUMAN_REGIONS
from touch2robot.geometry import quat_to_mat
from touch2robot.leap import description as hd
from touch2robot.sim.scene import Scene, build_scene

# MJCF group 4 holds sites and helper geoms no viewer should draw (fingertip sites, the wrist target).
HIDDEN_GROUPS = (3, 4, 5)
REGION_PAD_GEOMS: dict[str, str] = {r.name: r.box.name for r in hd.REGIONS}
# Contact magenta: no task object, pad or table shares it, so a pixel test can find it in a rendered frame.
CONTACT_RGB = (255, 26, 168)
IDLE_REGION_RGB = (150, 150, 160)
HUMAN_RGB = (230, 190, 150)


@dataclass(frozen=True)
class GeomMesh:
    """One geom: its body, a triangle mesh in the body's frame and its MJCF colour (0..255)."""

    name: str
    body: str
    vertices: np.ndarray
    faces: np.ndarray
    color: tuple[int, int, int]


def _mesh(kind: int, size: np.ndarray) -> trimesh.Trimesh | None:
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return trimesh.creation.box(extents=2.0 * size)
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(height=2.0 * size[1], radius=size[0], count=[12, 12])
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2.0 * size[1], sections=24)
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=2, radius=size[0])
    if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
        sphere.apply_scale(size)
        return sphere
    return None  # planes, meshes, height fields: the task scenes have none the view needs


class ScenePoser:
    """Poses one task's scene. ``meshes`` lists the drawable geoms; :meth:`pose` returns every body's
    world position and wxyz quaternion for a configuration."""

    def __init__(self, task: str) -> None:
        self.scene: Scene = build_scene(task)
        model = self.scene.model
        self._data = mujoco.MjData(model)
        self.bodies: tuple[str, ...] = tuple(model.body(b).name for b in range(model.nbody))
        meshes = []
        for g in range(model.ngeom):
            if int(model.geom_group[g]) in HIDDEN_GROUPS or model.geom_rgba[g, 3] == 0:
                continue
            mesh = _mesh(int(model.geom_type[g]), model.geom_size[g])
            if mesh is None:
                continue
            transform = np.eye(4)
            transform[:3, :3] = quat_to_mat(model.geom_quat[g])
            transform[:3, 3] = model.geom_pos[g]
            mesh.apply_transform(transform)
            rgba = model.geom_rgba[g]
            meshes.append(
                GeomMesh(
                    model.geom(g).name or f"geom{g}",
                    self.bodies[int(model.geom_bodyid[g])],
                    np.asarray(mesh.vertices, np.float32),
                    np.asarray(mesh.faces, np.uint32),
                    (int(255 * rgba[0]), int(255 * rgba[1]), int(255 * rgba[2])),
                )
            )
        self.meshes: tuple[GeomMesh, ...] = tuple(meshes)

    def pose(
        self,
        joints: np.ndarray | None = None,
        wrist: np.ndarray | None = None,
        object_pose: np.ndarray | None = None,
        drawer_opening: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every body's world position (nbody, 3) and wxyz quaternion (nbody, 4); what is not given stays
        at the scene's reset state."""
        scene, data = self.scene, self._data
        data.qpos[:] = scene.home_qpos
        if joints is not None:
            data.qpos[scene.hand_qpos] = joints
        if wrist is not None:
            data.qpos[scene.wrist_qpos : scene.wrist_qpos + 7] = wrist
        if scene.is_drawer:
            if drawer_opening is not None:
                data.qpos[scene.object_qpos] = drawer_opening
        elif object_pose is not None:
            data.qpos[scene.object_qpos : scene.object_qpos + 7] = object_pose
        mujoco.mj_kinematics(scene.model, data)
        return data.xpos.copy(), data.xquat.copy()


# MediaPipe hand skeleton: each finger's chain from the wrist, and the knuckle line.
SKELETON_EDGES: tuple[tuple[int, int], ...] = tuple(
    (a, b)
    for chain in ((0, 1, 2, 3, 4), (0, 5, 6, 7, 8), (0, 9, 10, 11, 12), (0, 13, 14, 15, 16), (0, 17, 18, 19, 20))
    for a, b in itertools.pairwise(chain)
) + ((5, 9), (9, 13), (13, 17))

# Where each glove region sits on the hand, as weights over keypoints (schemas/glove.py's region layout):
# the fingertips at the tip keypoints; P1/P2 the distal palm below index+middle / ring+little, P3 the thenar
# (proximal radial), P4 the hypothenar (proximal ulnar).
GLOVE_REGION_KEYPOINTS: dict[str, dict[int, float]] = {
    "T1": {4: 1.0},
    "T2": {8: 1.0},
    "T3": {12: 1.0},
    "T4": {16: 1.0},
    "T5": {20: 1.0},
    "P1": {5: 0.35, 9: 0.35, 0: 0.3},
    "P2": {13: 0.35, 17: 0.35, 0: 0.3},
    "P3": {0: 0.5, 1: 0.25, 5: 0.25},
    "P4": {0: 0.55, 17: 0.45},
}


def glove_region_points(keypoints: np.ndarray) -> dict[str, np.ndarray]:
    """World position of each glove region's marker for one frame's keypoints (21, 3)."""
    return {
        r: np.sum([w * keypoints[k] for k, w in weights.items()], axis=0)
        for r, weights in GLOVE_REGION_KEYPOINTS.items()
    }


@dataclass(frozen=True)
class MeshGroup:
    """Several geoms as one triangle mesh of one colour: ``faces`` index ``parts`` concatenated vertices."""

    key: str
    color: tuple[int, int, int]
    faces: np.ndarray
    parts: tuple[np.ndarray, ...]  # per part: its vertices in its own frame
    owners: tuple[int, ...]  # per part: the body (or marker) index that poses it
    names: tuple[str, ...]


def mesh_group(
    key: str, color: tuple[int, int, int], parts: list[tuple[str, int, np.ndarray, np.ndarray]]
) -> MeshGroup:
    faces, offset = [], 0
    for _, _, vertices, f in parts:
        faces.append(f + offset)
        offset += len(vertices)
    return MeshGroup(
        key,
        color,
        np.concatenate(faces).astype(np.uint32),
        tuple(p[2] for p in parts),
        tuple(p[1] for p in parts),
        tuple(p[0] for p in parts),
    )


def posed_vertices(
    group: MeshGroup, position: np.ndarray, rotation: np.ndarray, shown: np.ndarray | None = None
) -> np.ndarray:
    """World vertices (V, 3) of a group for its owners' poses; a part whose ``shown`` is False collapses to a
    point (so one group's triangles stay fixed while parts leave or join it)."""
    out = []
    for k, (vertices, owner) in enumerate(zip(group.parts, group.owners, strict=True)):
        world = vertices @ rotation[owner].T + position[owner]
        if shown is not None and not shown[k]:
            world = np.broadcast_to(world.mean(axis=0), world.shape)
        out.append(world)
    return np.concatenate(out).astype(np.float32)


def scene_groups(poser: ScenePoser) -> tuple[MeshGroup, ...]:
    """The scene's geoms merged by colour, the eight tactile pads twice (idle colour and ``CONTACT_RGB``, each
    pad shown in one of them), for :func:`posed_vertices` with the body poses of :meth:`ScenePoser.pose`."""
    pads = {geom: region for region, geom in REGION_PAD_GEOMS.items()}
    by_color: dict[tuple[int, int, int], list] = {}
    pad_parts = []
    for mesh in poser.meshes:
        part = (mesh.name, poser.bodies.index(mesh.body), mesh.vertices.astype(np.float64), mesh.faces)
        if mesh.name in pads:
            pad_parts.append((pads[mesh.name], *part[1:]))
        else:
            by_color.setdefault(mesh.color, []).append(part)
    order = {r: k for k, r in enumerate(REGION_PAD_GEOMS)}
    pad_parts.sort(key=lambda p: order[p[0]])
    pad_rgb = next(m.color for m in poser.meshes if m.name in pads)
    groups = [mesh_group(f"geoms_{r}_{g}_{b}", (r, g, b), parts) for (r, g, b), parts in by_color.items()]
    return (*groups, mesh_group("pads", pad_rgb, pad_parts), mesh_group("pads_contact", CONTACT_RGB, pad_parts))


def bone_transforms(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre, rotation (taking +z onto the bone) and length of each skeleton bone of keypoints (21, 3)."""
    a = points[[e[0] for e in SKELETON_EDGES]]
    b = points[[e[1] for e in SKELETON_EDGES]]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-9)[:, None]
    # the half-way quaternion (w = 1 + u_z, xyz = z x u) takes +z onto u; u = -z: a half turn about x
    q = np.stack([1.0 + u[:, 2], -u[:, 1], u[:, 0], np.zeros(len(u))], axis=1)
    q[q[:, 0] < 1e-9] = [0.0, 1.0, 0.0, 0.0]
    return (a + b) / 2, quat_to_mat(q), np.maximum(length, 1e-3)


def human_groups() -> tuple[MeshGroup, MeshGroup, MeshGroup]:
    """The skeleton's bones (unit-length cylinders along z, one per edge) and the nine glove markers twice
    (idle and in contact, each marker shown in one), for :func:`posed_bones` and :func:`posed_vertices`."""
    bone = trimesh.creation.cylinder(radius=0.003, height=1.0, sections=8)
    marker = trimesh.creation.icosphere(subdivisions=2, radius=0.009)
    bone_part = np.asarray(bone.vertices, np.float64), np.asarray(bone.faces)
    markers = [
        (r, k, np.asarray(marker.vertices, np.float64), np.asarray(marker.faces)) for k, r in enumerate(HUMAN_REGIONS)
    ]
    return (
        mesh_group("bones", HUMAN_RGB, [(f"bone{k}", k, *bone_part) for k in range(len(SKELETON_EDGES))]),
        mesh_group("glove", IDLE_REGION_RGB, markers),
        mesh_group("glove_contact", CONTACT_RGB, markers),
    )


def posed_bones(bones: MeshGroup, points: np.ndarray) -> np.ndarray:
    """World vertices of the skeleton's bones for keypoints (21, 3): each unit cylinder stretched to its bone."""
    center, rotation, length = bone_transforms(points)
    stretched = [p * [1.0, 1.0, n] for p, n in zip(bones.parts, length, strict=True)]
    return posed_vertices(dataclasses.replace(bones, parts=tuple(stretched)), center, rotation)
