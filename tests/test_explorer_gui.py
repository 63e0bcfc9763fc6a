"""The explorer window under a real X server (Xvfb in CI: `xvfb-run -a pytest`), with pytest-qt.

Skips with a reason when PySide6/pyvistaqt/pytest-qt are missing, when there is no DISPLAY, or when
the shipped model is missing."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from latent_model.shipped import ShippedPaths

if not os.environ.get("DISPLAY"):
    pytest.skip("no DISPLAY: run the GUI tests under an X server (xvfb-run -a python -m pytest)", allow_module_level=True)
if os.environ.get("QT_QPA_PLATFORM") == "offscreen":
    pytest.skip("QT_QPA_PLATFORM=offscreen leaves VTK views blank; unset it and use Xvfb", allow_module_level=True)
pytest.importorskip("PySide6", reason="PySide6 is not installed (pip install -e '.[gui]')")
pytest.importorskip("pyvistaqt", reason="pyvistaqt is not installed (pip install -e '.[gui]')")
pytest.importorskip("pytestqt", reason="pytest-qt is not installed (pip install -e '.[gui]')")
if not ShippedPaths.at().checkpoint.exists() or not ShippedPaths.at().bank.exists():
    pytest.skip(f"the shipped model is missing ({ShippedPaths.at().checkpoint.parent}); restore assets/model",
                allow_module_level=True)

from PySide6.QtCore import QPoint, Qt  # noqa: E402

from explorer.selection import Selection  # noqa: E402

TIMEOUT = 120_000  # ms; the first load regenerates ground truth (and builds anny's cache on a fresh machine)
BACKGROUND = np.array([0x2B, 0x2F, 0x36])


@pytest.fixture(scope="module")
def window(qapp):
    import torch

    from explorer.main_window import MainWindow
    from latent_model.shipped import load_identity_specs

    torch.set_num_threads(1)
    specs, _ = load_identity_specs(ShippedPaths.at().identities)
    target = next(s.id for s in specs if s.split == "test")
    w = MainWindow(Selection(target=target, pose="elbowBentLf", strategy="nearest_identity_delta"))
    w.show()  # at its default size: the tests run on what a user gets
    yield w
    w.close()


def _wait_state(qtbot, w, cond, timeout=TIMEOUT):
    qtbot.waitUntil(lambda: w.state is not None and cond(w.state) and w.worker.idle, timeout=timeout)
    return w.state


def test_window_opens_with_three_views_and_heatmaps(window, qtbot):
    st = _wait_state(qtbot, window, lambda s: True)
    qtbot.waitUntil(lambda: window.heatmaps.data is not None, timeout=TIMEOUT)
    v = window.views
    assert [n for n, p in v.plotters.items() if p.isVisible()] == ["source", "prediction", "truth"]
    assert st.truth is not None and st.prediction.error_mm is not None
    assert "last update" in window.update_label.text()
    assert window.heatmaps.data.target == st.target


def test_window_fits_1366x768_by_default(window, qtbot):
    from explorer.main_window import fit_size

    qtbot.waitExposed(window)
    _wait_state(qtbot, window, lambda s: True)
    frame = window.frameGeometry()
    assert frame.width() <= 1366 and frame.height() <= 768, f"default window {frame.width()}x{frame.height()}"
    hint = window.minimumSizeHint()
    assert hint.width() <= 1366 and hint.height() <= 768
    # nothing cut off at that size: the controls fit their panel, every view keeps a usable width
    scroll = window.controls.parentWidget().parentWidget()
    assert scroll.viewport().width() >= window.controls.minimumSizeHint().width()
    assert all(p.width() >= 200 for n, p in window.views.plotters.items() if p.isVisible())
    assert window.heatmaps.width() >= 240
    # a size asked for is shrunk to the screen's free area less the frame
    assert fit_size((1366, 768), (1280, 720), (0, 30)) == (1280, 690)
    assert fit_size((1000, 600), (1920, 1080), (4, 30)) == (1000, 600)
    avail = window.screen().availableGeometry()
    window.fit_to_screen(avail.width() + 500, avail.height() + 500)
    assert window.width() <= avail.width() and window.height() <= avail.height()
    window.fit_to_screen()
    assert (window.width(), window.height()) == (1366, 768)


def test_each_slider_changes_the_prediction(window, qtbot):
    c = window.controls
    base = _wait_state(qtbot, window, lambda s: True).prediction.vertices.copy()
    c.magnitude.setValue(170)
    st = _wait_state(qtbot, window, lambda s: s.selection.magnitude == pytest.approx(1.7))
    assert not np.allclose(st.prediction.vertices, base)
    c.magnitude.setValue(100)
    c.pose_b.setCurrentText("kneeBentLf")
    assert c.blend.isEnabled()
    before = _wait_state(qtbot, window, lambda s: s.selection.pose_b == "kneeBentLf" and s.selection.magnitude == 1.0)
    c.blend.setValue(60)
    st = _wait_state(qtbot, window, lambda s: s.selection.blend == pytest.approx(0.6))
    assert not np.allclose(st.prediction.vertices, before.prediction.vertices)
    c.do_reset_sliders()
    st = _wait_state(qtbot, window, lambda s: s.selection.blend == 0 and s.selection.magnitude == 1.0)
    assert np.allclose(st.prediction.vertices, before.prediction.vertices, atol=1e-6)


def test_scrubbing_coalesces(window, qtbot):
    c = window.controls
    shown = len(window.update_ms)
    for v in range(100, 200, 2):  # 50 slider steps as fast as Qt delivers them
        c.magnitude.setValue(v)
    st = _wait_state(qtbot, window, lambda s: s.selection.magnitude == pytest.approx(1.98))
    assert len(window.update_ms) - shown < 50  # intermediate values were dropped, not queued
    c.magnitude.setValue(100)
    _wait_state(qtbot, window, lambda s: s.selection.magnitude == 1.0)


def test_a_face_or_finger_pose_is_framed_close_up_and_the_focus_can_be_pinned(window, qtbot):
    """Choosing a face pose frames what it moves (the brow) in all views; a slider keeps the camera where it is;
    a broad pose frames the whole body again; the Frame box pins the head or a hand."""
    c, v = window.controls, window.views
    cam = v.plotters["source"].camera

    def look(state) -> tuple[np.ndarray, float]:
        qtbot.waitUntil(lambda: v.framing == state.framing, timeout=TIMEOUT)
        return np.array(cam.focal_point), float(np.linalg.norm(np.subtract(cam.position, cam.focal_point)))

    body_at, body_far = look(_wait_state(qtbot, window, lambda s: s.selection.pose == "elbowBentLf"))
    c.pose.setCurrentText("browDwLf")
    st = _wait_state(qtbot, window, lambda s: s.selection.pose == "browDwLf")
    at, far = look(st)
    src = st.source
    height = np.ptp(src[:, 2])
    assert st.framing.region == "moving" and at[2] > src[:, 2].min() + 0.85 * height  # at the head
    assert far < 0.5 * body_far  # close up
    assert all(p.camera is cam or np.allclose(p.camera.position, cam.position) for p in v.plotters.values())
    c.magnitude.setValue(150)
    _wait_state(qtbot, window, lambda s: s.selection.magnitude == pytest.approx(1.5))
    assert np.allclose(cam.focal_point, at) and np.isclose(np.linalg.norm(np.subtract(cam.position, at)), far)
    c.magnitude.setValue(100)
    c.focus.setCurrentIndex(c.focus.findData("hand_right"))
    st = _wait_state(qtbot, window, lambda s: s.selection.focus == "hand_right")
    hand_at, _ = look(st)
    assert st.framing.region == "hand_right" and hand_at[0] < -0.3  # the character's right hand is at -X
    c.focus.setCurrentIndex(c.focus.findData("auto"))
    c.pose.setCurrentText("elbowBentLf")
    st = _wait_state(qtbot, window, lambda s: s.selection.pose == "elbowBentLf" and s.selection.focus == "auto")
    at, far = look(st)
    assert st.framing.region == "body" and np.allclose(at, body_at, atol=1e-3) and np.isclose(far, body_far, rtol=1e-3)


def test_switching_strategy_changes_it(window, qtbot):
    c = window.controls
    c.strategy.setCurrentIndex(1)
    near = _wait_state(qtbot, window, lambda s: s.prediction.strategy == "nearest_identity_delta")
    c.strategy.setCurrentIndex(0)
    mean = _wait_state(qtbot, window, lambda s: s.prediction.strategy == "mean_pose_delta")
    assert not np.allclose(mean.prediction.vertices, near.prediction.vertices)
    assert mean.prediction.title.startswith("mean pose delta")


def test_compare_mode_shows_both(window, qtbot):
    c = window.controls
    c.compare.setChecked(True)
    st = _wait_state(qtbot, window, lambda s: s.selection.compare)
    assert [p.strategy for p in st.predictions] == ["mean_pose_delta", "nearest_identity_delta"]
    assert window.views.plotters["prediction_b"].isVisible()
    imgs = window.views.view_images()
    assert set(imgs) == {"source", "prediction", "prediction_b", "truth"}
    c.compare.setChecked(False)
    _wait_state(qtbot, window, lambda s: not s.selection.compare)
    assert not window.views.plotters["prediction_b"].isVisible()


def test_heatmap_click_sets_conditioning(window, qtbot):
    _wait_state(qtbot, window, lambda s: True)
    qtbot.waitUntil(lambda: window.heatmaps.data is not None and window.worker.idle, timeout=TIMEOUT)
    window.heatmaps.setCurrentIndex(0)
    canvas = window.heatmaps.identity
    data = window.heatmaps.data
    current = window.state.conditioning
    col = next(i for i, x in enumerate(data.ids) if x != current and x != data.target)
    want = data.ids[col]
    x, y = canvas.cell_centre(3, col)
    qtbot.mouseClick(canvas, Qt.MouseButton.LeftButton, pos=QPoint(int(round(x)), int(round(y))))
    st = _wait_state(qtbot, window, lambda s: s.selection.strategy == f"identity:{want}")
    assert st.conditioning == want and window.controls.strategy.currentIndex() == 2
    qtbot.waitUntil(lambda: window.heatmaps.data.conditioning == want, timeout=TIMEOUT)  # highlight follows


def test_bad_file_shows_error_and_window_survives(window, qtbot, tmp_path):
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv nan 1 0\nv 0 1 1\nf 1 2 3\n")
    with qtbot.waitSignal(window.error_shown, timeout=TIMEOUT) as sig:
        window.open_path(bad)
    assert "broken.obj" in sig.args[0] and "NaN" in sig.args[0]
    assert window.error_dialog is not None and window.error_dialog.isVisible()
    with qtbot.waitSignal(window.error_shown, timeout=TIMEOUT) as sig:
        window.open_path(tmp_path / "missing.ply")
    assert "no such file" in sig.args[0]
    window.error_dialog.close()
    window.controls.magnitude.setValue(130)  # still alive and predicting
    _wait_state(qtbot, window, lambda s: s.selection.magnitude == pytest.approx(1.3))
    window.controls.magnitude.setValue(100)


def test_condition_on_an_example_pair(window, qtbot, tmp_path, monkeypatch):
    """File > Condition on an example pair…: two dialogs (A, then A1), the pair drawn beside the target
    (A | A1 | source | prediction), the prediction conditioned and labelled, the magnitude scaling it, an
    out-of-distribution warning in the status bar, a clear error for a wrong A1, and Clear back to the pose."""
    import trimesh
    from PySide6.QtWidgets import QFileDialog

    from latent_model.types import FINAL

    c, s = window.controls, window.session
    held = _wait_state(qtbot, window, lambda st: st.truth is not None).target
    other = next(t for t in s.test_ids if t != held)
    for name, pose in (("A.obj", None), ("A1.obj", "elbowBentLf")):
        v = s.truth.state(other, pose, "neutral" if pose is None else FINAL)
        trimesh.Trimesh(v, s.truth.faces, process=False).export(tmp_path / name)
    answers = iter([str(tmp_path / "A.obj"), str(tmp_path / "A1.obj")])
    monkeypatch.setattr(QFileDialog, "getOpenFileName", lambda *a, **k: (next(answers), ""))
    c.example_open.click()
    st = _wait_state(qtbot, window, lambda st: st.example is not None)
    assert st.target == held and st.truth is None and st.prediction.title.startswith("example: A.obj → A1.obj")
    v = window.views
    assert [n for n, p in v.plotters.items() if p.isVisible()] == ["example_neutral", "example_posed", "source",
                                                                    "prediction"]
    assert "example: A.obj → A1.obj" in c.example_label.text() and c.example_clear.isEnabled()
    assert not c.pose.isEnabled() and not c.kind.isEnabled() and not c.compare.isEnabled()
    assert np.abs(st.prediction.vertices - st.source).max() > 1e-3
    c.magnitude.setValue(0)
    zero = _wait_state(qtbot, window, lambda st: st.selection.magnitude == 0 and st.example is not None)
    assert np.array_equal(zero.prediction.vertices, zero.source)

    bank = s.transfer.bank
    kept = bank.ood_threshold
    try:  # every latent beyond a tiny threshold: the warning reaches the status bar
        bank.ood_threshold = 1e-6
        c.magnitude.setValue(100)
        _wait_state(qtbot, window, lambda st: st.selection.magnitude == 1.0 and st.warnings)
        qtbot.waitUntil(lambda: window.status_text.is_warning, timeout=TIMEOUT)
        assert "out of distribution" in window.status_text.text() and held in window.status_text.text()
    finally:
        bank.ood_threshold = kept
    c.magnitude.setValue(90)
    _wait_state(qtbot, window, lambda st: st.selection.magnitude == pytest.approx(0.9) and not st.warnings)
    qtbot.waitUntil(lambda: not window.status_text.is_warning, timeout=TIMEOUT)

    wrong = tmp_path / "A1_other.obj"
    trimesh.Trimesh(s.truth.state(other, "kneeBentLf", FINAL), s.truth.faces[:-10], process=False).export(wrong)
    with qtbot.waitSignal(window.error_shown, timeout=TIMEOUT) as sig:
        window.open_example(tmp_path / "A.obj", wrong)
    assert "must be A.obj deformed" in sig.args[0]
    window.error_dialog.close()
    assert window.state.example is st.example  # the pair that conditions is kept

    c.example_clear.click()
    back = _wait_state(qtbot, window, lambda st: st.example is None)
    assert back.truth is not None and [n for n, p in v.plotters.items() if p.isVisible()] == ["source", "prediction",
                                                                                              "truth"]
    assert c.pose.isEnabled() and c.compare.isEnabled() and not c.example_clear.isEnabled()
    c.magnitude.setValue(100)
    _wait_state(qtbot, window, lambda st: st.selection.magnitude == 1.0)


def test_displacement_box_shows_an_opened_meshs_colouring(window, qtbot, tmp_path):
    """An opened mesh has no truth and is coloured by displacement: the box says so, fixed."""
    import trimesh

    c, s = window.controls, window.session
    held = _wait_state(qtbot, window, lambda st: st.truth is not None).target
    assert not c.displacement.isChecked() and c.displacement.isEnabled()
    f = tmp_path / "my_body.ply"
    trimesh.Trimesh(s.truth.state(held, None, "neutral"), s.truth.faces, process=False).export(f)
    window.open_path(f)
    st = _wait_state(qtbot, window, lambda st: s.is_mesh(st.target))
    assert st.truth is None and st.colour == "displacement"
    assert c.displacement.isChecked() and not c.displacement.isEnabled()
    assert "ground truth" in c.displacement.toolTip()
    assert "displacement" in next(iter(window.views.plotters["prediction"].scalar_bars.keys()))
    c.toggle_displacement()  # the D shortcut cannot uncheck what is shown
    assert c.displacement.isChecked()
    c.target.setCurrentText(held)  # back to a held-out body: coloured by error, the box free again
    st = _wait_state(qtbot, window, lambda st: st.target == held)
    assert st.colour == "error" and not c.displacement.isChecked() and c.displacement.isEnabled()
    assert "error" in next(iter(window.views.plotters["prediction"].scalar_bars.keys()))


def _run_app(args: list[str], timeout: float = 200) -> subprocess.CompletedProcess:
    """`explorer.app.main(args)` in a subprocess, under this X server."""
    code = "import sys; from explorer.app import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})


def test_screenshot_with_a_bad_mesh_or_session_fails_with_the_error(tmp_path):
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv nan 1 0\nv 0 1 1\nf 1 2 3\n")
    junk = tmp_path / "junk.json"
    junk.write_text("{not json")
    out = tmp_path / "out.png"
    for args, named in ((["--mesh", str(bad)], "broken.obj"), (["--mesh", str(tmp_path / "missing.ply")], "missing.ply"),
                        (["--session", str(junk)], "junk.json"),
                        (["--example-neutral", str(bad), "--example-posed", str(bad)], "broken.obj"),
                        (["--example-neutral", str(bad)], "--example-posed")):
        r = _run_app([*args, "--screenshot", str(out)])
        assert r.returncode != 0, f"{args}: exit 0\n{r.stderr[-1000:]}"
        assert "lrr-explorer: error:" in r.stderr and named in r.stderr, r.stderr[-1000:]
        assert not out.exists()
    # a session whose mesh breaks once the window is up (the model loaded): the same
    sess = tmp_path / "s.json"
    sess.write_text(json.dumps({"format": 1, "selection": {"target": "broken"}, "meshes": {"broken": str(bad)}}))
    r = _run_app(["--session", str(sess), "--screenshot", str(out), "--timeout", "150"])
    assert r.returncode != 0 and "lrr-explorer: error:" in r.stderr and "broken.obj" in r.stderr, r.stderr[-1000:]
    assert not out.exists()


def _view_spans(img: np.ndarray) -> list[tuple[int, int]]:
    """Column spans of the 3D views: columns where most pixels are the views' background colour."""
    bg = (np.abs(img[:, :, :3].astype(int) - BACKGROUND).sum(axis=2) < 12)
    cols = bg.mean(axis=0) > 0.5
    spans, start = [], None
    for x, on in enumerate(list(cols) + [False]):
        if on and start is None:
            start = x
        elif not on and start is not None:
            if x - start > 60:
                spans.append((start, x))
            start = None
    return spans


def test_screenshot_has_all_three_meshes_drawn(tmp_path):
    """The real command line: `lrr-explorer --screenshot` renders once and exits."""
    from PIL import Image

    out = tmp_path / "shot.png"
    r = subprocess.run([sys.executable, "-m", "explorer.app", "--screenshot", str(out), "--size", "1500x850",
                        "--pose", "kneeBentLf", "--timeout", "150"], capture_output=True, text=True, timeout=200,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert r.returncode == 0, r.stderr[-2000:]
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape[:2] == (850, 1500)
    spans = _view_spans(img)
    assert len(spans) == 3, f"expected three 3D views, found column spans {spans}"
    for x0, x1 in spans:
        region = img[60:-60, x0:x1].astype(int)  # inside the view, away from titles and colour bar
        diff = np.abs(region - BACKGROUND).sum(axis=2)
        mesh = diff > 40
        frac = mesh.mean()
        assert 0.02 < frac < 0.6, f"view {x0}-{x1}: {frac:.3f} of its pixels are mesh"
        black = (region.sum(axis=2) < 30).mean()
        assert black < 0.2, f"view {x0}-{x1} is mostly black"
        lum = region[mesh].mean(axis=1)
        assert lum.std() > 5, f"view {x0}-{x1}: no shading on the mesh (flat colour)"
        ys, xs = np.nonzero(mesh)
        assert np.ptp(ys) > 0.3 * region.shape[0], f"view {x0}-{x1}: the drawn mesh is not body-sized"
