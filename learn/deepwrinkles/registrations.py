"""DeepWrinkles' registered frames from simulated sequences (Lähner et al. 2018, Sec. 3.1).

The paper registers one garment template to every frame of a 4D scan. Here a sequence's fine
simulated garment plays the scanned garment: each frame is seen by the virtual camera ring of
``sim.scans.scanner`` (the body occluding it, sensor noise, holes, marked borders, no
correspondence), and the template — the sequence's coarse garment, one topology for every
sequence of a reference-fit dataset — is registered to that point cloud
(``sim.scans.registration``, Eq. 1-2). The template starts each frame skinned to the frame's
body pose (linear blend skinning with weights from the nearest body vertices); with ``tracking``
it starts from the previous frame's registration moved by the skinning's change between the two
frames, as a tracker of a 4D sequence does.

The simulation gives the truth the paper lacks: each template vertex's place on the fine frame,
found through the shared sewing pattern (``sim.garments.correspondence.layout_locations``), so
the registration error is measured, not guessed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from sim.errors import WrinklesInputError

GARMENT_REGISTRATION_SETTINGS = {"cell": 0.06, "rigid": 0.05, "smooth": 0.05, "boundary": 1.0, "edge": 0.3}
"""Registration weights for a coarse garment template and a simulated frame's scan. Measured on
walking t-shirts (334-vertex template, 1,334-vertex fine garment): the paper's weights (500, 500,
10 at a 4 cm grid) keep the data term at 18 mm rms (vertices 15 mm from the surface, 35 mm from
their true places); rigidity 0.05 / 0.05 and border 1 at a 6 cm grid bring them 2 mm from the
surface and 20 mm from their places (no border term: 37 mm on that frame), 3.7x faster than at
4 cm; the edge-length term (0.3) then holds the template's own lengths (edge strain 0.107 against
0.156; the true places' own 0.042) and brings it 18.5 mm from its places at 2.3 mm off the surface,
at three times the solve's cost. What is left is sliding along the surface, which the scan cannot
see."""


def garment_registration():
    """``RegistrationConfig`` with ``GARMENT_REGISTRATION_SETTINGS``."""
    from sim.scans.registration import RegistrationConfig

    return RegistrationConfig(**GARMENT_REGISTRATION_SETTINGS)


@dataclass(frozen=True)
class SequenceRig:
    """A sequence's template and the skinning that poses it.

    Attributes:
        rest: template rest positions [m] (Vc, 3) (``coarse/rest_vertices``).
        faces: template faces (Fc, 3).
        weights: template skinning weights (Vc, J), from the nearest rest-body vertices.
        transforms: bone transforms (T, J, 3, 4), rest pose to each frame's world.
        local: the joints' local rotations (T, J, 3, 3).
    """

    rest: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    transforms: np.ndarray
    local: np.ndarray

    def skinned(self, frames: np.ndarray | None = None) -> np.ndarray:
        """The rest template skinned to frames (all by default): float32 (n, Vc, 3)."""
        from learn.deepwrinkles.subspace import repose

        t = self.transforms if frames is None else self.transforms[np.asarray(frames)]
        return repose(self.rest, self.weights, t)


def sequence_rig(
    seq: Mapping[str, np.ndarray], body, *, garment_betas: np.ndarray | None = None, neighbours: int = 4
) -> SequenceRig:
    """The template rig of a dataset sequence (its ``coarse/*`` and ``body/*`` arrays) on the body
    model it was simulated with.

    A reference-fit garment is built on the body of ``garment_betas`` (None: the mean shape) and
    worn by every shape; its rest template moves to the sequence's shape with the body surface
    (each vertex bound to its closest point of the reference rest body, offset kept in that
    triangle's frame: DeepWrinkles' Eq. 5, the mean shape plus the body's shape offsets).
    """
    from learn.methods.skinned_mlp import pose_transforms
    from sim.dressing import bind_to_surface
    from sim.skinning.transfer import transfer_skinning_weights

    for key in ("coarse/rest_vertices", "coarse/faces", "body/betas", "body/poses", "body/joints"):
        if key not in seq:
            raise WrinklesInputError(
                f"sequence has no {key!r}: DeepWrinkles needs the coarse garment "
                "(a dataset made with coarse twins) and the body"
            )
    betas = np.asarray(seq["body/betas"], np.float32).reshape(-1)
    shaped = body.rest_mesh(betas)
    rest = np.asarray(seq["coarse/rest_vertices"], np.float32)
    ref = body.rest_mesh(garment_betas)
    if not np.allclose(ref, shaped, atol=1e-6):
        rest = bind_to_surface(rest, ref, body.faces, device="cpu").targets(shaped)
    weights = transfer_skinning_weights(rest, shaped, body.weights, k=neighbours)
    A, local = pose_transforms(
        np.asarray(seq["body/poses"], np.float32),
        np.asarray(seq["body/joints"], np.float32),
        body.rest_joints(betas),
        np.asarray(body.parents),
    )
    return SequenceRig(
        rest=rest,
        faces=np.asarray(seq["coarse/faces"], np.int32),
        weights=np.asarray(weights, np.float32),
        transforms=A,
        local=local,
    )


def template_truth(seq: Mapping[str, np.ndarray]):
    """Where each template vertex lies on the fine garment (``SurfaceLocations``): its frames'
    true template positions are ``.evaluate(seq["fine/faces"], seq["fine/vertices"])``."""
    from sim.garments.correspondence import layout_locations

    return layout_locations(
        np.asarray(seq["coarse/faces"]),
        np.asarray(seq["coarse/uvs"]),
        np.asarray(seq["coarse/uv_faces"]),
        np.asarray(seq["fine/uvs"]),
        np.asarray(seq["fine/uv_faces"]),
    )


@dataclass(frozen=True)
class RegisteredSequence:
    """Registrations of a sequence's frames.

    Attributes:
        frames: the registered frame indices (n,).
        vertices: registered template positions [m] (n, Vc, 3).
        truth: the template's true positions on the simulated fine frames [m] (n, Vc, 3).
        pairs: data pairs kept in each frame's last round (n,).
    """

    frames: np.ndarray
    vertices: np.ndarray
    truth: np.ndarray
    pairs: np.ndarray

    def errors(self) -> np.ndarray:
        """Per frame and template vertex, the distance [m] to the truth (n, Vc)."""
        return np.linalg.norm(self.vertices - self.truth, axis=-1)


def register_sequence(
    seq: Mapping[str, np.ndarray],
    body,
    *,
    frames=None,
    scan_config=None,
    registration_config=None,
    tracking: bool = True,
    seed: int = 0,
    device: str | None = None,
    progress: Callable[[int], None] | None = None,
    rig: SequenceRig | None = None,
) -> RegisteredSequence:
    """Scan and register frames of a dataset sequence (module docstring).

    Args:
        seq: the sequence's arrays (``fine/*``, ``coarse/*``, ``body/*``).
        body: its ``BodyModel`` (the occluder and the template's skinning).
        frames: frame indices, increasing (all by default).
        scan_config, registration_config: ``ScanConfig`` / ``RegistrationConfig`` (defaults:
            ``ScanConfig()``, ``garment_registration()``).
        tracking: start each frame from the previous registered frame (when it is the one just
            before), else from the skinned template.
        seed: the scans' noise; frame t uses ``seed + t``.
        device: Warp device of the scans and skinning; a CUDA device also solves the registration's
            normal equations (dense Cholesky, torch).
        progress: called with 1 after each frame.
        rig: the sequence's ``sequence_rig`` when the caller has it.
    """
    from sim.device import resolve_device
    from sim.scans.registration import register
    from sim.scans.scanner import scan_garment

    rig = rig or sequence_rig(seq, body)
    T = rig.transforms.shape[0]
    where = resolve_device(device)
    solve_device = where if where.startswith("cuda") else None
    idx = np.arange(T) if frames is None else np.asarray(frames, np.int64)
    if idx.size == 0 or idx.min() < 0 or idx.max() >= T or np.any(np.diff(idx) <= 0):
        raise WrinklesInputError(f"register_sequence: frames must increase within [0, {T - 1}]")
    betas = np.asarray(seq["body/betas"], np.float32).reshape(-1)[: body.num_betas]
    fine = np.asarray(seq["fine/vertices"])
    fine_faces = np.asarray(seq["fine/faces"], np.int32)
    joints = np.asarray(seq["body/joints"], np.float64)
    skinned = rig.skinned(idx)
    out = np.empty((len(idx), *rig.rest.shape), np.float32)
    pairs = np.zeros(len(idx), np.int64)
    poses, trans = np.asarray(seq["body/poses"])[idx], np.asarray(seq["body/trans"])[idx]
    posed = body.pose(betas, poses, trans, device=device)  # the occluding body of every frame at once
    for i, t in enumerate(idx):
        scan = scan_garment(
            fine[t],
            fine_faces,
            joints[t, 0],
            body_vertices=posed.vertices[i],
            body_faces=posed.faces,
            config=scan_config,
            seed=seed + int(t),
            device=device,
        )
        start = skinned[i]
        if tracking and i > 0 and idx[i - 1] == t - 1:
            start = out[i - 1] + skinned[i] - skinned[i - 1]
        reg = register(start, rig.faces, scan, config=registration_config or garment_registration(),
                       solve_device=solve_device)
        out[i], pairs[i] = reg.vertices, reg.pairs
        if progress is not None:
            progress(1)
    truth = template_truth(seq).evaluate(fine_faces, fine[idx])
    return RegisteredSequence(frames=idx, vertices=out, truth=truth, pairs=pairs)
