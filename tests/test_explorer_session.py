"""The explorer's session model without a display: predictions, sliders, strategies, compare,
heatmaps, noise floor, opened meshes, session JSON and the coalescing of updates."""
import json
import threading
import time

import numpy as np
import pytest

from explorer.session import (Coalescer, Selection, Session, SessionError, read_session, save_session)
from latent_model.shipped import ShippedPaths

needs_model = pytest.mark.skipif(not ShippedPaths.at().checkpoint.exists() or not ShippedPaths.at().bank.exists(),
                                 reason=f"the shipped model is missing ({ShippedPaths.at().checkpoint.parent}); "
                                        f"restore assets/model or set LRR_ASSETS")


def test_coalescer_runs_latest_only():
    c = Coalescer()
    assert c.submit(1) is True  # idle: start now
    assert c.submit(2) is False and c.submit(3) is False and c.submit(4) is False  # busy: only the latest waits
    assert c.dropped == 2
    assert c.done() == 4  # the newest request runs next, 2 and 3 never do
    assert c.done() is None and not c.busy
    assert c.submit(5) is True


def test_coalescer_under_a_fast_producer():
    c, ran = Coalescer(), []

    def work(x):
        while x is not None:
            time.sleep(0.01)
            ran.append(x)
            x = c.done()

    threads = []
    for i in range(200):
        if c.submit(i):
            t = threading.Thread(target=work, args=(i,))
            t.start()
            threads.append(t)
        time.sleep(0.0005)
    for t in threads:
        t.join()
    assert ran[-1] == 199 and len(ran) < 100 and ran == sorted(ran)  # never queued up, ends on the last


def test_selection_json_round_trip(tmp_path):
    sel = Selection(target="id014", pose="kneeBentLf", pose_b="elbowBentLf", blend=0.25, magnitude=1.5,
                    strategy="identity:id003", colour="displacement", compare=True)
    p = save_session(tmp_path / "s.json", sel, {"mine.obj": "/x/mine.obj"})
    back, meshes = read_session(p)
    assert back == sel and meshes == {"mine.obj": "/x/mine.obj"}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": 1, "selection": {"magnitude": 7}}))
    with pytest.raises(SessionError, match="magnitude"):
        read_session(bad)
    bad.write_text("{not json")
    with pytest.raises(SessionError, match="not a readable"):
        read_session(bad)
    with pytest.raises(SessionError, match="no such"):
        read_session(tmp_path / "none.json")


@pytest.fixture(scope="module")
def session():
    import torch

    torch.set_num_threads(1)
    if not ShippedPaths.at().checkpoint.exists():
        pytest.skip("the shipped model is missing")
    return Session.load_shipped()


@needs_model
def test_prediction_sliders_strategies_compare(session):
    t = session.test_ids[0]
    sel = Selection(target=t, pose="elbowBentLf", strategy="nearest_identity_delta")
    a = session.compute(sel)
    assert a.truth is not None and a.prediction.error_mm is not None
    n = len(a.source)
    assert a.prediction.vertices.shape == (n, 3) and a.prediction.error_mm.shape == (n,)
    assert np.allclose(a.prediction.error_mm, np.linalg.norm(a.prediction.vertices - a.truth, axis=1) * 1000)
    assert a.conditioning in session.training_ids and "error mean" in a.prediction.title
    moved = session.compute(Selection(target=t, pose="elbowBentLf", strategy="nearest_identity_delta", magnitude=1.8))
    assert not np.allclose(moved.prediction.vertices, a.prediction.vertices)
    blended = session.compute(Selection(target=t, pose="elbowBentLf", pose_b="kneeBentLf", blend=0.6,
                                        strategy="nearest_identity_delta"))
    assert not np.allclose(blended.prediction.vertices, a.prediction.vertices)
    assert "blended" in blended.truth_title
    other = [i for i in session.training_ids if i != a.conditioning][0]
    chosen = session.compute(Selection(target=t, pose="elbowBentLf", strategy=f"identity:{other}"))
    assert chosen.conditioning == other and not np.allclose(chosen.prediction.vertices, a.prediction.vertices)
    cmp = session.compute(Selection(target=t, pose="elbowBentLf", compare=True))
    assert [p.strategy for p in cmp.predictions] == ["mean_pose_delta", "nearest_identity_delta"]
    assert all(p.error_mm is not None for p in cmp.predictions)
    with pytest.raises(SessionError, match="unknown pose"):
        session.compute(Selection(target=t, pose="elbowBent"))
    with pytest.raises(SessionError, match="not a training identity"):
        session.compute(Selection(target=t, strategy=f"identity:{t}"))


@needs_model
def test_heatmaps_and_noise_floor(session):
    t = session.test_ids[0]
    sel = Selection(target=t, pose="kneeBentLf")
    h = session.heatmaps(sel, conditioning=session.training_ids[2])
    n = len(session.training_ids) + 1
    assert h.identity_distance.shape == (n, n) and h.ids[-1] == t
    assert np.allclose(np.diag(h.identity_distance), 0) and (h.identity_distance[~np.eye(n, dtype=bool)] > 0).all()
    assert h.pose_cosine.shape == (len(h.cosine_ids),) * 2 and np.allclose(np.diag(h.pose_cosine), 1, atol=1e-5)
    nf = session.noise_floor(t, ("elbowBentLf", "kneeBentLf"))
    assert nf.poses == ["elbowBentLf", "kneeBentLf"] and all(d > 0 for d in nf.d_noise + nf.d_condition)


@needs_model
def test_opened_mesh_has_no_truth_and_exports_in_its_frame(session, tmp_path):
    import trimesh

    from latent_model import meshio

    t = session.test_ids[0]
    v = session.truth.state(t, None, "neutral").astype(np.float64)
    user = (v @ meshio._R_Y_UP) * 100.0
    f = tmp_path / "mine.ply"
    trimesh.Trimesh(user, session.truth.faces, process=False).export(f)
    name = session.open_mesh(f)
    assert name in session.targets and not session.has_truth(name)
    st = session.compute(Selection(target=name, pose="elbowBentLf"))
    assert st.truth is None and st.prediction.error_mm is None and "displacement" in st.prediction.title
    out = session.export(st, tmp_path / "out.glb")
    back, _, _ = meshio.read_file(out)
    assert back.shape == user.shape and np.abs(back - user).max() < 60  # centimetres, Y up
    with pytest.raises(SessionError, match="neutral_to_pose"):
        session.compute(Selection(target=name, kind="skinning_to_skinning_plus_blendshape", pose="elbowBentLf"))
    with pytest.raises(ValueError, match="no such file"):
        session.open_mesh(tmp_path / "nope.obj")


@needs_model
def test_shipped_model_was_trained_on_the_current_rig():
    """The window regenerates ground truth through today's rig code; the shipped checkpoint
    records the digest of the corpus it was trained on. A rig fix (a new generator version)
    without a retrained model would show the model against a truth it never saw."""
    from latent_model.config import corpus_preset
    from latent_model.train.checkpoint import read_metadata

    meta = read_metadata(ShippedPaths.at().checkpoint)
    specs = json.loads(ShippedPaths.at().identities.read_text())
    assert json.loads(meta["extra"])["corpus_digest"] == corpus_preset(specs["preset"]).digest()
