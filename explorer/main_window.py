"""The main window: controls | three linked views | heatmap panel, a File menu, drag-and-drop,
shortcuts, a status bar with progress, the last update's time and out-of-distribution warnings.

The window owns no model state: the `Session` does (selection, prediction shown, heatmaps, noise
floor, opened meshes, pending work) and the widgets subscribe to its events. The window is the
controller between them: it turns edits into `Session.select`, events that need work into worker
jobs, and each worker result, dispatched by its type, into `Session.apply`. Errors a user can
cause are shown in a dialog and the window keeps running."""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QAction, QGuiApplication, QKeySequence
from PySide6.QtWidgets import (QFileDialog, QLabel, QMainWindow, QMessageBox, QProgressBar, QScrollArea,
                               QSplitter)

from latent_model.atomic import atomic_write
from latent_model.facing import face_front
from latent_model.meshio import EXPORT_FORMATS, FORMATS, UserMesh, load_mesh
from latent_model.types import PairKind

from explorer.controls import Controls
from explorer.heatmaps import HeatmapPanel
from explorer.results import (ExampleOpened, Exported, Failed, HeatmapData, HeatmapRequest, MeshOpened, NoiseFloor,
                              Predicted, ViewState, example_subject)
from explorer.selection import Selection, read_session, save_session
from explorer.session import Loaded, Session
from explorer.status import StatusLabel
from explorer.viewports import ViewPanel
from explorer.workers import ModelWorker

MESH_FILTER = "Meshes (" + " ".join(f"*{x}" for x in FORMATS) + ")"
EXPORT_FILTER = ";;".join(f"{x[1:].upper()} (*{x})" for x in EXPORT_FORMATS)
DEFAULT_SIZE = (1366, 768)  # fits the smallest common laptop screen; shrunk further to the screen's free area
SPLIT_SIZES = (280, 766, 320)  # controls | views | heatmaps at the default width


def fit_size(wanted: tuple[int, int], available: tuple[int, int], frame: tuple[int, int] = (0, 0)) -> tuple[int, int]:
    """The window's (width, height): `wanted`, shrunk so that with its frame (title bar and borders,
    `frame` = their total width and height) it fits the screen's available area."""
    return (max(1, min(wanted[0], available[0] - frame[0])), max(1, min(wanted[1], available[1] - frame[1])))


class MainWindow(QMainWindow):
    prediction_shown = Signal(object)  # ViewState, once its points are set in the views
    error_shown = Signal(str)
    loaded = Signal(object)  # Session, once the controls show its choices

    def __init__(self, initial: Selection | None = None, session: Session | None = None,
                 assets_root: Path | None = None) -> None:
        super().__init__()
        self.setWindowTitle("LatentReRig Explorer")
        self.initial = initial or Selection()
        self.assets_root = assets_root
        self.session: Session | None = None  # set when the load job's result arrives
        self.last_error: str | None = None
        self.error_dialog: QMessageBox | None = None
        self.update_ms: list[float] = []  # request -> on screen, per prediction shown
        self.draw_ms: list[float] = []  # of which: setting the views' points (the render follows at the paint)
        self._on_screen_pending: tuple[float, ViewState] | None = None

        self.worker = ModelWorker()
        self.controls = Controls(self)
        self.views = ViewPanel(self)
        self.heatmaps = HeatmapPanel(self)
        scroll = QScrollArea(self)
        scroll.setWidget(self.controls)
        scroll.setWidgetResizable(True)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setMinimumWidth(self.controls.minimumSizeHint().width() + scroll.verticalScrollBar().sizeHint().width())
        self.views.setMinimumWidth(420)
        self.heatmaps.setMinimumWidth(240)
        split = QSplitter(Qt.Orientation.Horizontal, self)
        split.addWidget(scroll)
        split.addWidget(self.views)
        split.addWidget(self.heatmaps)
        split.setStretchFactor(1, 1)
        split.setChildrenCollapsible(False)
        split.setSizes(list(SPLIT_SIZES))
        self.splitter = split
        self.setCentralWidget(split)

        self.status_text = StatusLabel("starting", self)
        self.progress = QProgressBar(self)
        self.progress.setMaximumWidth(180)
        self.progress.setVisible(False)
        self.update_label = QLabel("", self)
        sb = self.statusBar()
        sb.addWidget(self.status_text, 1)
        sb.addPermanentWidget(self.progress)
        sb.addPermanentWidget(self.update_label)

        self._make_actions()
        self.setAcceptDrops(True)
        self.fit_to_screen()

        # worker results, dispatched by type: the session takes what changes the window state
        self._handlers: dict[type, Callable] = {
            Loaded: self._loaded, Predicted: self._predicted, Failed: self._failed,
            HeatmapData: self._apply, NoiseFloor: self._apply, MeshOpened: self._apply, ExampleOpened: self._apply,
            Exported: self._apply}
        self.worker.result.connect(self._on_result)
        self.worker.progress.connect(self._on_progress)
        self.controls.changed.connect(self.request)
        self.controls.view_requested.connect(self.views.set_view)
        self.controls.reset_all.clicked.connect(self.reset_selection)
        self.controls.example_requested.connect(self._example_dialog)
        self.heatmaps.identity_clicked.connect(self.controls.condition_on)
        self.heatmaps.noise_requested.connect(self.request_noise)
        self.views.on_rendered("prediction", self._prediction_rendered)

        if session is not None:
            QTimer.singleShot(0, lambda: self._on_result(Loaded(session)))
        else:
            self.worker.submit(Loaded, self._load_job)

    # -------------------------------------------------------------- size
    def fit_to_screen(self, width: int | None = None, height: int | None = None) -> None:
        """Resize to width x height (default DEFAULT_SIZE), shrunk to the screen's available area
        (without taskbars) less the window frame, and moved back onto that area if it sticks out."""
        w, h = width or DEFAULT_SIZE[0], height or DEFAULT_SIZE[1]
        screen = self.screen() or QGuiApplication.primaryScreen()
        if screen is None:
            self.resize(w, h)
            return
        avail = screen.availableGeometry()
        frame, geo = self.frameGeometry(), self.geometry()
        extra = (frame.width() - geo.width(), frame.height() - geo.height())
        w, h = fit_size((w, h), (avail.width(), avail.height()), extra)
        self.resize(w, h)
        if self.isVisible() and not avail.contains(self.frameGeometry()):
            self.move(max(avail.left(), min(frame.left(), avail.right() + 1 - (w + extra[0]))),
                      max(avail.top(), min(frame.top(), avail.bottom() + 1 - (h + extra[1]))))

    def showEvent(self, e) -> None:
        super().showEvent(e)
        if not getattr(self, "_refitted", False):  # the frame's size is known once a window manager decorated it
            self._refitted = True
            QTimer.singleShot(200, lambda: self.fit_to_screen(self.width(), self.height()))

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
        act(f, "Condition on an e&xample pair…", "Ctrl+Shift+O", self._example_dialog)
        act(f, "C&lear example pair", "Ctrl+Shift+X", self.controls.clear_example)
        act(f, "&Export prediction…", "Ctrl+E", self._export_dialog)
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
        act(v, "Colour by &displacement", "D", self.controls.toggle_displacement)
        act(v, "&Compare mean vs nearest", "C", self.controls.toggle_compare)
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
            "Ctrl+Shift+O condition on an example pair · Ctrl+Shift+X clear it\n"
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
        # the latent: the heatmaps read it (a neutral_to_pose prediction does not)
        s.prepared(target, "neutral_to_pose", self.initial.pose if self.initial.pose in s.poses() else None).mu
        return Loaded(s)

    @property
    def state(self) -> ViewState | None:
        """The prediction on screen (the session's; None before the model is loaded)."""
        return None if self.session is None else self.session.state

    # -------------------------------------------------------------- results (UI thread)
    def _on_result(self, result) -> None:
        if not isinstance(result, Predicted):
            self.progress.setVisible(False)
        self._handlers[type(result)](result)

    def _apply(self, result) -> None:
        self.session.apply(result)

    def _loaded(self, result: Loaded) -> None:
        s = self.session = result.session
        self.worker.session = s
        self.controls.bind(s)
        self.views.bind(s)
        self.heatmaps.bind(s)
        ev = s.events
        ev.selection.connect(self._selected)
        ev.state.connect(self._state_shown)
        ev.heatmaps_wanted.connect(self._start_heatmaps)
        ev.heatmaps.connect(lambda _: self._ready())
        ev.noise.connect(lambda _: self._ready())
        ev.mesh_opened.connect(lambda m: self.status_text.setText(m.summary))
        ev.example_opened.connect(lambda e: self.status_text.setText(e.summary))
        ev.exported.connect(lambda e: self.status_text.setText(f"exported {e.path}"))
        ev.failed.connect(lambda f: self.show_error(f.message))
        self.controls.set_choices(s.targets, s.kinds(), {k: s.poses(k) for k in s.kinds()}, s.training_ids)
        self.status_text.setText(f"ready: {len(s.test_ids)} held-out identities, {len(s.training_ids)} training "
                                 f"identities in the bank")
        sel = self.initial
        s.select(sel if sel.target in s.targets else replace(sel, target=s.targets[0]))
        self.loaded.emit(s)

    def _predicted(self, result: Predicted) -> None:
        t_draw = time.perf_counter()
        if self.worker.idle:  # a slow first prediction (a registration) showed the busy bar; no job shows it now
            self.progress.setVisible(False)
        self.session.apply(result)  # -> the views draw it (event `state`)
        self.draw_ms.append((time.perf_counter() - t_draw) * 1000)
        self._on_screen_pending = (result.requested, result.state)  # timed when the prediction view's render ends
        self.prediction_shown.emit(result.state)

    def _failed(self, result: Failed) -> None:
        if self.session is None:  # the load job (or a request before it ended)
            self.show_error(f"could not load the model: {result.message}" if result.job is Loaded else result.message)
        else:
            self.session.apply(result)  # -> event `failed`: the dialog

    def _on_progress(self, msg: str, frac) -> None:
        self.progress.setVisible(True)
        if frac is None:
            self.progress.setRange(0, 0)
        else:
            self.progress.setRange(0, 100)
            self.progress.setValue(int(frac * 100))
        self.status_text.setText(msg)

    # -------------------------------------------------------------- session events -> work
    def request(self, sel: Selection | None = None) -> None:
        """An edit in the controls (or a caller): make it the session's selection."""
        if self.session is not None:
            self.session.select(sel or self.controls.selection())

    def reset_selection(self) -> None:
        if self.session is not None:
            self.session.select(self.session.default_selection())

    def _selected(self, sel: Selection) -> None:
        if not sel.target:
            return
        if sel.wireframe != self.views.wireframe:
            self.views.set_wireframe(sel.wireframe)
        self.worker.request(sel)

    def _state_shown(self, state: ViewState) -> None:
        if state.warnings:
            self._ready()
        elif self.status_text.is_warning:  # the mesh that was out of distribution is no longer shown
            self.status_text.setText("ready")
        if self.heatmaps.currentIndex() == 2:
            self.request_noise()

    def _ready(self) -> None:
        """Work finished: "ready", or the shown prediction's out-of-distribution warning (it must not be
        lost under a later message: the prediction on screen is extrapolation)."""
        warnings = self.state.warnings if self.state is not None else []
        if warnings:
            self.status_text.show_message(" · ".join(warnings), warning=True)
        else:
            self.status_text.setText("ready")

    def _start_heatmaps(self, req: HeatmapRequest) -> None:
        s = self.session
        self.worker.cancel(HeatmapData)

        def job():
            yield "heatmaps", None
            return s.heatmaps(req.selection, req.conditioning)

        self.worker.submit(HeatmapData, job)

    def request_noise(self) -> None:
        s = self.session
        if s is None or s.selection is None:
            return
        target = s.selection.target
        if not s.has_truth(target):
            self.heatmaps.noise_message(f"The noise floor needs ground truth: choose a held-out identity as the target "
                                        f"({target} is an opened mesh).")
            return
        if not s.begin_noise(target):
            return
        self.worker.cancel(NoiseFloor)
        self.heatmaps.noise_message(f"computing the noise floor of {target} (two SDF samplings of each posed state)…")

        def job():
            nf = None
            for frac, nf in s.noise_floor_steps(target):
                yield f"noise floor of {target}: {len(nf.poses)} poses", frac
            return nf

        self.worker.submit(NoiseFloor, job, subject=target)

    def _prediction_rendered(self) -> None:
        """The prediction view finished a render: the pending prediction is on screen."""
        if self._on_screen_pending is None:
            return
        t0, state = self._on_screen_pending
        self._on_screen_pending = None
        ms = (time.perf_counter() - t0) * 1000
        self.update_ms.append(ms)
        self.update_label.setText(f"last update {ms:.0f} ms (model {state.seconds * 1000:.0f} ms, "
                                  f"Transfer.predict {state.seconds_predict * 1000:.0f} ms) at {time.strftime('%H:%M:%S')}")

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
    def open_path(self, path: str | Path, mesh: UserMesh | None = None, kind: PairKind = "neutral_to_pose") -> None:
        """Open a user's mesh (in the worker: big meshes take a moment); a bad file gives a dialog.
        `mesh`: the file already read (the command line checks it before the window opens); `kind`: the pair kind
        whose source it is taken as (the command line's --kind; a neutral otherwise)."""
        path = str(path)
        s = self.session
        if s is None:
            self.show_error("the model is still loading; open the mesh again in a moment")
            return

        def job():
            yield f"opening {Path(path).name}", None
            m = mesh if mesh is not None else load_mesh(path)
            yield f"encoding {Path(path).name}", 0.2
            m = face_front(s.transfer, m, kind)  # read facing another axis when the model finds it novel as it is
            name = s.add_mesh(m)
            yield f"encoding {name}", 0.5
            try:
                s.prepared(name).mu  # encode now: the heatmaps read it, and a mesh that cannot be encoded is no target
            except Exception:
                s.remove_mesh(name)  # a mesh that cannot be encoded is no target
                raise
            return MeshOpened(name, path, m.summary(), kind)

        self.worker.submit(MeshOpened, job, subject=path)

    def open_example(self, neutral: str | Path, posed: str | Path) -> None:
        """Condition on an example pair: A and A1 are read and encoded in the worker (seconds, with
        progress), then predict the current target; a bad pair gives a dialog."""
        s = self.session
        if s is None:
            self.show_error("the model is still loading; open the example pair again in a moment")
            return
        neutral, posed = str(neutral), str(posed)
        self.worker.submit(ExampleOpened, lambda: s.open_example_steps(neutral, posed),
                           subject=example_subject(neutral, posed))

    def export_path(self, path: str | Path) -> None:
        state = self.state
        if state is None:
            self.show_error("nothing to export yet: wait for a prediction")
            return
        s = self.session

        def job():
            yield f"exporting to {path}", None
            return Exported(s.export(state, path))

        self.worker.submit(Exported, job, subject=str(path))

    def save_screenshot(self, path: str | Path) -> Path:
        """The whole window with its 3D views painted in (PNG, written atomically)."""
        pix = self.views.paint_into(self.grab(), self)

        def write(tmp: Path) -> None:
            if not pix.save(str(tmp)):
                raise OSError(f"{path}: could not write the image")

        path = atomic_write(path, write)
        self.status_text.setText(f"screenshot saved to {path}")
        return path

    def save_session(self, path: str | Path) -> Path:
        s = self.session
        sel = s.selection if s is not None and s.selection is not None else self.controls.selection()
        held = s.example_paths if s is not None else {}
        examples = {sel.example: held[sel.example]} if sel.example in held else {}
        return save_session(path, sel, s.mesh_paths if s is not None else {}, examples)

    def load_session(self, path: str | Path) -> None:
        try:
            saved = read_session(path)
        except ValueError as e:
            self.show_error(str(e))
            return
        self.restore_session(*saved)

    def restore_session(self, sel: Selection, meshes: dict[str, str],
                        examples: dict[str, tuple[str, str]] | None = None) -> None:
        """Show a saved selection, opening its meshes and its example pair first."""
        if self.session is None:
            self.show_error("the model is still loading; load the session again in a moment")
            return
        to_open = self.session.restore(sel, meshes, examples)
        for p in to_open.meshes.values():
            self.open_path(p)
        for neutral, posed in to_open.examples.values():
            self.open_example(neutral, posed)

    def _open_dialog(self) -> None:
        p, _ = QFileDialog.getOpenFileName(self, "Open mesh", "", MESH_FILTER)
        if p:
            self.open_path(p)

    def _example_dialog(self) -> None:
        """Two file dialogs: the character's neutral mesh A, then A deformed (A1, same vertices and triangles)."""
        a, _ = QFileDialog.getOpenFileName(self, "Example pair: the neutral mesh A", "", MESH_FILTER)
        if not a:
            return
        a1, _ = QFileDialog.getOpenFileName(self, f"Example pair: {Path(a).name} deformed (A1, same vertices and "
                                                  f"triangles)", str(Path(a).parent), MESH_FILTER)
        if a1:
            self.open_example(a, a1)

    def _export_dialog(self) -> None:
        p, _ = QFileDialog.getSaveFileName(self, "Export prediction", "prediction.obj", EXPORT_FILTER)
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
        s = self.session
        return s is not None and s.state is not None and not s.heatmaps_pending and self.worker.idle

    def closeEvent(self, e) -> None:
        self.worker.stop()
        self.views.close_plotters()
        super().closeEvent(e)
