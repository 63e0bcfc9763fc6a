import pytest

from latent_model.corpus.poses import COMBO_POSES, PAPER_POSES, POSES, SINGLE_POSES, get_pose, pose_line


def test_vocabulary_size_and_paper_poses():
    assert len(SINGLE_POSES) >= 50
    assert len(COMBO_POSES) >= 20
    for name in PAPER_POSES:
        assert name in POSES
    for letter in "ABCD":
        for level in ("01", "02", "03"):
            assert f"fingerKnuckle{letter}{level}Lf" in POSES and f"fingerKnuckle{letter}{level}Rt" in POSES


def test_groups_span_broad_finger_and_face():
    groups = {POSES[n].group for n in SINGLE_POSES}
    assert {"body", "finger", "face"} <= groups
    bones = {j.bone.split(".")[0] for n in SINGLE_POSES for j in POSES[n].joints}
    for needed in ("lowerarm01", "lowerleg01", "clavicle", "upperarm01", "upperleg01", "wrist", "neck01", "spine03"):
        assert needed in bones


def test_every_left_pose_has_a_true_right_mirror():
    for name, p in POSES.items():
        if name.endswith("Lf") and not p.is_combo:
            r = POSES[name[:-2] + "Rt"]
            assert len(r.joints) == len(p.joints)
            for jl, jr in zip(p.joints, r.joints):
                assert jr.bone == jl.bone.replace(".L", ".R") and jr.degrees == jl.degrees
                assert jr.mirrored and not jl.mirrored


def test_combos_are_made_of_singles():
    for name in COMBO_POSES:
        p = POSES[name]
        assert all(c in SINGLE_POSES for c in p.components)
        assert len(p.joints) == sum(len(POSES[c].joints) for c in p.components)


def test_unknown_pose_lists_valid_names():
    with pytest.raises(KeyError) as e:
        get_pose("elbowBentLeft")
    assert "elbowBentLf" in str(e.value) and "unknown pose" in str(e.value)


def test_pose_line_mentions_parts():
    line = pose_line(POSES["neckTurnLf+jawOpen"])
    assert "combo" in line and "neck01" in line and "jawOpen" in line
