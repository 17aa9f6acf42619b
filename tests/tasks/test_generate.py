from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import vgpl.tasks.generate as gen
from tests.conftest import REPO
from vgpl.data.schema import DatasetError, validate
from vgpl.data.shard import read_shard
from vgpl.tasks.generate import generate, plan_shards


def config(root, *overrides):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose(
            "config",
            overrides=[
                "task=generate", "env=rigid_fall", "env.scene.n_steps=8", f"data.root={root}",
                "data.n_rollouts=7", "data.train_fraction=0.8", "data.shard_size=2", "data.batch_size=2", "data.progress=false",
                "paths.output_dir=" + str(root), *overrides,
            ],
        )
    return cfg


def test_plan_splits_train_and_test_without_overlap():
    plans = plan_shards(20, 0.9, 4)
    ids = [g for p in plans for g in p.rollouts]
    assert sorted(ids) == list(range(20))
    assert [p.split for p in plans].count("test") == 1 and plans[-1].rollouts == (18, 19)
    with pytest.raises(ValueError, match="data.train_fraction"):
        plan_shards(10, 1.5, 4)


def test_generate_writes_valid_shards_that_never_repeat_a_rollout(tmp_path):
    summary = generate(config(tmp_path))
    assert summary["written"] == 4 and summary["rollouts_written"] == 7  # train 6 (3 shards), test 1 (1)
    shards = [read_shard(p) for p in summary["shards"]]
    ids = np.concatenate([s.rollout_ids for s in shards])
    assert sorted(ids.tolist()) == list(range(7))
    starts = np.concatenate([s.positions[:, 0] for s in shards]).reshape(7, -1)
    assert len({row.tobytes() for row in starts}) == 7  # every rollout starts differently
    params = np.concatenate([s.params for s in shards])
    assert len(set(params[:, 0].tolist())) == 7 and (params >= -15).all() and (params <= -5).all()
    assert validate(summary["shards"][0])["attrs"]["split"] == "train"


def test_same_seed_same_bytes_other_seed_other_data(tmp_path):
    a = generate(config(tmp_path / "a"))
    b = generate(config(tmp_path / "b"))
    c = generate(config(tmp_path / "c", "seed=1"))
    for pa, pb, pc in zip(a["shards"], b["shards"], c["shards"]):
        with h5py.File(pa) as fa, h5py.File(pb) as fb, h5py.File(pc) as fc:
            for key in ("positions", "images", "params"):
                assert fa[key][()].tobytes() == fb[key][()].tobytes()
            assert fa["positions"][()].tobytes() != fc["positions"][()].tobytes()


def test_killed_run_resumes_without_rewriting_finished_shards(tmp_path, monkeypatch):
    cfg = config(tmp_path)
    real_write, calls = gen.write_shard, []

    def dying_write(path, shard, level=4, **place):
        if len(calls) == 2:
            # the process dies while writing the third shard: a partial temporary file is left
            path.with_name(path.name + ".tmp").write_bytes(b"partial")
            raise KeyboardInterrupt
        calls.append(path)
        return real_write(path, shard, level, **place)

    monkeypatch.setattr(gen, "write_shard", dying_write)
    with pytest.raises(KeyboardInterrupt):
        generate(cfg)
    finished = {p: p.stat().st_mtime_ns for p in calls}
    monkeypatch.setattr(gen, "write_shard", real_write)
    summary = generate(cfg)
    assert summary["skipped"] == 2 and summary["written"] == 2
    assert all(p.stat().st_mtime_ns == t for p, t in finished.items())  # nothing rewritten
    for p in summary["shards"]:
        validate(p)
    again = generate(cfg)
    assert again["written"] == 0 and again["skipped"] == 4
    # the files of the resumed run are, byte for byte, those of an uninterrupted run (no time of writing in them)
    fresh = generate(config(tmp_path / "fresh"))
    for resumed, whole in zip(summary["shards"], fresh["shards"]):
        assert Path(resumed).read_bytes() == Path(whole).read_bytes(), resumed


def test_workers_split_the_shards(tmp_path):
    w0 = generate(config(tmp_path, "data.num_workers=2", "data.worker=0"))
    w1 = generate(config(tmp_path, "data.num_workers=2", "data.worker=1"))
    assert set(w0["shards"]).isdisjoint(w1["shards"])
    assert w0["written"] + w1["written"] == 4
    with pytest.raises(ValueError, match="data.worker"):
        generate(config(tmp_path, "data.num_workers=2", "data.worker=2"))


@pytest.mark.slow  # starts several processes
def test_worker_processes_make_the_same_bytes(tmp_path):
    one = generate(config(tmp_path / "one"))
    two = generate(config(tmp_path / "two", "data.processes=2"))
    assert two["written"] == 4
    for pa, pb in zip(one["shards"], two["shards"]):
        with h5py.File(pa) as fa, h5py.File(pb) as fb:
            assert fa["positions"][()].tobytes() == fb["positions"][()].tobytes()
            assert fa["images"][()].tobytes() == fb["images"][()].tobytes()


def test_changed_config_never_overwrites_existing_data(tmp_path):
    generate(config(tmp_path))
    before = (tmp_path / "rigid_fall/train/shard_00000.h5").read_bytes()
    with pytest.raises(DatasetError, match="dataset.json: .*rigid_fall belongs to another configuration"):
        generate(config(tmp_path, "env.scene.param_low=[-12.0]"))
    assert (tmp_path / "rigid_fall/train/shard_00000.h5").read_bytes() == before


def test_a_folder_written_before_claims_existed_is_not_claimed_over(tmp_path):
    """Without a dataset.json, the shards' own config_hash still refuses another configuration,
    and the refused run does not record itself as the folder's."""
    generate(config(tmp_path))
    (tmp_path / "rigid_fall/dataset.json").unlink()
    with pytest.raises(DatasetError, match="shard_00000.h5: exists with a different configuration"):
        generate(config(tmp_path, "seed=1"))
    assert not (tmp_path / "rigid_fall/dataset.json").exists()
    assert generate(config(tmp_path))["skipped"] == 4


def test_a_shard_is_placed_only_while_its_configuration_holds_the_folder(tmp_path, monkeypatch):
    """The claim is checked again when each shard is renamed into place: once another
    configuration holds the folder, the next shard is refused, its temporary file removed, and
    the shards placed before stay as they were."""
    real_simulate, manifest = gen.simulate_shard, tmp_path / "rigid_fall/dataset.json"

    def simulate_then_lose_the_folder(scene, plan, *args, **kwargs):
        shard = real_simulate(scene, plan, *args, **kwargs)
        if plan.index == 1:
            manifest.write_text(json.dumps({"config_hash": "0123456789abcdef", "seed": 1}))
        return shard

    monkeypatch.setattr(gen, "simulate_shard", simulate_then_lose_the_folder)
    with pytest.raises(DatasetError, match="dataset.json: .*another configuration \\(config_hash 0123456789abcdef, seed 1; this run: config_hash"):
        generate(config(tmp_path))
    train = tmp_path / "rigid_fall/train"
    assert sorted(p.name for p in train.iterdir()) == ["shard_00000.h5"]  # shard 1 neither placed nor left as .tmp
    assert validate(train / "shard_00000.h5")["attrs"]["seed"] == 0


@pytest.mark.slow  # starts several processes
def test_two_runs_of_other_seeds_started_together_never_mix(tmp_path):
    """Two generate processes, seeds 0 and 1, into one folder at the same time: one is refused
    with the claim's error before it writes, and every shard carries the other run's seed."""
    args = ["task=generate", "env=rigid_fall", "env.scene.n_steps=8", "data.n_rollouts=7", "data.shard_size=2", "data.progress=false",
            f"data.root={tmp_path}/data", "hydra.run.dir=" + str(tmp_path / "run_${seed}")]
    procs = [subprocess.Popen([sys.executable, str(REPO / "run.py"), *args, f"seed={seed}"], cwd=tmp_path, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for seed in (0, 1)]
    outcomes = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    assert sorted(rc == 0 for rc, _ in outcomes) == [False, True], outcomes
    winner = [rc for rc, _ in outcomes].index(0)
    refused = outcomes[1 - winner][1]
    assert "dataset.json" in refused and "belongs to another configuration" in refused
    shards = sorted((tmp_path / "data/rigid_fall").rglob("shard_*.h5"))
    assert len(shards) == 4 and {int(validate(p)["attrs"]["seed"]) for p in shards} == {winner}
    assert not list((tmp_path / "data/rigid_fall").rglob("*.tmp"))


@pytest.mark.slow  # starts several processes
def test_two_identical_runs_started_together_leave_whole_shards(tmp_path):
    """Two generate processes of one configuration into one folder at the same time (a resume
    started twice): both end with rc 0, each writes its own temporary files, and the shards are
    the bytes of a single run's."""
    args = ["task=generate", "env=rigid_fall", "env.scene.n_steps=8", "data.n_rollouts=10", "data.shard_size=2", "data.batch_size=2",
            "data.progress=false", "seed=0"]
    procs = [subprocess.Popen([sys.executable, str(REPO / "run.py"), *args, f"data.root={tmp_path}/data", f"hydra.run.dir={tmp_path}/h{k}"],
                              cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k in (1, 2)]
    outcomes = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    assert [rc for rc, _ in outcomes] == [0, 0], outcomes
    single = run_py(*args, f"data.root={tmp_path}/single", f"hydra.run.dir={tmp_path}/single_run", cwd=tmp_path)
    assert single.returncode == 0, single.stderr[-2000:]
    both = sorted((tmp_path / "data/rigid_fall").rglob("shard_*.h5"))
    alone = sorted((tmp_path / "single/rigid_fall").rglob("shard_*.h5"))
    assert [p.relative_to(tmp_path / "data") for p in both] == [p.relative_to(tmp_path / "single") for p in alone] and len(both) == 6
    for a, b in zip(both, alone):
        assert a.read_bytes() == b.read_bytes(), a
    assert not list((tmp_path / "data/rigid_fall").rglob("*.tmp"))

def test_the_learned_stages_env_keys_leave_the_data_as_it_is(tmp_path):
    """Only the env's scene (and name) makes the data: a dataset stays valid when the env config's
    keys for the models change (otherwise each such change would refuse the data as "another
    configuration"), and a scene change is still refused."""
    first = generate(config(tmp_path))
    again = generate(config(tmp_path, "env.graph_radius=0.1", "env.rigid_head=pooled", "env.start_frame=3",
                            "env.prior_history=2"))
    assert (first["written"], again["written"]) == (4, 0)
    assert gen.config_hash(config(tmp_path).env, config(tmp_path).data, 0) != gen.config_hash(
        config(tmp_path, "env.scene.n_steps=9").env, config(tmp_path).data, 0)


def run_py(*args, cwd):
    return subprocess.run([sys.executable, str(REPO / "run.py"), *args], cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # starts several processes
def test_hydra_multirun_splits_generation_across_jobs(tmp_path):
    proc = run_py(
        "-m", "task=generate", "env=mass_rope", "env.scene.n_steps=5", f"data.root={tmp_path}/data",
        "data.n_rollouts=4", "data.shard_size=1", "data.num_workers=2", "data.worker=0,1", "data.progress=false",
        f"hydra.sweep.dir={tmp_path}/multirun", cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "multirun").iterdir() if p.is_dir()) == ["0", "1"]
    files = sorted((tmp_path / "data/mass_rope").rglob("*.h5"))
    assert len(files) == 4
    assert sorted(int(read_shard(f, images=False).rollout_ids[0]) for f in files) == [0, 1, 2, 3]


def test_demo_job_writes_data_and_previews_for_all_envs(tmp_path):
    proc = run_py("task=demo", "task.n_steps=6", "task.n_rollouts=2", f"data.root={tmp_path}/data", f"hydra.run.dir={tmp_path}/run", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    for env in ("rigid_fall", "fluid_cube", "mass_rope"):
        gif = tmp_path / "run/preview" / f"{env}.gif"
        assert gif.stat().st_size > 1000
        from PIL import Image

        assert Image.open(gif).n_frames == 6
        validate(next((tmp_path / "data" / env / "train").glob("*.h5")))
    assert Image.open(tmp_path / "run/preview/envs.png").size == (3 * 320, 240)


def test_the_main_job_is_the_quick_pipeline(tmp_path):
    proc = run_py("--cfg", "job", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "name: pipeline" in proc.stdout and "tag: quick" in proc.stdout and "name: rigid_fall" in proc.stdout


def test_bad_option_gives_one_clear_error(tmp_path):
    proc = run_py("task=generate", "env=water", cwd=tmp_path)
    assert proc.returncode != 0 and "water" in proc.stderr and "rigid_fall" in proc.stderr


@pytest.mark.slow  # starts several processes
def test_local_launcher_runs_a_two_job_sweep_in_parallel_processes(tmp_path):
    proc = run_py("-m", "hydra/launcher=local", "task=generate", "env=rigid_fall,mass_rope", "env.scene.n_steps=4", "data.n_rollouts=2", "data.train_fraction=0.5",
                  "data.shard_size=2", "data.render=false", "data.progress=false", "threads=1", f"data.root={tmp_path}/data",
                  f"hydra.sweep.dir={tmp_path}/sweep", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Joblib.Parallel(n_jobs=2" in proc.stdout + proc.stderr
    assert sorted(p.name for p in (tmp_path / "sweep").iterdir() if p.is_dir()) == ["0", "1"]
    for env in ("rigid_fall", "mass_rope"):
        validate(next((tmp_path / "data" / env / "train").glob("*.h5")))


@pytest.mark.parametrize(("overrides", "message"), [
    (["data.n_rollouts=abc"], r"data\.n_rollouts='abc': expected an integer"),
    (["data.train_fraction=most"], r"data\.train_fraction='most': expected a number"),
    (["data.n_rollouts=2"], r"data\.n_rollouts=2 with data\.train_fraction=0\.8 leaves the test split empty .* at least 8 rollouts"),
    (["data.batch_size=0"], r"data\.batch_size=0: expected an integer >= 1"),
    (["data.processes=1.5"], r"data\.processes=1\.5: expected an integer"),
    (["data.worker=a"], r"data\.worker='a': expected an integer"),
    (["seed=abc"], r"seed='abc': expected an integer"),
    (["data.render=maybe"], r"data\.render='maybe': expected true or false"),
])
def test_bad_sizes_are_refused_by_their_key_before_anything_is_simulated(tmp_path, overrides, message):
    with pytest.raises(ValueError, match=message):
        generate(config(tmp_path, *overrides))
    assert not (tmp_path / "rigid_fall").exists()
    assert generate(config(tmp_path, "data.n_rollouts=2", "data.train_fraction=1.0"))["written"] == 1  # no test split asked for: fine


def test_an_unwritable_data_folder_is_found_before_any_simulation(tmp_path):
    import os

    if os.geteuid() == 0:  # root writes anywhere: make the folder a file instead, which nobody can write into
        (tmp_path / "ro").write_text("not a folder")
    else:
        (tmp_path / "ro").mkdir(mode=0o500)
    with pytest.raises(PermissionError, match=r"ro/rigid_fall: cannot write the dataset there \(data\.root\).*nothing was simulated"):
        generate(config(tmp_path / "ro"))


def _edit_shard(path: Path, **attrs) -> None:
    with h5py.File(path, "r+") as f:
        for key, value in attrs.items():
            if key == "params":
                f["params"][0] = value
            else:
                f.attrs[key] = value


def test_shards_that_do_not_belong_to_their_folder_are_refused_naming_the_attribute(tmp_path):
    """Each of these used to train with rc 0: another env's shard, a shard of another seed copied
    into the split, and parameters outside the env's range with a widened range written into the
    file. The error names the file, the attribute and both values."""
    import shutil

    from vgpl.data.trajectories import load_split

    generate(config(tmp_path / "a", "data.render=false"))
    generate(config(tmp_path / "b", "data.render=false", "seed=1"))
    assert load_split(tmp_path / "a", "rigid_fall", "train").positions.shape[0] == 6  # the folder as generated reads

    def case(name: str) -> Path:
        shutil.copytree(tmp_path / "a", tmp_path / name)
        return tmp_path / name / "rigid_fall" / "train"

    other_env = case("env")
    _edit_shard(other_env / "shard_00001.h5", env="mass_rope")
    with pytest.raises(DatasetError, match=r"shard_00001.h5: attribute env='mass_rope', expected 'rigid_fall', the env of its folder"):
        load_split(tmp_path / "env", "rigid_fall", "train")
    other_seed = case("seed")
    shutil.copy(tmp_path / "b/rigid_fall/train/shard_00000.h5", other_seed / "shard_00009.h5")
    with pytest.raises(DatasetError, match=r"shard_00009.h5: attribute config_hash=\w+, but .*dataset.json records config_hash=\w+"):
        load_split(tmp_path / "seed", "rigid_fall", "train")
    widened = case("range")
    _edit_shard(widened / "shard_00002.h5", params=[-25.0], param_low=np.array([-30.0], np.float32))
    with pytest.raises(DatasetError, match=r"shard_00002.h5: attribute param_low=\[-30.0\], but .*dataset.json records param_low=\[-15.0\]"):
        load_split(tmp_path / "range", "rigid_fall", "train")


def test_a_damaged_video_chunk_is_named_and_a_resumed_generation_writes_the_shard_again(tmp_path):
    """A damaged gzip chunk of the video (h5py: "filter returned failure") is one DatasetError
    naming the file; a resumed task=generate reads every chunk of the shards it finds, so it
    writes that shard again instead of counting it complete."""
    from vgpl.data.trajectories import load_split

    first = generate(config(tmp_path))
    clean = Path(first["shards"][1]).read_bytes()
    with h5py.File(first["shards"][1], "r") as f:
        chunk = f["images"].id.get_chunk_info(0)
    with open(first["shards"][1], "r+b") as f:  # overwrite the middle of the first video chunk
        f.seek(chunk.byte_offset + chunk.size // 2)
        f.write(b"\xff" * 64)
    with pytest.raises(DatasetError, match=r"shard_00001.h5: its data cannot be read \(.*\): a damaged file or copy"):
        load_split(tmp_path, "rigid_fall", "train", images=True)
    again = generate(config(tmp_path))
    assert again["written"] == 1 and Path(first["shards"][1]).read_bytes() == clean
    assert load_split(tmp_path, "rigid_fall", "train", images=True).images.shape[0] == 6


def test_a_dataset_larger_than_the_free_space_is_refused_before_any_simulation(tmp_path, monkeypatch):
    """The smallest size the shards left to write can take is set against the folder's free space."""
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(gen.shutil, "disk_usage", lambda folder: usage(10**9, 10**9 - 2 * 10**6, 2 * 10**6))  # 2 MB free
    monkeypatch.setattr(gen, "simulate_shard", lambda *args, **kwargs: pytest.fail("simulated although the data cannot fit"))
    with pytest.raises(OSError, match=r"rigid_fall: this dataset takes at least 8\.7 MB \(data.n_rollouts, data.render\), the disk has 2\.0 MB free"):
        generate(config(tmp_path, "env.scene.n_steps=120"))  # 7 rollouts x 120 frames: 3.9 MB of arrays, 4.8 MB of video at a tenth of raw
    assert not list((tmp_path / "rigid_fall").rglob("*.h5"))
    monkeypatch.setattr(gen.shutil, "disk_usage", shutil.disk_usage)


def test_a_full_disk_while_writing_names_the_folder_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    """h5py reports a full disk as "Can't write data (... errno = 28 ...)": one OSError naming the
    folder and the free space, and the shard's temporary file removed."""
    import h5py as real_h5py

    import vgpl.data.shard as shard_module

    class FullDisk(real_h5py.File):
        def create_dataset(self, name, *args, **kwargs):
            if name == "images":
                raise OSError(28, "Can't write data (file write failed: errno = 28, error message = 'No space left on device')")
            return super().create_dataset(name, *args, **kwargs)

    monkeypatch.setattr(shard_module.h5py, "File", FullDisk)
    with pytest.raises(OSError, match=r"rigid_fall/train: the disk is full \(\d+ MB free\) while writing shard_00000.h5; its temporary file was removed"):
        generate(config(tmp_path))
    assert not list(tmp_path.rglob("*.tmp")) and not list(tmp_path.rglob("shard_*.h5"))


def test_a_dataset_generated_without_a_test_split_says_so_instead_of_asking_to_generate_one(tmp_path):
    from vgpl.data.trajectories import load_split

    generate(config(tmp_path, "data.n_rollouts=2", "data.train_fraction=1.0", "data.render=false"))
    with pytest.raises(DatasetError, match=r"rigid_fall/test: no test split: .*dataset.json records data.train_fraction=1.0, so generation writes none"):
        load_split(tmp_path, "rigid_fall", "test")


def test_a_local_sweep_names_every_failed_job_not_only_the_first(tmp_path):
    proc = run_py("-m", "hydra/launcher=local", "task=generate", "env=rigid_fall", "data.n_rollouts=abc,xyz", "data.render=false",
                  "data.progress=false", "threads=1", f"data.root={tmp_path}/data", f"hydra.sweep.dir={tmp_path}/sweep", cwd=tmp_path)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "job 0 (task=generate env=rigid_fall data.n_rollouts=abc" in out and "data.n_rollouts='abc': expected an integer" in out
    assert "job 1 (task=generate env=rigid_fall data.n_rollouts=xyz" in out and "data.n_rollouts='xyz': expected an integer" in out
