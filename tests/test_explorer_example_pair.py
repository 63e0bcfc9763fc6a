"""The explorer's "Condition on an example pair…" without a display, end to end on the tiny model: the
session reads and encodes A and A1 once, the example's delta conditions the target (magnitude still
scales it, pose A is not read), clearing it returns to the pose, bad pairs fail with the clear message
on the window's error path, and the out-of-distribution warning reaches the view state."""
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from explorer.results import ExampleOpened, ExamplePair, Failed, MeshOpened, PairRef, Prediction, ViewState
from explorer.selection import Selection, SessionError, read_session, save_session
from explorer.session import Session
from explorer.workers import describe_error
from latent_model import meshio
from latent_model.meshio import MeshError, from_identity
from latent_model.transfer import Novelty
from latent_model.types import FINAL


@pytest.fixture(scope="module")
def files(tiny_corpus, tmp_path_factory):
    """A/A1 (elbow) and A/A1 (knee) of one held-out identity, exported as a DCC would (Y up, centimetres);
    the target B, another held-out identity, in metres Z up; an A1 of another topology."""
    c = tiny_corpus
    a, b = c.split_indices("test", rest="bind")[1], c.split_indices("test", rest="bind")[0]
    d = tmp_path_factory.mktemp("example_pair")

    def to_cm(x):
        return (x.astype(np.float64) @ meshio._R_Y_UP) * 100.0

    def write(name, v, faces=c.faces, cm=True):
        trimesh.Trimesh(to_cm(v) if cm else v, faces, process=False).export(d / name)
        return str(d / name)

    neutral = c.vertices(c.state(a, None, "neutral"))
    out = {"A": write("A.obj", neutral),
           "A1": write("A1.obj", c.vertices(c.state(a, "elbowBentLf", FINAL))),
           "A1knee": write("A1knee.obj", c.vertices(c.state(a, "kneeBentLf", FINAL))),
           "B": write("B.ply", c.vertices(c.state(b, None, "neutral")), cm=False)}
    sub = trimesh.Trimesh(to_cm(neutral), c.faces, process=False).subdivide()
    out["bad"] = write("other_topology.obj", sub.vertices, sub.faces, cm=False)
    return out


def _recorder(s: Session) -> list:
    seen = []
    for name in ("selection", "example_opened", "failed"):
        getattr(s.events, name).connect(lambda v, n=name: seen.append((n, v)))
    return seen


@pytest.fixture()
def session(tiny_motion, files):
    """A session on the tiny transfer whose target is B (an opened mesh), selected as the window would."""
    s = Session(tiny_motion[0])
    name = s.open_mesh(files["B"])
    s.apply(MeshOpened(name, files["B"], "B"))
    return s


def test_example_pair_conditions_the_target(session, files, monkeypatch):
    s = session
    seen = _recorder(s)
    by_pose = s.compute(s.selection)
    assert by_pose.prediction.label == "mean" and by_pose.example is None
    encoded = []
    real_prepare = s.transfer.prepare
    monkeypatch.setattr(s.transfer, "prepare", lambda *a, **k: encoded.append(len(a[0])) or real_prepare(*a, **k))
    opened = s.open_example(files["A"], files["A1"])
    pair = opened.pair
    assert pair.name == "A.obj → A1.obj" and pair.label == "example: A.obj → A1.obj" and len(encoded) == 2
    assert pair.delta.shape == (s.transfer.bank.mu.shape[1],)
    assert np.abs(pair.posed.vertices - pair.neutral.vertices).max() > 0.01  # A1 read in A's frame: the arm moved
    s.apply(opened)
    sel = s.selection
    assert [n for n, _ in seen] == ["example_opened", "selection"] and sel.example == pair.name
    assert sel.kind == "neutral_to_pose" and sel.target == by_pose.target

    st = s.compute(sel)
    p = st.prediction
    assert st.example is pair and p.is_example and p.label == pair.name and st.truth is None
    assert p.title.startswith("example: A.obj → A1.obj") and "displacement" in p.title
    assert st.conditioning is None  # no identity to highlight in the heatmaps
    assert np.abs(p.vertices - st.source).max() > 1e-3, "the example did not move the target"
    assert np.array_equal(st.source, by_pose.source)
    # the pose list is not read for pose A while the example conditions; the magnitude still scales it
    other_pose = s.compute(replace(sel, pose="kneeBentLf"))
    assert np.array_equal(other_pose.prediction.vertices, p.vertices)
    assert np.array_equal(s.compute(replace(sel, magnitude=0.0)).prediction.vertices, st.source)
    half = s.compute(replace(sel, magnitude=0.5)).prediction.vertices
    assert 0 < np.abs(half - st.source).max() < np.abs(p.vertices - st.source).max()
    # comparing mean vs nearest is about pose strategies: one prediction under an example
    assert len(s.compute(replace(sel, compare=True)).predictions) == 1

    # another example, another prediction (the delta decides, not a pose name)
    knee = s.open_example(files["A"], files["A1knee"])
    s.apply(knee)
    st_knee = s.compute(s.selection)
    assert s.selection.example == "A.obj → A1knee.obj"
    assert np.abs(st_knee.prediction.vertices - p.vertices).max() > 1e-3

    # the same files again: the held pair, not encoded again
    encoded.clear()
    again = s.open_example(files["A"], files["A1"])
    assert again.pair is pair and encoded == []

    # clearing returns to the pose conditioning, exactly
    s.condition(None)
    assert s.selection.example is None
    back = s.compute(s.selection)
    assert back.example is None and back.prediction.label == "mean"
    assert np.array_equal(back.prediction.vertices, by_pose.prediction.vertices)


def test_a_bad_example_pair_gives_the_clear_error(session, files):
    s = session
    with pytest.raises(MeshError, match="must be A.obj deformed") as e:
        s.open_example(files["A"], files["bad"])
    with pytest.raises(MeshError, match="no such file"):
        s.open_example(files["A"], files["A"] + ".missing.obj")
    assert s.examples.names() == []
    # the window's path: the worker turns the exception into a Failed, the session announces it
    seen = _recorder(s)
    before = s.selection
    s.apply(Failed(ExampleOpened, describe_error(e.value), subject="x"))
    assert seen == [("failed", Failed(ExampleOpened, str(e.value), subject="x"))]
    assert "Export both from the same mesh" in seen[0][1].message and s.selection == before
    with pytest.raises(SessionError, match="unknown example pair"):
        s.compute(replace(s.selection, example="A.obj → A1.obj"))


def test_a_saved_session_reopens_its_example_pair(session, files, tmp_path):
    s = session
    opened = s.open_example(files["A"], files["A1"])
    s.apply(opened)
    name = opened.pair.name
    path = save_session(tmp_path / "s.json", s.selection, s.mesh_paths, {name: s.example_paths[name]})
    sel, meshes, examples = read_session(path)
    assert sel.example == name and examples == {name: (files["A"], files["A1"])}

    fresh = Session(s.transfer)
    to_open = fresh.restore(sel, meshes, examples)
    assert set(to_open.meshes) == set(meshes) and to_open.examples == examples and fresh.selection is None
    for n, p in to_open.meshes.items():
        fresh.open_mesh(p)
        fresh.apply(MeshOpened(n, p, n))
    assert fresh.selection is None  # still waiting for the example pair
    fresh.apply(fresh.open_example(*examples[name]))
    assert fresh.pending_selection is None and fresh.selection.example == name
    assert fresh.compute(fresh.selection).prediction.is_example
    # its pair failing to open: the restored selection is selected, conditioned on its pose
    other = Session(s.transfer)
    other.add_mesh(from_identity(s.meshes[sel.target].vertices, s.meshes[sel.target].faces, sel.target))
    other.restore(sel, {}, examples)
    other.apply(Failed(ExampleOpened, "broken", subject="\n".join(examples[name])))
    assert other.selection.example is None and other.selection.target == sel.target


def test_out_of_distribution_warning_reaches_the_view_state(session, files, tiny_corpus):
    from latent_model.bank import calibrate_ood_threshold

    s = session
    bank = s.transfer.bank
    kept = bank.ood_threshold
    try:
        bank.ood_threshold = calibrate_ood_threshold(s.transfer.model, tiny_corpus, bank)
        assert bank.ood_threshold > 0
        s.apply(s.open_example(files["A"], files["A1"]))
        held = s.compute(s.selection)
        assert held.warnings == [] and "out of distribution" not in held.prediction.title
        b = s.meshes[s.selection.target]
        centre = b.vertices.mean(axis=0)
        big = s.add_mesh(from_identity((b.vertices - centre) * 2.0 + centre, b.faces, "big.obj"))
        st = s.compute(replace(s.selection, target=big))
        assert st.prediction.novelty.out_of_distribution
        assert len(st.warnings) == 1 and st.warnings[0].startswith("warning: big.obj is out of distribution")
        assert "out of distribution" in st.prediction.title
    finally:
        bank.ood_threshold = kept


def test_an_out_of_distribution_example_is_warned_about_too():
    v = np.zeros((4, 3), np.float32)
    a = from_identity(np.eye(4, 3, dtype=np.float32), np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]), "A.obj")
    pair = ExamplePair("A.obj → A1.obj", a, a, np.zeros(3, np.float32), ("A.obj", "A1.obj"), (), Novelty(9.0, 4.0))
    pred = Prediction("example", pair.name, v, None, np.zeros(4), novelty=Novelty(1.0, 4.0))
    st = ViewState(Selection(target="B"), PairRef("B", "neutral_to_pose", "elbowBentLf", None, None, None),
                   a.faces, v, None, "", [pred], example=pair)
    assert st.warnings == [pair.warning()] and "the example's neutral A.obj is out of distribution" in st.warnings[0]
