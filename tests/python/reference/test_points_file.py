"""hirad.reference.read_points: a points file that is not a text CSV is an error naming the
file and the line, never a UnicodeDecodeError or a csv traceback."""

from __future__ import annotations

import os

import numpy as np
import pytest

from hirad.bake import BakeError
from hirad.reference import read_points


def points_error(path) -> str:
    with pytest.raises(BakeError) as info:
        read_points(path)
    return str(info.value)


def test_binary_file_names_the_file_and_line(tmp_path):
    path = tmp_path / "points.csv"
    path.write_bytes(b"x,y,z\n0.1,0.2,0.3\n\x89PNG\r\n\x1a\n\xff\xd8 binary\n")
    msg = points_error(path)
    assert msg.startswith(f"{path}:3: not UTF-8 text (byte 0x89 at offset 18)")


def test_nul_byte_names_the_file_and_line(tmp_path):
    path = tmp_path / "points.csv"
    path.write_bytes(b"0.1,0.2,0.3\n0.1,0.2,0.3\n0.1,\x000.2,0.3\n")
    assert points_error(path).startswith(f"{path}:3: a NUL byte")


def test_fifo_is_refused(tmp_path):
    path = tmp_path / "points.csv"
    os.mkfifo(path)
    assert points_error(path) == f"{path}: not a regular file (a CSV of x,y,z[,nx,ny,nz] is expected)"


def test_missing_file(tmp_path):
    assert points_error(tmp_path / "nope.csv") == f"{tmp_path / 'nope.csv'}: file not found"


def test_good_file_with_bom_header_comments_and_normals(tmp_path):
    path = tmp_path / "points.csv"
    path.write_bytes("\ufeffx,y,z,nx,ny,nz\n# a comment\n\n1,2,3,0,0,1\n4, 5, 6\n".encode("utf-8"))
    pts, nrm, lines = read_points(path)
    np.testing.assert_array_equal(pts, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(nrm, [[0, 0, 1], [0, 0, 0]])
    assert lines == [4, 5]


def test_bad_number_keeps_its_line(tmp_path):
    path = tmp_path / "points.csv"
    path.write_text("x,y,z\n0.3,0.0,0.6\n0.5,oops,0.5\n")
    assert points_error(path).startswith(f"{path}:3: not a number")
