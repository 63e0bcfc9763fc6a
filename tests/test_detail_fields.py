"""The local detail stage's displacement fields (latent_model/detail_fields.py) on synthetic regions: the affine
alignment finds a known map, a field pooled from differently proportioned characters lands where their motion
was, and a delta is read as the mix of poses that makes it, dropping what is below the noise floor."""
import numpy as np
import pytest

from latent_model.detail_fields import RegionFields, affine_align, build_fields


def _ellipsoid(n: int, seed: int) -> np.ndarray:
    x = np.random.default_rng(seed).normal(size=(n, 3))
    return x / np.linalg.norm(x, axis=1, keepdims=True) * np.array([1.0, 0.8, 1.2])


def test_affine_align_recovers_a_stretch_and_a_shift():
    anchor = _ellipsoid(3000, 0)
    A0 = np.diag([1.25, 0.9, 1.0])
    x = _ellipsoid(2500, 1) @ np.linalg.inv(A0).T - np.array([0.1, 0.0, -0.05])
    A, b = affine_align(x, anchor)
    assert np.allclose(A, A0, atol=0.05) and np.allclose(x @ A.T + b, _ellipsoid(2500, 1), atol=0.05)


def test_a_field_pooled_from_other_proportions_lands_on_the_moving_part():
    anchor = _ellipsoid(3000, 0)
    bump = lambda p: np.exp(-np.sum((p - [0, 0, 1.2]) ** 2, axis=1) / 0.05)[:, None] * [0, 0, 0.1]  # noqa: E731
    chars = []
    for seed, stretch in ((0, 1.0), (2, 1.3), (3, 0.8)):
        x = _ellipsoid(3000, seed) * [stretch, 1.0, 1.0 / stretch]  # the top moves with the shape
        top = bump(x * [1.0 / stretch, 1.0, stretch])  # the same part of each character moves
        chars.append((x, {"up": x + top, "still": x}))
    f = build_fields(chars, ["up", "still"])
    truth = bump(anchor)
    moving = truth[:, 2] > 0.05
    assert np.abs(f.values[0][moving, 2] - truth[moving, 2]).mean() < 0.2 * truth[moving, 2].mean()
    assert np.abs(f.values[1]).max() == 0.0
    # placed on a new character of other proportions, the motion comes back in its own coordinates
    y = _ellipsoid(2000, 5) * [1.15, 1.0, 1.0 / 1.15]
    d = f.displacement(f.place(y), np.array([0.5, 0.0]))
    top = bump(y * [1 / 1.15, 1.0, 1.15])[:, 2] > 0.05
    assert d[top, 2].mean() > 0.3 * 0.5 * 0.1 and np.abs(d[~top]).mean() < 0.1 * d[top, 2].mean()


def test_a_delta_reads_as_its_mix_of_poses_above_the_floor():
    basis = np.array([[1.0, 0.0, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 2.0]])
    assert RegionFields.read(0.5 * basis[0] + 2.0 * basis[2], basis, 0.1) == pytest.approx([0.5, 0.0, 2.0])
    # a little of the third pose (0.02 of its 2.0 length: under the floor) is dropped, not kept as noise
    assert RegionFields.read(basis[1] + 0.01 * basis[2], basis, 0.1) == pytest.approx([0.0, 1.0, 0.0])
    assert not RegionFields.read(-basis[0], basis, 0.1).any()  # no pose makes the opposite motion
    # antagonists (mean deltas pointing apart, a brow down and up) are never mixed: the larger stays
    anti = np.array([[1.0, 0.0, 0.0], [-0.9, 0.3, 0.0], [0.0, 0.0, 1.0]])
    w = RegionFields.read(0.8 * anti[0] + 0.5 * anti[1] + anti[2], anti, 0.01)
    assert w[1] == 0.0 and w[0] > 0 and w[2] == pytest.approx(1.0)
    # a delta all under the floor still reads as its best pose (the noise gate, not the read, judges it)
    assert RegionFields.read(0.05 * basis[0], basis, 0.1) == pytest.approx([0.05, 0.0, 0.0])


def _finger(n: int = 600, seed: int = 0) -> np.ndarray:
    """Points of a thin finger along x in [0, 3] (joints at x = 1 and 2)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, n)
    return np.c_[rng.uniform(0.0, 3.0, n), 0.1 * np.cos(a), 0.1 * np.sin(a)]


def _turn(x: np.ndarray, joint: float, degrees: float) -> np.ndarray:
    """x with the part beyond `joint` turned about the z axis through (joint, 0, 0)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    pivot = np.array([joint, 0.0, 0.0])
    out = x.copy()
    beyond = x[:, 0] > joint
    out[beyond] = (x[beyond] - pivot) @ r.T + pivot
    return out


def test_a_fingers_knuckle_turns_compose_as_a_skeletons_and_one_turn_is_its_field():
    from latent_model.detail_fields import fit_turn

    x = _finger()
    base, tip = _turn(x, 1.0, 40.0) - x, _turn(x, 2.0, 50.0) - x
    fields = RegionFields(x, ["base", "tip"], np.stack([base, tip]), chains=((0, 1),))
    t = fit_turn(x, base)
    assert np.allclose(t.pivot[:2], [1.0, 0.0], atol=1e-6) and np.degrees(np.linalg.norm(t.rotvec)) == pytest.approx(40.0)
    # both at once: the tip turns about its joint where the base's turn carried it (forward kinematics)
    truth = np.where((x[:, 0] > 1.0)[:, None], (_turn(_turn(x, 2.0, 50.0), 1.0, 40.0)), x) - x
    assert np.abs(fields.mixed(np.array([1.0, 1.0])) - truth).max() < 1e-9
    summed = RegionFields(x, ["base", "tip"], np.stack([base, tip])).mixed(np.array([1.0, 1.0]))
    assert np.allclose(summed, base + tip) and np.abs(summed - truth).max() > 0.3  # added, the tip lands elsewhere
    # one turn alone is its field; half of it turns half the angle (not half the displacement)
    assert np.abs(fields.mixed(np.array([1.0, 0.0])) - base).max() < 1e-12
    assert np.abs(fields.mixed(np.array([0.5, 0.0])) - (_turn(x, 1.0, 20.0) - x)).max() < 1e-9


def test_a_source_bent_at_the_base_turns_its_tip_about_where_the_tip_joint_now_is():
    x = _finger()
    base, tip = _turn(x, 1.0, 40.0) - x, _turn(x, 2.0, 50.0) - x
    fields = RegionFields(x, ["base", "tip"], np.stack([base, tip]), chains=((0, 1),))
    y = _finger(500, seed=1)  # another finger, sampled elsewhere, standing in the base pose (source_to_combo)
    source = _turn(y, 1.0, 40.0)
    truth = np.where((y[:, 0] > 1.0)[:, None], _turn(_turn(y, 2.0, 50.0), 1.0, 40.0), y)
    held = fields.place(source, fields.weights_of(["base"]))
    assert held.held.tolist() == [1.0, 0.0]
    moved = source + fields.displacement(held, np.array([0.0, 1.0]))
    error = lambda p: np.linalg.norm(p - truth, axis=1)  # noqa: E731
    assert error(moved).mean() < 0.02 and error(moved).max() < 0.1  # the tip moves up to 0.85
    # placed on the straight anchor, the bent tip is matched to the wrong points and turns the wrong way
    plain = source + fields.displacement(fields.place(source), np.array([0.0, 1.0]))
    assert error(plain).mean() > 0.2
    assert fields.place(source, fields.weights_of([])).held is None  # no held pose: the plain placement


def test_finger_chains_group_each_fingers_knuckles_base_first():
    from latent_model.detail_poses import finger_chains

    poses = ["browDwLf", "fingerKnuckleA02Lf", "fingerKnuckleA01Lf", "fingerKnuckleB01Lf", "fistLf", "fingerKnuckleA01Rt"]
    assert finger_chains(poses) == ((2, 1), (5,), (3,))
