from pathlib import Path

import pytest

from vp2.data.datasets import dataset_dir, default_dataset, default_trajectories


def test_default_dataset_directories():
    assert default_trajectories() == {"robodesk": 20, "tabletop": 100}
    assert default_dataset("robodesk") == Path("data/robodesk-20x-64px")
    assert default_dataset("tabletop") == Path("data/tabletop-100x-64px")
    assert dataset_dir("tabletop", 7, image_size=None) == Path("data/tabletop-7x-states")
    with pytest.raises(KeyError):
        default_dataset("nosuchenv")
