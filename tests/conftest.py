"""Shared test fixtures: devices to run kernels on, small synthetic bodies."""

from __future__ import annotations

import numpy as np
import pytest


def _devices() -> list[str]:
    from sim.device import warp

    wp = warp()
    devs = ["cpu"]
    if wp.get_cuda_device_count() > 0:
        devs.append("cuda")
    return devs


DEVICES = _devices()


@pytest.fixture(params=["cpu", "cuda"])
def device(request) -> str:
    """Every kernel test runs on each available device (STYLE.md 8); cuda skips when absent."""
    if request.param not in DEVICES:
        pytest.skip("no CUDA device here")
    return request.param


def random_body(num_vertices: int = 400, *, seed: int = 0, posedirs: bool = True, num_betas: int = 8):
    """A random SMPL-structured body (24 joints) for kernel tests: not a human, but every
    array has SMPL's layout and realistic sparsity (few skinning influences per vertex)."""
    from sim.bodies.model import BodyModel
    from sim.types import SMPL_JOINT_NAMES, SMPL_PARENTS

    rng = np.random.default_rng(seed)
    V, J = num_vertices, 24
    vt = rng.normal(size=(V, 3)).astype(np.float32) * 0.3
    w = rng.random((V, J)) ** 6
    w[w < 0.2] = 0.0
    w[np.arange(V), rng.integers(0, J, V)] += 0.5
    w /= w.sum(axis=1, keepdims=True)
    jr = rng.random((J, V))
    jr[jr < 0.95] = 0.0
    jr[:, 0] += 1e-3
    jr /= jr.sum(axis=1, keepdims=True)
    return BodyModel(
        v_template=vt,
        faces=rng.integers(0, V, (2 * V, 3)),
        shapedirs=rng.normal(size=(V, 3, num_betas)) * 0.01,
        posedirs=rng.normal(size=(V, 3, 207)) * 0.01 if posedirs else None,
        j_regressor=jr,
        weights=w,
        parents=SMPL_PARENTS,
        joint_names=SMPL_JOINT_NAMES,
        name="random-test-body",
    )


@pytest.fixture(scope="session")
def sample_dataset(tmp_path_factory):
    """The shipped sample dataset (``wrinkles dataset generate --config sample``), made once per
    test session on CPU (about 2 minutes on 2 cores): 8 sequences of t-shirts and skirts (one
    topology per category), 18 frames each, 64² images."""
    from sim.datasets.config import load_config
    from sim.datasets.generate import generate

    root = tmp_path_factory.mktemp("sample-dataset") / "data"
    summary = generate(load_config("sample"), root, device="cpu")
    assert summary.accepted >= 4, "the sample config should simulate cleanly on CPU"
    return root
