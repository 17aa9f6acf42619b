"""Contacts between particles and against half-spaces, with rigid bodies resolved as bodies.

A contact at a particle of a rigid body moves the whole body: the correction uses the body's
generalised inverse mass along the contact normal, w = 1/M + (r x n)^T I^-1 (r x n), and the
impulse changes the body's translation and rotation (rigid-body PBD, Mueller et al. 2020, in
particle form). Particle-level corrections followed by shape matching would instead be diluted by
the number of particles in the body (an impact would tunnel, friction would tip cubes instead of
stopping them). Free particles (fluid, rope) are bodies without rotation.

All functions take p [B, N, 3] predicted positions and x_prev [B, N, 3] substep start positions,
and a :class:`Bodies` describing which particles are rigid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from vgpl.sim.vector import squared_norm, squared_norm_weighted


@dataclass
class Bodies:
    """Static particle description. instance [N] ids, rigid_particle [N] bool, inv_mass [N],
    radius [N], n_instances M; rigid_index [R] (derived) the indices of the rigid particles, over
    which every rigid-body sum runs (FluidCube: 48 of 348), found once instead of every pass."""

    instance: torch.Tensor
    rigid_particle: torch.Tensor
    inv_mass: torch.Tensor
    radius: torch.Tensor
    n_instances: int
    rigid_index: torch.Tensor = field(init=False)

    def __post_init__(self) -> None:
        self.rigid_index = self.rigid_particle.nonzero().squeeze(1)


def body_frames(p: torch.Tensor, bodies: Bodies) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Centroids [B, M, 3], inverse masses [M] and world inverse inertia [B, M, 3, 3] of the rigid instances."""
    b, m = p.shape[0], bodies.n_instances
    rigid = bodies.rigid_index
    q, inst = p.index_select(1, rigid), bodies.instance.index_select(0, rigid)
    mass = 1.0 / bodies.inv_mass.index_select(0, rigid).clamp_min(1e-12)
    total = torch.zeros(m, dtype=p.dtype, device=p.device).index_add_(0, inst, mass)
    centroid = torch.zeros(b, m, 3, dtype=p.dtype, device=p.device).index_add_(1, inst, q * mass[:, None])
    centroid = centroid / total.clamp_min(1e-12)[:, None]
    r = q - centroid[:, inst]
    eye = torch.eye(3, dtype=p.dtype, device=p.device)
    per = mass[:, None, None] * (squared_norm(r)[..., None, None] * eye - r.unsqueeze(-1) * r.unsqueeze(-2))
    inertia = torch.zeros(b, m, 3, 3, dtype=p.dtype, device=p.device).index_add_(1, inst, per)
    rigid_body = total > 0
    inertia = torch.where(rigid_body[None, :, None, None], inertia, eye)  # placeholders for non-rigid instances
    return centroid, torch.where(rigid_body, 1.0 / total.clamp_min(1e-12), torch.zeros_like(total)), torch.linalg.inv(inertia)


def rodrigues(rotvec: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [..., 3, 3] from rotation vectors [..., 3]."""
    angle = rotvec.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    k = rotvec / angle
    zero = torch.zeros_like(k[..., 0])
    kx = torch.stack([zero, -k[..., 2], k[..., 1], k[..., 2], zero, -k[..., 0], -k[..., 1], k[..., 0], zero], -1).reshape(*k.shape[:-1], 3, 3)
    s, c = torch.sin(angle)[..., None], torch.cos(angle)[..., None]
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device)
    return eye + s * kx + (1 - c) * (kx @ kx)


class _Frame:
    """Per-call rigid frames and helpers to compute effective masses and apply impulses."""

    def __init__(self, p: torch.Tensor, bodies: Bodies) -> None:
        self.p, self.bodies = p, bodies
        self.b, self.n = p.shape[:2]
        self.centroid, self.body_inv_mass, self.inv_inertia = body_frames(p, bodies)
        flat_inst = bodies.instance.repeat(self.b)
        scene = torch.arange(self.b, device=p.device).repeat_interleave(self.n)
        self.body_of = scene * bodies.n_instances + flat_inst  # [B*N] flat body index
        self.rigid = bodies.rigid_particle.repeat(self.b)  # [B*N]
        self.r = (p - self.centroid.index_select(1, bodies.instance)).reshape(-1, 3)  # [B*N, 3]
        self.rigid_rows = (torch.arange(self.b, device=p.device)[:, None] * self.n + bodies.rigid_index).reshape(-1)  # [B*R] rows of rigid particles
        self.inv_mass = bodies.inv_mass.repeat(self.b)
        self.flat_inv_inertia = self.inv_inertia.reshape(-1, 3, 3)
        self.flat_body_inv_mass = self.body_inv_mass.repeat(self.b)

    def effective_inv_mass(self, idx: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
        """[E] generalised inverse mass of particles ``idx`` along unit ``normal`` [E, 3]."""
        rxn = torch.cross(self.r.index_select(0, idx), normal, dim=-1)
        body = self.body_of.index_select(0, idx)
        angular = squared_norm_weighted(rxn, self.flat_inv_inertia.index_select(0, body))
        rigid_w = self.flat_body_inv_mass.index_select(0, body) + angular
        return torch.where(self.rigid.index_select(0, idx), rigid_w, self.inv_mass.index_select(0, idx))

    def apply(self, idx: torch.Tensor, impulse: torch.Tensor, average_free: bool = True) -> torch.Tensor:
        """Apply impulses [E, 3] at particles ``idx``. Jacobi: averaged over each body's contacts,
        and over each free particle's contacts when ``average_free`` (False for half-spaces, whose
        corrections at a corner are independent and must add up)."""
        b, n, m = self.b, self.n, self.bodies.n_instances
        active = (impulse.abs().sum(-1) > 0).to(impulse.dtype)
        rigid = self.rigid.index_select(0, idx)
        # free particles
        free = (~rigid).to(impulse.dtype)[:, None]
        dp = torch.zeros(b * n, 3, dtype=impulse.dtype, device=impulse.device).index_add_(0, idx, free * impulse * self.inv_mass.index_select(0, idx)[:, None])
        cnt = torch.zeros(b * n, dtype=impulse.dtype, device=impulse.device).index_add_(0, idx, active * free[:, 0])
        flat = self.p.reshape(-1, 3) + (dp / cnt.clamp_min(1.0)[:, None] if average_free else dp)
        # rigid bodies
        if bool(self.bodies.rigid_particle.any()):
            rw = rigid.to(impulse.dtype)[:, None]
            body = self.body_of.index_select(0, idx)
            lin = torch.zeros(b * m, 3, dtype=impulse.dtype, device=impulse.device).index_add_(0, body, rw * impulse)
            ang = torch.zeros(b * m, 3, dtype=impulse.dtype, device=impulse.device).index_add_(0, body, rw * torch.cross(self.r.index_select(0, idx), impulse, dim=-1))
            bcnt = torch.zeros(b * m, dtype=impulse.dtype, device=impulse.device).index_add_(0, body, active * rw[:, 0]).clamp_min(1.0)
            dx = lin * self.flat_body_inv_mass[:, None] / bcnt[:, None]
            dtheta = (self.flat_inv_inertia @ ang.unsqueeze(-1)).squeeze(-1) / bcnt[:, None]
            rot = rodrigues(dtheta)  # [B*M, 3, 3]
            rows = self.rigid_rows
            pb = self.body_of.index_select(0, rows)
            r = self.r.index_select(0, rows)
            moved = self.centroid.reshape(-1, 3).index_select(0, pb) + (rot.index_select(0, pb) @ r.unsqueeze(-1)).squeeze(-1) + dx.index_select(0, pb)
            flat = flat.index_copy(0, rows, moved)
        return flat.reshape(b, n, 3)


def _friction_impulse(rel_move: torch.Tensor, normal: torch.Tensor, w: torch.Tensor, normal_lambda: torch.Tensor, friction: float) -> torch.Tensor:
    """Coulomb friction impulse [E, 3] opposing the tangential relative displacement, |J_t| <= mu J_n."""
    tangential = rel_move - (rel_move * normal).sum(-1, keepdim=True) * normal
    t_len = tangential.norm(dim=-1)
    lam_t = torch.minimum(t_len / w, friction * normal_lambda)
    return -(lam_t / t_len.clamp_min(1e-12))[:, None] * tangential


def project_particle_contacts(
    p: torch.Tensor, x_prev: torch.Tensor, bodies: Bodies, i: torch.Tensor, j: torch.Tensor, distance: float, friction: float = 0.0
) -> torch.Tensor:
    """Push apart particle pairs closer than ``distance``.

    Args: i, j [E] directed pairs as flat indices into [B * N] (both directions present; each
    directed pair applies its half of the impulse to particle i).
    Returns: [B, N, 3] corrected positions.
    """
    frame = _Frame(p, bodies)
    flat, flat_prev = p.reshape(-1, 3), x_prev.reshape(-1, 3)
    d = flat.index_select(0, i) - flat.index_select(0, j)
    length = squared_norm(d).sqrt()
    normal = d / length.clamp_min(1e-9)[:, None]
    penetration = (distance - length).clamp_min(0.0)
    w = (frame.effective_inv_mass(i, normal) + frame.effective_inv_mass(j, normal)).clamp_min(1e-12)
    lam = penetration / w
    impulse = lam[:, None] * normal
    if friction > 0.0:
        rel = (flat[i] - flat_prev[i]) - (flat[j] - flat_prev[j])
        impulse = impulse + _friction_impulse(rel, normal, w, lam, friction) * (penetration > 0)[:, None]
    return frame.apply(i, impulse)


def project_planes(
    p: torch.Tensor, x_prev: torch.Tensor, bodies: Bodies, planes: torch.Tensor, friction: float = 0.0, plane_velocity: torch.Tensor | None = None
) -> torch.Tensor:
    """Keep particles on the free side of half-spaces ``n . p >= d + radius``.

    Args: planes [B, K, 4] rows (n_x, n_y, n_z, d) with unit normals pointing into the free space;
    plane_velocity: optional [B, K, 3] displacement of each plane over the substep (for friction).
    Returns: [B, N, 3] corrected positions.
    """
    b, n, _ = p.shape
    normals, offsets = planes[..., :3], planes[..., 3]
    signed = torch.einsum("bnc,bkc->bnk", p, normals) - offsets[:, None, :] - bodies.radius[None, :, None]
    scene, particle, k = (signed < 0).nonzero(as_tuple=True)
    if scene.numel() == 0:
        return p
    idx = scene * n + particle
    normal = normals[scene, k]
    penetration = -signed[scene, particle, k]
    frame = _Frame(p, bodies)
    w = frame.effective_inv_mass(idx, normal).clamp_min(1e-12)
    lam = penetration / w
    impulse = lam[:, None] * normal
    if friction > 0.0:
        rel = p.reshape(-1, 3)[idx] - x_prev.reshape(-1, 3)[idx]
        if plane_velocity is not None:
            rel = rel - plane_velocity[scene, k]
        impulse = impulse + _friction_impulse(rel, normal, w, lam, friction)
    return frame.apply(idx, impulse, average_free=False)


def push_rigid_out_of_planes(p: torch.Tensor, bodies: Bodies, planes: torch.Tensor) -> torch.Tensor:
    """Translate each rigid instance by its deepest penetration of each plane (keeps bodies rigid,
    so a body never rests inside a plane after the Jacobi iterations)."""
    normals, offsets = planes[..., :3], planes[..., 3]
    signed = torch.einsum("bnc,bkc->bnk", p, normals) - offsets[:, None, :] - bodies.radius[None, :, None]
    penetration = (-signed).clamp_min(0.0) * bodies.rigid_particle[None, :, None]
    b, _, k = penetration.shape
    deepest = torch.zeros(b, bodies.n_instances, k, dtype=p.dtype, device=p.device)
    deepest = deepest.scatter_reduce(1, bodies.instance[None, :, None].expand_as(penetration), penetration, "amax")
    shift = torch.einsum("bmk,bkc->bmc", deepest, normals)
    return p + shift[:, bodies.instance] * bodies.rigid_particle[None, :, None]
