"""Checkpoints of format 1 (before the pose fields had their own module), read by upgrading them.

Format 1 stored a flat `ModelConfig` (decoder fields prefixed `vd_`) and kept the pose fields'
buffers under `vertex_decoder.`. Format 2 nests `decoder` and `fields` and stores the fields under
`pose_fields.` (`readouts` was `proto_fields`). Only the design that shipped is readable: a format-1
checkpoint trained with an unshipped switch (bilinear basis, whitening, no prototypes) is refused.
"""
from __future__ import annotations

import math

# format-1 `vd_` field -> (section, format-2 field)
_V1_FIELDS = {
    "vd_fourier": ("decoder", "fourier"), "vd_hidden": ("decoder", "hidden"), "vd_cond": ("decoder", "cond"),
    "vd_bones": ("decoder", "bones"), "vd_knn": ("decoder", "knn"), "vd_edge": ("decoder", "edge"),
    "vd_stages": ("decoder", "stages"),
    "vd_proto_fields": ("fields", "features"), "vd_rff_sigma": ("fields", "rff_sigma"),
    "vd_rff_seed": ("fields", "rff_seed"), "vd_proto_temp": ("fields", "proto_temp"),
    "vd_coef_max": ("fields", "coef_max"), "vd_fit_ridge": ("fields", "fit_ridge"),
    "vd_fit_vertices": ("fields", "fit_vertices"), "vd_fit_kinds": ("fields", "fit_kinds"),
    "vd_fields_only_kinds": ("fields", "only_kinds"),
}
_V1_TENSORS = {"vertex_decoder.prototypes": "pose_fields.prototypes", "vertex_decoder.proto_r": "pose_fields.proto_r",
               "vertex_decoder.rff": "pose_fields.rff", "vertex_decoder.proto_fields": "pose_fields.readouts"}


class LegacyError(ValueError):
    pass


def upgrade_preset_v1(d: dict) -> dict:
    """A format-1 preset dict -> format 2 (raises LegacyError for an unshipped design)."""
    m = dict(d["model"])
    unshipped = []
    if m.get("vd_basis", 0):
        unshipped.append(f"vd_basis={m['vd_basis']}")
    if m.get("vd_whiten", False):
        unshipped.append("vd_whiten")
    if not m.get("vd_prototypes", False) or not m.get("vd_proto_fields", 0):
        unshipped.append("no pose prototypes/fields")
    if not m.get("vd_detail", True):
        unshipped.append("vd_detail=False")
    if not math.isclose(m.get("vd_dir_gain", 1.0), math.sqrt(m["latent"])):
        unshipped.append(f"vd_dir_gain={m.get('vd_dir_gain', 1.0)}")
    if m.get("vd_fit_scaled", True):
        unshipped.append("vd_fit_scaled")
    if unshipped:
        raise LegacyError(f"a format-1 checkpoint of a design that did not ship ({', '.join(unshipped)}); "
                          f"re-train it with this version (`lrr train all --preset ...`)")
    out: dict = {"decoder": {}, "fields": {}}
    for k, v in m.items():
        if k in _V1_FIELDS:
            section, name = _V1_FIELDS[k]
            out[section][name] = v
        elif not k.startswith("vd_") and k != "n_pair_kinds":
            out[k] = v
    return {**d, "model": out}


def upgrade_tensors_v1(tensors: dict) -> dict:
    """Format-1 state-dict keys -> format 2 (the same tensors)."""
    return {_V1_TENSORS.get(k, k): v for k, v in tensors.items()}
