"""Tests for latent_model.corpus.sdf on analytic meshes (icosphere, box)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from latent_model.corpus.sdf import (
    SdfSampling,
    body_component_faces,
    sample_sdf,
    signed_distance,
    vertex_normals,
)

R = 0.5  # sphere radius


@pytest.fixture(scope="module")
def sphere() -> tuple[np.ndarray, np.ndarray]:
    # subdivisions=5: 10242 vertices; the flat faces sit at most ~1e-4 * R inside the true sphere.
    m = trimesh.creation.icosphere(subdivisions=5, radius=R)
    return np.asarray(m.vertices), np.asarray(m.faces)


BOX_HALF = np.array([0.4, 0.25, 0.1])


@pytest.fixture(scope="module")
def box() -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.box(extents=2 * BOX_HALF)
    return np.asarray(m.vertices), np.asarray(m.faces)


def box_sdf(x: np.ndarray) -> np.ndarray:
    """Exact SDF of the origin-centred box with half-extents BOX_HALF."""
    q = np.abs(x) - BOX_HALF
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


# --- signed_distance ---------------------------------------------------------


def test_sphere_signs_and_distance(sphere):
    v, f = sphere
    rng = np.random.default_rng(0)
    x = rng.uniform(-1.5 * R, 1.5 * R, size=(4000, 3))
    r = np.linalg.norm(x, axis=1)
    s = signed_distance(x, v, f)
    assert s.dtype == np.float32 and s.shape == (4000,)

    # Away from the tessellation band the sign must be exact.
    clear = np.abs(r - R) > 2e-3 * R
    assert np.all(s[clear & (r < R)] < 0)
    assert np.all(s[clear & (r > R)] > 0)
    # Magnitude matches the analytic sphere distance up to tessellation error.
    np.testing.assert_allclose(np.abs(s), np.abs(r - R), atol=1e-3 * R)


def test_box_exact(box):
    v, f = box
    rng = np.random.default_rng(1)
    x = rng.uniform(-2 * BOX_HALF - 0.1, 2 * BOX_HALF + 0.1, size=(3000, 3))
    x = x[np.abs(box_sdf(x)) > 1e-4]  # keep the sign test away from the surface itself
    s = signed_distance(x, v, f)
    # Box faces are exact, so the SDF is exact (up to float32 output rounding).
    np.testing.assert_allclose(s, box_sdf(x), atol=1e-6)
    assert (s < 0).any() and (s > 0).any()


def test_signed_distance_empty_points(box):
    v, f = box
    s = signed_distance(np.zeros((0, 3)), v, f)
    assert s.shape == (0,) and s.dtype == np.float32


# --- body_component_faces ----------------------------------------------------


def test_body_component_picks_biggest():
    big = trimesh.creation.icosphere(subdivisions=3, radius=1.0)  # 642 vertices
    eye = trimesh.creation.icosphere(subdivisions=1, radius=0.1)  # 42 vertices
    eye.apply_translation([0.5, 0.0, 0.0])  # inside the big one, like an eyeball in a head
    # Put the small shell first so the answer is not simply "component 0".
    v = np.concatenate([eye.vertices, big.vertices])
    f = np.concatenate([eye.faces, big.faces + len(eye.vertices)])
    fb = body_component_faces(v, f)
    assert fb.dtype == np.int64
    np.testing.assert_array_equal(fb, big.faces + len(eye.vertices))

    # Why it matters: with the eyeball shell included, the distance at the eyeball centre is to
    # the eyeball (0.1); with body faces only it is to the body shell (~0.5) and inside.
    c = np.array([[0.5, 0.0, 0.0]])
    assert signed_distance(c, v, f)[0] == pytest.approx(-0.1, abs=0.01)
    assert signed_distance(c, v, fb)[0] == pytest.approx(-0.5, abs=0.01)


def test_body_component_single_shell(sphere):
    v, f = sphere
    np.testing.assert_array_equal(body_component_faces(v, f), f)


# --- vertex_normals ----------------------------------------------------------


def test_vertex_normals_sphere(sphere):
    v, f = sphere
    n = vertex_normals(v, f)
    assert n.dtype == np.float32 and n.shape == v.shape
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    radial = v / np.linalg.norm(v, axis=1, keepdims=True)
    assert np.min(np.sum(n * radial, axis=1)) > 0.99


def test_vertex_normals_area_weighted_matches_igl():
    import igl

    m = trimesh.creation.icosphere(subdivisions=2)
    v = m.vertices * np.array([1.0, 0.4, 0.7]) + np.random.default_rng(2).normal(0, 0.02, m.vertices.shape)
    f = np.asarray(m.faces, dtype=np.int64)
    ref = igl.per_vertex_normals(
        np.ascontiguousarray(v), f, igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA
    )
    np.testing.assert_allclose(vertex_normals(v, f), ref, atol=1e-6)


def test_vertex_normals_unreferenced_vertex_is_zero(box):
    v, f = box
    v2 = np.concatenate([v, [[5.0, 5.0, 5.0]]])
    n = vertex_normals(v2, f)
    np.testing.assert_array_equal(n[-1], 0.0)


# --- sample_sdf --------------------------------------------------------------


def test_counts_split_exactly():
    assert SdfSampling().counts() == (3686, 3686, 820)
    assert SdfSampling(k=16384).counts() == (7372, 7372, 1640)
    assert SdfSampling(k=100, near_fractions=(0.29, 0.71)).counts() == (29, 71, 0)
    assert SdfSampling(k=7, near_fractions=(0.5, 0.5)).counts() == (3, 3, 1)
    for k in (1, 2, 3, 999, 8193):
        assert sum(SdfSampling(k=k).counts()) == k


def test_sample_shapes_blocks_and_values(sphere):
    v, f = sphere
    cfg = SdfSampling(k=2000)
    p, s = sample_sdf(v, f, cfg, seed=3)
    assert p.shape == (2000, 3) and s.shape == (2000,)
    assert p.dtype == np.float32 and s.dtype == np.float32
    n0, n1, nu = cfg.counts()
    assert (n0, n1, nu) == (900, 900, 200)

    r = np.linalg.norm(p.astype(np.float64), axis=1)
    d0, d1 = np.abs(r[:n0] - R), np.abs(r[n0 : n0 + n1] - R)
    # Noise norm is chi(3)*sigma: P(> 6 sigma) ~ 1e-7 per point.
    assert d0.max() < 6 * cfg.near_sigmas[0]
    assert d1.max() < 6 * cfg.near_sigmas[1]
    # E|N(0, sigma^2)| = 0.8 sigma for the radial component.
    assert 0.6 * cfg.near_sigmas[0] < np.mean(d0) < 1.0 * cfg.near_sigmas[0]
    assert 0.6 * cfg.near_sigmas[1] < np.mean(d1) < 1.0 * cfg.near_sigmas[1]

    uni = p[n0 + n1 :]
    lim = R + cfg.box_padding + 1e-6
    assert np.all(np.abs(uni) <= lim)
    assert np.abs(uni).max() > R  # actually spans the padded box, not just the mesh

    # Values are the SDF of the returned float32 points.
    np.testing.assert_array_equal(s, signed_distance(p, v, f))
    np.testing.assert_allclose(np.abs(s), np.abs(r - R), atol=1e-3 * R)


def test_surface_sampling_is_area_weighted():
    # Box 4x1x1: two 1x1 end caps (area 1 each) out of a total area of 18.
    m = trimesh.creation.box(extents=(4.0, 1.0, 1.0))
    cfg = SdfSampling(k=6000, near_sigmas=(1e-9, 1e-9), near_fractions=(0.5, 0.5))
    p, s = sample_sdf(m.vertices, m.faces, cfg, seed=4)
    assert np.abs(s).max() < 1e-5
    on_caps = np.mean(np.abs(np.abs(p[:, 0]) - 2.0) < 1e-5)
    assert abs(on_caps - 2.0 / 18.0) < 0.025


def test_seed_determinism(box):
    v, f = box
    cfg = SdfSampling(k=1024)
    p1, s1 = sample_sdf(v, f, cfg, seed=7)
    p2, s2 = sample_sdf(v, f, cfg, seed=7)
    assert np.array_equal(p1, p2) and np.array_equal(s1, s2)
    p3, s3 = sample_sdf(v, f, cfg, seed=8)
    assert not np.allclose(p1, p3)
    assert not np.allclose(s1, s3)


# --- validation --------------------------------------------------------------


def _good():
    m = trimesh.creation.box()
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces)


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda v, f: (v[:0], f), "vertices is empty"),
        (lambda v, f: (v, f[:0]), "faces is empty"),
        (lambda v, f: (v[:, :2], f), r"vertices must have shape"),
        (lambda v, f: (v, f[:, :2]), r"faces must have shape"),
        (lambda v, f: (np.where(np.arange(len(v))[:, None] == 0, np.nan, v), f), "NaN or inf"),
        (lambda v, f: (np.where(np.arange(len(v))[:, None] == 1, np.inf, v), f), "NaN or inf"),
        (lambda v, f: (v, np.where(f == 0, len(v), f)), "out of range"),
        (lambda v, f: (v, np.where(f == 0, -1, f)), "out of range"),
        (lambda v, f: (v, f.astype(np.float64)), "integer dtype"),
    ],
)
def test_bad_mesh_raises(mutate, match):
    v, f = mutate(*_good())
    with pytest.raises(ValueError, match=match):
        signed_distance(np.zeros((1, 3)), v, f)
    with pytest.raises(ValueError, match=match):
        sample_sdf(v, f, SdfSampling(k=16), seed=0)
    with pytest.raises(ValueError, match=match):
        body_component_faces(v, f)
    with pytest.raises(ValueError, match=match):
        vertex_normals(v, f)


def test_bad_points_raise():
    v, f = _good()
    with pytest.raises(ValueError, match="NaN or inf"):
        signed_distance(np.array([[0.0, np.nan, 0.0]]), v, f)
    with pytest.raises(ValueError, match="points must have shape"):
        signed_distance(np.zeros(3), v, f)


def test_degenerate_mesh_raises():
    v = np.zeros((3, 3))
    f = np.array([[0, 1, 2]])
    with pytest.raises(ValueError, match="zero total surface area"):
        sample_sdf(v, f, SdfSampling(k=16), seed=0)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(k=0),
        dict(k=2.5),
        dict(near_sigmas=(0.0, 0.01)),
        dict(near_sigmas=(0.01, float("nan"))),
        dict(near_fractions=(0.6, 0.6)),
        dict(near_fractions=(-0.1, 0.5)),
        dict(near_fractions=(0.5,)),
        dict(box_padding=-0.1),
    ],
)
def test_bad_config_raises(kwargs):
    with pytest.raises(ValueError):
        SdfSampling(**kwargs)


def test_mesh_edges_are_each_undirected_edge_once(sphere):
    from latent_model.topology import mesh_edges

    f = np.asarray(sphere[1], dtype=np.int64)
    rows = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    assert np.array_equal(mesh_edges(f), rows)
    assert len(mesh_edges(f)) == 3 * len(f) // 2  # a closed surface: each edge shared by two triangles
    assert mesh_edges(np.array([[2, 1, 0], [0, 1, 3]])).tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3]]
