"""The main window: controls | three linked views | heatmap panel, a File menu, drag-and-drop,
shortcuts, a status bar with progress and the last update's time. Heavy work runs in the
model worker; errors a user can cause are shown in a dialog and the window keeps running."""
from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import (QFileDialog, QLabel, QMainWindow, QMessageBox, QProgressBar, QScrollArea,
                               QSplitter, QWidget)

from explorer.controls import Controls
from explorer.heatmaps import HeatmapPanel
from explorer.session import Selection, Session, ViewState, read_session, save_session
from explorer.viewports import ViewPanel
from explorer.workers import ModelWorker

MESH_FILTER = "Meshes (*.obj *.ply *.stl *.glb *.gltf *.off)"


class MainWindow(QMainWindow):
    prediction_shown = Signal(object)  # ViewState, once on screen
    error_shown = Signal(str)

    def __init__(self, initial: Selection | None = None, session: Session | None = None,
                 assets_root: Path | None = None) -> None:
        super().__init__()
        self.setWindowTitle("LatentReRig Explorer")
        self.resize(1680, 900)
        self.initial = initial or Selection()
        self.assets_root = assets_root
        self.state: ViewState | None = None
        self.heatmap_key: tuple | None = None
        self.heatmaps_pending = False
        self.last_error: str | None = None
        self.error_dialog: QMessageBox | None = None
        self.update_ms: list[float] = []  # request -> on screen, per prediction shown
        self.draw_ms: list[float] = []  # of which: setting the views' points (the render follows at the paint)
        self._on_screen_pending: tuple[float, ViewState] | None = None
        self._mesh_paths: dict[str, str] = {}
        self._pending_selection: Selection | None = None
        self._noise_for: str | None = None  # target whose noise floor is being computed

        self.worker = ModelWorker()
        self.controls = Controls(self)
        self.views = ViewPanel(self)
        self.heatmaps = HeatmapPanel(self)
        scroll = QScrollArea(self)
        scroll.setWidget(self.controls)
        scroll.setWidgetResizable(True)
        scroll.setMinimumWidth(300)
        split = QSplitter(Qt.Orientation.Horizontal, self)
        split.addWidget(scroll)
        split.addWidget(self.views)
        split.addWidget(self.heatmaps)
        split.setStretchFactor(1, 1)
        split.setSizes([310, 980, 390])
        self.setCentralWidget(split)

        self.status_text = QLabel("starting", self)
        self.progress = QProgressBar(self)
        self.progress.setMaximumWidth(220)
        self.progress.setVisible(False)
        self.update_label = QLabel("", self)
        sb = self.statusBar()
        sb.addWidget(self.status_text, 1)
        sb.addPermanentWidget(self.progress)
        sb.addPermanentWidget(self.update_label)

        self._make_actions()
        self.setAcceptDrops(True)

        self.controls.changed.connect(self.request)
        self.controls.view_requested.connect(self.views.set_view)
        self.controls.reset_all.clicked.connect(lambda: self.controls.set_selection(self._default_selection()))
        self.heatmaps.identity_clicked.connect(self.controls.condition_on)
        self.heatmaps.noise_requested.connect(self.request_noise)
        self.worker.predicted.connect(self._on_predicted)
        self.views.on_rendered("prediction", self._prediction_rendered)
        self.worker.prediction_failed.connect(self.show_error)
        self.worker.job_progress.connect(self._on_progress)
        self.worker.job_done.connect(self._on_job_done)
        self.worker.job_failed.connect(self._on_job_failed)

        if session is not None:
            self.worker.session = session
            QTimer.singleShot(0, lambda: self._on_job_done("load", session))
        else:
            self.worker.submit("load", self._load_job)

    # -------------------------------------------------------------- actions
    def _make_actions(self) -> None:
        def act(menu, text, shortcut, slot, checkable=False):
            a = QAction(text, self)
            if shortcut:
                a.setShortcut(QKeySequence(shortcut))
                a.setShortcutContext(Qt.ShortcutContext.ApplicationShortcut)
            a.setCheckable(checkable)
            a.triggered.connect(slot)
            menu.addAction(a)
            self.addAction(a)
            return a

        f = self.menuBar().addMenu("&File")
        act(f, "&Open mesh…", "Ctrl+O", self._open_dialog)
        act(f, "&Export prediction (OBJ/PLY/GLB)…", "Ctrl+E", self._export_dialog)
        act(f, "Save &screenshot…", "Ctrl+Shift+S", self._screenshot_dialog)
        f.addSeparator()
        act(f, "&Save session…", "Ctrl+S", self._save_session_dialog)
        act(f, "&Load session…", "Ctrl+L", self._load_session_dialog)
        f.addSeparator()
        act(f, "&Quit", "Ctrl+Q", self.close)
        v = self.menuBar().addMenu("&View")
        act(v, "&Front view", "F", lambda: self.views.set_view("front"))
        act(v, "&Side view", "S", lambda: self.views.set_view("side"))
        act(v, "&Reset view", "R", lambda: self.views.set_view("reset"))
        act(v, "&Wireframe", "W", lambda: self.controls.wireframe.toggle())
        act(v, "Colour by &displacement", "D", lambda: self.controls.displacement.toggle())
        act(v, "&Compare mean vs nearest", "C", lambda: self.controls.compare.toggle())
        s = self.menuBar().addMenu("&Sliders")
        act(s, "Magnitude +0.1", "]", lambda: self.controls.magnitude.setValue(self.controls.magnitude.value() + 10))
        act(s, "Magnitude -0.1", "[", lambda: self.controls.magnitude.setValue(self.controls.magnitude.value() - 10))
        act(s, "Blend +0.1", ".", lambda: self.controls.blend.setValue(self.controls.blend.value() + 10))
        act(s, "Blend -0.1", ",", lambda: self.controls.blend.setValue(self.controls.blend.value() - 10))
        act(s, "Reset sliders", "0", self.controls.do_reset_sliders)
        h = self.menuBar().addMenu("&Help")
        act(h, "Keyboard shortcuts", "F1", self._help)

    def _help(self) -> None:
        QMessageBox.information(self, "Keyboard shortcuts", (
            "Ctrl+O open mesh · Ctrl+E export prediction · Ctrl+Shift+S screenshot\n"
            "Ctrl+S / Ctrl+L save / load session · Ctrl+Q quit\n"
            "F front · S side · R reset view · W wireframe · D displacement colours · C compare\n"
            "[ ] magnitude −/+ 0.1 · , . blend −/+ 0.1 · 0 reset sliders\n"
            "Drop a mesh file on the window to open it."))

    # -------------------------------------------------------------- loading
    def _load_job(self):
        yield "loading the model and latent bank", None
        s = Session.load_shipped(root=self.assets_root, with_truth=False)
        yield "preparing the body model for ground truth (the first launch builds anny's cache: minutes)", 0.3
        from latent_model.shipped import ShippedPaths

        s.attach_truth(ShippedPaths.at(self.assets_root).identities)
        target = self.initial.target if self.initial.target in s.targets else s.targets[0]
        yield f"regenerating and encoding {target}", 0.7
        s.prepared(target, "neutral_to_pose", self.initial.pose if self.initial.pose in s.poses() else s.poses()[0])
        self.worker.session = s
        return s

    def _default_selection(self) -> Selection:
        s = self.worker.session
        sel = Selection()
        if s is not None and s.targets and sel.target not in s.targets:
            sel.target = s.targets[0]
        return sel

    # -------------------------------------------------------------- requests
    def request(self, sel: Selection | None = None) -> None:
        sel = sel or self.controls.selection()
        if self.worker.session is None or not sel.target:
            return
        if sel.wireframe != self.views.wireframe:
            self.views.set_wireframe(sel.wireframe)
        self.worker.request(sel)

    def request_noise(self) -> None:
        s = self.worker.session
        target = self.controls.target.currentText()
        if s is None:
            return
        if not s.has_truth(target):
            self.heatmaps.noise_message(f"The noise floor needs ground truth: choose a held-out identity as the target "
                                        f"({target} is an opened mesh).")
            return
        if self.heatmaps.noise_target == target or self._noise_for == target:
            return
        self._noise_for = target
        self.worker.cancel_jobs("noise")
        self.heatmaps.noise_message(f"computing the noise floor of {target} (two SDF samplings of each posed state)…")

        def job():
            nf = None
            for frac, nf in s.noise_floor_steps(target):
                yield f"noise floor of {target}: {len(nf.poses)} poses", frac
            return nf

        self.worker.submit("noise", job)

    def _on_predicted(self, state: ViewState, t0: float) -> None:
        self.state = state
        sel = state.selection
        t_draw = time.perf_counter()
        self.views.show_state(state, sel.colour)
        self.draw_ms.append((time.perf_counter() - t_draw) * 1000)
        self._on_screen_pending = (t0, state)  # timed when the prediction view's render ends
        if self.heatmaps.currentIndex() == 2 and self.heatmaps.noise_target != sel.target:
            self.request_noise()
        key = (sel.target, sel.kind, sel.pose, state.conditioning)
        if key != self.heatmap_key:
            self.heatmap_key = key
            self.heatmaps_pending = True
            self.worker.cancel_jobs("heatmaps")
            s = self.worker.session
            cond = state.conditioning

            def job():
                yield "heatmaps", None
                return s.heatmaps(sel, cond)

            self.worker.submit("heatmaps", job)
        self.prediction_shown.emit(state)

    def _prediction_rendered(self) -> None:
        """The prediction view finished a render: the pending prediction is on screen."""
        if self._on_screen_pending is None:
            return
        t0, state = self._on_screen_pending
        self._on_screen_pending = None
        ms = (time.perf_counter() - t0) * 1000
        self.update_ms.append(ms)
        self.update_label.setText(f"last update {ms:.0f} ms (model {state.seconds * 1000:.0f} ms, "
                                  f"decoder {state.seconds_decoder * 1000:.0f} ms) at {time.strftime('%H:%M:%S')}")

    def _on_progress(self, name: str, msg: str, frac) -> None:
        self.progress.setVisible(True)
        if frac is None:
            self.progress.setRange(0, 0)
        else:
            self.progress.setRange(0, 100)
            self.progress.setValue(int(frac * 100))
        self.status_text.setText(msg)

    def _on_job_done(self, name: str, result) -> None:
        self.progress.setVisible(False)
        if name == "load":
            s: Session = result
            poses = {k: s.poses(k) for k in s.kinds()}
            self.controls.set_choices(s.targets, s.kinds(), poses, s.training_ids)
            self.status_text.setText(f"ready: {len(s.test_ids)} held-out identities, {len(s.training_ids)} training "
                                     f"identities in the bank")
            sel = self.initial
            if sel.target not in s.targets:
                sel.target = s.targets[0]
            self.controls.set_selection(sel)
        elif name == "heatmaps":
            self.heatmaps.show_data(result)
            self.heatmaps_pending = False
            self.status_text.setText("ready")
        elif name == "noise":
            self._noise_for = None
            self.heatmaps.show_noise(result)
            self.status_text.setText("ready")
        elif name == "open":
            mesh_name, path = result
            self._mesh_paths[mesh_name] = path
            self.controls.add_target(mesh_name)
            self.status_text.setText(self.worker.session.meshes[mesh_name].summary())
            s = self.worker.session
            sel, self._pending_selection = self._pending_selection, None
            if sel is None or sel.target not in s.targets:
                sel = self.controls.selection()
                sel.target, sel.kind = mesh_name, "neutral_to_pose"
            if sel.target in s.meshes:
                poses = s.poses("neutral_to_pose")
                sel.kind = "neutral_to_pose"
                sel.pose = sel.pose if sel.pose in poses else poses[0]
                sel.pose_b = sel.pose_b if sel.pose_b in poses else None
            self.controls.set_selection(sel)
        elif name == "export":
            self.status_text.setText(f"exported {result}")

    def _on_job_failed(self, name: str, msg: str) -> None:
        self.progress.setVisible(False)
        if name == "heatmaps":
            self.heatmaps_pending = False
        if name == "noise":
            self._noise_for = None
            self.heatmaps.noise_message(f"noise floor unavailable: {msg}")
        self.show_error(msg if name != "load" else f"could not load the model: {msg}")

    def show_error(self, msg: str) -> None:
        """A non-blocking error dialog; the window keeps running."""
        self.last_error = msg
        self.status_text.setText(f"error: {msg[:200]}")
        if self.error_dialog is not None:
            self.error_dialog.close()
        self.error_dialog = QMessageBox(QMessageBox.Icon.Critical, "LatentReRig Explorer", msg, parent=self)
        self.error_dialog.setModal(False)
        self.error_dialog.open()
        self.error_shown.emit(msg)

    # -------------------------------------------------------------- file operations
    def open_path(self, path: str | Path) -> None:
        """Open a user's mesh (in the worker: big meshes take a moment); a bad file gives a dialog."""
        path = str(path)
        if self.worker.session is None:
            self.show_error("the model is still loading; open the mesh again in a moment")
            return
        s = self.worker.session

        def job():
            yield f"opening {Path(path).name}", None
            name = s.open_mesh(path)
            yield f"encoding {name}", 0.5
            s.prepared(name, "neutral_to_pose", s.poses()[0])
            return name, path

        self.worker.submit("open", job)

    def export_path(self, path: str | Path) -> None:
        if self.state is None:
            self.show_error("nothing to export yet: wait for a prediction")
            return
        s, state = self.worker.session, self.state

        def job():
            yield f"exporting to {path}", None
            return s.export(state, path)

        self.worker.submit("export", job)

    def save_screenshot(self, path: str | Path) -> Path:
        """The whole window with its 3D views painted in (PNG, written atomically)."""
        import os

        path = Path(path)
        pix = self.views.paint_into(self.grab(), self)
        tmp = path.with_name(f".{path.name}.tmp{path.suffix or '.png'}")
        if not pix.save(str(tmp)):
            raise OSError(f"{path}: could not write the image")
        os.replace(tmp, path)
        self.status_text.setText(f"screenshot saved to {path}")
        return path

    def save_session(self, path: str | Path) -> Path:
        return save_session(path, self.controls.selection(), self._mesh_paths)

    def load_session(self, path: str | Path) -> None:
        try:
            sel, meshes = read_session(path)
        except ValueError as e:
            self.show_error(str(e))
            return
        for name, p in meshes.items():
            if self.worker.session is not None and name not in self.worker.session.meshes:
                self._pending_selection = sel
                self.open_path(p)
        if self._pending_selection is None:
            self.controls.set_selection(sel)

    def _open_dialog(self) -> None:
        p, _ = QFileDialog.getOpenFileName(self, "Open mesh", "", MESH_FILTER)
        if p:
            self.open_path(p)

    def _export_dialog(self) -> None:
        p, _ = QFileDialog.getSaveFileName(self, "Export prediction", "prediction.obj", "OBJ (*.obj);;PLY (*.ply);;GLB (*.glb)")
        if p:
            self.export_path(p)

    def _screenshot_dialog(self) -> None:
        p, _ = QFileDialog.getSaveFileName(self, "Save screenshot", "explorer.png", "PNG (*.png)")
        if p:
            try:
                self.save_screenshot(p)
            except OSError as e:
                self.show_error(str(e))

    def _save_session_dialog(self) -> None:
        p, _ = QFileDialog.getSaveFileName(self, "Save session", "session.json", "JSON (*.json)")
        if p:
            try:
                self.save_session(p)
                self.status_text.setText(f"session saved to {p}")
            except OSError as e:
                self.show_error(f"{p}: {e}")

    def _load_session_dialog(self) -> None:
        p, _ = QFileDialog.getOpenFileName(self, "Load session", "", "JSON (*.json)")
        if p:
            self.load_session(p)

    # -------------------------------------------------------------- drag and drop
    def dragEnterEvent(self, e) -> None:
        if e.mimeData().hasUrls():
            e.acceptProposedAction()

    def dropEvent(self, e) -> None:
        for url in e.mimeData().urls():
            if url.isLocalFile():
                self.open_path(url.toLocalFile())
        e.acceptProposedAction()

    # -------------------------------------------------------------- state
    def is_settled(self) -> bool:
        """A prediction is on screen, its heatmaps are drawn and no work is waiting."""
        return self.state is not None and not self.heatmaps_pending and self.worker.idle

    def closeEvent(self, e) -> None:
        self.worker.stop()
        self.views.close_plotters()
        super().closeEvent(e)
