"""``SelfContact``: the self-contact data, broadphase and detection of one cloth model."""

from __future__ import annotations

from sim.cloth.self_contact.bvh_broadphase import BvhBroadphase
from sim.cloth.self_contact.cluster_broadphase import ClusterBroadphase
from sim.cloth.self_contact.data import SelfContactData, self_contact_data
from sim.cloth.self_contact.records import incidence_slots, pair_records_kernel, vertex_summary_kernel
from sim.device import warp

BROADPHASES = ("bvh", "clusters")


class SelfContact:
    """Self-contact buffers, broadphase and detection for one ``ClothModel``; ``data`` is the
    ``SelfContactData`` the solve reads.

    Args:
        model: the cloth model.
        radius: contact distance [m] between cloth surfaces (pairs closer are pushed apart).
        margin: smallest query radius [m] of the detection.
        stiffness: penalty stiffness [N/m].
        friction: cloth-cloth Coulomb friction coefficient.
        speed_factor: the query radius is at least ``speed_factor |v| h``.
        capacity: pairs kept per vertex / triangle / edge.
        coarse_exclusion: pairs of one piece closer than this [m] at rest leave the coarse
            correction alone (``has_pairs``: no capped move, no self-contact stiffness in the
            coarse diagonal for them); they are in contact as ever. 0: every stored pair holds
            it back. On fine meshes the neighbours an edge or two apart (4-6 mm at 5.5 mm edges)
            lie within the 4 mm query margin as soon as the cloth moves, and nearly every
            particle has pairs: the correction would be left out of most of the garment
            (``test_neighbours_near_at_rest_leave_the_coarse_correction_of_a_fine_sheet_alone``).
        relative_lists: store a pair only within the query radius of its own relative speed (the
            package docstring says why); off: every pair within the query radius.
        pool: gather records per vertex on average (``records``); a vertex whose records do not
            fit is gathered from the lists, slower but the same forces.
        heavy_cap: vertices per colour with more than ``heavy_threshold`` records that the solve
            gives a thread block each (``records.vertex_summary_kernel``); 0: none.
        heavy_threshold: records above which a vertex is heavy (the solve's lanes per particle:
            more takes a vertex more than one round of its lanes).
        weight_floor: smallest pair weight the Hessian takes (``pairs.pair_force_hessian``): a
            vertex's Newton step is at most ``1 / weight_floor`` times a pair's penetration;
            0: the exact Gauss-Newton Hessian.
        broadphase: ``"bvh"`` (three trees, refitted and queried, ``bvh_broadphase``) or
            ``"clusters"`` (the flat two-level culling of ``sim.cloth.clusters``, no trees,
            ``cluster_broadphase``). Both find the same pairs.
        cluster_size: primitives per cluster of the ``"clusters"`` broadphase.
        cluster_split: threads per primitive of the ``"clusters"`` query (0: automatic,
            ``ClusterBroadphase``).
        cluster_lanes: the clusters' octet and cluster data from lane shuffles (CUDA;
            ``ClusterBroadphase``); None: wherever they can.
    """

    def __init__(self, model, *, radius: float, margin: float, stiffness: float, friction: float,
                 speed_factor: float, capacity: int, coarse_exclusion: float = 0.0,
                 relative_lists: bool = True, pool: int = 16, heavy_cap: int = 0, heavy_threshold: int = 16,
                 weight_floor: float = 0.5, broadphase: str = "bvh", cluster_size: int = 32,
                 cluster_split: int = 1, cluster_lanes: bool | None = None):
        if broadphase not in BROADPHASES:
            raise ValueError(f"SelfContact: broadphase must be 'bvh' or 'clusters', got {broadphase!r}")
        w = warp()
        d = model.device
        self.model = model
        self.margin = float(margin)
        self.speed_factor = float(speed_factor)
        self.data: SelfContactData = self_contact_data(
            model, radius=radius, stiffness=stiffness, friction=friction, capacity=capacity,
            coarse_exclusion=coarse_exclusion, relative_lists=relative_lists, pool=pool, heavy_cap=heavy_cap,
            heavy_threshold=heavy_threshold, weight_floor=weight_floor)
        # where each triangle corner / edge end sits in its vertex's incidence list
        # (``records.pair_records_kernel``)
        self._tri_slot = w.array(incidence_slots(model.vertex_tri_ids.numpy(),
                                                 model.vertex_tri_local.numpy() & 3, 3, model.tri_count),
                                 dtype=w.int32, device=d)
        self._edge_slot = w.array(incidence_slots(model.vertex_mesh_edge_ids.numpy(),
                                                  model.vertex_mesh_edge_local.numpy(), 2,
                                                  model.mesh_edge_indices.shape[0]),
                                  dtype=w.int32, device=d)
        self.broadphase: BvhBroadphase | ClusterBroadphase = (
            BvhBroadphase(model) if broadphase == "bvh"
            else ClusterBroadphase(model, self.data, cluster_size, cluster_split, cluster_lanes))

    @property
    def clusters(self):
        """The ``ClusterLayout`` of the cluster broadphase; None with the trees."""
        return self.broadphase.layout if isinstance(self.broadphase, ClusterBroadphase) else None

    def detect(self, x0, v, h: float, rebuild: bool = False, reference=None) -> None:
        """The pairs at ``x0`` (the substep start) into ``data``'s lists and gather records: the
        broadphase's queries (``rebuild``: rebuild the trees rather than refit them), with ``v``
        [m/s] the velocities the substep starts with and ``reference`` each instance's reference
        velocity (vec3 (I,), ``ClothControl.instance_velocity``; None: the one set last, zeros at
        first)."""
        sc = self.data
        if reference is not None:
            sc.reference = reference
        zeroed = self.broadphase.detect(x0, v, h, rebuild, self.margin, self.speed_factor, sc)
        self._records(zeroed)

    def _records(self, zeroed: bool) -> None:
        """The per-vertex summary and gather records of ``data``'s lists
        (``records.vertex_summary_kernel``, ``records.pair_records_kernel``); ``zeroed``: the
        detection zeroed their counters already."""
        w = warp()
        m = self.model
        sc = self.data
        if not zeroed:
            sc.pair_cursor.zero_()
            if sc.heavy_cap > 0:
                sc.heavy_count.zero_()
        w.launch(vertex_summary_kernel, dim=m.particle_count, inputs=[m.vertex_tri_offsets, m.vertex_tri_ids],
                 outputs=[sc], device=m.device)
        nt, ne = m.tri_count, m.mesh_edge_indices.shape[0]
        w.launch(pair_records_kernel, dim=m.particle_count + nt + ne,
                 inputs=[m.tri_indices, self._tri_slot, self._edge_slot, m.particle_count, nt], outputs=[sc],
                 device=m.device)
