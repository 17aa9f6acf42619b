"""Which inferred quantity makes a test video's rollout diverge? (session 25; a diagnostic)

For the given test videos (rollout ids, e.g. the worst rows of a task=evaluate params.csv) and
each inference checkpoint: the inferred rigidness Q and parameters P, then the future MSE x 1e4 at
T+n_steps when the dynamics prior rolls from the inferred (X, G, Q, P) and when one of them is
swapped for the truth (X: the recorded observed frames; G: the true grouping; Q: the true labels;
P: the true parameters). The one whose swap removes the blow-up is what triggered it.

Usage: python scripts/experiments/diverging_videos.py --env mass_rope CKPT [CKPT ...] --videos 996 928 950
       [--root data/standard] [--prior checkpoints/standard/<env>/dynamics/last.ckpt] [--visual ...]
"""

from __future__ import annotations

import argparse

import torch

from vgpl.checkpoint import load_stage, scene_of
from vgpl.data.trajectories import ground_truth_grouping, load_split
from vgpl.eval.error_breakdown import rollout_mse_x1e4
from vgpl.eval.grounding import infer_in_chunks, observed_proposals
from vgpl.eval.rollout import rollout
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.inference import InferenceModule
from vgpl.models.visual_prior import VisualPrior


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--env", required=True, choices=["rigid_fall", "fluid_cube", "mass_rope"])
    parser.add_argument("--videos", type=int, nargs="+", required=True, help="rollout ids of test videos")
    parser.add_argument("--root", default="data/standard")
    parser.add_argument("--prior", help="default checkpoints/standard/<env>/dynamics/last.ckpt")
    parser.add_argument("--visual", help="default checkpoints/standard/<env>/visual/last.ckpt")
    parser.add_argument("--observed", type=int, default=10)
    parser.add_argument("--n-steps", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(1)
    dynamics, cfg = load_stage(args.prior or f"checkpoints/standard/{args.env}/dynamics/last.ckpt", DynamicsPrior, env=args.env)
    visual, _ = load_stage(args.visual or f"checkpoints/standard/{args.env}/visual/last.ckpt", VisualPrior, env=args.env)
    scene, start = scene_of(cfg), cfg.env.get("start_frame", 0)
    test = load_split(args.root, args.env, "test", images=True)
    ids = test.rollout_ids.tolist()
    missing = [v for v in args.videos if v not in ids]
    if missing:
        raise SystemExit(f"--videos: {missing} are not rollout ids of {args.root}/{args.env}/test ({ids[0]}..{ids[-1]})")
    pick = [ids.index(v) for v in args.videos]
    kinematic = torch.as_tensor(scene.kinematic)
    h, t, n = dynamics.hparams.history, args.observed, args.n_steps
    proposals, logits = observed_proposals(visual, test.images[pick], start, t)[:2]  # the paper's window_pool=last
    positions = test.positions[pick]
    seen = positions[:, start : start + t]
    frames = slice(start + t - h, start + t + n)
    planes = scene.planes_at(test.actions[pick][:, frames])
    truth = positions[:, start + t : frames.stop]
    true_g, true_q = ground_truth_grouping(test).expand(len(pick), -1, -1), test.rigid.float().expand(len(pick), -1)
    print(f"{args.env} test videos {args.videos}: true {scene.param_names} {test.params[pick].squeeze(-1).tolist()}, rigid {test.rigid.tolist()}")
    for ckpt in args.checkpoints:
        inference, _ = load_stage(ckpt, InferenceModule, env=args.env)
        with torch.no_grad():
            out = infer_in_chunks(inference, proposals, logits, kinematic, 8)
            x = torch.where(kinematic[None, None, :, None], seen, out["positions"])
            print(f"{ckpt}\n  inferred Q {[[round(v, 3) for v in q] for q in out['rigidness'].tolist()]}, P {[round(v, 3) for v in out['params'].squeeze(-1).tolist()]}")
            for label, xs, g, q, p in [("inferred", x, out["grouping"], out["rigidness"], out["params"]),
                                       ("true X", seen, out["grouping"], out["rigidness"], out["params"]),
                                       ("true G", x, true_g, out["rigidness"], out["params"]),
                                       ("true Q", x, out["grouping"], true_q, out["params"]),
                                       ("true P", x, out["grouping"], out["rigidness"], test.params[pick]),
                                       ("all true", seen, true_g, true_q, test.params[pick])]:
                driven = torch.cat([xs[:, -h:], truth], 1)
                pred = rollout(dynamics, driven, g, q, p, planes, kinematic, n)
                print(f"  {label:9s} T+{n} MSE x1e4: {[round(v, 1) for v in rollout_mse_x1e4(pred, truth, n).tolist()]}")


if __name__ == "__main__":
    main()
