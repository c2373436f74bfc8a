"""DeepWrinkles' conditional GAN (``learn.deepwrinkles.cgan``, Lähner et al. Sec. 4.2, Eq. 4): the
pix2pix U-Net's shapes and levels, the PatchGAN's 70 px patches, the masked loss terms against hand
computations, the separation of the generator's and discriminator's gradients in the one summed
objective, and a tiny network overfitting one batch."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torch import nn

from learn.deepwrinkles.cgan import (
    CGANWeights,
    PatchDiscriminator,
    UNetGenerator,
    adversarial_term,
    cgan_loss,
    data_term,
    patchgan_receptive_field,
    temporal_term,
)
from sim.errors import WrinklesInputError

FLOAT32_RTOL = 1e-5
"""Relative tolerance of float32 results computed in a different order (sums over 1e2-1e4 terms)."""
GRAD_RTOL, GRAD_ATOL = 1e-9, 1e-12
"""Tolerances of float64 gradients of one objective computed along two graphs (round-off only)."""


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """The maps here are tiny: a second intra-op thread only adds synchronisation, which on a busy
    CPU costs more than the arithmetic (scripts/test.sh runs workers with one thread each)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def batch(size: int = 16, n: int = 2, seed: int = 0):
    """LR, HR, previous HR maps (n, 3, size, size) in [-1, 1] and a coverage mask (n, 1, size, size)
    with a different uncovered corner per image."""
    g = torch.Generator().manual_seed(seed)
    lr = torch.rand(n, 3, size, size, generator=g) * 2 - 1
    hr = (lr + 0.3 * torch.randn(n, 3, size, size, generator=g)).clamp(-1, 1)
    hr_prev = (hr + 0.1 * torch.randn(n, 3, size, size, generator=g)).clamp(-1, 1)
    mask = torch.ones(n, 1, size, size)
    mask[0, :, : size // 3, : size // 3] = 0
    mask[-1, :, -size // 4 :, :] = 0
    return lr, hr, hr_prev, mask


def tiny(size: int, *, norm: str = "batch", seed: int = 0):
    torch.manual_seed(seed)
    return (UNetGenerator(filters=4, resolution=size, norm=norm),
            PatchDiscriminator(filters=4, norm=norm))


# --- networks ----------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [32, 64])
@pytest.mark.parametrize("norm", ["batch", "instance"])
def test_generator_and_discriminator_shapes(size, norm):
    g, d = tiny(size, norm=norm)
    lr = batch(size)[0]
    hr = g(lr)
    assert hr.shape == lr.shape
    assert hr.abs().max() <= 1.0  # tanh output
    side = size // 8 - 2  # three stride-2 convolutions, then two 4x4 stride-1 ones with padding 1
    assert d(torch.cat([lr, hr], 1)).shape == (2, 1, side, side)


@pytest.mark.parametrize("size, levels", [(16, 4), (64, 6), (256, 8), (512, 9)])
def test_unet_has_log2_resolution_levels_with_pix2pix_channels(size, levels):
    g = UNetGenerator(filters=4, resolution=size)
    convs = [m for m in g.modules() if isinstance(m, nn.Conv2d)]
    ups = [m for m in g.modules() if isinstance(m, nn.ConvTranspose2d)]
    assert len(convs) == len(ups) == levels
    assert [c.out_channels for c in convs] == [4 * min(2**i, 8) for i in range(levels)]
    dropped = [i for i, level in enumerate(g.up) if any(isinstance(m, nn.Dropout) for m in level)]
    assert dropped == [levels - 3, levels - 2, levels - 1]  # the three innermost decoder levels
    assert not any(isinstance(m, nn.Dropout) for m in UNetGenerator(filters=4, resolution=size,
                                                                      dropout=0.0).modules())


def test_pix2pix_sizes_at_the_papers_settings():
    # pix2pix's unet_256 and basic (n_layers=3) discriminator at 64 filters: 54.414 M and 2.769 M parameters
    g, d = UNetGenerator(), PatchDiscriminator()
    assert sum(p.numel() for p in g.parameters()) == 54_414_531
    assert sum(p.numel() for p in d.parameters()) == 2_768_705


@pytest.mark.parametrize("resolution", [8, 48, 100, 0, 64.0])
def test_bad_resolution_is_refused(resolution):
    with pytest.raises(ValueError, match="power of two"):
        UNetGenerator(filters=4, resolution=resolution)


def test_input_of_the_wrong_size_is_refused():
    g = UNetGenerator(filters=4, resolution=64)
    with pytest.raises(ValueError, match=r"expected \(B, 3, 64, 64\)"):
        g(torch.zeros(1, 3, 32, 32))
    with pytest.raises(WrinklesInputError, match="norm 'group'"):
        UNetGenerator(filters=4, resolution=64, norm="group")


@pytest.mark.parametrize("layers", [1, 2, 3])
def test_patchgan_receptive_field_is_70px_for_three_layers(layers):
    """The input pixels one central output logit depends on, found from its gradient in eval mode
    (batch norm as a fixed affine map), span the analytic receptive field: 70 px for 3 layers."""
    torch.manual_seed(0)
    d = PatchDiscriminator(filters=4, layers=layers).double().eval()
    x = torch.randn(1, 6, 128, 128, dtype=torch.float64, requires_grad=True)
    out = d(x)
    out[0, 0, out.shape[2] // 2, out.shape[3] // 2].backward()
    rows, cols = np.nonzero(x.grad.abs().sum(dim=(0, 1)).numpy())
    assert 0 < rows.min() and rows.max() < 127 and 0 < cols.min() and cols.max() < 127  # not clipped
    extent = (rows.max() - rows.min() + 1, cols.max() - cols.min() + 1)
    assert extent == (patchgan_receptive_field(layers),) * 2
    assert patchgan_receptive_field(3) == 70


def test_patch_weights_leave_out_patches_that_see_no_chart():
    d = PatchDiscriminator(filters=4)
    mask = torch.zeros(1, 1, 128, 128)
    w = d.patch_weights(mask)
    assert w.shape == d(torch.zeros(1, 6, 128, 128)).shape and w.sum() == 0
    mask[0, 0, 64, 64] = 1
    w = d.patch_weights(mask)
    # 1 pixel is inside the 70 px patches of the outputs whose fields reach it: ceil(70/8) or one less
    assert int(w.sum()) in (8 * 8, 8 * 9, 9 * 9)


# --- loss terms --------------------------------------------------------------------------------


def test_eq4_temporal_term_cancels_opposite_changes_and_l1_l2_do_not():
    # one image, one channel; gen - prev = [[1, -1], [0.5, 9]] with the 9 outside the chart
    diff = torch.tensor([[[[1.0, -1.0], [0.5, 9.0]]]])
    prev = torch.zeros_like(diff)
    mask = torch.tensor([[True, True], [True, False]])
    np.testing.assert_allclose(temporal_term(diff, prev, mask, kind="eq4").item(), 0.5 / 3, rtol=FLOAT32_RTOL)
    np.testing.assert_allclose(temporal_term(diff, prev, mask, kind="l1").item(), 2.5 / 3, rtol=FLOAT32_RTOL)
    np.testing.assert_allclose(temporal_term(diff, prev, mask, kind="l2").item(), 2.25 / 3, rtol=FLOAT32_RTOL)


@pytest.mark.parametrize("per_image_mask", [True, False])
def test_temporal_terms_match_a_numpy_computation(per_image_mask):
    rng = np.random.default_rng(3)
    gen, prev = rng.uniform(-1, 1, (2, 2, 3, 5, 4))
    mask = rng.random((2, 1, 5, 4)) < 0.6 if per_image_mask else rng.random((5, 4)) < 0.6
    m = np.broadcast_to(mask if per_image_mask else mask[None, None], (2, 1, 5, 4))
    eq4 = 0.0
    for b in range(2):  # Eq. 4 per image: sum over channels of |sum over masked pixels|, / masked pixels
        per_channel = [abs(sum(gen[b, c, i, j] - prev[b, c, i, j]
                               for i in range(5) for j in range(4) if m[b, 0, i, j])) for c in range(3)]
        eq4 += sum(per_channel) / m[b].sum() / 2
    d = (gen - prev)[np.broadcast_to(m, gen.shape)]
    expected = {"eq4": eq4, "l1": np.abs(d).mean(), "l2": (d**2).mean()}
    args = (torch.tensor(gen, dtype=torch.float32), torch.tensor(prev, dtype=torch.float32),
            torch.tensor(mask))
    for kind, value in expected.items():
        np.testing.assert_allclose(temporal_term(*args, kind=kind).item(), value, rtol=FLOAT32_RTOL,
                                   err_msg=kind)


def test_data_term_ignores_pixels_outside_the_mask():
    _, hr, _, mask = batch()
    gen = torch.tanh(torch.randn_like(hr))
    base = data_term(gen, hr, mask)
    outside = mask.expand_as(hr) == 0
    gen2, hr2 = gen.clone(), hr.clone()
    gen2[outside], hr2[outside] = 5.0, -5.0
    np.testing.assert_allclose(data_term(gen2, hr2, mask).item(), base.item(), rtol=0)
    np.testing.assert_allclose(data_term(gen, hr, mask.bool()).item(), base.item(), rtol=0)
    expected = (gen - hr).abs()[~outside].mean()
    np.testing.assert_allclose(base.item(), expected.item(), rtol=FLOAT32_RTOL)
    gen2[~outside] += 0.1  # a covered pixel does count
    assert data_term(gen2, hr2, mask) != base


def test_masks_of_the_wrong_shape_are_refused():
    _, hr, _, _ = batch()
    with pytest.raises(ValueError, match="coverage mask"):
        data_term(hr, hr, torch.ones(8, 8))
    with pytest.raises(ValueError, match="coverage mask"):
        data_term(hr, hr, torch.ones(3, 1, 16, 16))


def test_weights_default_to_the_papers_and_are_validated():
    w = CGANWeights()
    assert (w.data, w.temporal, w.gan, w.temporal_kind) == (100.0, 50.0, 1.0, "eq4")
    with pytest.raises(dataclasses.FrozenInstanceError):
        w.data = 1.0
    with pytest.raises(ValueError, match="temporal_kind 'l3'"):
        CGANWeights(temporal_kind="l3")
    with pytest.raises(ValueError, match="gan must be >= 0"):
        CGANWeights(gan=-1.0)


# --- the summed objective ----------------------------------------------------------------------


def _grads(total: torch.Tensor, module: nn.Module) -> list[torch.Tensor]:
    params = list(module.parameters())
    return list(torch.autograd.grad(total, params, retain_graph=True, allow_unused=True))


def _assert_grads_equal(a: list[torch.Tensor], b: list[torch.Tensor]) -> None:
    for x, y in zip(a, b, strict=True):
        torch.testing.assert_close(x, y, rtol=GRAD_RTOL, atol=GRAD_ATOL)


@pytest.mark.parametrize("gan_mode", ["vanilla", "lsgan"])
def test_each_network_gets_only_its_own_objectives_gradient(gan_mode):
    """Built by hand with plain calls, the generator's terms and the discriminator's term: the total's
    gradient is the discriminator term's for D and the generator terms' for G, whereas their naive
    sum would also push D with the generator's adversarial term."""
    g, d = (m.double() for m in tiny(32))
    lr, hr, hr_prev, mask = (x.double() for x in batch(32))
    w = CGANWeights()
    torch.manual_seed(1)  # the same dropout masks in both evaluations
    total, _ = cgan_loss(g, d, lr, hr, hr_prev, mask, w, gan_mode=gan_mode)
    torch.manual_seed(1)
    fake = g(lr)
    patches = d.patch_weights(mask)
    adv_g = adversarial_term(d(torch.cat([lr, fake], 1) * mask), True, patches, gan_mode=gan_mode)
    g_terms = w.data * data_term(fake, hr, mask) + w.temporal * temporal_term(fake, hr_prev, mask) + adv_g
    d_term = 0.5 * (adversarial_term(d(torch.cat([lr, hr], 1) * mask), True, patches, gan_mode=gan_mode)
                    + adversarial_term(d(torch.cat([lr, fake.detach()], 1) * mask), False, patches,
                                       gan_mode=gan_mode))
    _assert_grads_equal(_grads(total, d), _grads(d_term, d))
    _assert_grads_equal(_grads(total, g), _grads(g_terms, g))
    naive = _grads(g_terms + d_term, d)
    assert max((a - b).abs().max().item() for a, b in zip(naive, _grads(d_term, d), strict=True)) > 1e-4


def test_generator_gets_no_gradient_from_outside_the_mask():
    g, d = tiny(32)
    lr, hr, hr_prev, mask = batch(32)
    outputs = []

    class Recording(nn.Module):
        def __init__(self):
            super().__init__()
            self.inner = g

        def forward(self, x):
            out = self.inner(x)
            out.retain_grad()
            outputs.append(out)
            return out

    total, _ = cgan_loss(Recording(), d, lr, hr, hr_prev, mask, CGANWeights())
    total.backward()
    grad = outputs[0].grad
    assert grad[mask.expand_as(grad) == 0].abs().max() == 0
    assert grad[mask.expand_as(grad) == 1].abs().max() > 0


def test_scalars_and_the_optional_previous_frame():
    g, d = tiny(32, norm="instance")
    lr, hr, hr_prev, mask = batch(32)
    g.eval()  # no dropout: the same generated map in every call
    total, s = cgan_loss(g, d, lr, hr, None, mask, CGANWeights())
    assert set(s) == {"data", "temporal", "gan_g", "gan_d", "d_real", "d_fake"}
    assert all(v.ndim == 0 and not v.requires_grad for v in s.values())
    assert s["temporal"] == 0 and 0 < s["d_real"] < 1 and 0 < s["d_fake"] < 1
    np.testing.assert_allclose(total.item(), (100 * s["data"] + s["gan_g"] + s["gan_d"]).item(),
                               rtol=FLOAT32_RTOL)
    total_t, s_t = cgan_loss(g, d, lr, hr, hr_prev, mask, CGANWeights())
    assert s_t["temporal"] > 0
    np.testing.assert_allclose((total_t - total).item(), 50 * s_t["temporal"].item(), rtol=1e-4)


def test_one_optimizer_overfits_a_batch_and_trains_the_discriminator():
    """30 Adam steps on one batch of 16 px maps (no dropout, so the generator can memorise): the data
    term falls by about a third, and the discriminator, trained by the same steps, tells the ground
    truth from the generated maps (it starts at 0.5 for both)."""
    torch.manual_seed(0)
    g = UNetGenerator(filters=8, resolution=16, dropout=0.0)
    d = PatchDiscriminator(filters=4, layers=1)  # 16 px maps: one stride-2 level leaves a 6x6 patch map
    lr, hr, hr_prev, mask = batch(16)
    opt = torch.optim.Adam([*g.parameters(), *d.parameters()], lr=1e-2, betas=(0.5, 0.999))
    history = []
    for _ in range(30):
        total, s = cgan_loss(g, d, lr, hr, hr_prev, mask, CGANWeights())
        opt.zero_grad()
        total.backward()
        opt.step()
        history.append(s["data"].item())
    assert history[-1] < 0.8 * history[0], history
    assert s["d_real"] > 0.6 and s["d_fake"] < 0.4, s


def test_training_is_deterministic_under_a_seed():
    def run():
        g, d = tiny(32, seed=7)
        lr, hr, hr_prev, mask = batch(32)
        opt = torch.optim.Adam([*g.parameters(), *d.parameters()], lr=1e-3)
        for _ in range(2):
            total, _ = cgan_loss(g, d, lr, hr, hr_prev, mask, CGANWeights())
            opt.zero_grad()
            total.backward()
            opt.step()
        return total.detach(), [p.detach().clone() for p in [*g.parameters(), *d.parameters()]]

    (t1, p1), (t2, p2) = run(), run()
    torch.testing.assert_close(t1, t2, rtol=0, atol=0)
    for a, b in zip(p1, p2, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
