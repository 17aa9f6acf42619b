"""The EMA of a stage's weights (``model.<stage>.ema.decay``): what last.ckpt holds, resuming it,
and recovering the trained weights."""

from __future__ import annotations

import lightning as L
import pytest
import torch
from omegaconf import OmegaConf
from torch.utils.data import DataLoader, TensorDataset

from vgpl.tasks.stage import fit
from vgpl.weight_averaging import ExponentialMovingAverage, ema_decay_at, trained_weights_checkpoint

DECAY = 0.8


class LinearFit(L.LightningModule):
    """A linear regression by SGD that records its weight after every optimiser step."""

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.layer = torch.nn.Linear(2, 1)
        self.history: list[torch.Tensor] = []

    def training_step(self, batch, batch_idx):
        x, y = batch
        return torch.nn.functional.mse_loss(self.layer(x), y)

    def on_train_batch_end(self, outputs, batch, batch_idx) -> None:
        self.history.append(self.layer.weight.detach().clone())

    def validation_step(self, batch, batch_idx):
        x, y = batch
        self.log("val/loss", torch.nn.functional.mse_loss(self.layer(x), y))

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.05)


class Data(L.LightningDataModule):
    """32 points of a plane, in a fixed order (8 steps an epoch): a resumed run sees what a straight one does."""

    def __init__(self) -> None:
        super().__init__()
        x = torch.randn(32, 2, generator=torch.Generator().manual_seed(1))
        self.points = TensorDataset(x, x @ torch.tensor([[2.0], [-1.0]]) + 0.5)

    def train_dataloader(self):
        return DataLoader(self.points, batch_size=4)

    def val_dataloader(self):
        return DataLoader(self.points, batch_size=32)


def train(tmp_path, max_steps: int, ema: dict | None, ckpt_path: str | None = None) -> LinearFit:
    cfg = OmegaConf.create({
        "paths": {"ckpt_dir": str(tmp_path)}, "ckpt_path": ckpt_path,
        "trainer": {"accelerator": "cpu", "max_steps": max_steps, "max_epochs": -1, "enable_progress_bar": False,
                    "enable_model_summary": False, "val_check_interval": 5, "check_val_every_n_epoch": None},
    })
    model = LinearFit()
    fit(cfg, "toy", OmegaConf.create({"ema": ema}), model, Data())
    return model


def by_hand(history: list[torch.Tensor], decay: float) -> torch.Tensor:
    average = history[0]
    for n, w in enumerate(history[1:], start=1):
        d = ema_decay_at(decay, n)
        average = d * average + (1 - d) * w
    return average


def test_the_average_is_a_plain_mean_until_it_spans_its_window():
    weights = [torch.tensor(float(k)) for k in range(5)]
    assert by_hand(weights, 0.9) == pytest.approx(2.0)  # 5 steps < 1 / (1 - 0.9): the mean
    assert ema_decay_at(0.998, 0) == 0.0 and ema_decay_at(0.998, 3) == 0.75
    assert ema_decay_at(0.998, 499) == pytest.approx(0.998) and ema_decay_at(0.998, 10_000) == 0.998


def test_last_ckpt_holds_the_average_and_the_trained_weights(tmp_path):
    model = train(tmp_path, 12, {"decay": DECAY, "start_step": 0})
    ckpt = torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)
    assert len(model.history) == 12
    torch.testing.assert_close(ckpt["state_dict"]["layer.weight"], by_hand(model.history, DECAY))
    # saved after fit: the trained weights, not the average the callback copied in at the end
    torch.testing.assert_close(ckpt["current_model_state"]["layer.weight"], model.history[-1])
    assert not torch.allclose(model.history[-1], by_hand(model.history, DECAY))


def test_averaging_starts_at_start_step(tmp_path):
    model = train(tmp_path, 12, {"decay": DECAY, "start_step": 6})
    ckpt = torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)
    torch.testing.assert_close(ckpt["state_dict"]["layer.weight"], by_hand(model.history[6:], DECAY))


def test_a_resumed_run_continues_both_the_weights_and_their_average(tmp_path):
    """The resumed fit starts from the trained weights (not their average) and carries the average
    on (its count too: the warm-up does not restart). Lightning replays the data differently after a
    mid-epoch stop, so the check is against the two fits' own step records."""
    first = train(tmp_path, 8, {"decay": DECAY})
    before = torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)
    resumed = train(tmp_path, 16, {"decay": DECAY}, ckpt_path="last")
    assert len(resumed.history) == 8
    # its first step is one SGD step on the first batch from the trained weights (the average differs)
    start = LinearFit()
    start.load_state_dict(before["current_model_state"])
    x, y = next(iter(Data().train_dataloader()))
    torch.nn.functional.mse_loss(start.layer(x), y).backward()
    torch.testing.assert_close(resumed.history[0], first.history[-1] - 0.05 * start.layer.weight.grad)
    assert not torch.allclose(before["state_dict"]["layer.weight"], first.history[-1])
    ckpt = torch.load(tmp_path / "toy" / "last.ckpt", weights_only=False)
    torch.testing.assert_close(ckpt["state_dict"]["layer.weight"], by_hand(first.history + resumed.history, DECAY))
    torch.testing.assert_close(ckpt["current_model_state"]["layer.weight"], resumed.history[-1])


def test_without_ema_the_checkpoint_is_plain_and_cannot_be_split(tmp_path):
    model = train(tmp_path, 6, None)
    last = tmp_path / "toy" / "last.ckpt"
    ckpt = torch.load(last, weights_only=False)
    assert "current_model_state" not in ckpt
    torch.testing.assert_close(ckpt["state_dict"]["layer.weight"], model.history[-1])
    with pytest.raises(KeyError, match=r"last\.ckpt: no 'current_model_state'"):
        trained_weights_checkpoint(last, tmp_path / "toy" / "trained.ckpt")


def test_the_trained_weights_are_recovered_into_a_loadable_checkpoint(tmp_path):
    model = train(tmp_path, 6, {"decay": DECAY})
    out = trained_weights_checkpoint(tmp_path / "toy" / "last.ckpt", tmp_path / "toy" / "trained.ckpt")
    loaded = LinearFit.load_from_checkpoint(out)
    torch.testing.assert_close(loaded.layer.weight, model.history[-1])


@pytest.mark.parametrize("decay,start,match", [(1.0, 0, "decay=1.0"), (0.0, 0, "decay=0.0"), (0.9, -1, "start_step=-1")])
def test_bad_settings_are_refused_by_name(decay, start, match):
    with pytest.raises(ValueError, match=match):
        ExponentialMovingAverage(decay, start)
