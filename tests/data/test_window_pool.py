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
