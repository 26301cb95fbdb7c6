import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import pytest  # noqa: E402
import torch  # noqa: E402


@pytest.fixture(autouse=True, scope="session")
def one_torch_thread():
    """One torch thread for the whole test session.

    On a 2-core machine shared with other work, two OpenMP threads stall on each other and a
    model test runs 5-30x slower than with one (measured; docs/testing.md).
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


#: Test files that start or join a Ray instance. ``ray.init()`` without an address joins the
#: newest cluster ``ray start`` made on this machine, so two of these at once (under
#: ``pytest -n``) could run one test's trials on another test's cluster: they share one worker.
RAY_TEST_FILES = frozenset({
    "tests/utils/test_executors.py",
    "tests/benchmark/test_trial_timeout.py",
    "tests/cli/test_run.py",
})


def pytest_collection_modifyitems(config, items):
    """Groups the tests for ``pytest -n N --dist loadgroup`` (``make test``): a file's tests
    stay on one worker (its module fixtures are built once), and every Ray test on the same one."""
    for item in items:
        path = item.path.relative_to(config.rootpath).as_posix()
        group = "ray" if path in RAY_TEST_FILES else path
        item.add_marker(pytest.mark.xdist_group(group))
