"""Regions of local detail sampled at their own scale (latent_model/regions.py): the frame follows the region's
rigid motion, a pair sampled with one seed is co-moving (only what deforms changes), the left hand reads as a
right hand, and a face pose changes the head's samples but not the hands'."""
import numpy as np
import pytest

from latent_model.corpus.identities import IdentitySpec
from latent_model.regions import REGIONS, RegionSampling, region_frames, sample_region
from latent_model.types import FINAL

PERSON = IdentitySpec("regions", "train", {}, {})
CFG = RegionSampling(k=512)


@pytest.fixture(scope="module")
def character(generator):
    from latent_model.corpus.poses import POSES
    from latent_model.corpus.sdf import body_component_faces

    v = generator.neutral(PERSON).astype(np.float64)
    faces = body_component_faces(v, generator.faces)
    posed = {p: getattr(generator.pose(PERSON, POSES[p]), FINAL).astype(np.float64) for p in ("browDwLf", "elbowBentLf")}
    return v, faces, region_frames(v, generator.faces), posed


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_regions_have_their_own_scale(character):
    _, _, frames, _ = character
    assert set(frames) == set(REGIONS)
    assert 0.08 < frames["head"].radius < 0.2 and 0.04 < frames["hand_left"].radius < 0.1
    for f in frames.values():
        assert np.allclose(f.rotation.T @ f.rotation, np.eye(3), atol=1e-9) and np.linalg.det(f.rotation) > 0


def test_a_rigidly_moved_body_samples_as_its_rest(character):
    v, faces, frames, _ = character
    moved = v @ _rotation(np.array([0.3, 0.2, 1.0]), 0.7).T + np.array([0.4, -0.2, 0.1])
    for name, f in frames.items():
        p0, s0 = sample_region(v, faces, f, CFG, seed=3)
        p1, s1 = sample_region(moved, faces, f, CFG, seed=3, rest=v)
        assert np.allclose(p0, p1, atol=1e-4) and np.allclose(s0, s1, atol=1e-4), name
        # without following the motion, the samples would be elsewhere
        p2, _ = sample_region(moved, faces, f, CFG, seed=3)
        assert np.abs(p2 - p0).max() > 0.5


def test_the_left_hand_reads_as_the_mirrored_right_hand(character):
    v, faces, frames, _ = character
    # anny is near-symmetric: the same seed's uniform points in the two hands' frames see similar distances
    _, left = sample_region(v, faces, frames["hand_left"], CFG, seed=5)
    _, right = sample_region(v, faces, frames["hand_right"], CFG, seed=5)
    n = CFG.counts()[2]
    assert np.abs(left[-n:] - right[-n:]).mean() < 0.05
    # unmirrored, the left hand's box would be the right hand's turned inside out
    flipped = frames["hand_left"].__class__(**{**frames["hand_left"].__dict__, "mirrored": False})
    _, plain = sample_region(v, faces, flipped, CFG, seed=5)
    assert np.abs(plain[-n:] - right[-n:]).mean() > 2 * np.abs(left[-n:] - right[-n:]).mean()


def test_a_face_pose_moves_head_samples_and_a_body_pose_not_the_hand_code(character):
    v, faces, frames, posed = character
    head0, _ = sample_region(v, faces, frames["head"], CFG, seed=1)
    head1, _ = sample_region(posed["browDwLf"], faces, frames["head"], CFG, seed=1, rest=v)
    moved = np.linalg.norm(head1 - head0, axis=1) * frames["head"].radius
    assert 0.002 < moved.max() < 0.03 and (moved > 0.2 * moved.max()).mean() < 0.2  # the brow, not the head
    # the forearm carries the hand: in the hand's following frame little changes
    hand0, _ = sample_region(v, faces, frames["hand_left"], CFG, seed=1)
    hand1, _ = sample_region(posed["elbowBentLf"], faces, frames["hand_left"], CFG, seed=1, rest=v)
    world = np.linalg.norm(posed["elbowBentLf"][frames["hand_left"].vertices] - v[frames["hand_left"].vertices], axis=1)
    assert world.mean() > 0.1
    assert np.median(np.linalg.norm(hand1 - hand0, axis=1)) * frames["hand_left"].radius < 0.005


def test_the_frame_follows_the_still_part_not_what_deforms_inside():
    """A rigid motion plus a large deformation of a part of the points: the fit recovers the rigid motion of the
    rest (a plain least-squares fit tilts), also when the deformed part is the majority but the base is still."""
    from latent_model.regions import rigid_motion

    rng = np.random.default_rng(0)
    a = rng.normal(size=(600, 3)) * 0.05
    depth = np.clip((a[:, 2] + 0.15) / 0.3, 0, 1)  # the base at low z
    r, t = _rotation(np.array([0.3, 1.0, 0.2]), 0.4), np.array([0.1, -0.2, 0.05])
    for moving in (a[:, 0] > 0.03, a[:, 2] > -0.04):  # ~30 % of the points; ~80 %, the base still
        b = a @ r.T + t
        b[moving] += np.array([0.0, 0.03, 0.02]) + 0.2 * (a[moving] - a[moving].mean(axis=0))
        rr, tt = rigid_motion(a, b, depth, tolerance=1e-4)
        assert np.abs(rr - r).max() < 1e-6 and np.abs(tt - t).max() < 1e-6
    plain, _ = rigid_motion(a, b, np.ones(len(a)), tolerance=1e-4, iterations=1)
    assert np.abs(plain - r).max() > 1e-3  # one unweighted fit tilts with what moves


def _angle_deg(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def test_a_hand_frame_turns_with_the_hand_between_rest_poses(generator):
    """A hand's frame is its own principal axes: from anny's bind rest to a T-pose the hand moves rigidly, and its
    frame moves with it (the limb frame, whose forward axis comes from the world, turned 13-17° about the hand and
    put a curled little finger's code elsewhere: test latent cosine 0.06-0.86 in the T-pose against 0.88 in bind)."""
    from dataclasses import replace

    from latent_model.regions import _nearest_rotation, _vertex_areas, _weighted_fit
    from latent_model.surface import surface_features

    rests = {r: generator.neutral(replace(PERSON, rest=r)).astype(np.float64) for r in ("bind", "tpose")}
    features = {r: surface_features(v, generator.faces) for r, v in rests.items()}
    frames = {r: region_frames(v, generator.faces, features[r]) for r, v in rests.items()}
    for hand in ("hand_left", "hand_right"):
        a, b = frames["bind"][hand], frames["tpose"][hand]
        common = np.intersect1d(a.vertices, b.vertices)
        carried, _ = _weighted_fit(rests["bind"][common], rests["tpose"][common], np.ones(len(common)))
        assert _angle_deg(b.rotation.T @ carried @ a.rotation) < 6.0, hand
        # the limb frame of the same vertices did not follow the hand
        limb = {}
        for r, v in rests.items():
            f = frames[r][hand]
            w = _vertex_areas(v, generator.faces)[f.vertices]
            limb[r] = _nearest_rotation(np.einsum("n,nij->ij", w / w.sum(), features[r].frames[f.vertices]))
        assert _angle_deg(limb["tpose"].T @ carried @ limb["bind"]) > 8.0, hand


@pytest.mark.parametrize("hand_scale", [0.0, 1.0])
def test_every_finger_lies_deep_in_its_hand_region(generator, hand_scale):
    """A hand region is cut across the wrist, so a large hand's little fingertip is in it (a ball about the middle
    fingertip left half of it out), far from the faded edge, and the still palm is the region's base (low depth)."""
    from latent_model.detail import EDGE

    person = IdentitySpec("hands", "train", {}, {"l-hand-scale-incr": hand_scale, "r-hand-scale-incr": hand_scale})
    v = generator.neutral(person).astype(np.float64)
    frames = region_frames(v, generator.faces)
    for pose, region in (("fingerKnuckleD03Lf", "hand_left"), ("fingerKnuckleA03Rt", "hand_right")):
        moved = np.linalg.norm(getattr(generator.pose(person, pose), FINAL) - v, axis=1) > 5e-4
        f = frames[region]
        depth = dict(zip(f.vertices, f.depth))
        assert moved.sum() > 50 and all(i in depth for i in np.flatnonzero(moved)), pose
        assert min(depth[i] for i in np.flatnonzero(moved)) > 2 * EDGE, pose
    # the head's region is untouched by a hand's size, and the hands do not reach the head
    assert not (set(frames["hand_left"].vertices) & set(frames["head"].vertices))


def test_hand_samples_can_favour_the_fingers(character):
    """`hand_depth_power` draws a hand's near samples towards its fingertips (depth 1), the head's as before."""
    from scipy.spatial import cKDTree

    v, faces, frames, _ = character
    deep = RegionSampling(k=512, hand_depth_power=3.0)
    hand = frames["hand_right"]
    tree = cKDTree(hand.to_local(v[hand.vertices]))

    def mean_depth(cfg: RegionSampling) -> float:
        points, _ = sample_region(v, faces, hand, cfg, seed=5)
        n0, _, _ = cfg.counts()
        return float(hand.depth[tree.query(points[:n0])[1]].mean())  # the tight near samples' vertices

    assert mean_depth(deep) > mean_depth(CFG) + 0.1
    head = frames["head"]
    assert all(np.array_equal(a, b) for a, b in zip(sample_region(v, faces, head, CFG, seed=5),
                                                  sample_region(v, faces, head, RegionSampling(k=512, hand_depth_power=3.0), seed=5)))
    with pytest.raises(ValueError, match="hand_depth_power"):
        RegionSampling(hand_depth_power=-1.0)
