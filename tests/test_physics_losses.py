"""Physics losses (Warp kernels behind torch autograd): every term against its plain-torch
reference (value and gradient) on a coarse t-shirt with the default body, central finite
differences, and physics facts (zero at rest, rigid invariance, analytic StVK stretch, the
collision penalty's shell and direction, inertia of constant velocity, gravity of a lift)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import ConvexHull

from learn.losses import (
    LOSS_TERMS,
    BendingLoss,
    CollisionLoss,
    GravityLoss,
    GSNetBendingLoss,
    GSNetCollisionLoss,
    GSNetEdgeLoss,
    InertiaLoss,
    MembraneLoss,
    PhysicsBatch,
)
from learn.losses import reference as R
from sim.losses import garment_topology, topology_of
from tests.test_geometry import rotation, sheet

B = 3
DT = 1.0 / 30.0
VALUE_RTOL = 1e-5
"""Warp sums float32 terms with atomics (order varies); the reference is float64."""
GRAD_RTOL = 1e-4
"""Per-vertex gradients are short float32 sums; relative to the largest component."""
FD_RTOL = 2e-3
"""Central differences of the float64 reference (h = 1e-6 m) against the float32 Warp gradient."""


@pytest.fixture(scope="module")
def shirt():
    """A coarse t-shirt (~300 vertices) on the default body (13k vertices)."""
    from sim.bodies import load_body
    from sim.garments import make_garment

    body = load_body()
    g = make_garment("t_shirt", body, resolution=0.06)
    return topology_of(g), body.rest_mesh().astype(np.float32), body.faces.astype(np.int32)


@pytest.fixture(scope="module")
def flat():
    """A flat 8 x 8 sheet, 0.4 m square, in the XY plane."""
    v, f, _ = sheet(8, 0.4)
    return garment_topology(v, f)


def deformed(topology, *, scale: float = 0.01, seed: int = 0) -> torch.Tensor:
    """B random deformations of the rest shape [m], (B, V, 3) float32."""
    g = torch.Generator().manual_seed(seed)
    rest = torch.as_tensor(topology.rest_vertices)
    return rest[None] + scale * torch.randn((B, topology.num_vertices, 3), generator=g)


def bodies(body_vertices: np.ndarray, seed: int = 1) -> torch.Tensor:
    """B copies of the body, each shifted by a few mm, (B, Vb, 3)."""
    g = torch.Generator().manual_seed(seed)
    return torch.as_tensor(body_vertices)[None] + 0.004 * torch.randn((B, 1, 3), generator=g)


def terms(topology, body_faces):
    """(name, Warp module, float64 reference of the same inputs) of every term."""
    m, bd = MembraneLoss(topology), BendingLoss(topology)
    grav, ine = GravityLoss(topology), InertiaLoss(topology, dt=DT)
    col = dict(body_faces=body_faces, stiffness=1e4, eps=0.01)
    out = [
        ("membrane", m, lambda t: R.membrane_energy(t.x, topology, m.mu, m.lam)),
        ("bending", bd, lambda t: R.bending_energy(t.x, topology, bd.bending)),
        ("gravity", grav, lambda t: R.gravity_energy(t.x, topology, grav.density)),
        ("inertia", ine, lambda t: R.inertia_energy(t.x, t.x_prev, t.x_prev2, topology, ine.density, DT)),
        ("gsnet_edge", GSNetEdgeLoss(topology), lambda t: R.edge_energy(t.x, topology)),
        ("gsnet_bending", GSNetBendingLoss(topology, weight=0.5),
         lambda t: R.gsnet_bending_energy(t.x, topology, 0.5)),
        ("gsnet_collision", GSNetCollisionLoss(topology, body_faces=body_faces, eps=0.01),
         lambda t: R.collision_energy(t.x, t.body_vertices, body_faces, stiffness=1.0, eps=0.01, power=2.0)),
    ]
    for anchor in ("vertex", "face"):
        for search in ("bvh", "brute"):
            mod = CollisionLoss(topology, anchor=anchor, search=search, **col)
            out.append((f"collision_{anchor}_{search}", mod, lambda t, a=anchor: R.collision_energy(
                t.x, t.body_vertices, body_faces, stiffness=1e4, eps=0.01, power=3.0, anchor=a)))
    for _, mod, _ in out:
        mod.reduction = "none"
    return out


def batch_of(topology, body_vertices, device) -> PhysicsBatch:
    x = deformed(topology)
    g = torch.Generator().manual_seed(5)
    xp = x - 0.002 + 0.001 * torch.randn(x.shape, generator=g)
    xpp = xp - 0.002 + 0.001 * torch.randn(x.shape, generator=g)
    return PhysicsBatch(x=x.to(device), x_prev=xp.to(device), x_prev2=xpp.to(device),
                        body_vertices=bodies(body_vertices).to(device))


def as64(batch: PhysicsBatch, *, grad: bool) -> PhysicsBatch:
    def c(t):
        return t.detach().cpu().double().requires_grad_(grad)
    return PhysicsBatch(x=c(batch.x), x_prev=c(batch.x_prev), x_prev2=c(batch.x_prev2),
                        body_vertices=batch.body_vertices.detach().cpu().double())


def test_terms_match_reference_value_and_gradient(shirt, device):
    topology, body_v, body_f = shirt
    batch = batch_of(topology, body_v, device)
    for t in (batch.x, batch.x_prev, batch.x_prev2):
        t.requires_grad_(True)
    ref_batch = as64(batch, grad=True)
    for name, mod, ref in terms(topology, body_f):
        e = mod.on_batch(batch)
        er = ref(ref_batch)
        assert e.shape == (B,) and e.dtype == torch.float32 and e.device.type == device
        ev, erv = e.detach().cpu().numpy(), er.detach().numpy()
        np.testing.assert_allclose(ev, erv, rtol=VALUE_RTOL, atol=1e-6 * np.abs(erv).max(), err_msg=name)
        if name.startswith("collision") or name == "gsnet_collision":
            assert erv.min() > 0.0, f"{name}: the test must put vertices inside the shell"
        wrt = [batch.x, batch.x_prev, batch.x_prev2] if name == "inertia" else [batch.x]
        wrt_ref = [ref_batch.x, ref_batch.x_prev, ref_batch.x_prev2] if name == "inertia" else [ref_batch.x]
        w = torch.linspace(0.5, 1.5, B, device=device)
        grads = torch.autograd.grad((w * e).sum(), wrt)
        grads_ref = torch.autograd.grad((w.cpu().double() * er).sum(), wrt_ref)
        for g, gr in zip(grads, grads_ref, strict=True):
            gr = gr.numpy()
            np.testing.assert_allclose(g.cpu().numpy(), gr, rtol=GRAD_RTOL, atol=GRAD_RTOL * np.abs(gr).max(),
                                       err_msg=name)


@pytest.mark.slow
@pytest.mark.xfail(reason="on the sewn t-shirt the float32 finite difference of gsnet_collision "
                          "disagrees with its gradient (0.142 against -0.119)", strict=False)
def test_gradients_match_finite_differences(shirt):
    """<grad E, d> of the Warp term equals the central difference of the float64 reference, and
    (looser) of the float32 Warp energy itself, in random directions."""
    topology, body_v, body_f = shirt
    batch = batch_of(topology, body_v, "cpu")
    batch.x.requires_grad_(True)
    rng = np.random.default_rng(3)
    for name, mod, ref in terms(topology, body_f):
        if name == "inertia" or name.endswith("brute"):
            continue
        (g,) = torch.autograd.grad(mod.on_batch(batch).sum(), [batch.x])
        for _ in range(2):
            d = torch.as_tensor(rng.uniform(-1.0, 1.0, batch.x.shape), dtype=torch.float64)
            h = 1e-6
            b64 = as64(batch, grad=False)
            plus = ref(PhysicsBatch(x=b64.x + h * d, body_vertices=b64.body_vertices)).sum()
            minus = ref(PhysicsBatch(x=b64.x - h * d, body_vertices=b64.body_vertices)).sum()
            fd = float((plus - minus) / (2 * h))
            an = float((g.double() * d).sum())
            np.testing.assert_allclose(an, fd, rtol=FD_RTOL, atol=1e-6 * float(g.abs().max()), err_msg=name)
            # the float32 Warp energy itself: h = 1e-4 m (rounding of float32 sums ~1e-7 relative)
            h32 = 1e-4
            x = batch.x.detach()
            bb = batch.body_vertices
            plus = mod.on_batch(PhysicsBatch(x=x + h32 * d.float(), body_vertices=bb)).double().sum()
            minus = mod.on_batch(PhysicsBatch(x=x - h32 * d.float(), body_vertices=bb)).double().sum()
            fd32 = float((plus - minus) / (2 * h32))
            np.testing.assert_allclose(an, fd32, rtol=2e-2, atol=1e-3 * abs(an) + 1e-7, err_msg=name)


def test_inertia_gradient_wrt_previous_positions_finite_differences(shirt):
    topology, body_v, _ = shirt
    batch = batch_of(topology, body_v, "cpu")
    mod = InertiaLoss(topology, dt=DT, reduction="sum")
    batch.x_prev.requires_grad_(True)
    batch.x_prev2.requires_grad_(True)
    gp, gpp = torch.autograd.grad(mod.on_batch(batch), [batch.x_prev, batch.x_prev2])
    np.testing.assert_allclose(gp.numpy(), -2.0 * gpp.numpy(), rtol=1e-5, atol=1e-9)
    d = torch.as_tensor(np.random.default_rng(0).uniform(-1, 1, batch.x.shape))
    b = as64(batch, grad=False)
    h = 1e-6

    def e(xp):
        return R.inertia_energy(b.x, xp, b.x_prev2, topology, mod.density, DT).sum()
    fd = float((e(b.x_prev + h * d) - e(b.x_prev - h * d)) / (2 * h))
    np.testing.assert_allclose(float((gp.double() * d).sum()), fd, rtol=FD_RTOL)


def test_membrane_and_bending_zero_at_rest_and_rigid_invariant(shirt, device):
    topology, _, _ = shirt
    rest = torch.as_tensor(topology.rest_vertices)[None].repeat(B, 1, 1)
    x = deformed(topology, scale=0.02)
    rng = np.random.default_rng(7)
    moved = torch.stack([x[k] @ torch.as_tensor(rotation(rng), dtype=torch.float32).T
                         + torch.as_tensor(rng.normal(size=3), dtype=torch.float32) for k in range(B)])
    for mod in (MembraneLoss(topology, reduction="none"), BendingLoss(topology, reduction="none"),
                GSNetEdgeLoss(topology, reduction="none")):
        e_def = mod(x.to(device)).cpu().numpy()
        # float32 rest coordinates (~0.5 m) are rounded to ~3e-8 m: strains ~1e-6 at rest
        np.testing.assert_allclose(mod(rest.to(device)).cpu().numpy(), 0.0, atol=1e-6 * e_def.max())
        np.testing.assert_allclose(mod(moved.to(device)).cpu().numpy(), e_def, rtol=2e-4)


def test_membrane_uniform_stretch_is_analytic_stvk(flat, device):
    """A sheet scaled by s in its plane: G = g I, g = (s^2 - 1)/2, E = A (mu 2 g^2 + lam/2 (2 g)^2)."""
    mod = MembraneLoss(flat, mu=300.0, lam=120.0, reduction="none")
    area = float(flat.areas.sum())
    s = torch.tensor([0.9, 1.0, 1.1])
    x = torch.as_tensor(flat.rest_vertices)[None] * s[:, None, None]
    g = (s.double() ** 2 - 1.0) / 2.0
    expect = area * (300.0 * 2.0 * g * g + 0.5 * 120.0 * (2.0 * g) ** 2)
    np.testing.assert_allclose(mod(x.to(device)).cpu().numpy(), expect.numpy(), rtol=1e-5, atol=1e-9)


def test_flat_hinges_have_finite_zero_gradients(flat, device):
    x = torch.as_tensor(flat.rest_vertices)[None].repeat(B, 1, 1).to(device).requires_grad_(True)
    for mod in (BendingLoss(flat, reduction="sum"), GSNetBendingLoss(flat, reduction="sum")):
        e = mod(x)
        (g,) = torch.autograd.grad(e, [x])
        assert torch.isfinite(g).all() and abs(float(e.detach())) < 1e-12
        np.testing.assert_allclose(g.cpu().numpy(), 0.0, atol=1e-9)
    # in-plane jitter keeps the sheet flat: bending energy zero, gradient finite
    xj = x.detach().clone()
    xj[..., :2] += 0.003 * torch.randn_like(xj[..., :2])
    xj.requires_grad_(True)
    e = BendingLoss(flat, reduction="sum")(xj)
    (g,) = torch.autograd.grad(e, [xj])
    assert torch.isfinite(g).all()


def ball(radius: float = 0.3, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """A convex polyhedral ball (Fibonacci points, hull faces turned outward)."""
    k = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * k / n)
    th = np.pi * (1 + 5 ** 0.5) * k
    v = radius * np.stack([np.cos(th) * np.sin(phi), np.cos(phi), np.sin(th) * np.sin(phi)], 1)
    f = ConvexHull(v).simplices.astype(np.int32)
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flip = np.sum(nrm * v[f].mean(1), 1) < 0
    f[flip] = f[flip][:, ::-1]
    return v.astype(np.float32), f


@pytest.mark.parametrize("anchor", ["vertex", "face"])
def test_collision_shell_and_push_direction(flat, device, anchor):
    """Garment vertices placed at radii 0.3 m + offset around a ball: outside the eps shell they
    cost nothing; inside they cost k (eps - d)^3 and the descent direction -grad is the anchor's
    outward normal (nearly radial)."""
    bv, bf = ball()
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(flat.num_vertices, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    eps = 0.005
    mod = CollisionLoss(flat, body_faces=bf, stiffness=1e3, eps=eps, anchor=anchor, reduction="none")
    body = torch.as_tensor(bv)[None].repeat(2, 1, 1).to(device)
    outside = torch.as_tensor(dirs * (0.3 + 0.02), dtype=torch.float32)
    inside = torch.as_tensor(dirs * (0.3 - 0.02), dtype=torch.float32)
    x = torch.stack([outside, inside]).to(device).requires_grad_(True)
    e = mod(x, body)
    (g,) = torch.autograd.grad(e.sum(), [x])
    e, g = e.detach().cpu().numpy(), g.cpu().numpy()
    assert e[0] == 0.0 and np.all(g[0] == 0.0)
    assert e[1] > flat.num_vertices * 1e3 * 0.01 ** 3  # each vertex >= 1 cm deep after faceting
    anchors = mod.nearest_anchors(x.detach(), body)
    n = anchors.normals[1].cpu().numpy()
    push = -g[1] / np.linalg.norm(g[1], axis=1, keepdims=True)
    np.testing.assert_allclose(push, n, atol=1e-5)
    assert np.all(np.sum(push * dirs, axis=1) > 0.9)


def test_collision_search_far_points_and_changing_batches(shirt):
    """The BVH search is exact far from the body (radius doubling) and after the bodies move or
    the batch size changes (rebuilt / refitted buffers): every point gets an anchor at its least
    distance, and the nearest anchor itself wherever the second nearest is 1e-5 m farther (a
    float32 search may take either of two anchors tied in float64)."""
    topology, body_v, body_f = shirt
    mod = CollisionLoss(topology, body_faces=body_f, radius0=0.01)
    for bsz, shift, lift in ((3, 0.0, 0.0), (3, 0.05, 2.5), (2, -0.3, 0.0)):
        x = deformed(topology)[:bsz] + torch.tensor([0.0, lift, 0.0])
        body = bodies(body_v)[:bsz] + shift
        got = mod.nearest_anchors(x, body)
        pts, nrm = R.body_anchors(body.double(), body_f)
        dist = torch.cdist(x.double(), pts)
        two = dist.topk(2, dim=-1, largest=False)
        np.testing.assert_allclose(torch.linalg.norm(x.double() - got.points.double(), dim=-1).numpy(),
                                   two.values[..., 0].numpy(), atol=1e-6)
        unique = (two.values[..., 1] - two.values[..., 0] > 1e-5).numpy()
        assert unique.mean() > 0.9
        gather = two.indices[..., :1].expand(-1, -1, 3)
        np.testing.assert_allclose(got.points.numpy()[unique], torch.gather(pts, 1, gather).numpy()[unique],
                                   atol=1e-6)
        np.testing.assert_allclose(got.normals.numpy()[unique], torch.gather(nrm, 1, gather).numpy()[unique],
                                   atol=1e-5)


def test_inertia_zero_for_constant_velocity_and_gravity_of_a_lift(flat, device):
    x0 = torch.as_tensor(flat.rest_vertices)[None].repeat(B, 1, 1)
    v = torch.tensor([0.3, -1.2, 0.5])
    ine = InertiaLoss(flat, dt=DT, density=0.2, reduction="none")
    e = ine(x0.to(device) + 2 * DT * v.to(device), x0.to(device) + DT * v.to(device), x0.to(device))
    np.testing.assert_allclose(e.cpu().numpy(), 0.0, atol=1e-8)
    grav = GravityLoss(flat, density=0.2, reduction="none")
    lift = grav((x0 + torch.tensor([0.0, 1.0, 0.0])).to(device)) - grav(x0.to(device))
    mass = 0.2 * float(flat.areas.sum())
    np.testing.assert_allclose(lift.cpu().numpy(), mass * 9.81, rtol=1e-5)


def test_cuda_respects_torch_stream(shirt):
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device here")
    topology, body_v, body_f = shirt
    batch = batch_of(topology, body_v, "cuda")
    mods = [MembraneLoss(topology, reduction="none"),
            CollisionLoss(topology, body_faces=body_f, eps=0.01, reduction="none")]
    ref = [m.on_batch(batch).cpu() for m in mods]
    s = torch.cuda.Stream()
    with torch.cuda.stream(s):
        got = [m.on_batch(batch) for m in mods]
    torch.cuda.synchronize()
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(a.cpu().numpy(), b.numpy(), rtol=1e-5)


def test_registry_reductions_and_input_errors(flat):
    bv, bf = ball()
    x = deformed(flat)
    for name, cls in LOSS_TERMS.items():
        kw = {"dt": DT} if name == "inertia" else {"body_faces": bf} if "collision" in name else {}
        mod = cls(flat, **kw)
        args = [x]
        if name == "inertia":
            args = [x, x.detach(), x.detach()]
        elif "collision" in name:
            args = [x, torch.as_tensor(bv)[None].repeat(B, 1, 1)]
        per = mod.energy(*args)
        assert per.shape == (B,)
        np.testing.assert_allclose(float(mod(*args)), float(per.mean()), rtol=1e-6)
        mod.reduction = "sum"
        np.testing.assert_allclose(float(mod(*args)), float(per.sum()), rtol=1e-6)
    with pytest.raises(ValueError, match="expected a tensor"):
        MembraneLoss(flat)(x[:, :-1])
    with pytest.raises(ValueError, match="reduction"):
        MembraneLoss(flat, reduction="avg")
    with pytest.raises(ValueError, match="anchor"):
        CollisionLoss(flat, body_faces=bf, anchor="edge")
    with pytest.raises(ValueError, match="lacks"):
        InertiaLoss(flat, dt=DT).on_batch(PhysicsBatch(x=x))


def test_hem_layers_weigh_mass_and_bending_as_the_simulator_does(shirt):
    """A garment's hems (``face_layers``) reach the losses as the simulator builds them
    (``ClothModelBuilder.add_cloth``): the lumped vertex masses equal the model's particle masses,
    the hinge stiffnesses its edge stiffnesses, and both differ from a topology without layers
    where the hems are."""
    from learn.losses.physics import cloth_params
    from sim.bodies import load_body
    from sim.cloth import ClothModelBuilder
    from sim.garments import make_garment

    g = make_garment("t_shirt", load_body(), resolution=0.06)
    assert (g.face_layers > 1.0).any()
    topo = topology_of(g)
    np.testing.assert_array_equal(topo.face_layers, g.face_layers)
    p = cloth_params("cotton")
    b = ClothModelBuilder()
    b.add_cloth(g.rest_vertices, g.faces, p, face_layers=g.face_layers)
    m = b.finalize("cpu")
    np.testing.assert_allclose(topo.vertex_masses(p.density), m.particle_mass.numpy(), rtol=1e-5)
    np.testing.assert_array_equal(topo.hinges, m.hinges)
    np.testing.assert_allclose(p.bending * topo.hinge_factors, m.edge_stiffness.numpy(), rtol=1e-5)
    plain = garment_topology(g.rest_vertices, g.faces)
    heavier = topo.vertex_areas > plain.vertex_areas * (1.0 + 1e-6)
    assert set(np.flatnonzero(heavier)) <= set(np.unique(g.faces[g.face_layers > 1.0]).tolist())
    assert heavier[np.unique(g.faces[g.face_layers > 1.01])].all()


def test_layers_scale_every_material_energy(flat, device):
    """Two layers everywhere double the membrane, bending, gravity and inertia energies (the
    same deformation); the geometric GSNet terms do not see layers. Bad layers are refused."""
    v, f = flat.rest_vertices, flat.faces
    two = garment_topology(v, f, np.full(len(f), 2.0))
    x = deformed(flat, scale=0.02).to(device)
    prev = deformed(flat, scale=0.02, seed=3).to(device)
    for name, make, args in [
            ("membrane", MembraneLoss, (x,)), ("bending", BendingLoss, (x,)), ("gravity", GravityLoss, (x,)),
            ("inertia", lambda t: InertiaLoss(t, dt=DT), (x, prev, prev)),
            ("gsnet_edge", GSNetEdgeLoss, (x,))]:
        one_e = make(flat).energy(*args).cpu().numpy()
        two_e = make(two).energy(*args).cpu().numpy()
        factor = 1.0 if name.startswith("gsnet") else 2.0
        assert np.abs(one_e).min() > 0.0, name
        np.testing.assert_allclose(two_e, factor * one_e, rtol=1e-5, err_msg=name)
    with pytest.raises(ValueError, match="face_layers"):
        garment_topology(v, f, np.full(len(f), 0.5))
    with pytest.raises(ValueError, match="face_layers"):
        garment_topology(v, f, np.ones(len(f) + 1))
