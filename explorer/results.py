"""The typed results the explorer's jobs return and its views draw: a selection's pair, predictions and
view states, heatmap data, the noise floor, and the outcomes of opening, exporting, failing (`Loaded`,
which carries the session itself, lives in session.py)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from latent_model.types import ColourBy, PairKind

from explorer.selection import Selection

ERROR_RANGE_MM = (0.0, 40.0)  # fixed colour range of per-vertex error (shared by every prediction view)
DISPLACEMENT_RANGE_MM = (0.0, 80.0)  # fixed colour range of |prediction - source|
STRATEGY_LABELS = {"mean_pose_delta": "mean pose delta", "nearest_identity_delta": "nearest identity delta"}


@dataclass(frozen=True)
class PairRef:
    """A selection's pair, derived once: the source and goal states of a held-out target, or an
    opened mesh (its own source, no goal)."""

    target: str
    kind: PairKind
    pose: str
    component: str | None  # source_to_combo: the component the combo starts from
    source: tuple | None  # (pose or None, variant) of the source state; None for an opened mesh
    goal: tuple | None  # (pose, variant) of the ground-truth state; None for an opened mesh

    @property
    def cache_key(self) -> tuple:
        return (self.target,) + (self.source or ())


# ----------------------------------------------------------------------------- results
@dataclass
class Prediction:
    """One prediction: model-frame arrays, all (V, 3) / (V,), with its error against the truth."""

    strategy: str
    label: str  # conditioning source: "mean" or an identity id
    vertices: np.ndarray
    error_mm: np.ndarray | None  # (V,) |pred - truth| in mm, None without truth
    displacement_mm: np.ndarray  # (V,) |pred - source| in mm
    normals: np.ndarray | None = None  # (V, 3) unit vertex normals for shading (computed off the UI thread)
    gate: float = 1.0  # the Transfer API's noise gate (1 = the predictor's output untouched)
    signal: float = float("inf")  # conditioning delta / latent noise floor

    @property
    def title(self) -> str:
        name = STRATEGY_LABELS.get(self.strategy, "identity " + self.strategy.split(":", 1)[-1])
        cond = f" ({self.label})" if self.strategy != "mean_pose_delta" and not self.strategy.startswith("identity:") else ""
        what, mm = ("error", self.error_mm) if self.error_mm is not None else ("displacement", self.displacement_mm)
        text = f"{name}{cond}\n{what} mean {mm.mean():.1f} mm\n{what} max {mm.max():.1f} mm"
        if self.gate < 1.0:
            text += f"\nnoise gate {self.gate:.2f}: delta {self.signal:.1f}x noise floor"
        return text


@dataclass
class ViewState:
    """What the three (or, comparing, four) views show for a selection."""

    selection: Selection
    pair: PairRef
    faces: np.ndarray  # (F, 3)
    source: np.ndarray  # (V, 3)
    truth: np.ndarray | None  # (V, 3) or None (an opened mesh has no ground truth)
    truth_title: str
    predictions: list[Prediction]  # one, or mean + nearest when comparing
    seconds: float = 0.0  # time the session took to compute it
    seconds_predict: float = 0.0  # of which inside Transfer.predict

    @property
    def target(self) -> str:
        return self.selection.target

    @property
    def prediction(self) -> Prediction:
        return self.predictions[0]

    @property
    def colour(self) -> ColourBy:
        """What colours the prediction: the user's choice, or displacement when there is no truth."""
        return "displacement" if self.truth is None else self.selection.colour

    @property
    def conditioning(self) -> str | None:
        """The identity whose delta conditioned the (first) prediction, if one did."""
        lab = self.prediction.label
        return None if lab in ("mean", "oracle") else lab


@dataclass(frozen=True)
class HeatmapRequest:
    """The heatmaps a shown prediction needs (the window starts their job)."""

    selection: Selection
    conditioning: str | None

    @property
    def key(self) -> tuple:
        s = self.selection
        return s.target, s.kind, s.pose, self.conditioning


@dataclass
class HeatmapData:
    ids: list[str]  # row/column labels (training identities, then the target if it is not one)
    identity_distance: np.ndarray  # (n, n) standardised neutral-latent distances
    cosine_ids: list[str]  # training identities with a delta for the pose
    pose_cosine: np.ndarray  # (m, m) cosine of standardised deltas
    pose: str
    kind: str
    target: str
    conditioning: str | None

    @property
    def key(self) -> tuple:
        return self.target, self.kind, self.pose, self.conditioning


@dataclass
class NoiseFloor:
    """Per pose of one target: d_condition = |std(mu_pose) - std(mu_neutral)| and d_noise =
    |std(mu_pose, sampling a) - std(mu_pose, sampling b)| (two SDF resamplings of the same state)."""

    target: str
    poses: list[str] = field(default_factory=list)
    d_condition: list[float] = field(default_factory=list)
    d_noise: list[float] = field(default_factory=list)

    @property
    def ratios(self) -> np.ndarray:
        return np.asarray(self.d_condition) / (np.asarray(self.d_noise) + 1e-6)


@dataclass(frozen=True)
class Predicted:
    """A prediction computed for a request made at `requested` (time.perf_counter())."""

    state: ViewState
    requested: float


@dataclass(frozen=True)
class MeshOpened:
    name: str  # its name among the targets
    path: str
    summary: str  # one line for the status bar


@dataclass(frozen=True)
class Exported:
    path: Path


@dataclass(frozen=True)
class Failed:
    """A job that raised: `job` is the type of result it would have returned (Predicted for a
    prediction), `subject` what it worked on (an opened mesh's path) when that matters."""

    job: type
    message: str
    subject: str | None = None
