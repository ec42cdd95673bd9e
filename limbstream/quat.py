"""Quaternion math, one place: scalar-first (w, x, y, z) unit quaternions as NumPy arrays.

scipy's Rotation is scalar-last; the converters here are the only place that swaps.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where it is used: scipy.spatial costs ~0.4 s of CPU at every process's start
    from scipy.spatial.transform import Rotation

Z_UP_TO_Y_UP = np.array([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0])
"""-90 degrees about X: ``multiply(Z_UP_TO_Y_UP, q)`` turns an orientation in a Z-up world (a
fusion filter's earth frame: VQF's, an IMU recording's, a SlimeVR tracker's) into limbstream's
Y-up world; its conjugate turns it back. The one definition of that turn."""


def normalize(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 4) float64 unit quaternions. Raises ValueError on zero norm."""
    q = np.asarray(q, np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(norm)):
        raise ValueError("q contains zero-norm or non-finite quaternions")
    return q / norm


def to_rotation(q: np.ndarray) -> Rotation:
    """(..., 4) scalar-first -> scipy Rotation."""
    from scipy.spatial.transform import Rotation
    q = np.asarray(q, np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def from_rotation(r: Rotation) -> np.ndarray:
    """scipy Rotation -> (..., 4) float64 scalar-first."""
    return r.as_quat()[..., [3, 0, 1, 2]]


def angle_deg(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Angular deviation 2 arccos |<q0, q1>| in degrees (paper, eq. 2); q and -q are equal.

    Parameters
    ----------
    q0, q1 : (..., 4) unit quaternions (broadcast). Returns (...) float64 degrees.
    """
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    dot = np.abs(np.sum(q0 * q1, axis=-1))
    dot /= np.linalg.norm(q0, axis=-1) * np.linalg.norm(q1, axis=-1)
    return np.degrees(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)))


def slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc, vectorised.

    Parameters
    ----------
    q0, q1 : (..., 4) unit quaternions (broadcast with u).
    u : (...) interpolation parameter in [0, 1] (values outside extrapolate).

    Returns
    -------
    (..., 4) float64 unit quaternions; u = 0 gives q0, u = 1 gives +-q1.
    """
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    u = np.asarray(u, np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-6  # nearly identical: linear interpolation is exact to float precision
    safe = np.where(near, 1.0, sin_theta)
    w0 = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(near, u, np.sin(u * theta) / safe)
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def interpolate(t_points: np.ndarray, q_points: np.ndarray, t: np.ndarray) -> np.ndarray:
    """SLERP reconstruction of a stream from its segment points.

    Parameters
    ----------
    t_points : (K,) float64 increasing seconds; q_points : (K, 4) unit quaternions.
    t : (m,) float64 seconds; values outside [t_points[0], t_points[-1]] are held at the ends.

    Returns
    -------
    (m, 4) float64 unit quaternions.
    """
    t_points = np.asarray(t_points, np.float64)
    q_points = np.asarray(q_points, np.float64)
    t = np.asarray(t, np.float64)
    if len(t_points) == 1:
        return np.broadcast_to(normalize(q_points[0]), (len(t), 4)).copy()
    k = np.clip(np.searchsorted(t_points, t, side="right") - 1, 0, len(t_points) - 2)
    span = t_points[k + 1] - t_points[k]
    u = np.clip((t - t_points[k]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    return slerp(normalize(q_points[k]), normalize(q_points[k + 1]), u)


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (..., 4) scalar-first quaternions."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def about_axes(angle: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(j, n, 4) float64 the rotations by ``angle`` (j, n) rad about coordinate axes ``axis`` (j,)
    (0: X, 1: Y, 2: Z): scipy's ``Rotation.from_rotvec`` of ``angle`` times the unit axis, bit for
    bit (its half-angle scale, with its series below 1e-3 rad), at a third of its cost."""
    c, s = half_turns(angle)
    out = np.zeros(c.shape + (4,))
    out[..., 0] = c
    out[np.arange(len(c)), :, 1 + np.asarray(axis)] = s
    return out


def half_turns(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(c, s), each shaped as ``angle`` (rad): the rotation by ``angle`` about a coordinate axis is
    the quaternion (c, s along that axis), as :func:`about_axes` (scipy's ``from_rotvec``) makes it."""
    angle = np.asarray(angle, np.float64)
    size = np.abs(angle)  # the rotation vector's norm: sqrt(a * a) is |a| exactly
    half = size / 2
    small = size <= 1e-3
    scale = np.sin(half)
    np.divide(scale, size, out=scale, where=~small)
    if small.any():  # scipy's series there
        size2 = size[small] * size[small]
        scale[small] = 0.5 - size2 / 48 + size2 * size2 / 3840
    return np.cos(half), angle * scale


def left_matrix(a: np.ndarray) -> np.ndarray:
    """The (4, 4) float64 matrix L of the left product by quaternion ``a``: ``multiply(a, b)`` is
    ``L @ b`` (``b @ L.T`` for (..., 4) ``b``), one matrix product when ``a`` is fixed."""
    w, x, y, z = np.asarray(a, np.float64)
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def conjugate(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 4) float64 (w, -x, -y, -z): the inverse of a unit quaternion."""
    return np.asarray(q, np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def body_rate(q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
    """Body angular rate of a unit quaternion moving at rate qdot: ``2 vec(conj(q) qdot)``.

    Parameters
    ----------
    q : (..., 4) unit quaternions; qdot : (..., 4) their time derivatives (per second), tangent
        to q (qdot . q = 0; a radial part is dropped).

    Returns
    -------
    (..., 3) float64 angular rates in q's body frame, rad/s (the inverse of :func:`predict`'s
    ``qdot = q (0, omega) / 2``).
    """
    return 2.0 * multiply(conjugate(q), qdot)[..., 1:]


def through_rate(q: np.ndarray, q_to: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """The body angular rate whose :func:`predict` from ``q`` passes through ``q_to`` after ``dt``
    seconds (negative: before): ``2 vec(d) / (d_w dt)`` with ``d = conj(q) q_to`` (the rate the
    fastSW live rule gives a point, docs/kernel.md). Zero where the two are half a turn apart
    (``|d_w| < 1e-6``: no finite rate passes through both) or ``dt`` is 0.

    Parameters
    ----------
    q, q_to : (..., 4) unit quaternions; dt : (...) seconds.

    Returns
    -------
    (..., 3) float64 rad/s.
    """
    d = multiply(conjugate(q), q_to)
    dt = np.asarray(dt, np.float64)
    scale = d[..., 0] * dt
    ok = (np.abs(d[..., 0]) >= 1e-6) & (dt != 0)
    return np.where(ok[..., None], 2.0 * d[..., 1:] / np.where(ok, scale, 1.0)[..., None], 0.0)


def predict(q: np.ndarray, omega: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """The live view of a segment point: the receiver's prediction of the orientation ``dt``
    seconds after the point ``q`` whose body angular rate is ``omega`` (docs/kernel.md,
    "Live rule"; the fastSW kernel checks every sample against exactly this).

    First-order extrapolation along the tangent, normalised:
    ``normalize(q^ + dt qdot)`` with ``q^ = normalize(q)`` and ``qdot = q^ (0, omega) / 2``.
    It rotates about ``omega``'s axis by ``2 arctan(|omega| dt / 2)``: the angular rate
    ``|omega|`` at the point, slowing down as the angle grows; ``omega = 0`` holds the point.

    Parameters
    ----------
    q : (N, 4) or (4,) points (scalar-first, any nonzero norm).
    omega : (N, 3) or (3,) body angular rates, rad/s.
    dt : (N,) or scalar, seconds after each point (negative: before).

    Returns
    -------
    (N, 4) float64 unit quaternions (shapes broadcast).
    """
    q_hat = normalize(q)
    omega = np.asarray(omega, np.float64)
    pure = np.concatenate([np.zeros(omega.shape[:-1] + (1,)), omega], axis=-1)
    qdot = 0.5 * multiply(q_hat, pure)
    return normalize(q_hat + np.asarray(dt, np.float64)[..., None] * qdot)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate (..., 3) vectors v by (..., 4) unit quaternions q (broadcast)."""
    q = np.asarray(q, np.float64)
    v = np.asarray(v, np.float64)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3) cross product, broadcast (np.cross costs ~20 us of overhead per call)."""
    a, b = np.broadcast_arrays(a, b)
    out = np.empty(a.shape, np.result_type(a, b))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def continuous(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """Flip signs so that consecutive quaternions along ``axis`` have a non-negative dot product.

    Parameters
    ----------
    q : (..., 4) quaternions; ``axis`` is the time axis (not the last one).

    Returns
    -------
    Same shape, float64; the first sample keeps its sign, the rotations are unchanged.
    """
    q = np.moveaxis(np.asarray(q, np.float64), axis, 0)
    if len(q) < 2:
        return np.moveaxis(q.copy(), 0, axis)
    dots = np.sum(q[1:] * q[:-1], axis=-1)
    flips = np.cumsum(dots < 0, axis=0) % 2
    sign = np.concatenate([np.ones_like(flips[:1]), 1 - 2 * flips]).astype(np.float64)
    return np.moveaxis(q * sign[..., None], 0, axis)


def mirror_x(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 4) float64 (w, x, -y, -z): the rotation seen in the frame mirrored in x
    (M R M with M = diag(-1, 1, 1)), e.g. limbstream's right-handed frame -> Unity's left-handed one."""
    return np.asarray(q, np.float64) * np.array([1.0, 1.0, -1.0, -1.0])


def unity_euler_deg(q: np.ndarray) -> np.ndarray:
    """Unity's Euler angles of (..., 4) scalar-first unit quaternions already in Unity's frame.

    Unity's ``Quaternion.Euler(x, y, z)`` turns z degrees about Z, then x about X, then y about Y
    (world axes): q = qy * qx * qz, the same product as scipy's intrinsic ``"YXZ"``.

    Returns
    -------
    (..., 3) float64 degrees (x, y, z): x in [-90, 90], y and z in (-180, 180]; at x = +-90
    (gimbal lock: only y - z or y + z is defined) z is 0.
    """
    import warnings
    with warnings.catch_warnings():  # scipy warns at gimbal lock; the angles returned are exact
        warnings.simplefilter("ignore", UserWarning)
        yxz = to_rotation(normalize(q)).as_euler("YXZ", degrees=True)
    return yxz[..., [1, 0, 2]]
