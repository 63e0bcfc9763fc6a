"""Decoder v2 through the Transfer API on the tiny model: blends and magnitudes are continuous, the
prediction reads the mesh's latent and geometry, an example pair conditions it (API, `lrr transfer`),
and the out-of-distribution warning fires on meshes unlike the validation characters."""
import numpy as np
import pytest
import trimesh

from latent_model import meshio
from latent_model.types import FINAL


@pytest.fixture(scope="module")
def held_out(tiny_corpus):
    c = tiny_corpus
    i = c.split_indices("test", rest="bind")[0]
    return c, i, c.vertices(c.state(i, None, "neutral"))


def _region_motion(pred, truth, src, region):
    """Fraction of the true motion of `region` (bool (V,)) that the prediction makes, along the truth."""
    t, p = (truth - src)[region], (pred - src)[region]
    return float((p * t).sum() / max((t * t).sum(), 1e-12))


def test_blend_is_continuous_and_moves_both_regions(tiny_motion, held_out):
    transfer, _ = tiny_motion
    c, i, v = held_out
    mesh = transfer.prepare(v, c.faces, sdf_faces=c.body_faces)
    steps = [transfer.predict(mesh, "elbowBentLf", pose_b="kneeBentLf", blend=b) for b in np.linspace(0, 1, 21)]
    moves = np.array([np.linalg.norm(b - a, axis=1).max() for a, b in zip(steps, steps[1:])])
    assert moves.max() <= 3.0 * np.median(moves)  # no step snaps
    elbow, knee = (c.vertices(c.state(i, p, FINAL)) for p in ("elbowBentLf", "kneeBentLf"))
    region = {p: np.linalg.norm(t - v, axis=1) > 0.01 for p, t in (("elbow", elbow), ("knee", knee))}
    half = steps[10]
    # at 0.5 both regions move, each a fair part of what its own pose moves it by the model at 1
    for name, truth, full in (("elbow", elbow, steps[0]), ("knee", knee, steps[-1])):
        assert _region_motion(half, truth, v, region[name]) > 0.3 * _region_motion(full, truth, v, region[name]) > 0
    # the ends are the two poses' own predictions; the slider mixes their motions, not their deltas
    assert np.allclose(steps[-1], transfer.predict(mesh, "kneeBentLf"), atol=1e-5)
    mixed_delta = 0.5 * (transfer.bank.mean_delta("neutral_to_pose", "elbowBentLf")
                         + transfer.bank.mean_delta("neutral_to_pose", "kneeBentLf"))
    assert not np.allclose(half, transfer.predict(mesh, None, delta=mixed_delta), atol=1e-4)


def test_magnitude_is_exact_at_zero_and_continuous(tiny_motion, held_out):
    transfer, _ = tiny_motion
    c, _, v = held_out
    mesh = transfer.prepare(v, c.faces, sdf_faces=c.body_faces)
    assert np.array_equal(transfer.predict(mesh, "elbowBentLf", magnitude=0.0), mesh.vertices)
    preds = [transfer.predict(mesh, "elbowBentLf", magnitude=m) for m in np.linspace(0, 2, 41)]
    moves = [np.abs(b - a).max() for a, b in zip(preds, preds[1:])]
    assert max(moves) < 4 * np.median(moves) and max(moves) > 0


def test_the_prediction_reads_the_latent_and_the_geometry(tiny_motion, held_out):
    transfer, _ = tiny_motion
    c, i, v = held_out
    mesh = transfer.prepare(v, c.faces, sdf_faces=c.body_faces)
    base = transfer.predict(mesh, "elbowBentLf")
    # another mu_src, same geometry
    other_mu = transfer.prepare(v, c.faces, sdf_faces=c.body_faces, mu=mesh.mu + 0.5)
    assert np.abs(transfer.predict(other_mu, "elbowBentLf") - base).max() > 1e-4
    # another geometry (another character), same mu_src: the motion follows the mesh, not a template
    j = c.split_indices("test", rest="bind")[1]
    w = c.vertices(c.state(j, None, "neutral"))
    other_geo = transfer.prepare(w, c.faces, sdf_faces=c.body_faces, mu=mesh.mu)
    assert np.abs((transfer.predict(other_geo, "elbowBentLf") - w) - (base - v)).max() > 1e-3


def test_example_pair_conditions_the_prediction(tiny_motion, held_out):
    transfer, _ = tiny_motion
    c, i, v = held_out
    a = c.split_indices("test", rest="bind")[1]
    neutral = transfer.prepare(c.vertices(c.state(a, None, "neutral")), c.faces, sdf_faces=c.body_faces)
    posed = transfer.prepare(c.vertices(c.state(a, "elbowBentLf", FINAL)), c.faces, sdf_faces=c.body_faces)
    delta = transfer.example_delta(neutral, posed)
    assert np.allclose(delta, posed.mu - neutral.mu)
    mesh = transfer.prepare(v, c.faces, sdf_faces=c.body_faces)
    out = transfer.predict_detail(mesh, None, delta=delta)
    assert out.label == "example" and out.predictor == "motion"
    assert np.abs(out.vertices - v).max() > 1e-3
    # the example's delta, not a pose name, decides: another example gives another prediction
    knee = transfer.prepare(c.vertices(c.state(a, "kneeBentLf", FINAL)), c.faces, sdf_faces=c.body_faces)
    assert np.abs(transfer.predict(mesh, None, delta=transfer.example_delta(neutral, knee)) - out.vertices).max() > 1e-3
    with pytest.raises(ValueError, match="one topology"):
        transfer.example_delta(neutral, transfer.prepare(v[:-10], c.faces[:100]))


def test_a_reading_keeps_no_small_weight():
    """An example's pose weights are 0 or at least READ_DROP, and fit the target as well as bounded least squares
    on the poses kept: one refit after dropping the small weights could leave a weight near 0 (a wrist twist was
    read as "neckTurnRt 0.00"); seeded random problems hold such cases."""
    from scipy.optimize import lsq_linear

    from latent_model.transfer import READ_DROP, READ_MAX, read_weights

    rng = np.random.default_rng(0)
    for _ in range(1500):
        cols, target = rng.normal(size=(6, 4)), rng.normal(size=6)
        w = read_weights(cols, target)
        assert np.all((w == 0) | ((w >= READ_DROP) & (w <= READ_MAX))), w
        keep = w > 0
        if keep.any():
            best = lsq_linear(cols[:, keep], target, bounds=(0.0, READ_MAX)).x
            assert np.allclose(w[keep], best, atol=1e-6)


def test_an_example_pair_reads_as_the_poses_that_make_it(tiny_motion, held_out):
    """A's motion made by two poses' motions reads back as those two poses and makes nearly all of it; B then
    moves by their motions (the two poses blended on B), scaled by the magnitude; a still pair reads as no
    motion; a read that makes too little of its example leaves the latent delta to the decoder, and says so."""
    from latent_model.transfer import READ_MIN, BodyReading

    transfer, _ = tiny_motion
    c, i, v = held_out
    a = c.split_indices("test", rest="bind")[1]
    neutral = transfer.prepare(c.vertices(c.state(a, None, "neutral")), c.faces, sdf_faces=c.body_faces)
    made = transfer.predict(neutral, "elbowBentLf", pose_b="kneeBentLf", blend=0.5)
    posed = transfer.prepare(made, c.faces, sdf_faces=c.body_faces)
    read = transfer.example_body(neutral, posed)
    assert read.used and read.explained > 0.9
    assert abs(read.weights["elbowBentLf"] - 0.5) < 0.15 and abs(read.weights["kneeBentLf"] - 0.5) < 0.15
    mesh = transfer.prepare(v, c.faces, sdf_faces=c.body_faces)
    delta = transfer.example_delta(neutral, posed)
    out = transfer.predict_detail(mesh, None, delta=delta, body_reading=read)
    blended = transfer.predict(mesh, "elbowBentLf", pose_b="kneeBentLf", blend=0.5)
    scale = np.linalg.norm(blended - v, axis=1).max()
    assert np.linalg.norm(out.vertices - blended, axis=1).max() < 0.2 * scale
    assert out.label == "example" and "reads as" in out.note and "elbowBentLf" in out.note
    assert np.array_equal(transfer.predict(mesh, None, magnitude=0.0, delta=delta, body_reading=read), mesh.vertices)
    half = transfer.predict(mesh, None, magnitude=0.5, delta=delta, body_reading=read)
    assert 0.3 < np.linalg.norm(half - v, axis=1).max() / np.linalg.norm(out.vertices - v, axis=1).max() < 0.7
    still = transfer.example_body(neutral, neutral)
    assert still.weights == {} and np.array_equal(transfer.predict(mesh, None, delta=delta * 0, body_reading=still), v)
    # blending toward a pose: continuous, and at 1 the pose's own prediction
    sweep = [transfer.predict(mesh, None, delta=delta, body_reading=read, pose_b="elbowBentRt", blend=b)
             for b in np.linspace(0, 1, 11)]
    steps = [np.linalg.norm(y - x, axis=1).max() for x, y in zip(sweep, sweep[1:])]
    assert max(steps) <= 3.0 * np.median(steps) and np.allclose(sweep[0], out.vertices, atol=1e-6)
    assert np.allclose(sweep[-1], transfer.predict(mesh, "elbowBentRt"), atol=1e-5)
    weak = BodyReading(read.weights, READ_MIN / 2)
    fallback = transfer.predict_detail(mesh, None, delta=delta, body_reading=weak)
    assert np.array_equal(fallback.vertices, transfer.predict(mesh, None, delta=delta)) and "latent delta" in fallback.note


def test_lrr_transfer_end_to_end(tiny_motion, held_out, tmp_path, capsys):
    from latent_model.checkpoint import save_checkpoint
    from latent_model.cli import main

    transfer, p = tiny_motion
    c, i, v = held_out
    ck, bk = tmp_path / "m.safetensors", tmp_path / "bank.safetensors"
    save_checkpoint(ck, transfer.model, p, "all", 0)
    transfer.bank.save(bk)
    a = c.split_indices("test", rest="bind")[1]
    # the example pair in Y-up centimetres (a DCC export); the target B in metres, Z-up, with another topology
    to_cm = lambda x: (x.astype(np.float64) @ meshio._R_Y_UP) * 100.0  # noqa: E731
    for name, state in (("A.obj", c.state(a, None, "neutral")), ("A1.obj", c.state(a, "elbowBentLf", FINAL))):
        trimesh.Trimesh(to_cm(c.vertices(state)), c.faces, process=False).export(tmp_path / name)
    sub = trimesh.Trimesh(v, c.faces, process=False).subdivide()
    sub.export(tmp_path / "B.ply")
    out = tmp_path / "B1.obj"
    argv = ["transfer", "--example-neutral", tmp_path / "A.obj", "--example-posed", tmp_path / "A1.obj",
            "--mesh", tmp_path / "B.ply", "--checkpoint", ck, "--bank", bk, "-o", out]
    assert main([str(x) for x in argv]) == 0
    printed = capsys.readouterr().out
    assert "example A.obj -> A1.obj" in printed and "wrote" in printed
    got, faces, _ = meshio.read_file(out)
    assert got.shape == sub.vertices.shape and np.array_equal(faces, sub.faces)
    assert np.linalg.norm(got - sub.vertices, axis=1).max() > 1e-3  # it moved B
    # A1 of another topology: a clear error, nothing written
    trimesh.Trimesh(to_cm(v), c.faces, process=False).subdivide().export(tmp_path / "bad.obj")
    out2 = tmp_path / "never.obj"
    argv[4] = tmp_path / "bad.obj"
    argv[-1] = out2
    assert main([str(x) for x in argv]) == 2
    assert "must be A.obj deformed" in capsys.readouterr().err and not out2.exists()


def test_out_of_distribution_warning(tiny_motion, tiny_corpus):
    from latent_model.bank import calibrate_ood_threshold

    transfer, _ = tiny_motion
    c = tiny_corpus
    bank = transfer.bank
    bank.ood_threshold = calibrate_ood_threshold(transfer.model, c, bank)
    assert bank.ood_threshold > 0
    i = c.split_indices("test", rest="bind")[0]
    v = c.vertices(c.state(i, None, "neutral"))
    held = transfer.novelty(transfer.prepare(v, c.faces, sdf_faces=c.body_faces))
    assert not held.out_of_distribution and held.warning() is None
    centre = v.mean(axis=0)
    big = transfer.novelty(transfer.prepare((v - centre) * 2.0 + centre, c.faces, sdf_faces=c.body_faces))
    assert big.out_of_distribution and "out of distribution" in big.warning("big.obj")
    squashed = transfer.novelty(transfer.prepare(v * np.array([2.0, 1.0, 0.5], np.float32), c.faces,
                                                 sdf_faces=c.body_faces))
    assert squashed.out_of_distribution


def test_a_posed_source_is_judged_against_the_posed_threshold(tiny_motion, tiny_corpus):
    """A held-out character's skinned pose (a corrective pair's source) lies farther from the training states than its
    neutral; judged as a source of its own kind it is not novel, doubled in size it is."""
    from latent_model.bank import calibrate_ood_threshold, calibrate_posed_threshold

    transfer, _ = tiny_motion
    c, bank = tiny_corpus, transfer.bank
    kept = bank.ood_threshold, bank.ood_threshold_posed
    try:
        bank.ood_threshold = calibrate_ood_threshold(transfer.model, c, bank)
        bank.ood_threshold_posed = calibrate_posed_threshold(transfer.model, c, bank)
        assert bank.ood_threshold_posed > 0
        assert bank.threshold_for("neutral_to_pose") == bank.ood_threshold
        assert bank.threshold_for("skinning_to_skinning_plus_blendshape") == bank.ood_threshold_posed
        i = c.split_indices("test", rest="bind")[0]
        v = c.vertices(c.state(i, "elbowBentLf", "skinning"))
        held = transfer.novelty(transfer.prepare(v, c.faces, sdf_faces=c.body_faces), "skinning_to_skinning_plus_blendshape")
        assert held.posed and held.threshold == bank.ood_threshold_posed and not held.out_of_distribution
        centre = v.mean(axis=0)
        big = transfer.novelty(transfer.prepare((v - centre) * 2.0 + centre, c.faces, sdf_faces=c.body_faces),
                               "skinning_to_skinning_plus_blendshape")
        assert big.out_of_distribution and "posed state" in big.warning("big.obj")
    finally:
        bank.ood_threshold, bank.ood_threshold_posed = kept
