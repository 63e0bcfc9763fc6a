"""The corrective fields (latent_model/corrective_fields.py, train/corrective_fields.py): `lrr train correctives` on
the tiny preset, its file, and what `Transfer` does with a skinning -> skinning+blendshape pair: the corrective of
the pose, read from the mesh's own region shape, better than no motion on a held-out character, linear in the
magnitude; another topology reads them through anny's template registered onto it, and is told so."""
import dataclasses

import numpy as np
import pytest

KIND = "skinning_to_skinning_plus_blendshape"


@pytest.fixture(scope="module")
def fields(tmp_path_factory):
    from latent_model.config import preset
    from latent_model.corrective_fields import CorrectiveFields
    from latent_model.train.corrective_fields import corrective_training, run_correctives

    path = tmp_path_factory.mktemp("correctives") / "correctives.safetensors"
    run_correctives(preset("tiny"), corrective_training("tiny"), path, workers=1, log=lambda _m: None)
    return path, CorrectiveFields.load(path)


@pytest.fixture(scope="module")
def with_fields(tiny_motion, fields):
    transfer, _ = tiny_motion
    return type(transfer)(transfer.model, transfer.bank, transfer.sdf_k, correctives=fields[1])


def _skinned(generator, spec, pose="elbowBentLf", rest=None):
    g = generator.pose(spec, pose, rest)
    return g.skinning.astype(np.float64), g.skinning_plus_blendshape.astype(np.float64)


def _held_out():
    from latent_model.config import preset
    from latent_model.corpus.build import plan

    specs, _, _ = plan(preset("tiny").corpus)
    return [s for s in specs if s.split == "test"]


def test_the_file_holds_each_corrected_pose(fields, tmp_path):
    from latent_model.checkpoint import CheckpointError
    from latent_model.corrective_fields import CorrectiveFields

    path, f = fields
    assert set(f.poses) == {"elbowBentLf", "elbowBentRt", "kneeBentLf"}  # the tiny preset's body poses
    c = f.poses["elbowBentLf"]
    assert len(c.persons) == len(c.shapes) == len(c.coef) == 2 * 2  # 2 persons x 2 rests
    assert set(f.validation) == set(f.poses) and all(set(r) == {"bind", "armsSides"} for r in f.validation.values())
    assert c.basis.shape == (3, len(c.index) * 3) and np.abs(c.mean).max() > 0
    again = tmp_path / "again.safetensors"
    f.save(again)
    other = CorrectiveFields.load(again)
    assert np.array_equal(other.poses["kneeBentLf"].index, f.poses["kneeBentLf"].index)
    assert np.array_equal(other.poses["kneeBentLf"].coef, f.poses["kneeBentLf"].coef)
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a file")
    with pytest.raises(CheckpointError, match="lrr train correctives"):
        CorrectiveFields.load(bad)


def test_the_elbow_region_is_at_the_left_elbow(fields, generator):
    f = fields[1]
    spec = _held_out()[0]
    skinned, truth = _skinned(generator, spec)
    moved = np.linalg.norm(truth - skinned, axis=1)
    region = f.poses["elbowBentLf"].index
    # the region holds where the rig's corrective is: 95 % of it (by size), and is a small part of the body
    assert moved[region].sum() / moved.sum() > 0.95 and len(region) < 0.15 * len(skinned)
    x = skinned[region, 0]
    assert np.sign(np.median(x)) == np.sign(np.median(skinned[np.argmax(moved), 0]))  # the same side


def test_a_held_out_corrective_beats_no_motion_and_scales(with_fields, generator, tiny_corpus):
    from latent_model.analysis.metrics import mesh_errors

    assert with_fields.predicts_with(KIND) == "correctives"
    for spec in _held_out()[:2]:
        skinned, truth = _skinned(generator, spec)
        mesh = with_fields.prepare(skinned, tiny_corpus.faces)
        out = with_fields.predict_detail(mesh, "elbowBentLf", "mean", kind=KIND)
        assert out.predictor == "correctives" and out.note is None and out.gate == 1.0
        assert mesh_errors(out.vertices, truth, skinned)["explained"] > 0.2, spec.id
        zero = with_fields.predict(mesh, "elbowBentLf", "mean", magnitude=0.0, kind=KIND)
        assert np.array_equal(zero, mesh.vertices)  # magnitude 0: the source exactly
        half = with_fields.predict(mesh, "elbowBentLf", "mean", magnitude=0.5, kind=KIND)
        np.testing.assert_allclose(half - mesh.vertices, 0.5 * (out.vertices - mesh.vertices), atol=1e-6)


def test_the_read_follows_the_mesh_shape(fields, generator, monkeypatch):
    """With one sample read, a training person posed on top of a rest reads that person's own sample in that rest:
    what is read comes from the mesh's region, not from the pose's name alone."""
    import latent_model.corrective_fields as cf
    from latent_model.config import preset
    from latent_model.corpus.build import plan

    monkeypatch.setattr(cf, "NEAREST", 1)
    c = fields[1].poses["elbowBentLf"]
    specs, _, _ = plan(preset("tiny").corpus)
    person = next(s for s in specs if s.id == c.persons[-1])
    for rest, sample in (("bind", len(c.persons) - 2), ("armsDown", len(c.persons) - 1)):
        skinned, _ = _skinned(generator, person, rest=rest)
        assert c.nearest(c.frame(skinned)[3])[0].tolist() == [sample], rest
    a, _ = fields[1].displacement(_skinned(generator, person, rest="bind")[0], "elbowBentLf")
    b, _ = fields[1].displacement(_skinned(generator, person, rest="armsDown")[0], "elbowBentLf")
    assert np.abs(a - b).max() > 1e-4


def test_a_person_is_read_only_where_its_samples_are_alike(fields, generator, monkeypatch):
    import latent_model.corrective_fields as cf
    from latent_model.config import preset
    from latent_model.corpus.build import plan

    c = fields[1].poses["elbowBentLf"]
    specs, _, _ = plan(preset("tiny").corpus)
    person = next(s for s in specs if s.id == c.persons[-1])
    shape = c.frame(_skinned(generator, person, rest="armsDown")[0])[3]
    near, own = c.nearest(shape, person.id)
    assert own and all(c.persons[i] == person.id for i in near)
    # its own samples lie beyond the single nearest sample's distance when that sample is the other person's
    other = next(s for s in specs if s.id == c.persons[0])
    monkeypatch.setattr(cf, "NEAREST", 1)
    near, own = c.nearest(c.frame(_skinned(generator, other, rest="armsDown")[0])[3], person.id)
    assert not own and c.persons[near[0]] == other.id


def test_a_combo_adds_its_components_and_the_blend_mixes(with_fields, generator, tiny_corpus):
    spec = _held_out()[0]
    skinned, _ = _skinned(generator, spec, "elbowBentLf+kneeBentLf")
    mesh = with_fields.prepare(skinned, tiny_corpus.faces)
    v = mesh.vertices.astype(np.float64)
    combo = with_fields.predict(mesh, "elbowBentLf+kneeBentLf", "mean", kind=KIND) - v
    parts = [with_fields.predict(mesh, p, "mean", kind=KIND) - v for p in ("elbowBentLf", "kneeBentLf")]
    np.testing.assert_allclose(combo, parts[0] + parts[1], atol=1e-5)
    mixed = with_fields.predict(mesh, "elbowBentLf", "mean", kind=KIND, pose_b="kneeBentLf", blend=0.25) - v
    np.testing.assert_allclose(mixed, 0.75 * parts[0] + 0.25 * parts[1], atol=1e-5)


def test_an_example_pairs_corrective_reads_as_its_pose_and_carries_to_another_character(with_fields, generator,
                                                                                         tiny_corpus):
    from latent_model.analysis.metrics import mesh_errors

    a, b = _held_out()[:2]
    ex = [with_fields.prepare(x, tiny_corpus.faces) for x in _skinned(generator, a, "kneeBentLf")]
    mix = with_fields.example_corrective(*ex)
    assert max(mix, key=mix.get) == "kneeBentLf" and mix["kneeBentLf"] > 0.5
    skinned, truth = _skinned(generator, b, "kneeBentLf")
    mesh = with_fields.prepare(skinned, tiny_corpus.faces)
    delta = with_fields.example_delta(*ex)
    out = with_fields.predict_detail(mesh, None, kind=KIND, delta=delta, corrective_mix=mix)
    assert out.predictor == "correctives" and out.label == "example" and "kneeBentLf" in out.note
    assert mesh_errors(out.vertices, truth, skinned)["explained"] > 0.2
    # what the example reads as is what moves B: the elbow's corrective read instead moves the elbow
    elbow = with_fields.predict(mesh, None, kind=KIND, delta=delta, corrective_mix={"elbowBentLf": 1.0})
    assert np.abs(elbow - out.vertices).max() > 1e-3
    np.testing.assert_allclose(elbow, with_fields.predict(mesh, "elbowBentLf", "mean", kind=KIND), atol=1e-6)
    # unread (another topology's example): no motion, said so -- never the latent network's reading
    none = with_fields.predict_detail(mesh, None, kind=KIND, delta=delta)
    assert np.array_equal(none.vertices, mesh.vertices) and "example" in none.note


def test_lrr_transfer_carries_an_example_pairs_corrective(with_fields, fields, generator, tmp_path, capsys):
    import shutil

    import trimesh

    from latent_model import meshio
    from latent_model.checkpoint import save_checkpoint
    from latent_model.cli import main
    from latent_model.config import preset

    ck, bank = tmp_path / "model.safetensors", tmp_path / "bank.safetensors"
    save_checkpoint(ck, with_fields.model, preset("tiny"), "all", 0)
    with_fields.bank.save(bank)
    shutil.copy(fields[0], tmp_path / "correctives.safetensors")  # beside the checkpoint: loaded with it
    a, b = _held_out()[:2]
    faces = np.asarray(generator.faces)
    for name, x in zip(("A.obj", "A1.obj"), _skinned(generator, a, "kneeBentLf")):
        trimesh.Trimesh(x, faces, process=False).export(tmp_path / name)
    skinned, _ = _skinned(generator, b, "kneeBentLf")
    trimesh.Trimesh(skinned, faces, process=False).export(tmp_path / "B.obj")
    argv = ["transfer", "--example-neutral", tmp_path / "A.obj", "--example-posed", tmp_path / "A1.obj", "--mesh",
            tmp_path / "B.obj", "--kind", KIND, "--checkpoint", ck, "--bank", bank, "-o", tmp_path / "B1.obj"]
    assert main([str(x) for x in argv]) == 0
    printed = capsys.readouterr().out
    assert "the example's corrective reads as kneeBentLf" in printed and "corrective fields" in printed
    got, _, _ = meshio.read_file(tmp_path / "B1.obj")
    assert np.linalg.norm(got - skinned, axis=1).max() > 1e-3


def test_another_topology_reads_the_correctives_through_a_registered_template(with_fields, generator, monkeypatch):
    """A held-out character decimated to half its triangles (another topology, no vertex index to read): anny's
    template fitted and registered onto it carries the elbow's corrective to it, better than no motion against the
    truth carried to the decimated vertices, and the note says how it was read. Meshes with anny's topology are
    read by index, whatever the split of its quads."""
    import igl

    import latent_model.transfer as transfer_module
    from latent_model.analysis.metrics import mesh_errors
    from latent_model.corrective_fields import faces_digest
    from latent_model.registration import _closest

    faces = np.asarray(generator.faces)
    skinned, truth = _skinned(generator, _held_out()[0])
    v, f = [np.asarray(x) for x in igl.decimate(skinned, faces, len(faces) // 2) if np.ndim(x) == 2][:2]
    v, f = v.astype(np.float64), f.astype(np.int64)
    face, bary, _ = _closest(v, skinned, faces)
    carried = v + np.einsum("nk,nkj->nj", bary, (truth - skinned)[faces[face]])
    mesh = with_fields.prepare(v, f)
    # a window says it waits for the registration: once per mesh and pose, for the correctives only
    assert with_fields.registrations_to_fit(mesh, KIND, ["elbowBentLf", None, "elbowBentLf"]) == ["elbowBentLf"]
    assert with_fields.registrations_to_fit(mesh, "neutral_to_pose", ["elbowBentLf"]) == []
    out = with_fields.predict_detail(mesh, "elbowBentLf", "mean", kind=KIND)
    assert with_fields.registrations_to_fit(mesh, KIND, ["elbowBentLf"]) == []
    own = with_fields.predict_detail(with_fields.prepare(skinned, faces), "elbowBentLf", "mean", kind=KIND)
    assert with_fields.registrations_to_fit(with_fields.prepare(skinned, faces), KIND, ["elbowBentLf"]) == []
    explained = mesh_errors(out.vertices, carried, v)["explained"]
    by_index = mesh_errors(own.vertices, truth, skinned)["explained"]  # 0.27 (tiny fields); decimated 0.23
    assert explained > max(0.1, 0.5 * by_index) and out.gate == 1.0
    assert "registered onto this mesh" in out.note and own.note is None
    # a template the registration had to carry far from where the fit stood it is not read: no motion, said so
    monkeypatch.setattr(transfer_module, "SETTLE_LIMIT", -1.0)
    out = with_fields.predict_detail(mesh, "elbowBentLf", "mean", kind=KIND)
    assert np.array_equal(out.vertices, mesh.vertices) and out.gate == 0.0 and "had to move" in out.note
    # the same vertex count with other triangles is another topology too (below)
    # but anny's quads split along their other diagonals (another machine's anny, a DCC export), reordered, are anny's
    a, b = np.asarray(generator.faces)[0::2], np.asarray(generator.faces)[1::2]
    shared = [[v for v in x if v in y] for x, y in zip(a, b)]
    own_a = [[v for v in x if v not in y][0] for x, y in zip(a, b)]
    own_b = [[v for v in y if v not in x][0] for x, y in zip(a, b)]
    flipped = np.array([t for s, p, q in zip(shared, own_a, own_b) for t in ([p, s[0], q], [q, s[1], p])])
    flipped = np.concatenate([flipped[2:], flipped[:2]])
    assert faces_digest(flipped) == faces_digest(generator.faces) != faces_digest((faces + 1) % len(skinned))
    out = with_fields.predict_detail(with_fields.prepare(skinned, flipped), "elbowBentLf", "mean", kind=KIND)
    assert out.note is None and np.abs(out.vertices - skinned).max() > 1e-3


def test_the_evaluation_measures_every_pose_and_rest(with_fields):
    from latent_model.analysis.corrective_eval import evaluate_correctives, markdown

    specs = [s for s in _held_out() if s.id in ("id002", "id002@tpose")]
    m = evaluate_correctives(with_fields, specs, say=lambda _m: None)
    two = evaluate_correctives(with_fields, specs, say=lambda _m: None, workers=2)  # one character per process
    assert list(two) == list(m) and all(two[k] == pytest.approx(v, rel=1e-6, abs=1e-9) for k, v in m.items())
    assert m["correctives.elbowBentLf.no_motion.bind.explained"] == 0.0
    assert m["correctives.elbowBentLf.mean.bind.explained"] > 0.2
    assert {"correctives.targets.mean.tpose.explained", "correctives.targets.nearest.bind.explained"} <= set(m)
    # each character also reads the other's corrective as an example pair (its own rest: the T-pose's for bind)
    assert m["correctives.elbowBentLf.example.bind.explained"] > 0.1  # better than no motion (tiny fields: 4 samples)
    text = markdown(m)
    assert "kneeBentLf" in text and "tpose" in text and "example bind" in text
