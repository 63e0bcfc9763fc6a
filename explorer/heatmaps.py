"""The heatmap panel (matplotlib in Qt): identity distances of standardised neutral latents,
pose-delta cosines of the selected pose across training identities (target and conditioning
identity highlighted; clicking a cell conditions on that column's identity), and the noise floor.
"""
from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from PySide6.QtCore import Signal
from PySide6.QtWidgets import QLabel, QTabWidget, QVBoxLayout, QWidget

from latent_model.transfer import GATE_HI, GATE_LO

from explorer.session import HeatmapData, NoiseFloor

TARGET_COLOUR = "#00e5ff"
COND_COLOUR = "#ff3d7f"


class MatrixCanvas(FigureCanvasQTAgg):
    """One matrix with highlighted rows/columns; emits the column label of a clicked cell."""

    def __init__(self, cmap: str, vmin: float | None, vmax: float | None, parent: QWidget | None = None) -> None:
        self.fig = Figure(figsize=(4, 4), dpi=90, layout="constrained")
        super().__init__(self.fig)
        self.setParent(parent)
        self.ax = self.fig.add_subplot(111)
        self.cmap, self.vmin, self.vmax = cmap, vmin, vmax
        self.labels: list[str] = []
        self.on_click = None  # callable(label)
        self.mpl_connect("button_press_event", self._clicked)
        self._cbar = None

    def plot(self, m: np.ndarray, labels: list[str], title: str, highlight: dict[str, str], cbar_label: str) -> None:
        self.labels = list(labels)
        self.fig.clear()
        self.ax = self.fig.add_subplot(111)
        # aspect "auto": the matrix fills the (tall) panel instead of floating in its middle
        im = self.ax.imshow(m, cmap=self.cmap, vmin=self.vmin, vmax=self.vmax, interpolation="nearest", aspect="auto")
        self.fig.colorbar(im, ax=self.ax, location="bottom", shrink=0.7, aspect=30, label=cbar_label)
        n = len(labels)
        step = max(1, n // 16)
        ticks = list(range(0, n, step))
        for lab in highlight:
            if lab in labels and labels.index(lab) not in ticks:
                ticks.append(labels.index(lab))
        ticks.sort()
        self.ax.set_xticks(ticks, [labels[i] for i in ticks], rotation=90, fontsize=6)
        self.ax.set_yticks(ticks, [labels[i] for i in ticks], fontsize=6)
        for lab, colour in highlight.items():
            if lab not in labels:
                continue
            i = labels.index(lab)
            self.ax.add_patch(Rectangle((-0.5, i - 0.5), n, 1, fill=False, edgecolor=colour, lw=1.5))
            self.ax.add_patch(Rectangle((i - 0.5, -0.5), 1, n, fill=False, edgecolor=colour, lw=1.5))
            for t in self.ax.get_xticklabels() + self.ax.get_yticklabels():
                if t.get_text() == lab:
                    t.set_color(colour)
                    t.set_fontweight("bold")
        self.ax.set_title(title, fontsize=8)
        self.draw_idle()

    def cell_centre(self, row: int, col: int) -> tuple[float, float]:
        """Widget (Qt logical pixel) position of a cell's centre (for tests and automation)."""
        self.draw()
        x, y = self.ax.transData.transform((col, row))
        ratio = self.devicePixelRatioF() or 1.0
        return x / ratio, self.height() - y / ratio

    def _clicked(self, event) -> None:
        if event.inaxes is not self.ax or event.xdata is None or not self.labels:
            return
        col = int(round(event.xdata))
        if 0 <= col < len(self.labels) and self.on_click is not None:
            self.on_click(self.labels[col])


class NoiseCanvas(FigureCanvasQTAgg):
    def __init__(self, parent: QWidget | None = None) -> None:
        self.fig = Figure(figsize=(4, 4), dpi=90, layout="constrained")
        super().__init__(self.fig)
        self.setParent(parent)

    def plot(self, nf: NoiseFloor) -> None:
        self.fig.clear()
        ax = self.fig.add_subplot(111)
        x, y = np.asarray(nf.d_noise), np.asarray(nf.d_condition)
        ax.scatter(x, y, s=18, c="#1f77b4")
        for p, a, b in zip(nf.poses, x, y):
            ax.annotate(p, (a, b), fontsize=6, xytext=(2, 2), textcoords="offset points")
        hi = max(float(x.max(initial=1)), float(y.max(initial=1))) * 1.1
        ax.plot([0, hi], [0, hi], "k--", lw=0.8, label="R_cond/noise = 1")
        # the Transfer API's noise gate: no motion under GATE_LO, the decoder's output untouched over GATE_HI
        ax.plot([0, hi / GATE_LO], [0, hi], ":", color="#d62728", lw=0.9, label=f"R = {GATE_LO:g}: gate closed below")
        ax.plot([0, hi / GATE_HI], [0, hi], ":", color="#2ca02c", lw=0.9, label=f"R = {GATE_HI:g}: gate open above")
        ax.set_xlim(0, hi)
        ax.set_ylim(0, hi)
        ax.set_xlabel("d_noise: two SDF samplings of the posed state", fontsize=7)
        ax.set_ylabel("d_condition: |std(mu_pose) - std(mu_neutral)|", fontsize=7)
        r = nf.ratios
        ax.set_title(f"noise floor of {nf.target} ({len(nf.poses)} poses)\nR_cond/noise mean {r.mean():.2f}, "
                     f"median {np.median(r):.2f}" if len(r) else f"noise floor of {nf.target}", fontsize=7)
        ax.legend(fontsize=6, loc="lower right")
        self.draw_idle()


class HeatmapPanel(QTabWidget):
    """Tabs: identity distances | pose cosines | noise floor. `identity_clicked(id)` on a cell click."""

    identity_clicked = Signal(str)
    noise_requested = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.identity = MatrixCanvas("magma_r", 0.0, None, self)
        self.cosine = MatrixCanvas("RdBu_r", -1.0, 1.0, self)
        self.identity.on_click = self.identity_clicked.emit
        self.cosine.on_click = self.identity_clicked.emit
        noise_page = QWidget(self)
        lay = QVBoxLayout(noise_page)
        self.noise_note = QLabel("The noise floor is computed for the selected held-out identity when this tab is "
                                 "opened (two SDF samplings of 13 posed states; a few seconds).", noise_page)
        self.noise_note.setWordWrap(True)
        self.noise = NoiseCanvas(noise_page)
        lay.addWidget(self.noise_note)
        lay.addWidget(self.noise, 1)
        self.addTab(self.identity, "Identity distance")
        self.addTab(self.cosine, "Pose cosine")
        self.addTab(noise_page, "Noise floor")
        self.currentChanged.connect(lambda i: self.noise_requested.emit() if i == 2 else None)
        self.data: HeatmapData | None = None
        self.noise_target: str | None = None

    def show_data(self, d: HeatmapData) -> None:
        self.data = d
        hl = {d.target: TARGET_COLOUR}
        if d.conditioning:
            hl[d.conditioning] = COND_COLOUR
        cond = f", conditioning {d.conditioning}" if d.conditioning else ""
        self.identity.plot(d.identity_distance, d.ids,
                           f"standardised neutral-latent distance\ntarget {d.target}{cond}\nclick a cell: condition on its column",
                           hl, "distance")
        self.cosine.plot(d.pose_cosine, d.cosine_ids,
                         f"cosine of standardised {d.pose} deltas\n({d.kind}){cond}\nclick a cell: condition on its column",
                         hl, "cosine")

    def show_noise(self, nf: NoiseFloor) -> None:
        self.noise_target = nf.target
        self.noise_note.setText(f"Noise floor of {nf.target}: points above the dashed line carry a pose signal "
                                f"larger than SDF-resampling noise (the paper's R_cond/noise); the dotted lines "
                                f"bound the predictions' noise gate.")
        self.noise.plot(nf)

    def noise_message(self, text: str) -> None:
        self.noise_note.setText(text)
