import pytest

from vp2.data.collect import CollectionConfig, collect

# A tiny real dataset: 2 RoboDesk streams x 3 trajectories, 32x32 images, 2 per shard.
TINY = CollectionConfig(
    env="robodesk",
    trajectories_per_stream=3,
    streams=("robodesk/push_red", "robodesk/open_drawer"),
    image_size=32,
    chunk_size=2,
    valid_every=3,
)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    return collect(TINY, tmp_path_factory.mktemp("data") / "tiny", workers=1, progress=False)
