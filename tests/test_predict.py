"""`lrr predict` on a user's file, end to end through the shipped model and the Transfer API."""
import numpy as np
import pytest
import trimesh

from latent_model import meshio
from latent_model.shipped import ShippedPaths

pytestmark = pytest.mark.skipif(not ShippedPaths.at().checkpoint.exists() or not ShippedPaths.at().bank.exists(),
                                reason=f"the shipped model is missing ({ShippedPaths.at().checkpoint.parent}); "
                                       f"restore assets/model or set LRR_ASSETS")


@pytest.fixture(scope="module")
def maya_obj(tmp_path_factory):
    """A held-out identity exported the way Maya would: Y-up centimetres, shifted."""
    import torch

    from latent_model.shipped import GroundTruth, load_identity_specs

    torch.set_num_threads(1)
    specs, _ = load_identity_specs(ShippedPaths.at().identities)
    test = [s for s in specs if s.split == "test"]
    gt = GroundTruth(test[:1])
    v = gt.state(test[0].id, None, "neutral").astype(np.float64)
    user = (v @ meshio._R_Y_UP) * 100.0 + np.array([30.0, 0.0, 10.0])
    path = tmp_path_factory.mktemp("predict") / "character.obj"
    trimesh.Trimesh(user, gt.faces, process=False).export(path)
    return path, user


def _run(*argv):
    from latent_model.cli import main

    return main(["predict", *map(str, argv)])


def _front_and_turned(tmp_path, capsys, spec_rest: str, turn: np.ndarray, facing: str) -> tuple[dict, tuple]:
    """A test character of `spec_rest` in Z-up centimetres facing -Y ("front.obj") and turned by `turn` about Z
    ("turned.obj"), each predicted with elbowBentLf by `lrr predict`: ({name: motion in the file's frame}, the two
    files), checking that only the turned one is read `facing` and neither is warned about."""
    from latent_model.shipped import GroundTruth, load_identity_specs

    specs, _ = load_identity_specs(ShippedPaths.at().identities)
    spec = next(s for s in specs if s.split == "test" and s.rest == spec_rest)
    gt = GroundTruth([spec])
    v = gt.state(spec.id, None, "neutral").astype(np.float64) * 100.0  # Z up, centimetres, facing -Y
    moved = {}
    for name, user in (("front.obj", v), ("turned.obj", v @ turn.T)):
        trimesh.Trimesh(user, gt.faces, process=False).export(tmp_path / name)
        assert _run("--mesh", tmp_path / name, "--pose", "elbowBentLf", "-o", tmp_path / f"out_{name}") == 0
        printed = capsys.readouterr().out
        assert (f"facing {facing}" in printed) == (name == "turned.obj") and "warning" not in printed, printed
        moved[name] = meshio.read_file(tmp_path / f"out_{name}")[0] - user
    return moved, (tmp_path / "front.obj", tmp_path / "turned.obj")


def test_predict_writes_the_users_frame(maya_obj, tmp_path, capsys):
    src, user = maya_obj
    out = tmp_path / "posed.obj"
    assert _run("--mesh", src, "--pose", "elbowBentLf", "--strategy", "nearest", "-o", out) == 0
    printed = capsys.readouterr().out
    assert "cm, Y-up" in printed and "conditioning: id" in printed
    posed, faces, _ = meshio.read_file(out)
    _, faces_in, _ = meshio.read_file(src)
    assert posed.shape == user.shape and np.array_equal(faces, faces_in)  # same vertex order and faces
    d = np.linalg.norm(posed - user, axis=1)  # centimetres
    assert np.ptp(posed[:, 1]) == pytest.approx(np.ptp(user[:, 1]), rel=0.1)  # still Y-up cm (about 160 tall)
    assert 0.05 < d.max() < 60.0  # it moved, by a plausible amount in centimetres
    # magnitude 0 asks for no motion: a different, smaller result
    out0 = tmp_path / "still.ply"
    assert _run("--mesh", src, "--pose", "elbowBentLf", "--magnitude", "0", "-o", out0) == 0
    still, _, _ = meshio.read_file(out0)
    assert not np.allclose(still, posed)
    # blending toward another pose changes the result
    outb = tmp_path / "blend.obj"
    assert _run("--mesh", src, "--pose", "elbowBentLf", "--pose-b", "kneeBentLf", "--blend", "0.5", "-o", outb) == 0
    blended, _, _ = meshio.read_file(outb)
    assert not np.allclose(blended, posed, atol=1e-4)


def test_predict_encodes_the_mesh_once(maya_obj, tmp_path, monkeypatch):
    """The facing check encodes the mesh as read, and the prediction reads that latent (the mesh's own SDF samples
    once, not twice: 0.2-0.6 s at 14k vertices); with another SDF seed it would be encoded again."""
    from latent_model.transfer import Transfer

    calls = []
    encode = Transfer.encode
    monkeypatch.setattr(Transfer, "encode", lambda self, *a, **k: calls.append(1) or encode(self, *a, **k))
    assert _run("--mesh", maya_obj[0], "--pose", "elbowBentLf", "-o", tmp_path / "once.obj") == 0
    assert len(calls) == 1
    assert _run("--mesh", maya_obj[0], "--pose", "elbowBentLf", "--facing=+z", "-o", tmp_path / "told.obj") == 0
    assert len(calls) == 2  # told the facing, no check: encoded by the prediction


def test_predict_errors_are_clear_and_write_nothing(maya_obj, tmp_path, capsys):
    src, _ = maya_obj
    out = tmp_path / "never.obj"
    assert _run("--mesh", src, "--pose", "elbowBent", "-o", out) == 2
    err = capsys.readouterr().err
    assert "unknown pose 'elbowBent'" in err and "elbowBentLf" in err  # lists the valid names
    assert _run("--mesh", tmp_path / "missing.obj", "--pose", "elbowBentLf", "-o", out) == 2
    assert "no such file" in capsys.readouterr().err
    assert _run("--mesh", src, "--pose", "elbowBentLf", "--blend", "0.3", "-o", out) == 2
    assert "--pose-b" in capsys.readouterr().err
    assert _run("--mesh", src, "--pose", "elbowBentLf", "--strategy", "median", "-o", out) == 2
    assert "mean_pose_delta" in capsys.readouterr().err
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(100, 3))).export(cloud)
    assert _run("--mesh", cloud, "--pose", "elbowBentLf", "-o", out) == 2
    assert "point cloud" in capsys.readouterr().err
    assert _run("--mesh", src, "--pose", "elbowBentLf", "-o", tmp_path / "x.fbx") == 2
    assert not out.exists() and not any(p.name.endswith(".tmp") for p in tmp_path.iterdir())


def test_a_hand_joined_to_the_body_is_warned_about(tmp_path, capsys):
    """A hand fused to the thigh (as a remesh or scan fuses a hand resting on it; here a triangle bridging the left
    fingertip to the thigh) makes the torso-to-hand path run down the leg: `lrr predict` says which hand and the fix;
    the same mesh without the bridge gets no such warning."""
    from latent_model.shipped import GroundTruth, load_identity_specs
    from latent_model.surface import surface_features

    specs, _ = load_identity_specs(ShippedPaths.at().identities)
    spec = next(s for s in specs if s.split == "test" and s.rest == "armsDown30")
    gt = GroundTruth([spec])
    v = gt.state(spec.id, None, "neutral").astype(np.float64)
    faces = np.asarray(gt.faces, np.int64)
    sf = surface_features(v, faces)
    tip = sf.extremities["hand_left"]
    far = np.flatnonzero((sf.coords[:, 2] > 0.3) & (v[:, 0] > 0))  # the left side, away from the hand: the thigh
    thigh = far[np.argmin(np.linalg.norm(v[far] - v[tip], axis=1))]
    near = faces[(faces == tip).any(axis=1)][0]
    bridged = np.concatenate([faces, [[tip, thigh, next(k for k in near if k != tip)]]])
    for name, f in (("joined.obj", bridged), ("apart.obj", faces)):
        trimesh.Trimesh(v, f, process=False).export(tmp_path / name)
        assert _run("--mesh", tmp_path / name, "--pose", "elbowBentLf", "-o", tmp_path / f"out_{name}") == 0
        printed = capsys.readouterr().out
        assert ("joins the left hand" in printed and "gap between the hands" in printed) == (name == "joined.obj"), printed
        assert "right hand" not in printed


def test_a_character_facing_another_axis_is_found_by_the_model(tmp_path, capsys):
    """An Unreal-style export (Z up, centimetres, facing +X, a T-pose) read by the file's convention (facing -Y)
    lies far from every training state; `lrr predict` tries the other facings, reads it facing +X, and predicts
    what the same character facing -Y gets, turned into the file's frame; neither is out of distribution once
    placed. Told the wrong facing, it warns instead."""
    # a T-pose in centimetres: placed by the bounding box's centre it lay 15.5 from the training states (out of
    # distribution, 11.6) facing front; by its surface's centroid and the fitted feet height 5.5
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 degrees about Z: facing +X
    moved, (_, unreal) = _front_and_turned(tmp_path, capsys, "tpose", turn, "+X")
    d_front, d_turned = moved["front.obj"], moved["turned.obj"] @ turn  # the turned file's motion, turned back
    assert np.abs(d_front).max() > 5.0  # the elbow bends (centimetres)
    np.testing.assert_allclose(d_turned, d_front, atol=0.1)  # the same motion, within a millimetre
    assert _run("--mesh", unreal, "--pose", "elbowBentLf", "--up", "z", "--facing=-y",
                "-o", tmp_path / "wrong.obj") == 0
    printed = capsys.readouterr().out
    assert "is out of distribution" in printed and "facing +X" not in printed and "trying" not in printed


def test_a_character_turned_round_with_its_arms_down_is_read_on_its_toes(tmp_path, capsys):
    """Turned by 180 degrees, a character with its arms at its sides still lies within the out-of-distribution
    threshold, so only its feet say it faces the other way: as a neutral it is read facing +Y and gets the unturned
    file's motion, and so it is as a corrective's source (a posed source turned round lies within the threshold
    too)."""
    from latent_model.facing import toes_ahead

    turn = np.diag([-1.0, -1.0, 1.0])  # 180 degrees about Z: facing +Y
    moved, (front, back) = _front_and_turned(tmp_path, capsys, "armsDown30", turn, "+Y")
    assert toes_ahead(meshio.read_file(front)[0] / 100.0) > 0.05  # facing -Y, its toes ahead of its ankles
    np.testing.assert_allclose(moved["turned.obj"] @ turn, moved["front.obj"], atol=0.1)
    corrective = {}
    for name, path in (("front", front), ("back", back)):
        out = tmp_path / f"corrective_{name}.obj"
        assert _run("--mesh", path, "--pose", "elbowBentLf", "--kind", "skinning_to_skinning_plus_blendshape",
                    "-o", out) == 0
        assert ("facing +Y" in capsys.readouterr().out) == (name == "back")
        corrective[name] = meshio.read_file(out)[0] - meshio.read_file(path)[0]
    assert np.abs(corrective["front"]).max() > 0.2  # the elbow's corrective moves the surface (cm)
    np.testing.assert_allclose(corrective["back"] @ turn, corrective["front"], atol=0.05)


def test_toes_ahead_reads_the_feet_on_the_ground():
    """A posed mesh faces where the feet it stands on point: a leg lifted and bent at the knee hangs its foot
    behind the shins (the shins' mean against the lowest points read test character id008 with hipFlexLf +
    kneeBentLf as facing backwards, -0.10 m), and training character id012's hanging foot rests as low as its
    standing one, toes down and back: each foot counts as far as its sole rests flat (the largest of the feet read
    it turned round as facing front, +0.15 m)."""
    from latent_model.facing import TOES_BACK_M, toes_ahead
    from latent_model.shipped import GroundTruth, load_identity_specs

    specs, _ = load_identity_specs(ShippedPaths.at().identities)
    gt = GroundTruth([s for s in specs if s.id in ("id008", "id012")])
    for person in ("id008", "id012"):
        for pose in ("hipFlexLf+kneeBentLf", "kneeBentRt", None):
            v = gt.state(person, pose, "skinning" if pose else "neutral").astype(np.float64)
            assert toes_ahead(v) > 0.08, (person, pose)
            assert toes_ahead(v * [-1.0, -1.0, 1.0]) < -TOES_BACK_M, (person, pose)  # turned round about Z
            assert abs(toes_ahead(v * 100.0) / 100.0 - toes_ahead(v)) < 1e-6  # in the mesh's units
