"""Wrinkle diffusion: the DDPM/DDIM schedule against closed forms, the U-Net's contracts, and
DDIM sampling with an oracle noise predictor (Guo et al. 2024 Sec. 3.2, 4.1, 4.4)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learn.diffusion import (
    DDIMConfig,
    DDIMScheduler,
    DDPMScheduler,
    ScheduleConfig,
    UNetConfig,
    WrinkleUNet,
    count_parameters,
    ddim_sample,
    guided_epsilon,
)


def _np_alphas_cumprod(T=1000, b0=1e-4, b1=0.02):
    return np.cumprod(1.0 - np.linspace(b0, b1, T))


def _tiny_config(**kw) -> UNetConfig:
    base = dict(base_channels=16, channel_mult=(1, 2, 2), num_res_blocks=1, attention_levels=(2,),
                num_heads=2, norm_groups=8)
    base.update(kw)
    return UNetConfig(**base)


def _randomise_output(model: WrinkleUNet, seed: int = 0) -> None:
    """Give the zero-initialised output conv random weights, so predictions are not all zero."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        model.conv_out.weight.copy_(0.1 * torch.randn(model.conv_out.weight.shape, generator=g))


# ---------------------------------------------------------------- scheduler


def test_betas_and_alphas_cumprod_closed_form():
    s = DDPMScheduler()
    assert s.betas.dtype == torch.float64 and s.alphas_cumprod.dtype == torch.float64
    betas = np.linspace(1e-4, 0.02, 1000)
    np.testing.assert_allclose(s.betas.numpy(), betas, rtol=1e-14, atol=0)
    np.testing.assert_allclose(s.alphas.numpy(), 1.0 - betas, rtol=1e-14)
    np.testing.assert_allclose(s.alphas_cumprod.numpy(), _np_alphas_cumprod(), rtol=1e-12)
    assert s.betas[0] == 1e-4 and abs(float(s.betas[-1]) - 0.02) < 1e-15


def test_add_noise_exact_and_variance():
    s = DDPMScheduler()
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(4, 3, 8, 8, generator=g)
    eps = torch.randn(4, 3, 8, 8, generator=g)
    t = torch.tensor([0, 10, 500, 999])
    xt = s.add_noise(x0, eps, t)
    a = _np_alphas_cumprod()[t.numpy()]
    ref = (np.sqrt(a)[:, None, None, None] * x0.double().numpy()
           + np.sqrt(1 - a)[:, None, None, None] * eps.double().numpy())
    np.testing.assert_allclose(xt.numpy(), ref, rtol=1e-6, atol=1e-6)  # float32 sample
    # bit-exact against the same formula in torch float32
    ab = s.alphas_cumprod[t].reshape(-1, 1, 1, 1)
    torch.testing.assert_close(xt, ab.sqrt().float() * x0 + (1 - ab).sqrt().float() * eps, rtol=0, atol=0)
    assert torch.equal(s.training_target(x0, eps, t), eps)
    # x0 = 0: Var[x_t] = 1 - alpha_bar_t (200k samples per t: relative std. error ~0.3 %)
    for tt in (5, 300, 999):
        z = torch.randn(1, 200_000, generator=g)
        v = s.add_noise(torch.zeros_like(z), z, torch.tensor([tt])).double().var().item()
        np.testing.assert_allclose(v, 1.0 - _np_alphas_cumprod()[tt], rtol=0.02)


def test_set_timesteps_spacing():
    s = DDIMScheduler()
    ts = s.set_timesteps(50).tolist()
    assert ts[0] == 980 and ts[-1] == 0 and len(ts) == 50 and np.all(np.diff(ts) == -20)
    t2 = DDIMScheduler(timestep_spacing="trailing").set_timesteps(10).tolist()
    assert t2 == [999, 899, 799, 699, 599, 499, 399, 299, 199, 99]
    with pytest.raises(ValueError):
        DDIMConfig(timestep_spacing="linspace")
    d = DDIMScheduler.from_ddpm(DDPMScheduler(500, 2e-4, 0.03))
    assert d.config == ScheduleConfig(500, 2e-4, 0.03)
    torch.testing.assert_close(d.alphas_cumprod, DDPMScheduler(500, 2e-4, 0.03).alphas_cumprod)


@pytest.mark.parametrize("eta", [0.0, 1.0])
def test_ddim_step_matches_numpy_song_eq12(eta):
    s = DDIMScheduler()
    s.set_timesteps(50)
    g = torch.Generator().manual_seed(1)
    x = torch.randn(2, 3, 4, 4, generator=g)
    eps = torch.randn(2, 3, 4, 4, generator=g)
    z = torch.randn(2, 3, 4, 4, generator=g)
    a = _np_alphas_cumprod()
    for t, prev_t in ((980, 960), (20, 0), (0, -1)):
        out = s.step(eps, t, x, eta=eta, variance_noise=z)
        a_t, a_p = a[t], (a[prev_t] if prev_t >= 0 else 1.0)
        sig = eta * np.sqrt((1 - a_p) / (1 - a_t) * (1 - a_t / a_p))
        xd, ed, zd = x.double().numpy(), eps.double().numpy(), z.double().numpy()
        x0 = (xd - np.sqrt(1 - a_t) * ed) / np.sqrt(a_t)
        ref = np.sqrt(a_p) * x0 + np.sqrt(1 - a_p - sig**2) * ed + sig * zd
        np.testing.assert_allclose(out.pred_original_sample.numpy(), x0, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(out.prev_sample.numpy(), ref, rtol=1e-5, atol=1e-5)
        if eta > 0 and prev_t >= 0:
            assert sig > 0
            # the generator path draws the same z as torch.randn with the same seed
            g1, g2 = torch.Generator().manual_seed(7), torch.Generator().manual_seed(7)
            z7 = torch.randn(x.shape, generator=g2)
            torch.testing.assert_close(s.step(eps, t, x, eta=eta, generator=g1).prev_sample,
                                       s.step(eps, t, x, eta=eta, variance_noise=z7).prev_sample)
    # explicit prev_t
    out = s.step(eps, 500, x, eta=eta, prev_t=400, variance_noise=z)
    sig = eta * np.sqrt((1 - a[400]) / (1 - a[500]) * (1 - a[500] / a[400]))
    x0 = (x.double().numpy() - np.sqrt(1 - a[500]) * eps.double().numpy()) / np.sqrt(a[500])
    ed, zd = eps.double().numpy(), z.double().numpy()
    ref = np.sqrt(a[400]) * x0 + np.sqrt(1 - a[400] - sig**2) * ed + sig * zd
    np.testing.assert_allclose(out.prev_sample.numpy(), ref, rtol=1e-5, atol=1e-5)


# ---------------------------------------------------------------- sampling


class _Oracle:
    """The perfect noise predictor for one known x0: eps = (x_t - sqrt(a) x0) / sqrt(1 - a)."""

    out_channels = 3
    null_label = 0

    def __init__(self, x0: torch.Tensor, alphas_cumprod: torch.Tensor):
        self.x0, self.acp = x0.double(), alphas_cumprod

    def __call__(self, x_t, t, cond, label=None):
        a = self.acp[t].reshape(-1, 1, 1, 1)
        return ((x_t.double() - a.sqrt() * self.x0) / (1 - a).sqrt()).to(x_t.dtype)


@pytest.mark.parametrize("spacing", ["leading", "trailing"])
@pytest.mark.parametrize("num_steps", [50, 20, 10])
@pytest.mark.parametrize("eta", [0.0, 1.0])
def test_oracle_ddim_recovers_x0(num_steps, spacing, eta):
    s = DDIMScheduler(timestep_spacing=spacing)
    g = torch.Generator().manual_seed(3)
    x0 = 0.01 * torch.randn(2, 3, 16, 16, generator=g)  # wrinkle displacements are ~cm [m]
    cond = torch.randn(2, 2, 16, 16, generator=g)
    out = ddim_sample(_Oracle(x0, s.alphas_cumprod), s, cond, num_steps=num_steps, eta=eta, generator=g)
    np.testing.assert_allclose(out.numpy(), x0.numpy(), atol=1e-4, rtol=0)


def test_clip_x0_bounds_the_sample_and_is_inert_inside_the_range():
    s = DDIMScheduler()
    g = torch.Generator().manual_seed(5)
    x0 = torch.randn(2, 3, 16, 16, generator=g)
    x0[:, 1] *= 4.0  # channel 1 spans a wider range
    cond = torch.randn(2, 1, 16, 16, generator=g)
    oracle = _Oracle(x0, s.alphas_cumprod)
    bound = torch.tensor([0.5, 2.0, 1e9])
    out = ddim_sample(oracle, s, cond, num_steps=20, generator=torch.Generator().manual_seed(1),
                      clip_x0=bound)
    # the oracle always points at x0; clamped every step, the result is the clamped x0
    ref = torch.maximum(torch.minimum(x0, bound[None, :, None, None]), -bound[None, :, None, None])
    np.testing.assert_allclose(out.numpy(), ref.numpy(), atol=1e-4)
    assert out[:, 0].abs().max() <= 0.5 + 1e-4 and out[:, 1].abs().max() <= 2.0 + 1e-4
    # a bound above the data's range changes nothing
    free = ddim_sample(oracle, s, cond, num_steps=20, generator=torch.Generator().manual_seed(1))
    wide = ddim_sample(oracle, s, cond, num_steps=20, generator=torch.Generator().manual_seed(1),
                       clip_x0=float(x0.abs().max()) + 1.0)
    np.testing.assert_allclose(wide.numpy(), free.numpy(), atol=1e-5)


@pytest.mark.slow
def test_ddim_eta0_deterministic_and_noise_sharing_and_mask():
    torch.manual_seed(0)
    model = WrinkleUNet(_tiny_config()).eval()
    _randomise_output(model)
    s = DDIMScheduler()
    cond = torch.randn(3, 2, 16, 16)
    noise = torch.randn(3, 16, 16)  # shared by the 3 "frames"
    g1, g2 = torch.Generator().manual_seed(1), torch.Generator().manual_seed(2)
    a = ddim_sample(model, s, cond, num_steps=5, initial_noise=noise, generator=g1)
    b = ddim_sample(model, s, cond, num_steps=5, initial_noise=noise, generator=g2)
    assert torch.equal(a, b)  # eta = 0: no randomness past x_T
    c = ddim_sample(model, s, cond, num_steps=5, generator=torch.Generator().manual_seed(1))
    d = ddim_sample(model, s, cond, num_steps=5, generator=torch.Generator().manual_seed(1))
    assert torch.equal(c, d) and not torch.equal(a, c)
    # same noise and same condition: identical frames
    same = ddim_sample(model, s, cond[:1].expand(3, -1, -1, -1), num_steps=5, initial_noise=noise)
    torch.testing.assert_close(same[0], same[2])
    mask = (torch.rand(3, 16, 16) > 0.5).float()
    m = ddim_sample(model, s, cond, num_steps=5, initial_noise=noise, mask=mask)
    assert torch.all(m[mask[:, None].expand_as(m) == 0] == 0)
    assert torch.equal(m, ddim_sample(model, s, cond, num_steps=5, initial_noise=noise, mask=mask))


class _UntrainedOutside(_Oracle):
    """Exact inside the chart mask, untrained outside it (the training loss is masked): outside,
    the prediction is off by ``bias``; inside, it reads the mean of x_t outside the chart, as a
    convolution at the chart's border does, which is 0 in expectation over the training noise."""

    def __init__(self, x0, alphas_cumprod, mask, bias=3.0, coupling=0.5):
        super().__init__(x0 * mask, alphas_cumprod)
        self.mask, self.bias, self.coupling = mask.double(), bias, coupling

    def __call__(self, x_t, t, cond, label=None):
        eps = super().__call__(x_t, t, cond, label).double()
        out = 1.0 - self.mask
        leak = (x_t.double() * out).sum((1, 2, 3), keepdim=True) / out.sum((1, 2, 3), keepdim=True)
        return (eps + self.bias * out + self.coupling * leak * self.mask).to(x_t.dtype)


def test_the_mask_holds_x0_at_zero_outside_the_chart():
    """Outside the chart the network never learned the noise; the sampler keeps x0 = 0 there, so
    x_t outside stays pure scaled noise sqrt(1 - a_t) x_T / sqrt(1 - a_T) at every step, nothing
    outside drifts into the chart, and the oracle's x0 comes back inside. Without the mask the
    outside drifts (by the bias) and, through the border, spoils the inside."""
    s = DDIMScheduler()
    g = torch.Generator().manual_seed(4)
    x0 = torch.randn(2, 3, 16, 16, generator=g)
    mask = torch.zeros(2, 1, 16, 16)
    mask[:, :, 3:13, 2:14] = 1.0
    noise = torch.randn(2, 3, 16, 16, generator=g)
    model = _UntrainedOutside(x0, s.alphas_cumprod, mask)
    seen = []
    step = s.step

    def spy(eps, t, x_t, **kw):
        seen.append((int(t), x_t.clone()))
        return step(eps, t, x_t, **kw)

    s.step = spy
    out = ddim_sample(model, s, torch.zeros(2, 1, 16, 16), num_steps=20, initial_noise=noise, mask=mask[:, 0])
    a_T = float(s.alphas_cumprod[seen[0][0]])
    for t, x_t in seen:
        a = float(s.alphas_cumprod[t])
        want = noise * ((1 - a) / (1 - a_T)) ** 0.5
        torch.testing.assert_close(x_t * (1 - mask), want * (1 - mask), atol=1e-5, rtol=1e-4)
    # inside: the oracle's x0 (the leak of the pure noise outside is tiny)
    err = ((out - x0) * mask).abs().max()
    s.step = step
    free = ddim_sample(model, s, torch.zeros(2, 1, 16, 16), num_steps=20, initial_noise=noise)
    err_free = ((free - x0) * mask).abs().max()
    assert err < 1e-4 and err_free > 100 * err, (float(err), float(err_free))


# ---------------------------------------------------------------- U-Net


@pytest.mark.parametrize("cond_channels", [2, 1, 3])
def test_unet_shape_and_zero_init(cond_channels):
    model = WrinkleUNet(_tiny_config(cond_channels=cond_channels))
    x = torch.randn(2, 3, 64, 64)
    out = model(x, torch.tensor([3, 900]), torch.randn(2, cond_channels, 64, 64))
    assert out.shape == (2, 3, 64, 64)
    assert torch.count_nonzero(out) == 0  # zero-initialised output conv
    with pytest.raises(ValueError):
        model(x, torch.tensor([3, 900]), torch.randn(2, cond_channels + 1, 64, 64))
    with pytest.raises(ValueError):
        model(torch.randn(2, 3, 62, 62), torch.tensor([3, 900]), torch.randn(2, cond_channels, 62, 62))


@pytest.mark.slow
def test_unet_gradients_reach_every_parameter():
    torch.manual_seed(0)
    model = WrinkleUNet(_tiny_config(num_labels=2, dropout=0.1))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    s = DDPMScheduler()
    x0, cond = torch.randn(4, 3, 32, 32), torch.randn(4, 2, 32, 32)
    label = torch.tensor([0, 1, 2, 2])  # 2 = null label (CFG label dropout)

    def loss_step():
        opt.zero_grad()
        noise, t = torch.randn_like(x0), torch.randint(0, 1000, (4,))
        eps = model(s.add_noise(x0, noise, t), t, cond, label)
        loss = torch.mean((eps - s.training_target(x0, noise, t)) ** 2)  # Guo et al. Eq. 7
        loss.backward()
        return loss

    loss_step()
    opt.step()  # the zero output conv now has weights, so gradients flow to everything
    loss_step()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not torch.any(p.grad != 0)]
    assert missing == []


def test_cfg_guidance():
    torch.manual_seed(0)
    model = WrinkleUNet(_tiny_config(num_labels=3)).eval()
    _randomise_output(model)
    x, cond = torch.randn(2, 3, 16, 16), torch.randn(2, 2, 16, 16)
    t, label = torch.tensor([100, 700]), torch.tensor([0, 2])
    with torch.no_grad():
        e_cond = model(x, t, cond, label)
        e_unc = model(x, t, cond, torch.full((2,), model.null_label))
        assert torch.equal(guided_epsilon(model, x, t, cond, label=label, guidance_scale=1.0), e_cond)
        torch.testing.assert_close(model(x, t, cond, None), e_unc)
        assert not torch.allclose(e_cond, e_unc)  # the label matters
        calls = []
        h = model.register_forward_hook(lambda m, i, o: calls.append(i[0].shape[0]))
        g = guided_epsilon(model, x, t, cond, label=label, guidance_scale=3.0)
        h.remove()
    assert calls == [4]  # one batched forward of 2B
    # batch-of-4 vs batch-of-2 convolutions round differently in float32 (~1e-6), amplified by 2s - 1 = 5
    torch.testing.assert_close(g, e_unc + 3.0 * (e_cond - e_unc), rtol=1e-4, atol=5e-5)
    with pytest.raises(ValueError):
        ddim_sample(model, DDIMScheduler(), cond, guidance_scale=2.0)
    with pytest.raises(ValueError):
        WrinkleUNet(_tiny_config())(x, t, cond, label)  # num_labels = 0 takes no label


def test_default_config_size_and_roundtrip():
    from learn.train.config import config_from_dict, config_to_dict

    cfg = UNetConfig()
    assert config_from_dict(UNetConfig, config_to_dict(cfg)) == cfg
    n = count_parameters(WrinkleUNet(cfg))
    assert 8_000_000 < n < 10_500_000, n  # fp16 weights ~20 MB
