from __future__ import annotations

import pytest

from tests.classifiers import write_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("classifier_data") / "ds")
