"""Cloth self-contact for the VBD solver: vertex-triangle and edge-edge proximity and penalty
energies (after Chen et al. 2024, "Vertex Block Descent", Sec. 4).

* Detection, once per substep at the substep-start positions ``x0`` (``SelfContact.detect``):
  a broadphase (three grouped BVHs, ``bvh_broadphase``, or fixed clusters,
  ``cluster_broadphase``; one group per cloth instance, so batched instances never collide)
  hands each vertex its candidate triangles, each triangle its vertices and each edge its
  edges. A primitive's query radius is ``r = max(margin, speed_factor |v - v_ref| h)``, with
  ``v_ref`` its instance's reference velocity (``ClothControl.instance_velocity``;
  ``sim.simulate``: its body's mean velocity): contact depends on relative motion only, so the
  search runs in the frame moving with it (a run carries a whole t-shirt forward at 3.5 m/s).
* Lists (``lists``): of the pairs within ``r``, those whose own relative motion can bring them
  within the contact radius ``r_c`` during the substep's iterations are stored, closer than
  ``max(margin, speed_factor |v_a - v_b| h)`` with ``v_a - v_b`` the relative velocity of the
  closest points (``relative_lists``; off: every pair within ``r``). Cloth riding on a running
  limb moves with its surface neighbours, which never act: stored, they would be evaluated every
  iteration. Per vertex its triangles (VT), per triangle its vertices (TV, the same pairs seen
  from the triangle), per edge its edges (EE); gathering from both sides makes the solve a
  per-vertex gather without atomics (deterministic on every device). Pairs of one piece close
  at rest get a reduced radius (``pairs.reduced_radius_code``).
* Records (``records``): each vertex's pairs written to its block of a shared pool, read by the
  solve's gather (``gather``).
* Energy of a pair at distance ``d`` (closest points recomputed from the current positions
  each iteration, ``pairs``): ``k/2 (r_c - d)^2`` for ``d < r_c``, signed by the side the pair
  had at the detection, with lazy IPC friction on the relative tangential displacement over
  the substep.
"""

from sim.cloth.self_contact.bvh_broadphase import BvhBroadphase
from sim.cloth.self_contact.cluster_broadphase import SPLIT_SLOTS, ClusterBroadphase
from sim.cloth.self_contact.contact import BROADPHASES, SelfContact
from sim.cloth.self_contact.data import (
    SelfContactData,
    SolveContactArrays,
    contact_view,
    disabled_data,
    has_pairs,
    solve_contact_arrays,
    solve_contact_key,
)
from sim.cloth.self_contact.gather import (
    read_position,
    read_positions,
    read_triangle,
    self_contact_force_hessian,
    self_contact_list_force_hessian,
)
from sim.cloth.self_contact.lists import query_radius
from sim.cloth.self_contact.pairs import (
    RADIUS_CODES,
    pair_force_hessian,
    pair_radius,
    record_force_hessian,
    triangle_closest_bary,
)

__all__ = [
    "BROADPHASES", "RADIUS_CODES", "SPLIT_SLOTS", "BvhBroadphase", "ClusterBroadphase", "SelfContact",
    "SelfContactData", "SolveContactArrays", "contact_view", "disabled_data", "has_pairs",
    "pair_force_hessian", "pair_radius", "query_radius", "read_position", "read_positions",
    "read_triangle", "record_force_hessian", "self_contact_force_hessian",
    "self_contact_list_force_hessian", "solve_contact_arrays", "solve_contact_key",
    "triangle_closest_bary",
]
