"""Physics losses: Warp kernels and per-garment static data (no torch).

The kernels (``loss_kernels``) are batched, differentiable energies built on the simulator's
own ``wp.func``s; ``learn.losses`` wraps them as ``torch.autograd.Function``s and loss modules.
"""

from sim.losses.topology import GarmentTopology, garment_topology, topology_of

__all__ = ["GarmentTopology", "garment_topology", "topology_of"]
