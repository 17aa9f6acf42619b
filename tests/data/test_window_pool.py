"""window_pool: an observed window's proposals averaged over the visual prior's windows, never
reading a frame after the window."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vgpl.data.proposals import Proposals, propose_videos, propose_windows, read_proposals, write_proposals
from vgpl.data.schema import DatasetError
from vgpl.data.window_pool import pool_windows
from vgpl.models.visual_prior import VisualPrior


def _visual():
    torch.manual_seed(0)
    return VisualPrior(n_particles=5, n_instances=2, channels=[4, 4, 4, 4], hidden=8).eval()


def test_slots_hold_every_windows_prediction_of_every_frame_it_holds():
    model = _visual()
    images = torch.randint(0, 255, (2, 7, 120, 160, 3), dtype=torch.uint8)
    pos, logits, slots = propose_windows(model, images, batch_size=3)
    assert slots.shape == (2, 7, 4, 5, 3)
    paper = propose_videos(model, images, batch_size=3)
    torch.testing.assert_close(pos, paper[0])
    torch.testing.assert_close(logits, paper[1])
    with torch.no_grad():
        window, _ = model.propose(images[1:, 2:6])  # frames 2..5
    for k in range(4):
        torch.testing.assert_close(slots[1, 2 + k, k], window[0, k])  # frame 2 + k is slot k of the window starting at 2
    # frame 1 lies in windows starting at 0 and 1 only (slots 1, 0); frame 6 in those starting at 3 (slot 3) only
    assert not slots[:, 1, :2].isnan().any() and slots[:, 1, 2:].isnan().all()
    assert not slots[:, 6, 3].isnan().any() and slots[:, 6, :3].isnan().all()


def test_mean_averages_the_windows_that_end_within_the_observed_frames():
    f, t = 4, 6
    slots = torch.arange(t * f, dtype=torch.float).reshape(1, t, f, 1, 1).expand(1, t, f, 1, 3).clone()  # slot (i, k) = 4 i + k
    positions = torch.full((1, t, 1, 3), -1.0)
    pooled = pool_windows(positions, slots, "mean")[0, :, 0, 0]
    # frame i at slot k is in the window ending at i - k + 3: kept where that is <= 5
    expected = [sum(4 * i + k for k in range(f) if i - k + 3 <= 5) / sum(1 for k in range(f) if i - k + 3 <= 5) for i in range(t)]
    torch.testing.assert_close(pooled, torch.tensor(expected))
    assert pooled[-1] == 4 * 5 + 3  # the last frame: the one window ending at it, as the paper has it
    slots[0, 0, 1:] = float("nan")  # a frame with windows missing (the video's first frames): the rest
    assert pool_windows(positions, slots, "mean")[0, 0, 0, 0] == 0.0
    slots[0, 0] = float("nan")  # none at all: the paper's proposal
    assert pool_windows(positions, slots, "mean")[0, 0, 0, 0] == -1.0
    assert torch.equal(pool_windows(positions, slots, "last"), positions) and torch.equal(pool_windows(positions, None, "mean"), positions)
    for no_slots in (None, slots):  # a bad pool is refused before the paper's shortcut, with or without slots
        with pytest.raises(ValueError, match="window_pool='median'"):
            pool_windows(positions, no_slots, "median")


def test_an_index_picks_the_observed_window_out_of_positions_and_slots_alike():
    """pool_windows(p, s, pool, index) is pool_windows(p[index], s[index], pool): the frames after
    the index's last are not read, whichever leading dimensions it picks."""
    positions, slots = torch.rand(3, 9, 5, 3), torch.rand(3, 9, 4, 5, 3)
    slots[:, -3:] = float("nan")
    for index in (np.s_[:, :6], np.s_[1, 2:8], np.s_[:2, 3:5]):
        torch.testing.assert_close(pool_windows(positions, slots, "mean", index), pool_windows(positions[index], slots[index], "mean"))
        assert torch.equal(pool_windows(positions, slots, "last", index), positions[index])
        assert torch.equal(pool_windows(positions, None, "mean", index), positions[index])
    with pytest.raises(ValueError, match="pool='median': expected 'last'.*or 'mean'"):
        pool_windows(positions, slots, "median")


def test_a_pooled_window_reads_no_frame_after_it():
    """Changing the video after the observed frames [2, 8) leaves their pooled proposals as they were."""
    model = _visual()
    images = torch.randint(0, 255, (1, 12, 120, 160, 3), dtype=torch.uint8)
    changed = images.clone()
    changed[:, 8:] = torch.randint(0, 255, changed[:, 8:].shape, dtype=torch.uint8)
    pooled = [pool_windows(pos[:, 2:8], slots[:, 2:8], "mean") for pos, _, slots in (propose_windows(model, x) for x in (images, changed))]
    torch.testing.assert_close(pooled[0], pooled[1])
    whole = propose_windows(model, images)
    assert not torch.allclose(pool_windows(whole[0][:, 2:10], whole[2][:, 2:10], "mean")[:, :6], pooled[0])  # a longer window reads them


def test_slots_survive_the_proposals_file_and_a_mismatch_names_it(tmp_path):
    positions, logits, slots = torch.rand(2, 6, 5, 3), torch.rand(2, 6, 5, 2), torch.rand(2, 6, 4, 5, 3)
    path = write_proposals(tmp_path / "train.h5", Proposals(positions, logits, torch.arange(2), {"source": "visual"}, slots))
    torch.testing.assert_close(read_proposals(path).slots, slots)
    assert read_proposals(write_proposals(tmp_path / "old.h5", Proposals(positions, logits, torch.arange(2), {}))).slots is None
    write_proposals(path, Proposals(positions, logits, torch.arange(2), {}, slots[:, :5]))
    with pytest.raises(DatasetError, match=r"train.h5: 'slots' \(2, 5, 4, 5, 3\) do not match 'positions' \(2, 6, 5, 3\)"):
        read_proposals(path)


def test_slots_are_read_only_for_the_pool_that_needs_them_and_a_visual_file_without_them_is_refused_by_name(tmp_path):
    """read_proposals(path, window_pool): 'last' leaves the slots on disk, 'mean' reads them and
    refuses a visual prior's file that has none (the recorded particles have no windows: read as
    they are); None reads what the file holds. The export's reader for eval.proposals=exported
    refuses the same way."""
    from vgpl.data.proposals import exported_proposals

    positions, logits, slots = torch.rand(2, 6, 5, 3), torch.rand(2, 6, 5, 2), torch.rand(2, 6, 4, 5, 3)
    path = write_proposals(tmp_path / "test.h5", Proposals(positions, logits, torch.arange(2), {"source": "visual"}, slots))
    assert read_proposals(path, "last").slots is None
    torch.testing.assert_close(read_proposals(path, "mean").slots, slots)
    torch.testing.assert_close(exported_proposals(path, torch.tensor([1]), 4, "mean").slots, slots[[1], :4])
    old = write_proposals(tmp_path / "old.h5", Proposals(positions, logits, torch.arange(2), {"source": "visual"}))
    assert read_proposals(old, "last").slots is None and read_proposals(old).slots is None
    for read in (lambda: read_proposals(old, "mean"), lambda: exported_proposals(old, torch.tensor([1]), 4, "mean")):
        with pytest.raises(DatasetError, match=r"old.h5: no 'slots' .*window_pool='mean' needs them; re-export with task=export_proposals"):
            read()
    truth = write_proposals(tmp_path / "truth.h5", Proposals(positions, logits, torch.arange(2), {"source": "truth"}))
    assert read_proposals(truth, "mean").slots is None
    with pytest.raises(ValueError, match="window_pool='median'"):
        read_proposals(path, "median")


def _experiment_script(name: str):
    """scripts/experiments/<name>.py as a module (the scripts are not a package)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[2] / "scripts" / "experiments" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_merged_training_proposals_keep_every_videos_slots():
    """scripts/experiments/merge_proposals.py: the windows' slots follow their videos into the
    merged file (window_pool=mean needs every video's), and are dropped where a file lacks them."""
    merge_proposals = _experiment_script("merge_proposals")

    def prop(ids, frames, with_slots=True):
        r = len(ids)
        slots = torch.rand(r, frames, 4, 5, 3) if with_slots else None
        return Proposals(torch.rand(r, frames, 5, 3), torch.rand(r, frames, 5, 2), torch.tensor(ids), {"env": "mass_rope"}, slots)

    first, rest = prop([4, 1], 8), prop([1, 0, 3], 6)
    merged = merge_proposals.merge(first, rest)
    assert merged.rollout_ids.tolist() == [0, 1, 3, 4] and merged.slots.shape == (4, 6, 4, 5, 3)
    for row, (source, k) in enumerate([(rest, 1), (first, 1), (rest, 2), (first, 0)]):  # video 1 from FIRST
        torch.testing.assert_close(merged.slots[row], source.slots[k, :6])
        torch.testing.assert_close(merged.positions[row], source.positions[k, :6])
    assert merge_proposals.merge(first, prop([0], 6, with_slots=False)).slots is None


def test_window_slots_measures_each_slots_error_and_its_lead_along_the_motion():
    """scripts/experiments/window_slots.py: slots placed a known distance ahead of (or behind) the
    true motion read back that lead in mm and that error; the pooled proposals average the slots
    of the windows that end within the observed frames."""
    t, f, n = 8, 4, 5
    frames = torch.arange(t, dtype=torch.float)[None, :, None, None]
    truth = torch.zeros(2, t, n, 3) + frames * torch.tensor([0.01, 0.0, 0.0])  # 10 mm a frame along x
    lead = torch.tensor([3.0, 1.0, -1.0, -3.0]) * 1e-3  # slot k: this far ahead along the motion
    slots = truth[:, :, None] + lead[None, None, :, None, None] * torch.tensor([1.0, 0.0, 0.0])
    for k in range(1, f):
        slots[:, :k, k] = float("nan")  # frame t < k: no window starts at t - k
    first = torch.stack([slots[:, k, k] for k in range(f - 1)], 1)  # frames 0 .. F - 2: the first window's
    paper = torch.cat([first, slots[:, f - 1 :, f - 1]], 1)  # then each frame from the window ending at it
    movable = torch.tensor([True, True, True, True, False])
    report = _experiment_script("window_slots").slot_report(paper, slots, truth, movable)
    assert report["slot_lead_mm"] == pytest.approx([3.0, 1.0, -1.0, -3.0], abs=1e-4)
    assert report["slot_mse_x1e4"] == pytest.approx([(x * 1e-3) ** 2 / 3 * 1e4 for x in (3.0, 1.0, -1.0, -3.0)], rel=1e-4)
    assert report["mean"] == pytest.approx(float(((pool_windows(paper, slots, "mean") - truth)[..., :4, :] ** 2).mean() * 1e4))
    assert report["per_frame"][-1]["mean"] == report["per_frame"][-1]["last"]  # the last frame: the paper's one window
    assert report["per_frame"][3]["mean"] < report["per_frame"][3]["last"]  # +3, +1, -1 mm and -3 mm average towards zero


def test_proposals_travel_as_float16_parts_and_join_into_the_same_file(tmp_path):
    """scripts/experiments/proposals_parts.py: a proposals file split into parts of at most N
    rollouts (a device call returns files of at most 16 MB) joins back into one file with the same
    rollouts in order, its attrs, no slots, and positions within float16's rounding (< 1e-3 of 2 m)."""
    parts = _experiment_script("proposals_parts")
    torch.manual_seed(0)
    source = Proposals(torch.rand(5, 6, 4, 3) * 2.0, torch.randn(5, 6, 4, 2), torch.tensor([7, 3, 9, 0, 1]),
                       {"env": "fluid_cube", "split": "train", "visual_checkpoint": "v.ckpt", "source": "visual", "noise_std": 0.0},
                       torch.rand(5, 6, 4, 4, 3))
    written = parts.pack(write_proposals(tmp_path / "train.h5", source), tmp_path / "out", rollouts=2)
    assert [p.name for p in written] == ["train_part0.npz", "train_part1.npz", "train_part2.npz"]
    joined = read_proposals(parts.unpack(list(reversed(written)), tmp_path / "joined" / "train.h5"))  # parts in any order
    assert joined.rollout_ids.tolist() == [7, 3, 9, 0, 1] and joined.slots is None
    assert joined.positions.dtype == torch.float32 and joined.positions.shape == (5, 6, 4, 3)
    assert (joined.positions - source.positions).abs().max() <= 2.0 * 2**-11  # float16's spacing below 2 m is at most 2^-10
    torch.testing.assert_close(joined.logits, source.logits, atol=4e-3, rtol=1e-3)
    assert {k: joined.attrs[k] for k in ("env", "split", "visual_checkpoint", "source")} == {
        "env": "fluid_cube", "split": "train", "visual_checkpoint": "v.ckpt", "source": "visual"}
