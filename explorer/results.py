"""The typed results the explorer's jobs return and its views draw: a selection's pair, an example pair,
predictions and view states, heatmap data, the noise floor, and the outcomes of opening, exporting,
failing (`Loaded`, which carries the session itself, lives in session.py)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from latent_model.corpus.pairs import source_state_label
from latent_model.meshio import UserMesh
from latent_model.types import ColourBy, PairKind

from explorer.framing import Framing
from explorer.selection import Selection

if TYPE_CHECKING:  # the results only carry a Novelty: importing the Transfer API (torch) is the session's job
    from latent_model.transfer import BodyReading, Novelty

ERROR_RANGE_MM = (0.0, 40.0)  # colour range of per-vertex error for body motion (shared by every prediction view)
DISPLACEMENT_RANGE_MM = (0.0, 80.0)  # colour range of |prediction - source| for body motion
# finer ranges for small motion (a face pose, a corrective): the displacement range is the smallest of these holding
# the motion's 99th percentile, the error range half of it, so a 3 mm crease is not drawn in the colour of 0
DISPLACEMENT_STEPS_MM = (5.0, 10.0, 20.0, 40.0, 80.0)
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


@dataclass(frozen=True, eq=False)  # compared by identity: the arrays are large and a pair is opened once
class ExamplePair:
    """An example pair the session holds: a character's mesh A and the same mesh deformed, A1 (both in the
    model frame, A1 in A's frame), and the latent delta mu(A1) - mu(A) that conditions a prediction in
    place of a pose's delta, and what its body motion reads as. Encoding and reading are the slow part, so they
    are done once, when it is opened."""

    name: str  # its key among the session's example pairs: "A.obj → A1.obj"
    neutral: UserMesh  # A
    posed: UserMesh  # A1: A's vertices and triangles, deformed
    delta: np.ndarray  # (Z,) raw latent delta mu(A1) - mu(A)
    paths: tuple[str, str]  # the files of A and A1 (saved in session files)
    stamp: tuple  # the files' (size, mtime) when read: the same files unchanged are not encoded again
    novelty: Novelty | None = None  # how far A is from the training states (None: the bank has no threshold)
    detail: dict[str, np.ndarray] | None = None  # {region: delta} for the local detail stage (None: no stage)
    body: BodyReading | None = None  # its body motion read as the vocabulary's poses (Transfer.example_body)

    @property
    def label(self) -> str:
        return f"example: {self.name}"

    def warning(self) -> str | None:
        """The out-of-distribution warning of A, if its latent is beyond the validated range."""
        return None if self.novelty is None else self.novelty.warning(f"the example's neutral {self.neutral.name}")


# ----------------------------------------------------------------------------- results
@dataclass
class Prediction:
    """One prediction: model-frame arrays, all (V, 3) / (V,), with its error against the truth."""

    strategy: str  # a Strategy, or "example" when an example pair's delta conditioned pose A
    label: str  # conditioning source: "mean", an identity id, or the example pair's name
    vertices: np.ndarray
    error_mm: np.ndarray | None  # (V,) |pred - truth| in mm, None without truth
    displacement_mm: np.ndarray  # (V,) |pred - source| in mm
    normals: np.ndarray | None = None  # (V, 3) unit vertex normals for shading (computed off the UI thread)
    gate: float = 1.0  # the Transfer API's noise gate (1 = the predictor's output untouched)
    signal: float = float("inf")  # conditioning delta / latent noise floor
    novelty: Novelty | None = None  # how far the target's latent is from training (None: not judged)
    detail: dict[str, float] = field(default_factory=dict)  # the local detail stage's gate per region it moved
    detail_mix: dict[str, dict[str, float]] = field(default_factory=dict)  # {region: {pose: weight}} it read
    predictor: str = ""  # what the Transfer API predicted with ("correctives", "motion", ...)
    note: str | None = None  # what the user should know about it (a stage that could not run)

    @property
    def is_example(self) -> bool:
        return self.strategy == "example"

    @property
    def title(self) -> str:
        if self.is_example:
            name, cond = f"example: {self.label}", ""
        else:
            name = STRATEGY_LABELS.get(self.strategy, "identity " + self.strategy.split(":", 1)[-1])
            cond = f" ({self.label})" if self.strategy != "mean_pose_delta" and not self.strategy.startswith("identity:") else ""
        what, mm = ("error", self.error_mm) if self.error_mm is not None else ("displacement", self.displacement_mm)
        text = f"{name}{cond}\n{what} mean {mm.mean():.1f} mm\n{what} max {mm.max():.1f} mm"
        if self.predictor == "correctives":
            text += "\ncorrective fields" + ("" if self.gate > 0 else ": none for this pose")
        elif self.gate == 0.0 and self.detail:
            text += "\nbody: no motion (local detail alone)"
        elif self.gate < 1.0:
            text += f"\n{'body ' if self.detail else ''}noise gate {self.gate:.2f}: delta {self.signal:.1f}x its noise"
        if self.detail:
            from latent_model.detail import describe_mix

            text += "\nlocal detail: " + ", ".join(f"{r.replace('_', ' ')}" + (f" gate {g:.2f}" if g < 1.0 else "")
                                                   for r, g in self.detail.items())
            text += "".join(f"\n  {r.replace('_', ' ')} = {describe_mix(m, 2)}" for r, m in self.detail_mix.items() if m)
        if self.note:
            import textwrap

            text += "\n" + "\n".join(textwrap.wrap(self.note, 44))
        if self.novelty is not None and self.novelty.out_of_distribution:
            text += f"\nout of distribution: latent {self.novelty.distance:.1f} > {self.novelty.threshold:.1f}"
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
    example: ExamplePair | None = None  # the example pair that conditioned pose A, if one did
    framing: Framing | None = None  # what the views frame (explorer/framing.py; None: leave the camera alone)
    example_offset: np.ndarray | None = None  # (3,) where the example views draw A and A1 (`framing.example_offset`)
    source_frame: str = ""  # an opened mesh's file frame as read ("cm, Z-up, facing +X"; meshio.Frame.describe)

    @property
    def target(self) -> str:
        return self.selection.target

    @property
    def prediction(self) -> Prediction:
        return self.predictions[0]

    @property
    def source_title(self) -> str:
        """The source view's title: a held-out character's state, or what state an opened mesh is taken to be in."""
        kind = self.selection.kind
        if self.pair.source is not None:
            return f"source: {self.target}" + (f" ({kind})" if kind != "neutral_to_pose" else "")
        frame = f"\nfile: {self.source_frame}" if self.source_frame else ""
        return f"source: {self.target}{frame}\ntaken as {source_state_label(kind, self.pair.pose, self.pair.component)}"

    @property
    def colour(self) -> ColourBy:
        """What colours the prediction: the user's choice, or displacement when there is no truth."""
        return "displacement" if self.truth is None else self.selection.colour

    def colour_range(self, colour: ColourBy) -> tuple[float, float]:
        """(0, max) mm of the prediction views' colours: from the truth's motion (steady while a slider scrubs), or the
        prediction's without a truth (`DISPLACEMENT_STEPS_MM`)."""
        moved = self.truth if self.truth is not None else self.prediction.vertices
        p99 = float(np.percentile(np.linalg.norm(moved - self.source, axis=1), 99)) * 1000.0
        top = next((x for x in DISPLACEMENT_STEPS_MM if x >= p99), DISPLACEMENT_RANGE_MM[1])
        return (0.0, top / 2.0 if colour == "error" else top)

    @property
    def conditioning(self) -> str | None:
        """The identity whose delta conditioned the (first) prediction, if one did."""
        p = self.prediction
        return None if p.is_example or p.label in ("mean", "oracle") else p.label

    @property
    def warnings(self) -> list[str]:
        """Out-of-distribution warnings of what the model read: the target, and the example's neutral."""
        out = [w for p in self.predictions if p.novelty is not None and (w := p.novelty.warning(self.target))]
        if self.example is not None and (w := self.example.warning()):
            out.append(w)
        return list(dict.fromkeys(out))  # compare mode: one target, one warning


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
    kind: PairKind = "neutral_to_pose"  # the pair kind whose source it is taken as (a neutral unless asked otherwise)


@dataclass(frozen=True)
class ExampleOpened:
    """An example pair read and encoded: the session holds it (its prediction follows)."""

    pair: ExamplePair
    subject: str  # `example_subject` of its two paths (what a restored session waits for)
    summary: str  # one line for the status bar


def example_subject(neutral: str | Path, posed: str | Path) -> str:
    """One string naming an example pair's two files (a job's subject, a restore's pending item)."""
    return f"{neutral}\n{posed}"


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
