"""User meshes: formats, frame/unit detection, round trip back into the user's frame, bad input."""
import numpy as np
import pytest
import trimesh

from latent_model import meshio
from latent_model.meshio import MeshError


def _human(n_rings: int = 24, n_seg: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A closed capsule-like 'human' placed like the model's characters: 1.75 m tall, its surface's centroid at
    y = -0.047, feet at z = -0.261 * 1.75 - 0.371 (meshio's placement, fitted on the corpus)."""
    m = trimesh.creation.capsule(height=1.45, radius=0.15, count=[n_seg, n_rings])
    v = np.asarray(m.vertices) * np.array([1.4, 0.9, 1.0])
    v[:, 2] += -0.261 * np.ptp(v[:, 2]) - 0.371 - v[:, 2].min()
    v[:, 1] += -0.047
    return v, np.asarray(m.faces)


def _maya(v):
    """model frame (m, Z up) -> Maya-like Y-up centimetres, shifted."""
    return (v @ meshio._R_Y_UP) * 100.0 + np.array([12.0, 3.0, -7.0])


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "glb", "off"])
def test_formats_detect_maya_frame_and_round_trip(tmp_path, ext):
    v, f = _human()
    user = _maya(v)
    src = tmp_path / f"in.{ext}"
    trimesh.Trimesh(user, f, process=False).export(src)
    m = meshio.load_mesh(src)
    assert (m.frame.up, m.frame.units) == ("y", "cm")
    assert abs(np.ptp(m.vertices[:, 2]) - np.ptp(v[:, 2])) < 1e-4  # metres, Z up
    assert np.allclose(m.vertices.mean(0), v.mean(0), atol=0.03)  # placed like the model's characters
    assert np.ptp(m.vertices[:, 0]) > np.ptp(m.vertices[:, 1])  # wide along X, not Y: not rotated wrongly
    # a prediction moved by +1 cm along model Z (up) comes back 1 cm along the file's Y, same order and faces
    out = tmp_path / f"out.{ext}"
    meshio.export_mesh(m, m.vertices + np.array([0, 0, 0.01], np.float32), out)
    a, af, _ = meshio.read_file(src)
    b, bf, _ = meshio.read_file(out)
    assert b.shape == a.shape and np.array_equal(af, bf)
    assert np.allclose(b - a, [0, 1.0, 0], atol=1e-3)


def test_obj_rewrite_keeps_other_lines_and_polygons(tmp_path):
    v, _ = _human()
    user = _maya(v)  # a full-height body (the faces below use its first 8 vertices)
    text = ["# exported by a DCC", "mtllib body.mtl", "o body"] + [f"v {x} {y} {z}" for x, y, z in user]
    text += ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1", "vn 0 0 1", "usemtl skin", "g torso",
             "f 1/1/1 2/2/1 3/3/1 4/4/1", "f 5//1 6//1 7//1", "f 5 7 8"]
    src = tmp_path / "poly.obj"
    src.write_text("\n".join(text) + "\n")
    m = meshio.load_mesh(src, up="y", units="cm", placement="keep")
    assert len(m.file_faces) == 4  # the quad is fanned into two triangles for the model
    out = tmp_path / "poly_out.obj"
    meshio.export_mesh(m, m.vertices, out)
    lines = out.read_text().splitlines()
    assert "mtllib body.mtl" in lines and "usemtl skin" in lines and "g torso" in lines
    assert "f 1/1 2/2 3/3 4/4" in lines and "f 5 6 7" in lines  # quad kept; stale normals dropped
    assert not any(x.startswith("vn ") for x in lines)
    back = np.array([x.split()[1:4] for x in lines if x.startswith("v ")], float)
    assert np.allclose(back, user, atol=1e-4)


def test_a_posed_character_in_the_model_frame_is_kept_where_it_is(generator, people):
    """A bent hip moves the bounding box by up to 30 cm: a posed corpus character (a skinned pose, a corrective's or
    a combo's source) must not be re-centred, or the model reads it displaced (a test character's skinned knee,
    re-centred by 14 cm, lay 18.6 from the training states instead of 4.2)."""
    f = np.asarray(generator.faces)
    for pose in ("kneeBentLf", "hipFlexLf", "shoulderRaiseLf", "hipFlexLf+kneeBentLf"):
        v = generator.pose(people[0], pose).skinning.astype(np.float64)
        m = meshio.from_arrays(v, f)
        assert np.allclose(m.vertices, v, atol=1e-6), pose
        # the same pose exported by a DCC (Y up, centimetres, elsewhere) is still re-centred
        assert not np.allclose(meshio.from_arrays(_maya(v), f).frame.offset, 0.0)


def test_detection_z_up_millimetres_and_overrides(tmp_path):
    v, f = _human()
    m = meshio.from_arrays(v * 1000.0, f)
    assert (m.frame.up, m.frame.units) == ("z", "mm")
    m2 = meshio.from_arrays(v, f)  # already in the model frame: kept exactly where it is
    assert (m2.frame.up, m2.frame.units) == ("z", "m") and np.allclose(m2.vertices, v, atol=1e-6)
    forced = meshio.from_arrays(v * 100.0, f, up="z", units="cm")
    assert forced.frame.units == "cm"
    with pytest.raises(MeshError, match="absurd scale"):
        meshio.from_arrays(v * 100.0, f, units="m")  # 175 m tall


@pytest.mark.parametrize("up, facing, turn", [("z", "+x", 90), ("z", "+y", 180), ("z", "-x", 270),
                                              ("y", "+x", 90), ("y", "-z", 180)])
def test_a_character_facing_another_axis_is_turned_to_face_front_and_written_back(tmp_path, up, facing, turn):
    """--facing AXIS (an Unreal export faces +X): the model reads the character as its own characters stand,
    facing -Y, and the result goes back in the file's frame; the facing must be horizontal."""
    v, f = _human()
    v = v + np.array([0.05, 0.0, 0.0]) * (v[:, 2:] > 0.5)  # not symmetric about the vertical: a turn shows
    a = np.radians(turn)
    turned = v @ np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]).T
    user = (turned @ meshio._R_Y_UP) * 100.0 if up == "y" else turned  # Y-up centimetres, or Z-up metres
    m = meshio.from_arrays(user, f, facing=facing)
    assert m.frame.facing == facing and f"facing {facing.upper()}" in m.summary()
    centred = lambda x: x - x.mean(axis=0)  # noqa: E731 - a Y-up file is placed anew
    assert np.allclose(centred(m.vertices), centred(v), atol=2e-4)  # read as standing like the model's characters
    assert np.allclose(m.frame.to_user(m.vertices), user, atol=2e-4 * (100 if up == "y" else 1))
    as_convention = meshio.from_arrays(user, f)  # read by its up axis's convention: turned
    assert as_convention.frame.facing == "" and not np.allclose(centred(as_convention.vertices), centred(v), atol=0.01)
    with pytest.raises(MeshError, match="horizontal axis"):
        meshio.from_arrays(user, f, facing=f"+{up}")


def test_several_components_weld_and_sdf_shells():
    v, f = _human()
    eye = trimesh.creation.icosphere(1, radius=0.012)
    ev = np.asarray(eye.vertices) + [0.03, -0.2, 0.7]
    head = trimesh.creation.icosphere(2, radius=0.12)
    hv = np.asarray(head.vertices) + [0.0, -0.13, 0.75]
    allv = np.concatenate([v, ev, hv])
    allf = np.concatenate([f, np.asarray(eye.faces) + len(v), np.asarray(head.faces) + len(v) + len(ev)])
    soup = allv[allf.ravel()]  # STL-like triangle soup: every vertex repeated per face
    m = meshio.from_arrays(soup, np.arange(len(soup)).reshape(-1, 3))
    assert len(m.vertices) == len(allv) and m.n_file_vertices == len(soup)
    kept = len(m.sdf_faces)
    assert kept == len(f) + len(head.faces)  # the tiny eye shell is dropped, the big shells kept


@pytest.mark.parametrize("content,match", [
    (None, "no such file"),
    (b"", "empty"),
    (b"this is not a mesh at all\x00\x01", "cannot read|no faces|empty"),
])
def test_bad_files(tmp_path, content, match):
    p = tmp_path / "bad.ply"
    if content is not None:
        p.write_bytes(content)
    with pytest.raises(MeshError, match=match):
        meshio.load_mesh(p)


def test_bad_geometry(tmp_path):
    v, f = _human()
    bad = v.copy()
    bad[5, 0] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        meshio.from_arrays(bad, f)
    bad[5, 0] = np.inf
    with pytest.raises(MeshError, match="NaN or infinite"):
        meshio.from_arrays(bad, f)
    pc = tmp_path / "cloud.ply"
    trimesh.PointCloud(v).export(pc)
    with pytest.raises(MeshError, match="point cloud"):
        meshio.load_mesh(pc)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(MeshError, match="empty"):
        meshio.load_mesh(empty)
    with pytest.raises(MeshError, match="unsupported format"):
        meshio.load_mesh(tmp_path / "x.fbx") if (tmp_path / "x.fbx").write_text("x") else None
    assert issubclass(MeshError, ValueError)


def test_export_is_atomic(tmp_path, monkeypatch):
    v, f = _human()
    m = meshio.from_arrays(v, f)
    out = tmp_path / "out.ply"
    out.write_bytes(b"previous content")
    with pytest.raises(MeshError, match="NaN"):
        meshio.export_mesh(m, np.full_like(m.vertices, np.nan), out)
    assert out.read_bytes() == b"previous content"

    def boom(*a, **k):
        raise OSError("disk full")

    from latent_model import atomic

    monkeypatch.setattr(atomic.os, "fsync", boom)  # the one atomic writer every export goes through
    with pytest.raises(OSError, match="disk full"):
        meshio.export_mesh(m, m.vertices, out)
    assert out.read_bytes() == b"previous content"
    assert [p.name for p in tmp_path.iterdir()] == ["out.ply"]  # no temp file left behind


def test_200k_vertices_import(tmp_path):
    """Large meshes load and are normalised (speed is measured by bench/bench_predict.py)."""
    m = trimesh.creation.capsule(height=1.45, radius=0.15, count=[400, 500])
    v = np.asarray(m.vertices)
    v[:, 2] -= v[:, 2].min() + 0.88
    src = tmp_path / "big.ply"
    trimesh.Trimesh(v * 100, m.faces, process=False).export(src)
    um = meshio.load_mesh(src)
    assert len(um.vertices) >= 199_000 and um.frame.units == "cm"
    assert np.isfinite(um.vertices).all() and 1.4 < np.ptp(um.vertices[:, 2]) < 2.1
