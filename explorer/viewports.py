"""The linked 3D views: Source | Prediction (| second prediction when comparing) | Ground truth, or,
while an example pair conditions the prediction, Example A | Example A1 | Source | Prediction: the
analogy A → A1 as source → prediction, read left to right (there is no ground truth for the example's
deformation of the target, so its view makes room for the pair).

One shared camera (moving one view moves all), front/side/reset views of what the focus frames (the whole body, or a
close-up of the head, a hand, or what the pose moves: explorer/framing.py), wireframe, the prediction
coloured by per-vertex error against the truth (fixed shared range, colour bar) or by displacement
magnitude. Updates set points/scalars in place (no actor rebuild) so scrubbing stays fast.
"""
from __future__ import annotations

import textwrap

import numpy as np
import pyvista as pv
from pyvistaqt import QtInteractor
from PySide6.QtCore import QPoint, Qt
from PySide6.QtGui import QImage, QPainter, QPixmap
from PySide6.QtWidgets import QHBoxLayout, QWidget

from latent_model.corpus.sdf import vertex_normals

from explorer.framing import Framing
from explorer.results import ViewState
from explorer.session import Session

EXAMPLE_VIEWS = ("example_neutral", "example_posed")
TARGET_VIEWS = ("source", "prediction", "prediction_b", "truth")
VIEW_NAMES = EXAMPLE_VIEWS + TARGET_VIEWS  # left to right
BACKGROUND = "#2b2f36"
SKIN = "#d9c3b0"
TRUTH = "#b7cbd9"
EXAMPLE_POSED = "#b5d6b2"  # A1: neither the source's skin nor the truth's blue
TITLE_PX = 12  # view titles: a fixed pixel size (pyvista's corner annotations shrink with the view)
TITLE_PX_NARROW = 11  # when four views share the width (compare, example pair)
GLYPH_EM = 0.58  # VTK's title font: a glyph is up to ~0.56 of the pixel size wide (lower-case words, digits)


def _poly(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> pv.PolyData:
    f = np.hstack([np.full((len(faces), 1), 3, np.int64), faces.astype(np.int64)]).ravel()
    poly = pv.PolyData(np.asarray(vertices, np.float32), f)
    _set_geometry(poly, vertices, normals)
    return poly


def _set_geometry(poly: pv.PolyData, vertices: np.ndarray, normals: np.ndarray) -> None:
    """Points and their shading normals, in place. We hand VTK the normals (computed with numpy,
    for predictions in the model thread) instead of pyvista's smooth-shading filter, which re-runs
    a Python normals pipeline on the UI thread at every render of a changed mesh."""
    poly.points = vertices
    poly.point_data.set_array(np.asarray(normals, np.float32), "Normals")
    poly.point_data.active_normals_name = "Normals"


def _add_smooth(plotter: QtInteractor, poly: pv.PolyData, **kw):
    actor = plotter.add_mesh(poly, smooth_shading=False, **kw)
    actor.prop.interpolation = "gouraud"  # per-vertex normals given: smooth without the filter
    return actor


def _same_offset(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.allclose(a, b))


class ViewPanel(QWidget):
    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        lay = QHBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.setSpacing(2)
        self.plotters: dict[str, QtInteractor] = {}
        for name in VIEW_NAMES:
            p = QtInteractor(self, auto_update=False)
            p.set_background(BACKGROUND)
            p.enable_anti_aliasing("fxaa")
            lay.addWidget(p, 1)
            self.plotters[name] = p
        first = self.plotters["source"]
        for name in VIEW_NAMES:
            if name != "source":
                first.link_views_across_plotters(self.plotters[name])
        for p in self.plotters.values():  # shared camera: redraw the others after an interaction
            p.iren.add_observer("InteractionEvent", self._sync_others)
        for name in ("prediction_b",) + EXAMPLE_VIEWS:
            self.plotters[name].setVisible(False)
        self._faces: np.ndarray | None = None
        self._polys: dict[str, pv.PolyData] = {}
        self._actors: dict = {}
        self._texts: dict = {}
        self._mode: tuple | None = None  # (colour, compare, vertices, wireframe, example shown)
        self._range: tuple[float, float] | None = None  # the prediction views' colour range (mm)
        self._example = None  # the ExamplePair drawn in the example views
        self._example_actors: dict = {}
        self._example_offset: np.ndarray | None = None  # the shift A and A1 are drawn with
        self.wireframe = False
        self.state: ViewState | None = None
        self._camera_set = False
        self.framing: Framing | None = None  # what the camera fits (None: the source's bounds)
        self._framed: tuple | None = None  # the selection it was framed for (target, kind, pose, example, focus)
        self._n_views = 3  # visible views (titles wrap to their width)
        self._raw_titles: dict[str, str] = {}

    # -------------------------------------------------------------- drawing
    def _sync_others(self, *args) -> None:
        for p in self.plotters.values():
            p.update()

    def _title(self, name: str, text: str) -> bool:
        """Set a view's title, wrapped to the view's width; True when what it shows changed."""
        self._raw_titles[name] = text
        px = TITLE_PX if self._n_views <= 3 else TITLE_PX_NARROW
        chars = max(12, int(0.95 * self.width() / self._n_views / (px * GLYPH_EM)))
        text = text.replace("→", "->")  # the font VTK embeds has no arrow glyph
        wrapped = "\n".join(textwrap.fill(line, chars) for line in text.split("\n"))
        if name in self._texts:
            t = self._texts[name]
            if t.input == wrapped and t.prop.font_size == px:
                return False
            t.input, t.prop.font_size = wrapped, px
            return True
        t = pv.Text(wrapped, position=(0.03, 0.985))
        t.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
        t.prop.font_size = px
        t.prop.color = "white"
        t.prop.justification_horizontal = "left"
        t.prop.justification_vertical = "top"
        self.plotters[name].add_actor(t, reset_camera=False, name=f"title_{name}", pickable=False, render=False)
        self._texts[name] = t
        return True

    def resizeEvent(self, e) -> None:
        super().resizeEvent(e)
        changed = {n for n, text in list(self._raw_titles.items()) if n in self._texts and self._title(n, text)}
        if changed:
            self.schedule(changed)

    def _build(self, state: ViewState, colour: str) -> None:
        """(Re)create the actors: new topology, colour mode or compare layout."""
        compare = len(state.predictions) > 1
        by_example = state.example is not None
        rng = state.colour_range(colour)
        bar_title = "error vs truth (mm)" if colour == "error" else "displacement (mm)"
        for name in TARGET_VIEWS:
            p = self.plotters[name]
            for title in list(p.scalar_bars.keys()):
                p.remove_scalar_bar(title)
            p.clear_actors()
            self._texts.pop(name, None)
        self._n_views = 2 + compare + (2 if by_example else 1)
        normals = vertex_normals(state.source, state.faces)
        self._polys = {n: _poly(state.source, state.faces, normals) for n in TARGET_VIEWS}
        self._actors = {}
        style = "wireframe" if self.wireframe else "surface"
        self._actors["source"] = _add_smooth(self.plotters["source"], self._polys["source"], color=SKIN, style=style)
        self._actors["truth"] = _add_smooth(self.plotters["truth"], self._polys["truth"], color=TRUTH, style=style)
        for n in ("prediction", "prediction_b"):
            self._polys[n].point_data["values"] = np.zeros(len(state.source), np.float32)
            self._actors[n] = _add_smooth(
                self.plotters[n], self._polys[n], scalars="values", clim=rng,
                cmap="YlOrRd" if colour == "error" else "YlGnBu", style=style, show_scalar_bar=False)
        bar = dict(title=bar_title, n_labels=5, fmt="%.1f" if rng[1] < 10 else "%.0f", vertical=False, position_x=0.15, position_y=0.03,
                   width=0.7, height=0.06, color="white", title_font_size=12, label_font_size=11)
        sb = self.plotters["prediction"].add_scalar_bar(mapper=self._actors["prediction"].mapper, **bar)
        sb.SetTextPositionToPrecedeScalarBar()  # tick labels under the bar, the title over it: they never overlap
        self.plotters["prediction_b"].setVisible(compare)
        self.plotters["truth"].setVisible(not by_example)
        for n in EXAMPLE_VIEWS:
            self.plotters[n].setVisible(by_example)
        self._faces = state.faces
        self._range = rng
        self._mode = (colour, compare, len(state.source), self.wireframe, by_example)
        if not self._camera_set:
            self.set_view("front", render=False)
            self._camera_set = True

    def _draw_example(self, example, offset: np.ndarray | None = None) -> None:
        """Draw an example pair's A and A1 in their views (their own topology: actors made anew), shifted by
        `offset` (3,) so that the shared camera's close-up shows their own framed part (`framing.example_offset`)."""
        self._example, self._example_actors = example, {}
        self._example_offset = None if offset is None else np.asarray(offset, np.float64)
        shift = np.zeros(3) if offset is None else np.asarray(offset, np.float64)
        style = "wireframe" if self.wireframe else "surface"
        for n, mesh, colour, what in zip(EXAMPLE_VIEWS, (example.neutral, example.posed), (SKIN, EXAMPLE_POSED),
                                         ("example A (neutral)", "example A1 (posed)")):
            p = self.plotters[n]
            p.clear_actors()
            self._texts.pop(n, None)
            v = (mesh.vertices + shift).astype(np.float32)
            poly = _poly(v, mesh.faces, vertex_normals(mesh.vertices, mesh.faces))
            self._example_actors[n] = _add_smooth(p, poly, color=colour, style=style)
            self._title(n, f"{what}\n{mesh.name}")

    def bind(self, session: Session) -> None:
        """Draw each prediction the session shows."""
        session.events.state.connect(self.show_state)

    def show_state(self, state: ViewState) -> None:
        """Put a prediction on screen (in place when the topology and layout are unchanged)."""
        colour = state.colour
        compare = len(state.predictions) > 1
        rebuilt = False
        if (self._faces is None or self._faces is not state.faces and not np.array_equal(self._faces, state.faces)
                or self._mode != (colour, compare, len(state.source), self.wireframe, state.example is not None)
                or self._range != state.colour_range(colour)):  # the colour bar's labels follow the range
            self._build(state, colour)
            rebuilt = True
        prev, self.state = self.state, state
        # only views whose content changed are re-rendered (scrubbing touches the prediction only)
        dirty = {"prediction", "prediction_b"}
        src_title = state.source_title
        if not rebuilt and (prev is None or prev.source is not state.source or prev.target != state.target):
            _set_geometry(self._polys["source"], state.source, vertex_normals(state.source, state.faces))
            dirty.add("source")
        if self._title("source", src_title):
            dirty.add("source")
        if rebuilt or prev is None or prev.truth is not state.truth:
            truth_actor = self._actors["truth"]
            if state.truth is not None:
                _set_geometry(self._polys["truth"], state.truth, vertex_normals(state.truth, state.faces))
                truth_actor.visibility = True
            else:
                truth_actor.visibility = False
            dirty.add("truth")
        if self._title("truth", state.truth_title):
            dirty.add("truth")
        if rebuilt:
            dirty.add("source")
        key = (state.target, state.selection.kind, state.selection.pose, state.selection.example,
               state.selection.focus)
        if state.framing is not None and (key != self._framed or not self._camera_set):
            # a new character, pose or focus is framed; scrubbing a slider or switching conditioning keeps the camera
            self._framed, self.framing = key, state.framing
            self.set_view("reset", render=False)
            self._camera_set = True
            dirty.update(TARGET_VIEWS + EXAMPLE_VIEWS)
        moved_example = not _same_offset(state.example_offset, self._example_offset)
        if state.example is not None and (state.example is not self._example or moved_example):
            self._draw_example(state.example, state.example_offset)
            dirty.update(EXAMPLE_VIEWS)
        for n, pred in zip(("prediction", "prediction_b"), state.predictions + [None]):
            if pred is None:
                continue
            poly = self._polys[n]
            normals = pred.normals if pred.normals is not None else vertex_normals(pred.vertices, state.faces)
            _set_geometry(poly, pred.vertices, normals)
            vals = pred.error_mm if (colour == "error" and pred.error_mm is not None) else pred.displacement_mm
            poly.point_data["values"][:] = vals.astype(np.float32)
            poly.point_data["values"].Modified() if hasattr(poly.point_data["values"], "Modified") else None
            poly.Modified()
            self._title(n, pred.title)
        self.schedule(dirty)

    def render(self, which: set[str] | None = None) -> None:
        """Render now (before a screenshot or a camera change)."""
        for n, p in self.plotters.items():
            if p.isVisible() and (which is None or n in which):
                p.render()

    def schedule(self, which: set[str] | None = None) -> None:
        """Render at the next Qt paint. A direct render() here is followed by the widget's own
        paintEvent render anyway, so scrubbing paid for every frame twice (measured: 2 x 16 ms)."""
        for n, p in self.plotters.items():
            if p.isVisible() and (which is None or n in which):
                p.update()

    def on_rendered(self, name: str, callback) -> None:
        """Call `callback()` after each finished render of view `name` (the moment it is on screen)."""
        self.plotters[name].ren_win.AddObserver("EndEvent", lambda *_: callback())

    # -------------------------------------------------------------- camera, style
    def set_view(self, which: str, render: bool = True) -> None:
        """front: looking at the character's face (from -Y); side: from its left (+X); reset: the current direction.
        Each fits what the focus frames (`framing`; the whole source without one)."""
        p = self.plotters["source"]
        cam = p.camera
        if "source" in self._polys:
            bounds = self.framing.bounds if self.framing is not None else self._polys["source"].bounds
        else:
            bounds = (-1.0, 1.0, -1.0, 1.0, -1.0, 1.0)
        if which in ("front", "side"):
            c = np.array([(bounds[0] + bounds[1]) / 2, (bounds[2] + bounds[3]) / 2, (bounds[4] + bounds[5]) / 2])
            d = np.array([0.0, -1.0, 0.0]) if which == "front" else np.array([1.0, 0.0, 0.0])
            cam.focal_point = tuple(c)
            cam.position = tuple(c + 4.0 * d)
            cam.up = (0.0, 0.0, 1.0)
        p.reset_camera(render=False, bounds=bounds)
        p.renderer.ResetCameraClippingRange()  # fitted to a region: clip by every actor, not by the region alone
        cam.zoom(1.35 if self.framing is None or self.framing.region == "body" else 1.15)
        if render:
            self.render()

    def set_wireframe(self, on: bool) -> None:
        self.wireframe = on
        for a in list(self._actors.values()) + list(self._example_actors.values()):
            a.prop.style = "wireframe" if on else "surface"
        if self._mode is not None:
            self._mode = self._mode[:3] + (on,) + self._mode[4:]
        self.render()

    # -------------------------------------------------------------- images
    def view_images(self) -> dict[str, np.ndarray]:
        """(H, W, 3) uint8 renders of the visible views."""
        return {n: p.screenshot(None, return_img=True) for n, p in self.plotters.items() if p.isVisible()}

    def paint_into(self, pixmap: QPixmap, top: QWidget) -> QPixmap:
        """Paint the rendered views over a grab of `top` (Qt cannot grab OpenGL views itself)."""
        painter = QPainter(pixmap)
        ratio = pixmap.devicePixelRatio()
        for n, p in self.plotters.items():
            if not p.isVisible():
                continue
            img = np.ascontiguousarray(p.screenshot(None, return_img=True)[:, :, :3])
            h, w, _ = img.shape
            q = QImage(img.data, w, h, 3 * w, QImage.Format.Format_RGB888).copy()
            pos = p.mapTo(top, QPoint(0, 0))
            target = q.scaled(int(p.width() * ratio), int(p.height() * ratio), Qt.AspectRatioMode.IgnoreAspectRatio,
                              Qt.TransformationMode.SmoothTransformation)
            painter.drawImage(pos, target)
        painter.end()
        return pixmap

    def close_plotters(self) -> None:
        for p in self.plotters.values():
            p.close()
