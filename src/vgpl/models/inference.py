"""InferenceModule: from particle proposals over T observed frames, infer a refinement dX of
every particle in every frame [B, T, N, 3] (metres), the rigidness Q of every instance [B, M] and
the physical parameters P [B, P].

It is trained through the frozen DynamicsPrior: the loss is the L1 between the trajectory the prior
predicts and the ground truth, plus a direct L1 of the refined positions (the authors' code adds
it; ``refine_weight``). ``separate_param_net`` gives P its own encoder: the paper's two networks,
one for dX and Q, one for P. ``training_scheme`` says what each rollout is fed:

- ``paper``: each network rolls the prior with the true values of the other's outputs. dX and Q
  roll from the refined frames with the true P; P rolls from the true frames with the true G and Q.
- ``joint``: every rollout takes the module's own G, Q and P. ``trajectory_start`` then says where
  it starts: ``refined`` (the refined first frames), ``truth`` (the true ones: P and Q learn, dX
  only from its direct L1) or ``both`` (P from the true start, dX through the refined one).

``refined_steps`` and ``truth_steps`` set how many frames the run from the refined start
(``rollout``) and the run from the true start (``rollout_from_truth``) roll: null, through the rest
of the window and ``horizon`` frames past it; 0, no such run. ``one_step_windows`` adds one-step
predictions from refined histories. The authors' code trains dX and Q by one step from every
refined history of the window (``one_step_windows: null, refined_steps: 0``) and P by 2 steps from
the true frames (``truth_steps: 2``).

Options beyond the paper (docs/paper.md, Departures; docs/configuration.md): ``tail_horizon`` k > 0
adds an L1 of k frames rolled from the last ``history`` refined frames, where the evaluation starts;
``tail_detach_rigidness`` keeps Q out of it and ``tail_detach_params`` P (in the paper's scheme it rolls
with the true P); ``param_rotation`` shows the parameter encoder each
training scene turned about the vertical axis (RigidFall's symmetry); ``lr_anneal_steps`` anneals
every rate to zero over the last K steps; ``param_weight`` > 0 adds a supervised L1 on P;
``proposal_noise`` s > 0 jitters every training proposal by a std drawn per window in [0, s] metres.

``rigidness_estimator`` says what Q is to the prior. ``blend`` (the paper): Q is the prior's blend
weight between its rigid and per-particle heads, learnt through the gradient of the rollout.
``bernoulli``: Q is the probability that an instance is rigid, the prior sees the label Q > 0.5,
and Q learns from the expected trajectory L1 over the label, Q L1(rigid) + (1 - Q) L1(free), exact
per instance (``flipped_label_errors``, ``expected_rigidness_error``). ``bernoulli_from_step`` k
trains with the blend for k steps, then with ``bernoulli``, in one run.

``rollout_target``: what the rollouts are compared with. ``truth`` (the paper): the simulator's
trajectories. ``proposals``: the visual prior's particles of the same frames, slot by slot (the
visual prior gives every particle its own slot in every frame), so the module trains on unlabelled
videos; nothing then reads the trajectories but the logged metrics (it needs refine_weight 0 and
param_weight 0; the actuated particles are placed by the actions, as the Grounder places them).
The "true" start of ``trajectory_start`` truth / both is then the proposals' own first frames, unrefined;
``rigid_fit_start`` fits each instance the module's Q calls rigid (Q > 0.5) rigidly to its last-frame shape
(``vgpl.nn.rigid_start``, by the module's G; no gradient), so P reads a rigid body's motion rather than
the proposals' noise.

Nothing supervises Q or P directly unless ``param_weight`` > 0: ``rigid_correct/<type>`` and
``param_mae_pct`` are logged against the truth, never trained on.
"""

from __future__ import annotations

import logging

import lightning as L
import torch
from torch import nn
from torch_geometric.nn import MLP

from vgpl.data.vertical_symmetry import random_about_vertical
from vgpl.graph import edge_features, radius_graph
from vgpl.metrics import correct_rigidness_prob, mean_per_type
from vgpl.models.rollout import rollout, rollout_runs
from vgpl.models.step_learning_rate import AnnealedLearningRate
from vgpl.nn.normalisation import NormalisationBuffers
from vgpl.nn.propagation import EdgeEncoder, Propagator
from vgpl.nn.rigid_start import rigid_start

log = logging.getLogger(__name__)


def add_proposal_jitter(proposals: torch.Tensor, max_std: float) -> torch.Tensor:
    """proposals [B, T, N, 3] plus independent Gaussian noise of a std drawn per window uniformly
    in [0, ``max_std``] (metres): every frame and particle its own draw, so it shows as motion."""
    std = torch.rand(proposals.shape[0], 1, 1, 1, device=proposals.device, dtype=proposals.dtype) * max_std
    return proposals + torch.randn_like(proposals) * std


def tile_batch(z: torch.Tensor, copies: int) -> torch.Tensor:
    """[B, ...] -> [copies * B, ...]: the batch repeated ``copies`` times, copy-major."""
    return z.repeat(copies, *([1] * (z.dim() - 1)))


class SpatioTemporalEncoder(nn.Module):
    """Message passing on each frame's radius graph, then a bidirectional GRU over time per particle.

    forward(nodes [B, T, N, F], positions [B, T, N, 3], grouping [B, N, M]) -> [B, T, N, 2 W]
    """

    def __init__(self, node_dim: int, width: int, propagation_steps: int, gru_layers: int, radius: float, max_neighbors: int) -> None:
        super().__init__()
        self.radius, self.steps, self.max_neighbors = radius, propagation_steps, max_neighbors
        self.node_encoder = MLP([node_dim, width, width, width], norm=None, plain_last=False)
        self.edge_encoder = EdgeEncoder(node_dim, 5, width)
        self.edge_term = nn.Linear(width, width)
        self.propagator = Propagator(width)
        self.gru = nn.GRU(width, width, num_layers=gru_layers, batch_first=True, bidirectional=True)

    def forward(self, nodes: torch.Tensor, positions: torch.Tensor, grouping: torch.Tensor, pos_scale: torch.Tensor) -> torch.Tensor:
        b, t, n, _ = nodes.shape
        flat_nodes = nodes.reshape(b * t * n, -1)
        flat_pos = positions.reshape(b * t * n, 3)
        graph = torch.arange(b * t, device=nodes.device).repeat_interleave(n)
        with torch.no_grad():
            # proposals can be far denser than real particles (an untrained prior collapses them):
            # the nearest max_neighbors keep the cost bounded
            edge_index = radius_graph(flat_pos.detach(), self.radius, graph, max_neighbors=self.max_neighbors, graph_size=n)
        group = grouping[:, None].expand(b, t, n, -1).reshape(b * t * n, -1)
        scale = torch.cat([pos_scale, pos_scale.norm()[None], torch.ones(1, device=nodes.device)])
        edge_attr = edge_features(flat_pos, edge_index, group) / scale
        code = self.node_encoder(flat_nodes)
        term = self.edge_encoder(flat_nodes, edge_attr, edge_index, self.edge_term)
        effect = torch.zeros_like(code)
        for _ in range(self.steps):
            effect = self.propagator(effect, code, term, edge_index)
        seq = effect.reshape(b, t, n, -1).permute(0, 2, 1, 3).reshape(b * n, t, -1)
        out, _ = self.gru(seq)
        return out.reshape(b, n, t, -1).permute(0, 2, 1, 3)


class InferenceModule(AnnealedLearningRate, NormalisationBuffers, L.LightningModule):
    anneal_stage = "inference"

    def __init__(
        self,
        param_low: list[float],
        param_high: list[float],
        n_particles: int,
        n_instances: int,
        radius: float,
        width: int = 150,
        propagation_steps: int = 2,
        gru_layers: int = 2,
        separate_param_net: bool = True,
        horizon: int = 5,
        refine_weight: float = 1.0,
        lr: float = 1e-4,
        rigidness: bool = True,
        max_neighbors: int = 24,
        one_step_windows: int | None = 0,
        refined_steps: int | None = None,
        truth_steps: int | None = None,
        param_weight: float = 0.0,
        trajectory_start: str = "refined",
        param_lr: float | None = None,
        tail_horizon: int = 0,
        tail_detach_params: bool = False,
        tail_detach_rigidness: bool = False,
        lr_anneal_steps: int = 0,
        param_rotation: bool = False,
        instance_types: list[str] | None = None,
        rigidness_estimator: str = "blend",
        proposal_noise: float = 0.0,
        bernoulli_from_step: int | None = None,
        training_scheme: str = "joint",
        rollout_target: str = "truth",
        rigid_fit_start: bool = False,
    ) -> None:
        super().__init__()
        if param_rotation and not separate_param_net:
            raise ValueError("InferenceModule: param_rotation=true rotates what the parameter encoder sees, "
                             "and needs separate_param_net=true (a shared encoder would rotate dX and Q's input too)")
        if not 0 <= tail_horizon <= horizon:
            raise ValueError(f"InferenceModule: tail_horizon={tail_horizon}, expected 0 (off) to horizon={horizon} (the future frames a window holds)")
        if trajectory_start not in ("refined", "truth", "both"):
            raise ValueError(f"InferenceModule: trajectory_start={trajectory_start!r}, expected 'refined' (the paper), 'truth' or 'both'")
        if training_scheme not in ("joint", "paper"):
            raise ValueError(f"InferenceModule: training_scheme={training_scheme!r}, expected 'paper' (each network rolls the prior with "
                             "the true values of the other's outputs) or 'joint' (both roll with the module's own outputs)")
        if training_scheme == "paper" and (not separate_param_net or trajectory_start != "refined" or rigidness_estimator != "blend"):
            raise ValueError("InferenceModule: training_scheme='paper' trains the paper's two networks, each with its own rollout; it needs "
                             f"separate_param_net=true, trajectory_start='refined' and rigidness_estimator='blend' (got {separate_param_net}, "
                             f"{trajectory_start!r}, {rigidness_estimator!r})")
        if rollout_target not in ("truth", "proposals"):
            raise ValueError(f"InferenceModule: rollout_target={rollout_target!r}, expected 'truth' (the simulator's trajectories, the paper) "
                             "or 'proposals' (the visual prior's particles of the same frames: training without trajectories)")
        if rollout_target == "proposals" and (training_scheme != "joint" or refine_weight != 0 or param_weight != 0):
            raise ValueError("InferenceModule: rollout_target='proposals' trains without the simulator's trajectories, so nothing may read them: "
                             "it needs training_scheme='joint', refine_weight=0 and param_weight=0 (got "
                             f"{training_scheme!r}, {refine_weight}, {param_weight})")
        if rigid_fit_start and (rollout_target != "proposals" or trajectory_start not in ("truth", "both")):
            raise ValueError("InferenceModule: rigid_fit_start=true fits the rigid instances of the proposals' start that P rolls from; it needs "
                             f"rollout_target='proposals' and trajectory_start 'truth' or 'both' (got {rollout_target!r}, {trajectory_start!r})")
        for name, value in (("refined_steps", refined_steps), ("truth_steps", truth_steps)):
            if value is not None and value < 0:
                raise ValueError(f"InferenceModule: {name}={value}, expected null (the window and horizon), 0 (no such run) or a number of frames")
        if (refined_steps is not None or truth_steps is not None) and (rigidness_estimator == "bernoulli" or bernoulli_from_step is not None):
            raise ValueError("InferenceModule: refined_steps / truth_steps need rigidness_estimator='blend' without bernoulli_from_step "
                             "(the bernoulli estimator flips labels on one rollout length)")
        if rigidness_estimator not in ("blend", "bernoulli"):
            raise ValueError(f"InferenceModule: rigidness_estimator={rigidness_estimator!r}, expected 'blend' (the paper: Q is the prior's "
                             "blend weight) or 'bernoulli' (Q is the probability of the label the prior sees)")
        if bernoulli_from_step is not None and (rigidness_estimator != "blend" or not bernoulli_from_step >= 1):
            raise ValueError(f"InferenceModule: bernoulli_from_step={bernoulli_from_step!r} with rigidness_estimator={rigidness_estimator!r}, "
                             "expected a step >= 1 with 'blend' (blend until that step, then bernoulli), or null")
        if not proposal_noise >= 0:
            raise ValueError(f"InferenceModule: proposal_noise={proposal_noise!r}, expected a std in metres >= 0 (0: off, the paper)")
        if param_lr is not None and not param_lr > 0:
            raise ValueError(f"InferenceModule: param_lr={param_lr!r}, expected a positive learning rate or null (= lr)")
        if instance_types is not None and len(instance_types) != n_instances:
            raise ValueError(f"InferenceModule: instance_types={instance_types} names {len(instance_types)} instances, expected n_instances={n_instances}")
        self.save_hyperparameters()
        self.register_normalisation(param_low, param_high)
        node_dim = 3 + 3 + n_instances + 1
        make = lambda: SpatioTemporalEncoder(node_dim, width, propagation_steps, gru_layers, radius, max_neighbors)  # noqa: E731
        self.encoder = make()
        self.param_encoder = make() if separate_param_net else None
        self.refine_head = MLP([2 * width, width, 3], norm=None)
        self.rigid_head = MLP([2 * width, width, 1], norm=None)
        self.param_head = MLP([2 * width, width, len(param_low)], norm=None)
        self.dynamics = None  # the frozen DynamicsPrior (attach_dynamics); not part of this checkpoint
        self.estimator = rigidness_estimator  # the one in use: blend turns bernoulli at bernoulli_from_step; saved in the checkpoint

    def attach_dynamics(self, dynamics) -> None:
        """Use ``dynamics`` (frozen, eval mode) in the training loss; it is not saved with this module."""
        dynamics.eval().requires_grad_(False)
        object.__setattr__(self, "dynamics", dynamics)  # plain attribute: not a registered submodule

    # ---- inference ------------------------------------------------------------------------------
    def forward(self, proposals: torch.Tensor, grouping: torch.Tensor, kinematic: torch.Tensor) -> dict:
        """proposals [B, T, N, 3] (metres), grouping [B, N, M] (probabilities), kinematic [N] ->
        refine [B, T, N, 3] (metres), rigidness [B, M] in (0, 1), params [B, P] in (-1, 1)."""
        nodes = self._nodes(proposals, grouping, kinematic)
        h = self.encoder(nodes, proposals, grouping, self.pos_std)  # [B, T, N, 2W]
        refine = self.refine_head(h) * self.disp_std
        hp = h if self.param_encoder is None else self._param_code(nodes, proposals, grouping, kinematic)
        params = torch.tanh(self.param_head(hp.mean((1, 2))))
        return {"refine": refine, "rigidness": self._rigidness(h, grouping), "params": params}

    def rigidness(self, proposals: torch.Tensor, logits: torch.Tensor, kinematic: torch.Tensor) -> torch.Tensor:
        """Only Q [B, M], as ``infer`` gives it: without the refinement head and the parameter
        encoder (the rigidness curve runs this for every T = 1 .. 20)."""
        grouping = torch.softmax(logits, -1).mean(1)
        h = self.encoder(self._nodes(proposals, grouping, kinematic), proposals, grouping, self.pos_std)
        return self._rigidness(h, grouping)

    def _nodes(self, proposals: torch.Tensor, grouping: torch.Tensor, kinematic: torch.Tensor) -> torch.Tensor:
        """Encoder input [B, T, N, 3 + 3 + M + 1]: normalised position, displacement from the
        previous frame (zero in the first), grouping, kinematic flag."""
        b, t, n, _ = proposals.shape
        disp = torch.cat([torch.zeros_like(proposals[:, :1]), proposals[:, 1:] - proposals[:, :-1]], 1)
        disp = torch.where(torch.arange(t, device=proposals.device)[None, :, None, None] > 0, (disp - self.disp_mean) / self.disp_std, disp)
        return torch.cat([
            (proposals - self.pos_mean) / self.pos_std, disp, grouping[:, None].expand(b, t, n, -1),
            kinematic[None, None, :, None].expand(b, t, n, 1).float(),
        ], -1)

    def _param_code(self, nodes, proposals, grouping, kinematic) -> torch.Tensor:
        """The parameter encoder's [B, T, N, 2W]; in training with ``param_rotation``, of each scene
        turned about the vertical axis at random (``random_about_vertical``): P cannot then read the
        training videos' layouts, only their motion (not the paper; the scene must be symmetric so)."""
        if self.training and self.hparams.param_rotation:
            proposals = random_about_vertical(proposals)
            nodes = self._nodes(proposals, grouping, kinematic)
        return self.param_encoder(nodes, proposals, grouping, self.pos_std)

    def _rigidness(self, h: torch.Tensor, grouping: torch.Tensor) -> torch.Tensor:
        """Encoder output [B, T, N, 2W] pooled per instance (grouping [B, N, M]) -> Q [B, M]."""
        weights = grouping / grouping.sum(1, keepdim=True).clamp_min(1e-8)  # [B, N, M]
        per_instance = torch.einsum("bnm,bnw->bmw", weights, h.mean(1))
        return torch.sigmoid(self.rigid_head(per_instance).squeeze(-1))

    def infer(self, proposals, logits, kinematic, refinement: bool = True, rigidness: bool | None = None,
              params: bool = True, generator: torch.Generator | None = None) -> dict:
        """Everything the dynamics prior needs, in its units, with the ablations applied.

        Args: proposals [B, T, N, 3]; logits [B, T, N, M] (the visual prior's grouping logits).
        Returns positions [B, T, N, 3] (refined, or X' when ``refinement`` is off), grouping
        [B, N, M], rigidness [B, M] what the prior takes (Q, or the label Q > 0.5 with the
        ``bernoulli`` estimator; zeros when off), rigidness_prob [B, M] Q itself (zeros when off),
        params [B, P] physical (uniform draws when off), params_normalised [B, P].
        """
        rigidness = self.hparams.rigidness if rigidness is None else rigidness
        grouping = torch.softmax(logits, -1).mean(1)
        out = self(proposals, grouping, kinematic)
        positions = proposals + out["refine"] if refinement else proposals
        prob = out["rigidness"] if rigidness else torch.zeros_like(out["rigidness"])
        p = out["params"]
        if not params:
            p = torch.rand(p.shape, generator=generator, device="cpu").to(p.device) * 2.0 - 1.0
        return {"positions": positions, "grouping": grouping, "rigidness": self.prior_rigidness(prob), "rigidness_prob": prob,
                "params": self.to_physical(p), "params_normalised": p}

    def prior_rigidness(self, prob: torch.Tensor) -> torch.Tensor:
        """Q [B, M] -> the rigidness the dynamics prior is given: Q (``blend``), or the label Q > 0.5 (``bernoulli``)."""
        return (prob > 0.5).to(prob) if self.estimator == "bernoulli" else prob

    @torch.no_grad()
    def flipped_label_errors(self, start, target, grouping, labels, params, planes, kinematic, n_roll) -> torch.Tensor:
        """The trajectory L1 [B, M] with instance m's label flipped (1 - label), the others kept, for
        every m: one rollout of M B scenes, copy-major, without gradient. start [B, H, N, 3], target
        [B, n_roll, N, 3], grouping [B, N, M], labels [B, M] in {0, 1}, params [B, P], planes as rollout's."""
        b, m = labels.shape
        flipped = labels[None].repeat(m, 1, 1)  # [M copies, B, M]
        each = torch.arange(m, device=labels.device)
        flipped[each, :, each] = 1.0 - flipped[each, :, each]
        targets = tile_batch(target, m)
        future = rollout(self.dynamics, torch.cat([tile_batch(start, m), targets], 1), tile_batch(grouping, m), flipped.reshape(m * b, m),
                         tile_batch(params, m), tile_batch(planes, m), kinematic, n_roll)
        error = ((future - targets) / self.dynamics.disp_std).abs()[:, :, ~kinematic].mean((1, 2, 3))
        return error.reshape(m, b).T

    def expected_rigidness_error(self, prob, labels, at_labels, flipped) -> torch.Tensor:
        """The trajectory L1 expected over each instance's label, mean over scenes and instances:
        Q L1(rigid) + (1 - Q) L1(free), whose gradient in Q is L1(rigid) - L1(free), exactly.
        prob [B, M] Q; labels [B, M] the prior's labels; at_labels [B] L1 at them; flipped [B, M]
        L1 with each label flipped (``flipped_label_errors``)."""
        at_labels = at_labels.detach()[:, None].expand_as(flipped)
        rigid = torch.where(labels > 0.5, at_labels, flipped)
        free = torch.where(labels > 0.5, flipped, at_labels)
        return (prob * rigid + (1.0 - prob) * free).mean()

    # ---- training through the frozen dynamics prior ---------------------------------------------
    def _losses(self, batch, noise: bool = False) -> dict:
        """The loss terms of a batch; ``noise``: the training step's, with ``proposal_noise`` added to the proposals."""
        if self.dynamics is None:
            raise RuntimeError("InferenceModule: attach_dynamics(model) before training; the loss runs through the frozen DynamicsPrior")
        dyn = self.dynamics
        kinematic = batch["kinematic"][0]
        proposals, truth, planes = batch["proposals"], batch["positions"], batch["planes"]
        if self.hparams.rollout_target == "proposals":
            # the visual prior's particles of the window and its future frames stand for the trajectory; the actuated
            # particles are where the actions put them (Scene.kinematic_positions gives the recorded ones exactly)
            truth = torch.where(kinematic[None, None, :, None], truth, batch["target_proposals"])
        if noise and self.hparams.proposal_noise > 0:
            proposals = add_proposal_jitter(proposals, self.hparams.proposal_noise)
        b, t = proposals.shape[:2]
        h, k = dyn.hparams.history, self.hparams.horizon
        out = self.infer(proposals, batch["logits"], kinematic)
        x = torch.where(kinematic[None, None, :, None], truth[:, :t], out["positions"])  # kinematic parts are known
        g, q, p = out["grouping"], out["rigidness"], out["params"]
        paper = self.hparams.training_scheme == "paper"
        p_dx = batch["params"].to(p) if paper else p  # the P that dX and Q learn with: the true one in the paper's scheme
        scale = dyn.disp_std
        movable = ~kinematic
        losses = {}
        # every rollout of the loss: name -> its runs, each (start + target frames, G, Q, P, planes, length). They all
        # roll as one batch through the prior (rollout_runs: one call a step for the runs still rolling; scenes never
        # share edges), and each loss is the L1 of its runs' predictions against the frames they roll into
        pieces: dict[str, list[tuple]] = {}

        def run(name: str, first: int, start: torch.Tensor, g_, q_, p_, length: int) -> None:
            """A rollout of ``length`` frames from ``start`` (the h frames from ``first``) into truth[first + h:]."""
            target = truth[:, first + h : first + h + length]
            pieces.setdefault(name, []).append((torch.cat([start, target], 1), g_, q_, p_, planes[:, first : first + h + length], length))

        # one step from refined histories inside the observed window (the last few, or all T - h)
        k1 = self.hparams.one_step_windows
        for s in list(range(t - h)) if k1 is None else list(range(t - h))[-k1:] if k1 > 0 else []:
            run("one_step", s, x[:, s : s + h], g, q, p_dx, 1)
        # the trajectory: from the first h refined (or true) frames through the rest of the window
        # and k frames past it; a wrong parameter's error grows with every step, which makes P visible
        n_roll, mode = t - h + k, self.hparams.trajectory_start
        trajectories = {}
        if n_roll > 0:
            if paper:
                # the paper's two networks, each with the true values of the other's outputs: dX and Q
                # roll with the true P; P rolls from the true frames with the true G and Q
                true_q = batch["rigid"].to(q) if self.hparams.rigidness else torch.zeros_like(q)
                trajectories = {"rollout": (x[:, :h], g, q, p_dx), "rollout_from_truth": (truth[:, :h], batch["grouping"].to(g), true_q, p)}
            else:
                start = truth[:, :h]
                if self.hparams.rigid_fit_start:  # the proposals' start, each instance the module's Q calls rigid fitted rigidly
                    start = rigid_start(start, g.detach(), (q > 0.5).to(q), kinematic)
                trajectories = {"refined": {"rollout": (x[:, :h], g, q, p)}, "truth": {"rollout_from_truth": (start, g, q, p)},
                                "both": {"rollout": (x[:, :h], g, q, p.detach()), "rollout_from_truth": (start, g, q, p)}}[mode]
            # each run's length: refined_steps / truth_steps frames (null: the window and horizon; 0: no such run)
            steps = {"rollout": self.hparams.refined_steps, "rollout_from_truth": self.hparams.truth_steps}
            steps = {name: n_roll if steps[name] is None else steps[name] for name in trajectories}
            if max(steps.values()) > n_roll:
                raise ValueError(f"InferenceModule: refined_steps={self.hparams.refined_steps}, truth_steps={self.hparams.truth_steps}: "
                                 f"a window holds {n_roll} frames after the prior's history (observed - history + horizon)")
            for name, inputs in trajectories.items():  # "both": P learns from the true start only, dX through the refined one
                if steps[name] > 0:
                    run(name, 0, *inputs, steps[name])
        # the evaluation rolls from the LAST h refined frames, which the trajectory above never
        # starts from (only the per-position L1 trains them): tail_horizon > 0 rolls from them past
        # the window, so their motion is trained as the evaluation uses it. tail_detach_rigidness and
        # tail_detach_params keep Q and P out of it, as "both" keeps P out of the refined start: from
        # noisy frames, Q and P can absorb the start's errors (in the paper's scheme P is the true one)
        kt = self.hparams.tail_horizon
        if kt > 0:
            q_tail = q.detach() if self.hparams.tail_detach_rigidness else q
            p_tail = p_dx.detach() if self.hparams.tail_detach_params else p_dx
            run("tail", t - h, x[:, t - h :], g, q_tail, p_tail, kt)
        flat = [(name, piece) for name, found in pieces.items() for piece in found]
        errors: dict[str, list[torch.Tensor]] = {}
        for (name, piece), pred in zip(flat, rollout_runs(dyn, [piece for _, piece in flat], kinematic) if flat else []):
            errors.setdefault(name, []).append(((pred - piece[0][:, h:]) / scale).abs()[:, :, movable])  # [B, L, movable, 3]
        for name, found in errors.items():  # runs of one loss have one length: the mean over all of them
            losses[name] = torch.cat(found).mean()
        if self.estimator == "bernoulli" and self.hparams.rigidness and trajectories:
            # Q's only loss: the label of each instance flipped on the trajectory that trains P. The
            # bernoulli estimator keeps every run at n_roll (__init__)
            name = "rollout_from_truth" if "rollout_from_truth" in trajectories else next(iter(trajectories))
            start, _, _, p_run = trajectories[name]
            flipped = self.flipped_label_errors(start, truth[:, h : h + n_roll], g, q, p_run.detach(), planes, kinematic, n_roll)
            losses["rigidness"] = self.expected_rigidness_error(out["rigidness_prob"], q, errors[name][0].mean((1, 2, 3)), flipped)
        losses["refine"] = ((out["positions"] - batch["positions"][:, :t]) / scale).abs()[:, :, movable].mean()  # against the truth: logged; trained on with refine_weight
        p_error = (out["params_normalised"] - self.normalise_params(batch["params"])).abs()
        losses["loss"] = (losses.get("one_step", 0.0) + losses.get("rollout", 0.0) + losses.get("rollout_from_truth", 0.0)
                          + losses.get("tail", 0.0) + losses.get("rigidness", 0.0)
                          + (self.hparams.refine_weight * losses["refine"] if self.hparams.refine_weight else 0.0))
        if self.hparams.param_weight > 0:  # not the paper: a supervised shortcut for CPU-minute presets
            losses["loss"] = losses["loss"] + self.hparams.param_weight * p_error.mean()
        losses["param_mae_pct"] = (p_error * 50.0).mean()
        if self.hparams.rigidness and "rigid" in batch:  # Q's reading per object type, as task=evaluate reports it
            types = self.hparams.instance_types or [f"instance{m}" for m in range(q.shape[1])]
            for name, prob in mean_per_type(correct_rigidness_prob(out["rigidness_prob"].detach(), batch["rigid"][0]), types).items():
                losses[f"rigid_correct/{name}"] = prob
        return losses

    def training_step(self, batch, batch_idx):
        losses = self._losses(batch, noise=True)
        self.log_dict({f"train/{k}": v for k, v in losses.items()}, batch_size=batch["proposals"].shape[0], prog_bar=False)
        self.log("train/loss_bar", losses["loss"], prog_bar=True, logger=False, batch_size=batch["proposals"].shape[0])
        return losses["loss"]

    def validation_step(self, batch, batch_idx):
        losses = self._losses(batch)
        self.log_dict({f"val/{k}": v for k, v in losses.items()}, batch_size=batch["proposals"].shape[0], prog_bar=False)

    def on_fit_start(self) -> None:
        if self.dynamics is not None:
            self.dynamics.to(self.device)

    def on_train_batch_start(self, batch, batch_idx) -> None:
        super().on_train_batch_start(batch, batch_idx)
        k = self.hparams.bernoulli_from_step
        if k is not None and self.estimator == "blend" and self.global_step >= k:
            self.estimator = "bernoulli"
            log.info(f"InferenceModule: step {self.global_step}: Q is now trained as bernoulli (bernoulli_from_step={k})")

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["rigidness_estimator"] = self.estimator

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """The estimator the checkpoint was saved with (a resumed or evaluated blend-then-bernoulli run)."""
        self.estimator = checkpoint.get("rigidness_estimator", self.hparams.rigidness_estimator)

    def param_pathway(self) -> list[nn.Parameter]:
        """The weights only P's loss reaches: the parameter head, and the parameter encoder when separate."""
        modules = [self.param_head] + ([self.param_encoder] if self.param_encoder is not None else [])
        return [w for m in modules for w in m.parameters()]

    def configure_gradient_clipping(self, optimizer, gradient_clip_val=None, gradient_clip_algorithm=None) -> None:
        """The trainer's norm clipping applied to each network on its own when P has its own
        (``separate_param_net``): the parameter pathway's gradient norm and the rest's are each
        clipped to ``gradient_clip_val``. One global norm would scale P's small gradients by the
        refinement network's norm, a factor that changes from step to step and has nothing to do
        with P. Value clipping, or one shared encoder, clips as Lightning does."""
        if not gradient_clip_val or self.param_encoder is None or (gradient_clip_algorithm or "norm") != "norm":
            self.clip_gradients(optimizer, gradient_clip_val, gradient_clip_algorithm)
            return
        for weights in self.pathway_and_rest():
            torch.nn.utils.clip_grad_norm_([w for w in weights if w.grad is not None], gradient_clip_val)

    def pathway_and_rest(self) -> tuple[list[nn.Parameter], list[nn.Parameter]]:
        """(``param_pathway()``, every other weight): each weight in exactly one."""
        pathway = self.param_pathway()
        in_pathway = {id(w) for w in pathway}
        return pathway, [w for w in self.parameters() if id(w) not in in_pathway]

    def configure_optimizers(self):
        """Adam at ``lr``; the parameter pathway at ``param_lr`` when set (Adam moves a weight by
        about its rate a step)."""
        if self.hparams.param_lr is None:
            return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)
        pathway, rest = self.pathway_and_rest()
        return torch.optim.Adam([{"params": rest}, {"params": pathway, "lr": self.hparams.param_lr}], lr=self.hparams.lr)

    def base_learning_rates(self) -> list[float]:
        """The rate of each of configure_optimizers' parameter groups, which ``lr_anneal_steps`` scales."""
        return [self.hparams.lr] + ([] if self.hparams.param_lr is None else [self.hparams.param_lr])
