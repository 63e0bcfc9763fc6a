"""The control panel: target, pair kind, poses A/B, conditioning strategy, magnitude and blend
sliders, the example pair that conditions pose A instead of a pose, display toggles and reset
buttons. Emits `changed(Selection)` on every edit (the window makes it the session's selection);
bound to a session, it shows the session's selection and, for the colouring box, what the
prediction view shows."""
from __future__ import annotations

import html

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (QCheckBox, QComboBox, QFormLayout, QGroupBox, QHBoxLayout, QLabel, QPushButton,
                               QSlider, QVBoxLayout, QWidget)

from latent_model.types import BLEND_RANGE, MAGNITUDE_RANGE

from explorer.framing import FOCUS_CHOICES, FOCUS_LABELS
from explorer.results import STRATEGY_LABELS, ViewState
from explorer.selection import Selection
from explorer.session import Session

NONE_POSE = "(none)"
DISPLACEMENT_TIP = "Colour the prediction by how far each vertex moved from the source, not by its error against the truth"
NO_TRUTH_TIP = ("An opened mesh has no ground truth, so its prediction is coloured by displacement from the source "
                "(choose a held-out identity to colour by error)")
STRATEGY_ITEMS = (*((STRATEGY_LABELS[k], k) for k in ("mean_pose_delta", "nearest_identity_delta")),
                  ("chosen identity", "identity"))
SLIDER_STEPS = 100  # slider ticks per unit of magnitude / blend
NO_EXAMPLE = "none: pose A and the conditioning strategy condition the prediction"
EXAMPLE_TIP = ("Open a character's mesh A and the same mesh deformed (A1): the deformation A → A1 is transferred to "
               "the target, scaled by the delta magnitude, in place of pose A")
BY_EXAMPLE_TIP = "The example pair conditions pose A (clear it to choose a pose)"
FOCUS_TIP = ("What the views frame. What moves: at each new character or pose, a close-up of the part the pose moves "
             "when it is small (a face or finger pose), else the whole body. Head / hands: found on the surface of "
             "any humanoid, in any rest pose")


class Controls(QWidget):
    changed = Signal(object)  # Selection
    view_requested = Signal(str)  # front | side | reset
    example_requested = Signal()  # "Condition on an example pair…": the window asks for the two files

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._quiet = False
        outer = QVBoxLayout(self)
        box = QGroupBox("Prediction", self)
        form = QFormLayout(box)
        self.target = QComboBox(box)
        self.kind = QComboBox(box)
        self.pose = QComboBox(box)
        self.pose_b = QComboBox(box)
        self.strategy = QComboBox(box)
        for text, data in STRATEGY_ITEMS:
            self.strategy.addItem(text, data)
        self.identity = QComboBox(box)
        for w in (self.target, self.kind, self.pose, self.pose_b, self.identity):
            w.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
            w.setMinimumContentsLength(14)
        form.addRow("Target", self.target)
        form.addRow("Pair kind", self.kind)
        form.addRow("Pose A", self.pose)
        form.addRow("Pose B", self.pose_b)
        form.addRow("Conditioning", self.strategy)
        form.addRow("Identity", self.identity)
        self.magnitude = QSlider(Qt.Orientation.Horizontal, box)
        self.magnitude.setRange(*(round(x * SLIDER_STEPS) for x in MAGNITUDE_RANGE))
        self.magnitude.setValue(SLIDER_STEPS)
        self.magnitude_label = QLabel("1.00x", box)
        self.blend = QSlider(Qt.Orientation.Horizontal, box)
        self.blend.setRange(*(round(x * SLIDER_STEPS) for x in BLEND_RANGE))
        self.blend_label = QLabel("0.00", box)
        for s in (self.magnitude, self.blend):
            s.setSingleStep(1)
            s.setPageStep(10)
        form.addRow("Delta magnitude", self._row(self.magnitude, self.magnitude_label))
        form.addRow("Pose blend A→B", self._row(self.blend, self.blend_label))
        outer.addWidget(box)
        outer.addWidget(self._example_box())

        disp = QGroupBox("Display", self)
        dl = QVBoxLayout(disp)
        self.displacement = QCheckBox("Colour by displacement", disp)
        self.displacement.setToolTip(DISPLACEMENT_TIP)
        self._colour = "error"  # the user's choice (the box shows displacement, fixed, for a mesh without truth)
        self.compare = QCheckBox("Compare mean vs nearest", disp)
        self.wireframe = QCheckBox("Wireframe", disp)
        for w in (self.displacement, self.compare, self.wireframe):
            dl.addWidget(w)
        self.focus = QComboBox(disp)
        for name in FOCUS_CHOICES:
            self.focus.addItem(FOCUS_LABELS[name], name)
        self.focus.setToolTip(FOCUS_TIP)
        frame_row = QHBoxLayout()
        frame_row.addWidget(QLabel("Frame", disp))
        frame_row.addWidget(self.focus, 1)
        dl.addLayout(frame_row)
        views = QHBoxLayout()
        for text, which in (("Front", "front"), ("Side", "side"), ("Reset view", "reset")):
            b = QPushButton(text, disp)
            b.clicked.connect(lambda _=False, w=which: self.view_requested.emit(w))
            views.addWidget(b)
        dl.addLayout(views)
        self.reset_sliders = QPushButton("Reset sliders", disp)
        self.reset_all = QPushButton("Reset selection", disp)
        resets = QHBoxLayout()
        resets.addWidget(self.reset_sliders)
        resets.addWidget(self.reset_all)
        dl.addLayout(resets)
        outer.addWidget(disp)
        outer.addStretch(1)

        for w in (self.target, self.pose, self.pose_b, self.strategy, self.identity, self.focus):
            w.currentIndexChanged.connect(self._emit)
        self.kind.currentIndexChanged.connect(self._kind_changed)
        self.magnitude.valueChanged.connect(self._emit)
        self.blend.valueChanged.connect(self._emit)
        self.displacement.toggled.connect(self._colour_toggled)
        for w in (self.compare, self.wireframe):
            w.toggled.connect(self._emit)
        self.reset_sliders.clicked.connect(self.do_reset_sliders)
        self.example_open.clicked.connect(self.example_requested)
        self.example_clear.clicked.connect(self.clear_example)
        self._poses_by_kind: dict[str, list[str]] = {}
        self.setEnabled(False)

    def _example_box(self) -> QGroupBox:
        """The example pair: what conditions the prediction, a button to open a pair and one to clear it."""
        box = QGroupBox("Example pair", self)
        lay = QVBoxLayout(box)
        self._example: str | None = None  # the selection's example pair (the session holds it)
        self.example_label = QLabel(NO_EXAMPLE, box)
        self.example_label.setWordWrap(True)  # a long file name wraps instead of widening the panel
        self.example_open = QPushButton("Condition on an example pair…", box)
        self.example_open.setToolTip(EXAMPLE_TIP)
        self.example_clear = QPushButton("Clear", box)
        self.example_clear.setToolTip("Back to pose A and the conditioning strategy")
        buttons = QHBoxLayout()
        buttons.addWidget(self.example_open, 1)
        buttons.addWidget(self.example_clear)
        lay.addWidget(self.example_label)
        lay.addLayout(buttons)
        return box

    def clear_example(self) -> None:
        """Back to pose conditioning (the Clear button, the menu's Clear example pair)."""
        if self._example is not None:
            self._example = None
            self._emit()

    @staticmethod
    def _row(slider: QSlider, label: QLabel) -> QWidget:
        w = QWidget()
        lay = QHBoxLayout(w)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(slider, 1)
        label.setMinimumWidth(40)
        lay.addWidget(label)
        return w

    # -------------------------------------------------------------- choices
    def set_choices(self, targets: list[str], kinds: list[str], poses_by_kind: dict[str, list[str]],
                    identities: list[str]) -> None:
        self._quiet = True
        try:
            self._poses_by_kind = poses_by_kind
            self._fill(self.target, targets)
            self._fill(self.kind, kinds)
            self._fill(self.identity, identities)
            self._fill_poses(self.kind.currentText())
        finally:
            self._quiet = False
        self._emit(quiet=True)  # labels and enabled states follow the choices
        self.setEnabled(True)

    @staticmethod
    def _fill(combo: QComboBox, items: list[str]) -> None:
        cur = combo.currentText()
        combo.blockSignals(True)
        combo.clear()
        combo.addItems(items)
        if cur in items:
            combo.setCurrentText(cur)
        combo.blockSignals(False)

    def _fill_poses(self, kind: str) -> None:
        poses = self._poses_by_kind.get(kind, [])
        self._fill(self.pose, poses)
        self._fill(self.pose_b, [NONE_POSE] + poses)

    def add_target(self, name: str) -> None:
        if self.target.findText(name) < 0:
            self.target.addItem(name)

    def _kind_changed(self) -> None:
        was = self._quiet
        self._quiet = True
        self._fill_poses(self.kind.currentText())
        self._quiet = was
        self._emit()

    # -------------------------------------------------------------- the session
    def bind(self, session: Session) -> None:
        """Follow a session: show its selection, its opened meshes and how its prediction is coloured."""
        session.events.selection.connect(self.show_selection)
        session.events.state.connect(self.show_state)
        session.events.mesh_opened.connect(lambda m: self.add_target(m.name))

    def show_state(self, state: ViewState) -> None:
        """The colouring box shows the prediction's colouring: checked and fixed without truth."""
        fixed = state.truth is None
        box = self.displacement
        box.blockSignals(True)
        box.setChecked(True if fixed else self._colour == "displacement")
        box.setEnabled(not fixed)
        box.setToolTip(NO_TRUTH_TIP if fixed else DISPLACEMENT_TIP)
        box.blockSignals(False)

    def toggle_displacement(self) -> None:
        """The D shortcut: like a click on the box (nothing while the box is fixed)."""
        if self.displacement.isEnabled():
            self.displacement.toggle()

    def toggle_compare(self) -> None:
        """The C shortcut: like a click on the box (nothing while an example pair conditions)."""
        if self.compare.isEnabled():
            self.compare.toggle()

    def _colour_toggled(self, on: bool) -> None:
        self._colour = "displacement" if on else "error"
        self._emit()

    # -------------------------------------------------------------- selection
    def selection(self) -> Selection:
        strat = self.strategy.currentData()
        if strat == "identity":
            strat = f"identity:{self.identity.currentText()}"
        pb = self.pose_b.currentText()
        return Selection(target=self.target.currentText(), kind=self.kind.currentText(), pose=self.pose.currentText(),
                         pose_b=None if pb in ("", NONE_POSE) else pb, blend=self.blend.value() / SLIDER_STEPS,
                         magnitude=self.magnitude.value() / SLIDER_STEPS, strategy=strat,
                         colour=self._colour, compare=self.compare.isChecked(), wireframe=self.wireframe.isChecked(),
                         example=self._example, focus=self.focus.currentData())

    def show_selection(self, sel: Selection) -> None:
        """Show a selection (the session's: a loaded session, an opened mesh, a reset); emits nothing."""
        if sel == self.selection():
            return
        self._quiet = True
        try:
            self.target.setCurrentText(sel.target)
            self.kind.setCurrentText(sel.kind)
            self._fill_poses(sel.kind)
            self.pose.setCurrentText(sel.pose)
            self.pose_b.setCurrentText(sel.pose_b or NONE_POSE)
            if sel.strategy.startswith("identity:"):
                self.strategy.setCurrentIndex(2)
                self.identity.setCurrentText(sel.strategy.split(":", 1)[1])
            else:
                self.strategy.setCurrentIndex(0 if sel.strategy == "mean_pose_delta" else 1)
            self.magnitude.setValue(round(sel.magnitude * SLIDER_STEPS))
            self.blend.setValue(round(sel.blend * SLIDER_STEPS))
            self._colour = sel.colour
            if self.displacement.isEnabled():
                self.displacement.setChecked(sel.colour == "displacement")
            self.compare.setChecked(sel.compare)
            self.wireframe.setChecked(sel.wireframe)
            self._example = sel.example
            self.focus.setCurrentIndex(FOCUS_CHOICES.index(sel.focus))
        finally:
            self._quiet = False
        self._emit(quiet=True)

    def condition_on(self, identity: str) -> None:
        """Chosen-identity conditioning (a heatmap click); nothing while no strategy is read (an
        example pair conditions pose A and there is no pose B)."""
        if self.identity.findText(identity) < 0 or not self.strategy.isEnabled():
            return
        self._quiet = True
        self.identity.setCurrentText(identity)
        self.strategy.setCurrentIndex(2)
        self._quiet = False
        self._emit()

    def do_reset_sliders(self) -> None:
        self._quiet = True
        self.magnitude.setValue(100)
        self.blend.setValue(0)
        self._quiet = False
        self._emit()

    def _emit(self, *args, quiet: bool = False) -> None:
        self.magnitude_label.setText(f"{self.magnitude.value() / SLIDER_STEPS:.2f}x")
        self.blend_label.setText(f"{self.blend.value() / SLIDER_STEPS:.2f}")
        has_b = self.pose_b.currentText() not in ("", NONE_POSE)
        by_example = self._example is not None
        # under an example, pose A (and so the pair kind) is the example's; the strategy still gives pose B
        for w in (self.kind, self.pose):
            w.setEnabled(not by_example)
            w.setToolTip(BY_EXAMPLE_TIP if by_example else "")
        self.strategy.setEnabled(not by_example or has_b)
        self.identity.setEnabled(self.strategy.isEnabled() and self.strategy.currentData() == "identity")
        self.compare.setEnabled(not by_example)
        self.blend.setEnabled(has_b)
        self.example_clear.setEnabled(by_example)
        self.example_label.setText(NO_EXAMPLE if not by_example else f"<b>example: {html.escape(self._example)}</b> "
                                                                    f"conditions pose A")
        if not (self._quiet or quiet):
            self.changed.emit(self.selection())
