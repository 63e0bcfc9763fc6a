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

from explorer.results import Failed, HeatmapData, NoiseFloor
from explorer.session import Session

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
        marked = [labels.index(lab) for lab in highlight if lab in labels]
        # every step-th label, and the highlighted ones without a regular label crowding them
        ticks = sorted(set(marked) | {i for i in range(0, n, step) if all(abs(i - j) * 2 >= step for j in marked)})
        self.ax.set_xticks(ticks, [labels[i] for i in ticks], rotation=90, fontsize=7)
        self.ax.set_yticks(ticks, [labels[i] for i in ticks], fontsize=7)
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
        self.ax.set_title(title, fontsize=9)
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
    """R_cond/noise of each pose as a sorted bar, against the noise gate's bounds: one labelled
    row per pose (a scatter of d_noise against d_condition piled the face poses' labels up)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        self.fig = Figure(figsize=(4, 4), dpi=90, layout="constrained")
        super().__init__(self.fig)
        self.setParent(parent)

    def plot(self, nf: NoiseFloor) -> None:
        self.fig.clear()
        ax = self.fig.add_subplot(111)
        r = nf.ratios
        order = np.argsort(r)  # largest at the top
        rs = np.maximum(r[order], 1e-2)
        colours = np.where(rs < GATE_LO, "#d62728", np.where(rs < GATE_HI, "#ff9f1c", "#2ca02c"))
        y = np.arange(len(rs))
        ax.barh(y, rs, left=0, color=colours, height=0.7)
        ax.set_yticks(y, [nf.poses[i] for i in order], fontsize=8)
        ax.set_xscale("log")
        lo = min(0.5, float(rs.min(initial=1)) * 0.8)
        ax.set_xlim(lo, max(10.0, float(rs.max(initial=1)) * 1.3))
        ax.axvline(1.0, color="k", ls="--", lw=0.8, label="R = 1: noise level")
        # the Transfer API's noise gate: no motion under GATE_LO, the prediction untouched over GATE_HI
        ax.axvline(GATE_LO, color="#d62728", ls=":", lw=1.0, label=f"R = {GATE_LO:g}: gate closed below")
        ax.axvline(GATE_HI, color="#2ca02c", ls=":", lw=1.0, label=f"R = {GATE_HI:g}: gate open above")
        hi = ax.get_xlim()[1]
        ax.set_xticks([t for t in (0.5, 1, 2, 5, 10, 20, 50, 100) if lo <= t <= hi])
        ax.xaxis.set_major_formatter("{x:g}")
        ax.xaxis.set_minor_formatter("")
        ax.tick_params(axis="x", labelsize=8)
        ax.set_xlabel("R_cond/noise = d_condition / d_noise", fontsize=8)
        ax.set_title(f"noise floor of {nf.target} ({len(nf.poses)} poses)\nR mean {r.mean():.2f}, "
                     f"median {np.median(r):.2f}" if len(r) else f"noise floor of {nf.target}", fontsize=9)
        self.fig.legend(fontsize=7, loc="outside lower center", ncols=1, frameon=False)  # never over a bar
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
        self.session: Session | None = None

    def bind(self, session: Session) -> None:
        """Draw the session's heatmaps and noise floor as they arrive."""
        self.session = session
        session.events.heatmaps.connect(self.show_data)
        session.events.noise.connect(self.show_noise)
        session.events.failed.connect(self.show_failure)

    @property
    def data(self) -> HeatmapData | None:
        """The heatmaps drawn (the session's)."""
        return None if self.session is None else self.session.heatmap_data

    def show_data(self, d: HeatmapData) -> None:
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
        self.noise_note.setText(f"Noise floor of {nf.target}: poses right of the dashed line carry a pose signal "
                                f"larger than SDF-resampling noise (the paper's R_cond/noise); the dotted lines "
                                f"bound the noise gate of one character's delta (nearest, identity, example). "
                                f"The mean over N training characters has 1/sqrt(N) of that noise.")
        self.noise.plot(nf)

    def show_failure(self, f: Failed) -> None:
        if f.job is NoiseFloor:
            self.noise_message(f"noise floor unavailable: {f.message}")

    def noise_message(self, text: str) -> None:
        self.noise_note.setText(text)
