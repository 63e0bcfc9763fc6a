"""What the user chose (`Selection`), its validation, and the session file (JSON) that stores it (with
the files of the opened meshes and example pairs it names)."""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import NamedTuple

from latent_model.atomic import atomic_write_json
from latent_model.errors import UserFacingError
from explorer.framing import FOCUS_CHOICES
from latent_model.types import (COLOURS, PAIR_KINDS, ColourBy, PairKind, Strategy, check_blend, check_choice,
                                 check_magnitude, parse_strategy)

SESSION_FORMAT = 1


class SessionError(UserFacingError, ValueError):
    """A selection or session file the user gave cannot be used (message says why and what to do)."""


@dataclass
class Selection:
    """Everything the user chose: the state a session file stores."""

    target: str = "id008"
    kind: PairKind = "neutral_to_pose"
    pose: str = "elbowBentLf"
    pose_b: str | None = None
    blend: float = 0.0  # 0 = pose A, 1 = pose B (BLEND_RANGE)
    magnitude: float = 1.0  # scales r_delta (MAGNITUDE_RANGE)
    # mean by default: on held-out bodies it transfers better than a single identity's delta on
    # every broad body pose (README Results)
    strategy: Strategy = "mean_pose_delta"
    colour: ColourBy = "error"  # the user's choice; an opened mesh has no truth and shows displacement
    compare: bool = False
    wireframe: bool = False
    # an example pair the session holds (its name): its delta conditions pose A instead of the pose's;
    # None = the pose list and the strategy condition it
    example: str | None = None
    # what the views frame: "auto" (what the pose moves, close up when it is small), "body", "head", "hand_left",
    # "hand_right" (explorer/framing.py)
    focus: str = "auto"

    def to_dict(self) -> dict:
        return asdict(self)

    def checked(self) -> "Selection":
        """This selection with its numbers as floats and every bound and name checked (SessionError)."""
        try:
            return replace(self, blend=check_blend(self.blend), magnitude=check_magnitude(self.magnitude),
                           strategy=parse_strategy(self.strategy), colour=check_choice("colour", self.colour, COLOURS),
                           kind=check_choice("pair kind", self.kind, PAIR_KINDS),
                           focus=check_choice("focus", self.focus, FOCUS_CHOICES))
        except ValueError as e:
            raise SessionError(str(e)) from None

    @staticmethod
    def from_dict(d: dict) -> "Selection":
        if not isinstance(d, dict):
            raise SessionError("a selection must be a JSON object")
        names = {f.name for f in fields(Selection)}
        unknown = set(d) - names
        if unknown:
            raise SessionError(f"unknown selection fields {sorted(unknown)}; valid: {sorted(names)}")
        return Selection(**d).checked()


class SavedSession(NamedTuple):
    """A session file's content."""

    selection: Selection
    meshes: dict[str, str]  # opened mesh name -> its file
    examples: dict[str, tuple[str, str]]  # example pair name -> (file of A, file of A1)


def save_session(path: str | Path, sel: Selection, meshes: dict[str, str] | None = None,
                 examples: dict[str, tuple[str, str]] | None = None) -> Path:
    """Write the selection (and the paths of opened meshes and example pairs) as JSON, atomically."""
    return atomic_write_json(path, {"format": SESSION_FORMAT, "selection": sel.to_dict(), "meshes": meshes or {},
                                    "examples": {k: list(v) for k, v in (examples or {}).items()}})


def read_session(path: str | Path) -> SavedSession:
    """(selection, {mesh name: file path}, {example name: (file of A, file of A1)}) of a session file
    (files written before example pairs existed have none)."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise SessionError(f"{path}: no such session file") from None
    except (OSError, ValueError) as e:
        raise SessionError(f"{path}: not a readable session JSON ({e})") from None
    if not isinstance(d, dict) or d.get("format") != SESSION_FORMAT:
        raise SessionError(f"{path}: not an explorer session (format {SESSION_FORMAT} expected)")
    try:
        examples = {str(k): (str(v[0]), str(v[1])) for k, v in dict(d.get("examples", {})).items()}
        return SavedSession(Selection.from_dict(d["selection"]), dict(d.get("meshes", {})), examples)
    except SessionError as e:
        raise SessionError(f"{path}: {e}") from None
    except (KeyError, TypeError, IndexError, ValueError) as e:
        raise SessionError(f"{path}: broken session file ({e})") from None
