"""quat.slerp and quat.angle_deg against independent references: scipy's Rotation / Slerp and
the closed form slerp(1, i, u) = cos(pi u / 2) + sin(pi u / 2) i.

Rotations are compared by the angle of their relative rotation (scipy's ``magnitude``, an
atan2 form accurate near zero), so q and -q count as equal.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from limbstream import quat
from limbstream.kernel.tree import Tree

SEED = 20240614
ONE = np.array([1.0, 0.0, 0.0, 0.0])
QI = np.array([0.0, 1.0, 0.0, 0.0])


def rotation_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 4) x (..., 4) -> (...) radians between the rotations (reference, scipy)."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    shape = a.shape[:-1]
    rel = quat.to_rotation(a.reshape(-1, 4)).inv() * quat.to_rotation(b.reshape(-1, 4))
    return rel.magnitude().reshape(shape)


def random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    return quat.normalize(rng.normal(size=(n, 4)))


def scipy_slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Row-wise reference: scipy's Slerp between two key rotations at times 0 and 1."""
    return np.stack([quat.from_rotation(Slerp([0.0, 1.0], quat.to_rotation(np.stack([a, b])))(t))
                     for a, b, t in zip(q0, q1, u)])


def test_closed_form_one_to_i():
    u = np.linspace(-0.5, 1.5, 81)  # outside [0, 1]: extrapolation along the same great circle
    got = quat.slerp(ONE, QI, u)
    want = np.stack([np.cos(np.pi * u / 2), np.sin(np.pi * u / 2), 0 * u, 0 * u], axis=1)
    err = np.abs(got - want).max()
    assert err < 1e-14, f"slerp(1, i, u) off the closed form by {err:.3g}"


def test_matches_scipy_slerp_on_random_pairs():
    rng = np.random.default_rng(SEED)
    n = 300
    q0, q1 = random_unit(rng, n), random_unit(rng, n)
    u = rng.uniform(0.0, 1.0, n)
    err = rotation_angle(quat.slerp(q0, q1, u), scipy_slerp(q0, q1, u))
    assert err.max() < 1e-12, f"max {err.max():.3g} rad from scipy Slerp at pair {err.argmax()}"


def test_endpoints_are_returned_at_u_0_and_1():
    rng = np.random.default_rng(SEED + 1)
    q0, q1 = random_unit(rng, 200), random_unit(rng, 200)
    at0 = quat.slerp(q0, q1, np.zeros(200))
    at1 = quat.slerp(q0, q1, np.ones(200))
    e0, e1 = rotation_angle(at0, q0).max(), rotation_angle(at1, q1).max()
    assert e0 < 1e-12 and e1 < 1e-12, f"u=0 off q0 by {e0:.3g} rad, u=1 off q1 by {e1:.3g} rad"
    # u = 0 is q0 itself (same sign), u = 1 is q1 or -q1
    assert np.abs(at0 - q0).max() < 1e-14, np.abs(at0 - q0).max()
    d1 = np.minimum(np.abs(at1 - q1).max(axis=1), np.abs(at1 + q1).max(axis=1)).max()
    assert d1 < 1e-14, d1


def test_sign_of_q1_does_not_matter_and_the_short_arc_is_taken():
    rng = np.random.default_rng(SEED + 2)
    n = 300
    q0, q1 = random_unit(rng, n), random_unit(rng, n)
    u = rng.uniform(0.0, 1.0, n)
    plus, minus = quat.slerp(q0, q1, u), quat.slerp(q0, -q1, u)
    same = rotation_angle(plus, minus).max()
    assert same < 1e-12, f"slerp(q0, q1) and slerp(q0, -q1) differ by {same:.3g} rad"
    # short arc: the rotation from q0 grows linearly to the rotation angle (<= pi) of q0 -> q1
    total = rotation_angle(q0, q1)
    assert total.max() <= np.pi
    for got in (plus, minus):
        err = np.abs(rotation_angle(q0, got) - u * total).max()
        assert err < 1e-12, f"angle from q0 is not u * short angle (off by {err:.3g} rad)"
        rest = np.abs(rotation_angle(got, q1) - (1 - u) * total).max()
        assert rest < 1e-12, f"angle to q1 is not (1 - u) * short angle (off by {rest:.3g} rad)"


@pytest.mark.parametrize("delta", [0.0, 1e-9, 1e-7, 0.99e-6, 1.01e-6, 1e-5, 1e-2])
def test_nearly_identical_quaternions_give_finite_unit_results(delta):
    """Pairs delta radians apart (both sides of slerp's 1e-6 linear-interpolation switch)."""
    rng = np.random.default_rng(SEED + 3)
    n = 100
    q0 = random_unit(rng, n)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    q1 = quat.from_rotation(quat.to_rotation(q0) * Rotation.from_rotvec(delta * axis))
    q1[::2] *= -1  # half of them with the opposite sign
    u = np.linspace(0.0, 1.0, n)
    got = quat.slerp(q0, q1, u)
    assert np.all(np.isfinite(got)), f"non-finite slerp at delta {delta}"
    norm_err = np.abs(np.linalg.norm(got, axis=1) - 1).max()
    assert norm_err < 1e-14, f"norm off 1 by {norm_err:.3g} at delta {delta}"
    # the result lies on the arc: u * delta from q0 about the same axis
    want = quat.from_rotation(quat.to_rotation(q0) * Rotation.from_rotvec((u * delta)[:, None] * axis))
    err = rotation_angle(got, want).max()
    assert err < 1e-14, f"off the arc by {err:.3g} rad at delta {delta}"


def test_same_rotation_with_opposite_signs():
    rng = np.random.default_rng(SEED + 4)
    q = random_unit(rng, 50)
    got = quat.slerp(q, -q, rng.uniform(0, 1, 50))
    assert np.all(np.isfinite(got))
    err = rotation_angle(got, q).max()
    assert err < 1e-12, f"slerp(q, -q) moved by {err:.3g} rad"


def test_180_degrees_apart():
    """Rotations 180 deg apart (quaternion dot 0): both arcs are equally short; slerp takes the
    one through q0 and q1 as given (the closed form above), rotating about q0^-1 q1's axis."""
    rng = np.random.default_rng(SEED + 5)
    n = 100
    q0 = random_unit(rng, n)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    q1 = quat.from_rotation(quat.to_rotation(q0) * Rotation.from_rotvec(np.pi * axis))
    assert np.abs(quat.angle_deg(q0, q1) - 180).max() < 1e-6
    u = rng.uniform(0.0, 1.0, n)
    got = quat.slerp(q0, q1, u)
    assert np.all(np.isfinite(got))
    assert np.abs(np.linalg.norm(got, axis=1) - 1).max() < 1e-14
    rel = (quat.to_rotation(q0).inv() * quat.to_rotation(got)).as_rotvec()
    angle = np.linalg.norm(rel, axis=1)
    err = np.abs(angle - u * np.pi).max()
    assert err < 1e-9, f"angle from q0 is not u * pi (off by {err:.3g} rad)"
    along = np.abs(np.sum(rel * axis, axis=1)) / np.maximum(angle, 1e-300)
    assert np.all(along[angle > 1e-6] > 1 - 1e-9), "rotation leaves the axis of q0^-1 q1"
    ends = rotation_angle(quat.slerp(q0, q1, np.ones(n)), q1).max()
    assert ends < 1e-12, ends
    # exact: 1 -> i, 1 -> j, 1 -> k at u = 1/2 are the 90-degree rotations about x, y, z
    for k in range(1, 4):
        e = np.eye(4)[k]
        mid = quat.slerp(ONE, e, 0.5)
        assert np.abs(mid - (ONE + e) / np.sqrt(2)).max() < 1e-14, (k, mid)


def test_vectorised_shapes_match_row_by_row():
    rng = np.random.default_rng(SEED + 6)
    n = 64
    q0, q1 = random_unit(rng, n), random_unit(rng, n)
    u = rng.uniform(0.0, 1.0, n)
    rows = np.stack([quat.slerp(q0[i], q1[i], u[i]) for i in range(n)])
    assert quat.slerp(q0[0], q1[0], u[0]).shape == (4,)
    cases = {
        "(N,4),(N,4),(N,)": (quat.slerp(q0, q1, u), rows),
        "(4,),(4,),(N,)": (quat.slerp(q0[0], q1[0], u), np.stack([quat.slerp(q0[0], q1[0], t) for t in u])),
        "(N,4),(N,4),()": (quat.slerp(q0, q1, 0.3), np.stack([quat.slerp(a, b, 0.3) for a, b in zip(q0, q1)])),
        "(N,4),(4,),(N,)": (quat.slerp(q0, q1[0], u), np.stack([quat.slerp(a, q1[0], t) for a, t in zip(q0, u)])),
    }
    for name, (got, want) in cases.items():
        assert got.shape == want.shape == (n, 4), (name, got.shape)
        err = np.abs(got - want).max()
        assert err < 1e-14, f"{name}: vectorised differs from row by row by {err:.3g}"
    grid = quat.slerp(q0.reshape(8, 8, 4), q1.reshape(8, 8, 4), u.reshape(8, 8))
    assert grid.shape == (8, 8, 4) and np.abs(grid.reshape(n, 4) - rows).max() < 1e-14


def test_angle_deg_matches_scipy_and_ignores_sign():
    rng = np.random.default_rng(SEED + 7)
    q0, q1 = random_unit(rng, 500), random_unit(rng, 500)
    want = np.degrees(rotation_angle(q0, q1))
    for a, b in ((q0, q1), (-q0, q1), (q0, -q1), (q1, q0)):
        err = np.abs(quat.angle_deg(a, b) - want).max()
        assert err < 1e-9, f"angle_deg off scipy by {err:.3g} deg"
    assert np.all(quat.angle_deg(q0, -q0) == 0.0)
    # non-unit inputs are normalised; broadcast (4,) against (N, 4)
    err = np.abs(quat.angle_deg(3.0 * q0, q1[0]) - np.degrees(rotation_angle(q0, q1[0]))).max()
    assert err < 1e-9, err
    # resolution near zero (arccos of a dot product): about 1e-6 deg
    small = quat.from_rotation(quat.to_rotation(q0) * Rotation.from_rotvec([1e-5, 0, 0]))
    err = np.abs(quat.angle_deg(q0, small) - np.degrees(1e-5)).max()
    assert err < 5e-6, f"angle_deg of a 1e-5 rad rotation off by {err:.3g} deg"


def test_left_matrix_is_the_left_product():
    rng = np.random.default_rng(3)
    a = quat.normalize(rng.normal(size=4))
    b = quat.normalize(rng.normal(size=(50, 4)))
    np.testing.assert_allclose(b @ quat.left_matrix(a).T, quat.multiply(a, b), atol=1e-15)


def test_about_axes_is_scipys_rotation_vector_bit_for_bit():
    rng = np.random.default_rng(4)
    angle = np.concatenate([rng.uniform(-np.pi, np.pi, (6, 200)), rng.uniform(-2e-3, 2e-3, (6, 60)),
                            np.zeros((6, 2)), np.full((6, 2), 1e-3), np.full((6, 2), -1e-3)], axis=1)
    axis = np.array([0, 1, 2, 2, 0, 1])
    q = quat.about_axes(angle, axis)
    assert q.shape == angle.shape + (4,)
    rotvec = angle[..., None] * np.eye(3)[axis][:, None, :]
    want = quat.from_rotation(Rotation.from_rotvec(rotvec.reshape(-1, 3))).reshape(q.shape)
    assert np.array_equal(q, want)  # the generator's orientations stay those of its reference


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_tree_node_is_its_parent_times_its_elementary_rotation(axis):
    rng = np.random.default_rng(5 + axis)
    first = [0, 0, 1, 2, 2]  # the parent's own axis, from the identity
    angle = np.concatenate([rng.uniform(-180, 180, 250), rng.uniform(-0.1, 0.1, 48), [0.0, np.degrees(1e-3)]])
    deg = np.stack([rng.uniform(-180, 180, len(angle)), angle])
    deg[0, :20] = 0.0
    tree = Tree([first[axis + 1], axis], [-1, 0], [1, 0])
    got = tree.turn(deg)
    parent = quat.about_axes(np.radians(deg[:1]), [first[axis + 1]])[0]
    want = quat.multiply(parent, quat.about_axes(np.radians(angle)[None], [axis])[0])
    assert np.array_equal(got[:, 0], want)  # the same values (an exact zero's sign aside)
    assert np.array_equal(got[:, 1], parent)


def test_a_tree_refuses_a_child_before_its_parent_and_angles_of_another_shape():
    with pytest.raises(ValueError, match="parents before their children"):
        Tree([0, 1], [1, -1], [0])
    with pytest.raises(ValueError, match="axes 0..2"):
        Tree([3], [-1], [0])
    with pytest.raises(ValueError, match=r"deg must be \(2, n\)"):
        Tree([0, 1], [-1, 0], [1]).turn(np.zeros((3, 5)))
