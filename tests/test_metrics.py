"""Metric primitives on hand-made cases with known answers."""
import numpy as np

from latent_model.analysis.metrics import (cosine_stats, describe, ks, mesh_errors, normal_consistency,
                                           pairwise_distances)


def test_identical_deltas_have_cosine_one_and_opposite_minus_one():
    d = np.tile(np.array([[1.0, 2.0, -3.0]]), (5, 1)) * np.arange(1, 6)[:, None]  # same direction, other norms
    s = cosine_stats(d)
    assert abs(s["cos_mean"] - 1.0) < 1e-9 and s["cos_std"] < 1e-9
    assert abs(s["norm_mean"] - np.linalg.norm([1, 2, -3]) * 3.0) < 1e-9
    assert abs(cosine_stats(np.array([[1.0, 0.0], [-1.0, 0.0]]))["cos_mean"] + 1.0) < 1e-9


def test_known_rigid_offset_gives_known_errors():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(100, 3))
    truth = src.copy()
    truth[:50] += np.array([0.003, 0.0, 0.004])  # half the vertices move 5 mm
    pred = truth + np.array([0.0, 0.002, 0.0])  # every vertex off by 2 mm
    m = mesh_errors(pred, truth, src)
    assert abs(m["err_mm"] - 2.0) < 1e-9 and abs(m["err_moving_mm"] - 2.0) < 1e-9
    assert abs(m["leak_mm"] - 2.0) < 1e-9  # static half moved by 2 mm
    assert abs(m["explained"] - (1 - 2.0 / 2.5)) < 1e-9  # no-motion error = 2.5 mm mean
    assert mesh_errors(src, truth, src)["explained"] == 0.0
    assert mesh_errors(truth, truth, src)["explained"] == 1.0


def test_ks_on_equal_samples_is_zero_and_separated_samples_one():
    a = np.linspace(0, 1, 190)
    assert ks(a, a.copy())["D"] == 0.0
    assert ks(a, a + 10)["D"] == 1.0


def test_pairwise_distances_and_table():
    x = np.array([[0.0, 0.0], [3.0, 4.0], [0.0, 8.0]])
    d = pairwise_distances(x)
    assert sorted(d.tolist()) == [5.0, 5.0, 8.0]
    t = describe(d)
    assert t["n"] == 3 and t["min"] == 5.0 and t["max"] == 8.0 and t["median"] == 5.0
    assert len(pairwise_distances(np.zeros((20, 4)))) == 190


def test_normal_consistency():
    n = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    assert normal_consistency(n, n) == 1.0
    assert normal_consistency(n, -n) == -1.0


def test_vertex_normals_of_shared_faces_are_the_corpus_ones():
    import trimesh

    from latent_model.analysis.metrics import VertexNormals
    from latent_model.corpus.sdf import vertex_normals

    m = trimesh.creation.icosphere(subdivisions=2)
    normals = VertexNormals(m.faces)
    rng = np.random.default_rng(0)
    for v in (m.vertices, m.vertices * [1.0, 2.0, 0.5] + rng.normal(0, 0.01, m.vertices.shape)):
        got = normals(v)
        assert got.dtype == np.float32 and got.shape == v.shape
        np.testing.assert_allclose(got, vertex_normals(v, m.faces), atol=1e-6)
    # outward on a sphere; a vertex no triangle uses gets none
    assert (np.sum(normals(m.vertices) * m.vertices, axis=1) > 0.99).all()
    extra = np.vstack([m.vertices, [[0.0, 0.0, 5.0]]])
    assert np.array_equal(normals(extra)[-1], np.zeros(3, np.float32))
