"""One dataset sequence prepared for DeepWrinkles: its template rig, control vectors, registered
global shapes and normal maps (the data side of ``learn.methods.deepwrinkles``)."""

from __future__ import annotations

import functools
from collections.abc import Mapping

import numpy as np

from learn.deepwrinkles.global_shape import RegistrationSettings, normalise, pose, registrations
from learn.deepwrinkles.normal_maps import DetailMaps
from learn.deepwrinkles.registrations import sequence_rig

GARMENT_KEYS = (
    "fine/faces",
    "fine/uvs",
    "fine/uv_faces",
    "fine/rest_vertices",
    "coarse/rest_vertices",
    "coarse/faces",
    "coarse/uvs",
    "coarse/uv_faces",
)
"""The garment arrays a prediction needs (a checkpoint keeps them, ``fine/face_layers`` too where
the data stores it)."""
STATE_GARMENT_KEYS = (*GARMENT_KEYS, "fine/face_layers")
"""What a checkpoint keeps of its garment (``fine/face_layers`` where the data stores it)."""
BODY_KEYS = ("body/betas", "body/poses", "body/trans", "body/joints")
KEYS = (*GARMENT_KEYS, "fine/vertices", *BODY_KEYS)
"""The arrays a prepared sequence reads (``fine/vertices`` for training only)."""


def sequence_fps(sf, manifest_config: Mapping) -> float:
    """Frame rate of a sequence: its provenance's, else the generator config's, else 30."""
    try:
        fps = sf.json("provenance").get("config", {}).get("fps")
    except (KeyError, ValueError, AttributeError):
        fps = None
    return float(fps or manifest_config.get("fps") or 30.0)


class PreparedSequence:
    """A sequence's rig, control vectors and maps operator (and, for training, its registered,
    normalised global shapes).

    Args:
        seq: the sequence's arrays (``KEYS``).
        body: its ``BodyModel``.
        fps: frame rate of the control vectors' finite differences.
        resolution: normal-map side [px].
        device: Warp device.
    """

    def __init__(
        self, seq: Mapping[str, np.ndarray], body, fps: float, resolution: int, *, device: str | None = None
    ):
        from learn.deepwrinkles.regression import control_vectors

        self.seq = seq
        self.body = body
        self.rig = sequence_rig(seq, body)
        self.reference_rest = np.asarray(seq["coarse/rest_vertices"], np.float32)
        self.controls = control_vectors(np.asarray(seq["body/poses"]), np.asarray(seq["body/trans"]), fps)
        self.normalised: np.ndarray | None = None
        self._resolution, self._device = resolution, device

    @functools.cached_property
    def maps(self) -> DetailMaps:
        """The sequence's normal-map operator (made on first use: registering needs none)."""
        return DetailMaps(self.seq, self._resolution, device=self._device)

    def use_maps(self, maps: DetailMaps) -> None:
        """Take ``maps``, an operator of the same garment layout made before, as ``self.maps``."""
        self.__dict__["maps"] = maps

    @property
    def frames(self) -> int:
        return int(self.controls.shape[0])

    def register(
        self, sf, settings: RegistrationSettings, *, device: str | None = None, progress=None
    ) -> None:
        """Registered frames of the sequence, pose- and shape-normalised (``self.normalised``)."""
        reg = registrations(sf, self.seq, self.body, settings, device=device, progress=progress, rig=self.rig)
        self.normalised = normalise(self.rig, self.reference_rest, reg, self.frames)

    def posed(self, normalised: np.ndarray) -> np.ndarray:
        """World template positions (T, Vc, 3) of normalised shapes of every frame (T, Vc, 3)."""
        return pose(self.rig, self.reference_rest, normalised)
