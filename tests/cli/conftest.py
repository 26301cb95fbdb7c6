from __future__ import annotations

from tests.classifiers.conftest import dataset  # noqa: F401  (a small labelled RoboDesk dataset)
