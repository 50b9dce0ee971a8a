"""Rigid-body and primitive-shape geometry shared by the demonstrator, the simulation
and the retargeters: quaternions (w, x, y, z), signed distances and surface sampling
for MuJoCo-style primitives (box / cylinder / sphere / capsule)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # at run time importing touch2robot.scenes would discover the task modules, which use this one
    from touch2robot.scenes.spec import GeomSpec


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from unit quaternions (..., 4) in (w, x, y, z) order."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def mat_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4), w >= 0, from rotation matrices (..., 3, 3)."""
    m = np.asarray(m, dtype=np.float64)
    tr = np.trace(m, axis1=-2, axis2=-1)
    cands = np.stack(
        [
            np.stack(
                [1 + tr, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + 2 * m[..., 0, 0] - tr,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 + 2 * m[..., 1, 1] - tr,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 + 2 * m[..., 2, 2] - tr,
                ],
                -1,
            ),
        ],
        -2,
    )
    # choose the numerically largest candidate (Shepperd's method)
    pick = np.argmax(np.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1), axis=-1)
    q = np.take_along_axis(cands, pick[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (..., 4) quaternions (w, x, y, z)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Quaternions for rotations by ``angle`` (rad, broadcastable) about unit ``axis`` (3,)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    half = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (= inverse for unit quaternions) of (..., 4) quaternions (w, x, y, z)."""
    return np.asarray(q) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_from_rotvec(v: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions of axis x angle vectors (N, 3); a zero vector gives the identity
    (unlike ``quat_from_axis_angle``, each row has its own axis)."""
    angle = np.linalg.norm(v, axis=1, keepdims=True)
    half = 0.5 * angle
    axis = v / np.maximum(angle, 1e-12)
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=1)


def rotvec(q: np.ndarray) -> np.ndarray:
    """(N, 3) axis x angle of unit quaternions (shortest rotation)."""
    q = np.where(q[:, :1] < 0, -q, q)
    s = np.linalg.norm(q[:, 1:], axis=1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[:, :1])
    return q[:, 1:] * np.where(s > 1e-9, angle / np.maximum(s, 1e-12), 2.0)


def quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) rotation angle between unit quaternions."""
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0))


def twist_angle(quat: np.ndarray, quat0: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Signed angle (rad, in (-pi, pi]) of the rotation from ``quat0`` to ``quat`` (world frame)
    about the world ``axis`` (swing-twist decomposition: the tilt about other axes is ignored)."""
    rel = quat_mul(np.asarray(quat), quat_conj(np.asarray(quat0)))
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return 2.0 * np.arctan2(rel[..., 1:] @ axis, rel[..., 0])


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(angle)))


def transform_points(points: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Points (..., N, 3) from a local frame into its parent frame given the frame pose."""
    return np.einsum("...ij,...nj->...ni", quat_to_mat(quat), points) + np.asarray(pos)[..., None, :]


def inverse_transform_points(points: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Points (..., N, 3) from the parent frame into the local frame of pose (pos, quat)."""
    rot = quat_to_mat(quat)
    return np.einsum("...ji,...nj->...ni", rot, points - np.asarray(pos)[..., None, :])


def primitive_sdf(geom: GeomSpec, points: np.ndarray) -> np.ndarray:
    """Signed distance (m, negative inside) from points (..., 3) in the geom's *body*
    frame to the primitive surface."""
    p = np.asarray(points, dtype=np.float64) - np.asarray(geom.pos)
    p = p @ quat_to_mat(np.asarray(geom.quat))  # into the geom frame: R^T p as row vectors
    if geom.shape == "box":
        q = np.abs(p) - np.asarray(geom.size)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        inside = np.minimum(np.max(q, axis=-1), 0.0)
        return outside + inside
    if geom.shape == "sphere":
        return np.linalg.norm(p, axis=-1) - geom.size[0]
    if geom.shape == "capsule":
        radius, half = geom.size[0], geom.size[1]
        z = np.clip(p[..., 2], -half, half)
        closest = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1)
        return np.linalg.norm(p - closest, axis=-1) - radius
    if geom.shape == "cylinder":
        radius, half = geom.size[0], geom.size[1]
        d = np.stack([np.linalg.norm(p[..., :2], axis=-1) - radius, np.abs(p[..., 2]) - half], axis=-1)
        return np.minimum(np.max(d, axis=-1), 0.0) + np.linalg.norm(np.maximum(d, 0.0), axis=-1)
    raise ValueError(f"unsupported primitive shape {geom.shape!r}")


def body_sdf(geoms: tuple[GeomSpec, ...], points: np.ndarray) -> np.ndarray:
    """Signed distance to the union of a body's primitives (points in the body frame)."""
    return np.min(np.stack([primitive_sdf(g, points) for g in geoms], axis=0), axis=0)


def _primitive_area(geom: GeomSpec) -> float:
    s = geom.size
    if geom.shape == "box":
        return 8.0 * (s[0] * s[1] + s[1] * s[2] + s[0] * s[2])
    if geom.shape == "sphere":
        return 4.0 * np.pi * s[0] ** 2
    if geom.shape == "capsule":
        return 4.0 * np.pi * s[0] ** 2 + 2.0 * np.pi * s[0] * 2.0 * s[1]
    if geom.shape == "cylinder":
        return 2.0 * np.pi * s[0] ** 2 + 2.0 * np.pi * s[0] * 2.0 * s[1]
    raise ValueError(f"unsupported primitive shape {geom.shape!r}")


def _sample_primitive_surface(geom: GeomSpec, n: int, rng: np.random.Generator) -> np.ndarray:
    s = geom.size
    if geom.shape == "box":
        hx, hy, hz = s
        areas = np.array([hy * hz, hy * hz, hx * hz, hx * hz, hx * hy, hx * hy])
        face = rng.choice(6, size=n, p=areas / areas.sum())
        u = rng.uniform(-1.0, 1.0, size=(n, 3)) * np.asarray(s)
        axis = face // 2
        sign = np.where(face % 2 == 0, 1.0, -1.0)
        u[np.arange(n), axis] = sign * np.asarray(s)[axis]
        pts = u
    elif geom.shape == "sphere":
        v = rng.normal(size=(n, 3))
        pts = s[0] * v / np.linalg.norm(v, axis=1, keepdims=True)
    elif geom.shape in ("capsule", "cylinder"):
        r, h = s[0], s[1]
        side_area = 2 * np.pi * r * 2 * h
        cap_area = 4 * np.pi * r**2 if geom.shape == "capsule" else 2 * np.pi * r**2
        on_side = rng.uniform(size=n) < side_area / (side_area + cap_area)
        theta = rng.uniform(0, 2 * np.pi, size=n)
        pts = np.stack([r * np.cos(theta), r * np.sin(theta), rng.uniform(-h, h, size=n)], axis=1)
        caps = ~on_side
        m = int(caps.sum())
        if geom.shape == "capsule":
            v = rng.normal(size=(m, 3))
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            v[:, 2] = np.abs(v[:, 2]) * rng.choice([-1.0, 1.0], size=m)
            pts[caps] = r * v + np.stack([np.zeros(m), np.zeros(m), np.sign(v[:, 2]) * h], axis=1)
        else:
            rad = r * np.sqrt(rng.uniform(size=m))
            th = rng.uniform(0, 2 * np.pi, size=m)
            pts[caps] = np.stack([rad * np.cos(th), rad * np.sin(th), rng.choice([-h, h], size=m)], axis=1)
    else:
        raise ValueError(f"unsupported primitive shape {geom.shape!r}")
    return pts @ quat_to_mat(np.asarray(geom.quat)).T + np.asarray(geom.pos)


def sample_surface(geoms: tuple[GeomSpec, ...], n: int, seed: int = 0) -> np.ndarray:
    """``n`` points (n, 3) on the outer surface of a body's primitives, in the body frame,
    area-weighted; points buried inside another primitive of the body are resampled away."""
    rng = np.random.default_rng(seed)
    areas = np.array([_primitive_area(g) for g in geoms])
    out: list[np.ndarray] = []
    have = 0
    while have < n:
        counts = rng.multinomial(2 * n, areas / areas.sum())
        batch = np.concatenate(
            [_sample_primitive_surface(g, c, rng) for g, c in zip(geoms, counts, strict=True) if c > 0]
        )
        keep = body_sdf(geoms, batch) > -1e-6  # on the union's outer surface
        out.append(batch[keep])
        have += int(keep.sum())
    pts = np.concatenate(out)[:n]
    return pts.astype(np.float32)
