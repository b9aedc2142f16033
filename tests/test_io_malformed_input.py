"""Malformed input is reported with file and 1-based line, and never changes the output."""

import os

import numpy as np
import pytest

from torchquat.io import PoseFileError, convert_file, read_poses

GOOD_TUM = "{i}.5 1 2 3 0 0 0 1\n"


def tum_text(n: int, bad_at: int = None, bad: str = "", comments: int = 2) -> str:
    lines = ["# ground truth\n"] * comments
    for i in range(n):
        lines.append(bad if i == bad_at else GOOD_TUM.format(i=i))
    return "".join(lines)


@pytest.mark.parametrize("where", ["start", "middle", "end"])
@pytest.mark.parametrize("bad,reason", [
    ("1.5 1 2 3 0 0 1\n", "expected 8"),
    ("1.5 1 2 abc 0 0 0 1\n", "not a number"),
    ("1.5 1 2 nan 0 0 0 1\n", "not finite"),
    ("1.5 1 2 3 0 0 0 2\n", "norm"),
])
def test_bad_line_is_named_by_its_line_number(tmp_path, where, bad, reason):
    n = 25
    index = {"start": 0, "middle": 12, "end": n - 1}[where]
    src = tmp_path / "in.tum"
    src.write_text(tum_text(n, index, bad))
    out = tmp_path / "out.csv"
    with pytest.raises(PoseFileError) as info:
        convert_file(src, out, chunk_size=7)  # several chunks: line numbers must run across them
    assert info.value.line == index + 3  # two comment lines come first, lines count from 1
    assert f"{src}:{index + 3}:" in str(info.value)
    assert reason in str(info.value)
    assert not out.exists()
    assert os.listdir(tmp_path) == ["in.tum"]  # no temporary file left behind


def test_existing_output_is_untouched_on_failure(tmp_path):
    src = tmp_path / "in.tum"
    src.write_text(tum_text(30, 29, "oops\n"))
    out = tmp_path / "out.tum"
    out.write_bytes(b"precious\n")
    with pytest.raises(PoseFileError):
        convert_file(src, out, chunk_size=4)
    assert out.read_bytes() == b"precious\n"
    assert sorted(os.listdir(tmp_path)) == ["in.tum", "out.tum"]


def test_small_quaternion_norm_error_is_normalised_and_counted(tmp_path):
    src = tmp_path / "in.tum"
    src.write_text("0 0 0 0 0 0 0 1.0004\n1 0 0 0 0 0 0 1\n")
    from torchquat.io import Report
    report = Report()
    convert_file(src, tmp_path / "out.csv", report=report)
    q = read_poses(tmp_path / "out.csv").rotations.numpy()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=0, atol=1e-15)
    assert any("normalised" in line and ": 1 " in line for line in report.lines())


def test_nearly_orthogonal_matrix_is_projected_and_far_one_rejected(tmp_path):
    from torchquat.io import Report
    near = tmp_path / "near.kitti"
    near.write_text("1.001 0 0 0 0 1 0 0 0 0 1 0\n")
    report = Report()
    convert_file(near, tmp_path / "near.csv", to="matrix", report=report)
    R = read_poses(tmp_path / "near.csv").rotations.numpy()[0]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert any("projected" in line for line in report.lines())
    far = tmp_path / "far.kitti"
    far.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1.5 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(PoseFileError, match=r"far\.kitti:2: matrix is not a rotation"):
        convert_file(far, tmp_path / "far.csv")
    mirror = tmp_path / "mirror.kitti"
    mirror.write_text("-1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(PoseFileError, match="reflection"):
        convert_file(mirror, tmp_path / "mirror.csv")


@pytest.mark.parametrize("name", ["empty.txt", "empty.tum", "empty.kitti"])
@pytest.mark.parametrize("content", ["", "# only a comment\n\n"])
def test_empty_input_is_an_error_that_names_the_input(tmp_path, name, content):
    src = tmp_path / name
    src.write_text(content)
    with pytest.raises(PoseFileError, match="no poses") as error:
        convert_file(src, tmp_path / "out.csv")
    assert str(src) in str(error.value) and "out.csv" not in str(error.value)
    assert not (tmp_path / "out.csv").exists()


def test_output_equal_to_input_is_refused(tmp_path):
    src = tmp_path / "same.tum"
    src.write_text(tum_text(3))
    with pytest.raises(PoseFileError, match="same file"):
        convert_file(src, src)
    assert src.read_text() == tum_text(3)


def test_unknown_extension_and_missing_file(tmp_path):
    odd = tmp_path / "poses.dat"
    odd.write_text(tum_text(2))
    with pytest.raises(PoseFileError, match="--from"):
        convert_file(odd, tmp_path / "o.tum")
    convert_file(odd, tmp_path / "o.tum", from_format="tum")  # overridable
    with pytest.raises(PoseFileError, match="no such file"):
        convert_file(tmp_path / "missing.tum", tmp_path / "o2.tum")


def test_a_line_of_another_width_is_named_where_each_width_is_allowed(tmp_path):
    # EuRoC takes 8 or more numbers a line (extra columns are ignored), but a table has one width
    rows = [f"{1403715524907143168 + 5000000 * i},{i},2,3,1,0,0,0,0.1,0.2,0.3,1,2,3,4,5,6" for i in range(40)]
    rows[30] = rows[30].rsplit(",", 1)[0]  # 16 numbers instead of 17
    src = tmp_path / "data.csv"
    src.write_text("#timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...\n" + "\n".join(rows) + "\n")
    with pytest.raises(PoseFileError) as info:
        convert_file(src, tmp_path / "out.tum")
    assert info.value.line == 32  # the header is line 1
    assert "expected 17 numbers as on line 2, found 16" in str(info.value)
