"""Mesh errors say what is wrong in plain numbers: a damaged binary STL whose header
announces more triangles than the limit is 'malformed' (not 'decimate it'), and a mesh of
the wrong size shows its scale as numbers, not numpy reprs (np.float64(1.0))."""

import pytest

from planner.errors import InputError
from planner.objects import MAX_MESH_TRIANGLES, load_mesh


def test_a_damaged_binary_stl_is_malformed_not_too_large(tmp_path):
    path = tmp_path / "noise.stl"
    path.write_bytes(b"\1" * 80 + (MAX_MESH_TRIANGLES * 10).to_bytes(4, "little") + b"\7" * 2900)
    with pytest.raises(InputError) as err:
        load_mesh(path)
    assert "malformed" in str(err.value) and "announces" in str(err.value)
    assert "decimate" not in str(err.value)


def test_the_scale_of_a_mesh_out_of_size_is_shown_as_numbers(tmp_path):
    path = tmp_path / "tiny.obj"
    path.write_text("v 0 0 0\nv 1e-9 0 0\nv 0 1e-9 0\nv 0 0 1e-9\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    with pytest.raises(InputError) as err:
        load_mesh(path, (1.0, 2.0, 0.5))
    assert "scaled by [1, 2, 0.5]" in str(err.value) and "np." not in str(err.value)
