import numpy as np
import pytest
import torch

from vp2.data import storage
from vp2.data.loader import ClipDataset
from vp2.data.policies import make_data_env
from vp2.data.render import rerender


def _demo(root, index):
    for shard in sorted((root / "shards").glob("*.hdf5")):
        for traj in storage.read_trajectories(shard):
            if traj.index == index:
                return traj
    raise KeyError(index)


def test_clip_alignment(tiny_dataset):
    ds = ClipDataset(tiny_dataset, split="train")
    assert len(ds) == 4 * (36 - 12 + 1)  # 4 train trajectories, 25 clips each
    item = ds[30]  # second trajectory (demo_1), start 5
    assert item["index"] == 1 and item["start"] == 5
    traj = _demo(tiny_dataset, 1)
    assert item["frames"].shape == (12, 3, 32, 32) and item["frames"].dtype == torch.float32
    expected = torch.from_numpy(traj.images[5:17]).permute(0, 3, 1, 2).float() / 255
    torch.testing.assert_close(item["frames"], expected, rtol=0, atol=0)
    # actions[k] is executed in frames[k] and produced frames[k + 1]
    torch.testing.assert_close(item["actions"], torch.from_numpy(traj.actions[5:16]))


def test_splits_tasks_and_quantity(tiny_dataset):
    train = ClipDataset(tiny_dataset, split="train", uint8=True)
    valid = ClipDataset(tiny_dataset, split="valid")
    assert {r.name for r in train.records}.isdisjoint({r.name for r in valid.records})
    assert train[0]["frames"].dtype == torch.uint8
    red = ClipDataset(tiny_dataset, tasks=["robodesk/push_red"])
    assert {r.task for r in red.records} == {"robodesk/push_red"}
    first4 = ClipDataset(tiny_dataset, max_trajectories=4)
    assert [r.name for r in first4.records] == ["demo_0", "demo_1", "demo_3"]
    with pytest.raises(ValueError, match="fewer than max_trajectories"):
        ClipDataset(tiny_dataset, max_trajectories=100)
    with pytest.raises(ValueError, match="not in"):
        ClipDataset(tiny_dataset, tasks=["robodesk/push_green"])


def test_loader_with_workers(tiny_dataset):
    ds = ClipDataset(tiny_dataset)
    loader = torch.utils.data.DataLoader(ds, batch_size=8, num_workers=2, shuffle=True,
                                         generator=torch.Generator().manual_seed(0))
    batch = next(iter(loader))
    assert batch["frames"].shape == (8, 12, 3, 32, 32) and batch["actions"].shape == (8, 11, 5)


def test_rerender_matches_env_rendering(tiny_dataset, tmp_path):
    out = rerender(tiny_dataset, tmp_path / "r48", 48, workers=1, progress=False)
    assert storage.load_manifest(out)["config"]["image_size"] == 48
    traj = _demo(out, 2)
    assert traj.images.shape == (36, 48, 48, 3)
    env = make_data_env(traj.task, observation_size=None)
    env.reset_to(traj.states[7])
    np.testing.assert_array_equal(env.render(48), traj.images[7])
    # Re-rendering at the collection size reproduces the collected images exactly.
    same = rerender(tiny_dataset, tmp_path / "r32", 32, workers=1, progress=False)
    np.testing.assert_array_equal(_demo(same, 4).images, _demo(tiny_dataset, 4).images)
