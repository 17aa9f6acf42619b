"""One training proposals file from two visual priors: every video of FIRST, then the videos of REST
that FIRST lacks, over the frames both cover (session 41, RigidFall: the lent H200's visual prior
exported 300 of the 900 training videos, session 36's CPU prior can export all 900; the inference
module trained on the 300 reads gravity at 3.0% on them and 4.7% held out).

    python scripts/experiments/merge_proposals.py FIRST.h5 REST.h5 OUT.h5
"""

from __future__ import annotations

import argparse

import torch

from vgpl.data.proposals import Proposals, read_proposals, write_proposals


def merge(first: Proposals, rest: Proposals) -> Proposals:
    """[R1 + R2', T, N, *] ordered by rollout id, T the shorter of the two; R2' = rest's rollouts not in first.
    The windows' slots are kept where both files have them, dropped otherwise (window_pool=last only)."""
    if first.positions.shape[2:] != rest.positions.shape[2:] or first.logits.shape[3] != rest.logits.shape[3]:
        raise SystemExit(f"merge_proposals: particles/instances differ: {tuple(first.logits.shape[2:])} against {tuple(rest.logits.shape[2:])}")
    if first.attrs.get("env") != rest.attrs.get("env"):
        raise SystemExit(f"merge_proposals: env {first.attrs.get('env')} against {rest.attrs.get('env')}")
    frames = min(first.positions.shape[1], rest.positions.shape[1])
    extra = ~torch.isin(rest.rollout_ids, first.rollout_ids)
    ids = torch.cat([first.rollout_ids, rest.rollout_ids[extra]])
    order = ids.argsort()
    positions = torch.cat([first.positions[:, :frames], rest.positions[extra, :frames]])[order]
    logits = torch.cat([first.logits[:, :frames], rest.logits[extra, :frames]])[order]
    both = first.slots is not None and rest.slots is not None  # window_pool=mean needs every video's
    slots = torch.cat([first.slots[:, :frames], rest.slots[extra, :frames]])[order] if both else None
    attrs = dict(first.attrs) | {"visual_checkpoint": f"{first.attrs.get('visual_checkpoint')} ({len(first.rollout_ids)} videos) + "
                                                      f"{rest.attrs.get('visual_checkpoint')} ({int(extra.sum())} videos)"}
    return Proposals(positions, logits, ids[order], attrs, slots)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("first")
    parser.add_argument("rest")
    parser.add_argument("out")
    args = parser.parse_args()
    merged = merge(read_proposals(args.first), read_proposals(args.rest))
    write_proposals(args.out, merged)
    kept = "with" if merged.slots is not None else "without (a file had none: window_pool=last only)"
    print(f"{args.out}: {merged.positions.shape[0]} videos, {merged.positions.shape[1]} frames, {kept} slots ({merged.attrs['visual_checkpoint']})")


if __name__ == "__main__":
    main()
