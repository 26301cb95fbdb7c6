"""The Ray tests share one ``pytest -n`` worker (tests/conftest.py): every test file that
starts or joins a Ray instance must be listed there."""

import re
from pathlib import Path
from types import SimpleNamespace

from tests.conftest import RAY_TEST_FILES, pytest_collection_modifyitems

ROOT = Path(__file__).resolve().parents[1]
# What starts or joins a Ray instance in a test: the ray executor, ray.init, ray start.
USES_RAY = re.compile(r"executor=\"ray\"|\"--executor\", \"ray\"|ray\.init\(|\"ray\", \"start\"|import ray\b")


def test_every_test_file_that_uses_ray_is_grouped():
    using = {
        p.relative_to(ROOT).as_posix()
        for p in (ROOT / "tests").rglob("test_*.py")
        if p.name != Path(__file__).name and USES_RAY.search(p.read_text())
    }
    assert using, "the pattern found no Ray test at all: it no longer matches how tests use Ray"
    assert using <= RAY_TEST_FILES, f"not grouped in tests/conftest.py: {sorted(using - RAY_TEST_FILES)}"
    assert all((ROOT / f).is_file() for f in RAY_TEST_FILES), "a grouped file is gone"


def test_the_tests_of_a_file_share_a_group_and_ray_files_share_one():
    files = ("tests/utils/test_executors.py", "tests/cli/test_run.py", "tests/envs/test_tabletop.py")
    marks: list[list] = [[] for _ in files]
    items = [SimpleNamespace(path=ROOT / f, add_marker=m.append) for f, m in zip(files, marks, strict=True)]
    pytest_collection_modifyitems(SimpleNamespace(rootpath=ROOT), items)
    assert [[(m.name, *m.args) for m in found] for found in marks] == [
        [("xdist_group", "ray")], [("xdist_group", "ray")],
        [("xdist_group", "tests/envs/test_tabletop.py")],
    ]
