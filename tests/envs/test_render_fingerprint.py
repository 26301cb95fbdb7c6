"""The render fingerprint: stable, one per environment, and moved by what moves the pixels."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from vp2.envs import _robodesk_model, rendering, tabletop_scene
from vp2.envs.render_specs import render_description, render_fingerprint, render_fingerprints


def test_stable_short_and_one_per_environment():
    tabletop, robodesk = render_fingerprint("tabletop"), render_fingerprint("robodesk")
    assert render_fingerprint("tabletop") == tabletop and render_fingerprint("robodesk") == robodesk
    assert len(tabletop) == 16 and int(tabletop, 16) >= 0
    assert tabletop != robodesk
    assert render_fingerprints() == {"robodesk": robodesk, "tabletop": tabletop}


def test_the_same_in_another_process():
    code = "from vp2.envs.render_specs import render_fingerprint as f; print(f('tabletop'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == render_fingerprint("tabletop")


def test_moves_with_the_camera_the_spec_and_the_render_path(monkeypatch):
    tabletop, robodesk = render_fingerprint("tabletop"), render_fingerprint("robodesk")
    default = tabletop_scene.DEFAULT_SCENE
    assert render_description("tabletop")["camera"]["fovy"] == default.camera.fovy
    moved_camera = dataclasses.replace(default.camera, pos=(2.0, 0.0, 3.0))
    other = dataclasses.replace(default, camera=moved_camera)
    moved = render_fingerprint("tabletop", scene=other)
    assert moved != tabletop
    assert render_fingerprint("robodesk") == robodesk
    assert render_fingerprint("tabletop") == tabletop == render_fingerprint("tabletop", default)
    # The package's own fingerprint is its default scene's.
    monkeypatch.setattr(tabletop_scene, "DEFAULT_SCENE", other)
    assert render_fingerprint("tabletop") == moved
    monkeypatch.undo()
    monkeypatch.setattr(_robodesk_model, "RENDER_SPEC",
                        dataclasses.replace(_robodesk_model.RENDER_SPEC, shadow_size=1024))
    assert render_fingerprint("robodesk") != robodesk
    monkeypatch.undo()
    monkeypatch.setattr(rendering, "RENDER_PATH_VERSION", rendering.RENDER_PATH_VERSION + 1)
    assert render_fingerprint("tabletop") != tabletop
    assert render_fingerprint("robodesk") != robodesk


def test_unknown_environment():
    with pytest.raises(ValueError, match="unknown environment 'kitchen'; known: robodesk"):
        render_fingerprint("kitchen")
