"""What the views frame: the whole character, or a close-up of the part a pose moves.

A brow, a mouth corner or a finger moves a few millimetres to centimetres: at full-body scale nothing shows. With
the focus on "what moves" (the default) every change of character, pose or conditioning frames the part that moves
in the truth (or, without one, in the prediction) when it is small, and the whole body when it is not; when nothing
moves (a face pose the noise gate zeroes on an opened mesh), the pose's own region. The user can also pin the
focus on the head or a hand, located on the surface of any humanoid in any rest pose (`surface.detail_regions`).
The views share one camera, so an example pair's A and A1 are drawn shifted to put their own framed part where the
target's is (`example_offset`): a close-up of the target's hand shows the example's hand too.
Qt-free: the session computes a `Framing` with each view state; the views apply it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from latent_model.corpus.poses import get_pose

FOCUS_CHOICES = ("auto", "body", "head", "hand_left", "hand_right")
FOCUS_LABELS = {"auto": "What moves", "body": "Whole body", "head": "Head", "hand_left": "Left hand",
                "hand_right": "Right hand"}
MOVING_MM = 1.0  # a vertex moves when it moves more than this and more than MOVING_SHARE of the largest motion
MOVING_SHARE = 0.1
CLOSE_UP = 0.2  # what moves is framed close when its box's diagonal is under this share of the height
PAD = 0.35  # a close-up's box grows by this share of its size on each side
REGION_TRIM = 0.05  # of a region's vertices cut at each end of each axis when it is framed (no pad: a narrow view fits by width)
MIN_SIZE = 0.12  # metres: the smallest box a close-up shows (a brow alone would fill the view with a few cm)


@dataclass(frozen=True)
class Framing:
    """A region's name ("body", "head", "hand_left", "hand_right", or "moving" for a close-up of what moves) and
    the box (xmin, xmax, ymin, ymax, zmin, zmax) the camera fits, in the model frame."""

    region: str
    bounds: tuple[float, ...]

    @property
    def label(self) -> str:
        return "what moves" if self.region == "moving" else FOCUS_LABELS[self.region].lower()


def _box(points: np.ndarray, pad: float = 0.0, min_size: float = 0.0, trim: float = 0.0) -> tuple[float, ...]:
    """(xmin, xmax, ymin, ymax, zmin, zmax) of points (N, 3), the `trim` share cut at each end of each axis."""
    lo, hi = np.quantile(points, trim, axis=0), np.quantile(points, 1.0 - trim, axis=0)
    centre, half = (lo + hi) / 2, np.maximum((hi - lo) / 2 * (1 + 2 * pad), min_size / 2)
    return tuple(float(x) for pair in zip(centre - half, centre + half) for x in pair)


def moving_vertices(source: np.ndarray, moved: np.ndarray | None) -> np.ndarray:
    """(V,) bool: the vertices of `source` (V, 3) that `moved` (V, 3) moves (none when it is None)."""
    if moved is None:
        return np.zeros(len(source), bool)
    d = np.linalg.norm(moved - source, axis=1) * 1000.0
    return d > max(MOVING_MM, MOVING_SHARE * float(d.max(initial=0.0)))


def region_of_pose(pose: str | None) -> str:
    """The detail region a pose's name says it moves: a face pose the head, a finger pose its hand; "body" for
    the others, a combination across regions, or a name not in the vocabulary."""
    regions = set()
    for part in (pose or "").split("+"):
        try:
            group = get_pose(part).group
        except (KeyError, ValueError):
            return "body"
        if group == "face":
            regions.add("head")
        elif group == "finger":
            regions.add("hand_right" if part.endswith("Rt") else "hand_left")
        else:
            return "body"
    return regions.pop() if len(regions) == 1 else "body"


def frame(focus: str, source: np.ndarray, regions: Callable[[], dict[str, np.ndarray] | None],
          moved: list[np.ndarray | None], pose: str | None) -> Framing:
    """The framing for a focus choice (FOCUS_CHOICES) of a source mesh (V, 3), given the meshes that show motion,
    first choice first (the truth, then the prediction), and a function giving its detail regions (called only
    when a region is framed: locating them reads the surface; None: not located, the body is framed)."""
    if focus not in FOCUS_CHOICES:
        raise ValueError(f"unknown focus {focus!r}; choose one of {', '.join(FOCUS_CHOICES)}")
    body = Framing("body", _box(source))
    height = float(np.ptp(source[:, 2])) or 1.0
    if focus == "auto":
        for m in moved:
            sel = moving_vertices(source, m)
            if sel.any():
                box = _box(source[sel])
                diagonal = float(np.linalg.norm(np.subtract(box[1::2], box[0::2])))
                if diagonal >= CLOSE_UP * height:
                    return body
                return Framing("moving", _box(source[sel], PAD, MIN_SIZE))
        focus = region_of_pose(pose)
    masks = None if focus == "body" else regions()
    if masks is None or not masks.get(focus, np.zeros(1, bool)).any():
        return body
    # a region reaches from its extremity past the chin or the wrist: its sparse outer rim (the neck and shoulders)
    # would set the box, a head framed 30 cm wide; the densely meshed part sets it
    return Framing(focus, _box(source[masks[focus]], 0.0, MIN_SIZE, REGION_TRIM))


def _centre(box: tuple[float, ...]) -> np.ndarray:
    return np.array([(box[0] + box[1]) / 2, (box[2] + box[3]) / 2, (box[4] + box[5]) / 2])


def example_offset(framing: Framing, neutral: np.ndarray, posed: np.ndarray,
                   regions: Callable[[], dict[str, np.ndarray] | None]) -> np.ndarray:
    """(3,) the shift that puts an example pair's own framed part — its region of that name, or for a close-up of
    what moves what A -> A1 moves — at the centre of the target's framing; zero for the whole body or when the
    example has no such part (`regions`: A's detail regions, called only for a region)."""
    if framing.region == "body":
        return np.zeros(3)
    if framing.region == "moving":
        sel = moving_vertices(neutral, posed)
    else:
        masks = regions()
        sel = None if masks is None else masks.get(framing.region)
    if sel is None or not np.any(sel):
        return np.zeros(3)
    return _centre(framing.bounds) - _centre(_box(np.asarray(neutral)[sel], trim=REGION_TRIM))
