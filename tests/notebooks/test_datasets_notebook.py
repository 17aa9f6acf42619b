"""notebooks/datasets.ipynb runs on a dataset the generate task writes, and shows what it claims."""

from __future__ import annotations

from hydra import compose, initialize_config_dir

from tests.conftest import REPO
from tests.notebook import output_types, run_notebook, text_output
from vgpl.data.shard import read_shard
from vgpl.tasks.generate import generate


def test_datasets_notebook_projects_particles_and_reports_each_rollout(tmp_path):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[
            "task=generate", "env=fluid_cube", "env.scene.n_steps=12", f"data.root={tmp_path}", "data.n_rollouts=3",
            "data.train_fraction=0.7", "data.shard_size=3", "data.batch_size=3", "data.progress=false", f"paths.output_dir={tmp_path}",
        ])
    generate(cfg)
    split = tmp_path / "fluid_cube" / "train"
    nb = run_notebook(REPO / "notebooks/datasets.ipynb", tmp_path, SPLIT=str(split), FRAME=10)
    printed = text_output(nb)
    shard = read_shard(next(split.glob("shard_*.h5")))
    assert f"fluid_cube {shard.positions.shape}" in printed
    for viscosity in shard.params[:, 0]:
        assert f"viscosity {viscosity:6.1f}: cube height" in printed
    assert "image/png" in output_types(nb)  # the frame with the projected particles
