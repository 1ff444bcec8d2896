"""`check --png` writes its picture through the one atomic writer: a save that fails or is
interrupted half-way leaves the old file (or none) and no temporary file; it wrote straight
to the path (a symlink loop there was an OSError traceback, exit 1)."""

import os

import numpy as np
import pytest

pytest.importorskip("pybullet")

from PIL import Image  # noqa: E402

import planner.sim.render as render  # noqa: E402


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setattr(render, "render_image", lambda *a, **k: np.zeros((4, 4, 3), np.uint8))


def test_an_interrupted_save_leaves_the_old_picture(tiny, tmp_path, monkeypatch):
    out = tmp_path / "grasp.png"
    out.write_bytes(b"old picture")

    def half(self, fp, *a, **k):
        with open(fp, "wb") as fh:
            fh.write(b"\x89PNG half")
        raise KeyboardInterrupt

    monkeypatch.setattr(Image.Image, "save", half)
    with pytest.raises(KeyboardInterrupt):
        render.render_png(None, None, None, out)
    assert out.read_bytes() == b"old picture"
    assert os.listdir(tmp_path) == ["grasp.png"]


def test_the_picture_replaces_a_symlink_loop_and_keeps_its_format(tiny, tmp_path):
    (tmp_path / "a.png").symlink_to(tmp_path / "b.png")
    (tmp_path / "b.png").symlink_to(tmp_path / "a.png")
    render.render_png(None, None, None, tmp_path / "a.png")
    render.render_png(None, None, None, tmp_path / "c.jpg")
    assert Image.open(tmp_path / "a.png").format == "PNG" and Image.open(tmp_path / "c.jpg").format == "JPEG"
