"""Bad BVH and AMASS input: file:line where there is a line, a clear message where there is not."""

import numpy as np
import pytest

from torchquat.io import PoseFileError, read_amass, read_bvh

GOOD = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT knee
  {
    OFFSET 0 -4 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -4 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.04
0 1 2 3 4 5 6 7 8
0 1 2 3 4 5 6 7 8
0 1 2 3 4 5 6 7 8
"""
FIRST_FRAME_LINE = 19


def read_text(tmp_path, text: str):
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(PoseFileError) as info:
        read_bvh(path)
    return path, info.value


def test_the_good_file_reads(tmp_path):
    path = tmp_path / "good.bvh"
    path.write_text(GOOD)
    assert read_bvh(path).rotations.shape == (3, 2, 4)


@pytest.mark.parametrize("frame", [0, 1, 2])
@pytest.mark.parametrize("row,reason", [("0 1 2 3 4 5 6 7", "has 8 numbers"), ("0 1 2 3 4 5 6 7 8 9", "has 10 numbers"),
                                        ("0 1 2 3 x 5 6 7 8", "'x' is not a number"),
                                        ("0 1 2 3 nan 5 6 7 8", "'nan' is not finite")])
def test_a_bad_frame_line_is_named_by_file_and_line(tmp_path, frame, row, reason):
    lines = GOOD.splitlines()
    lines[FIRST_FRAME_LINE - 1 + frame] = row
    path, err = read_text(tmp_path, "\n".join(lines) + "\n")
    assert err.line == FIRST_FRAME_LINE + frame
    assert str(err).startswith(f"{path}:{FIRST_FRAME_LINE + frame}: ")
    assert reason in str(err)


def test_every_frame_line_short_is_still_named(tmp_path):
    text = GOOD.replace("0 1 2 3 4 5 6 7 8\n", "0 1 2 3 4 5 6 7\n")
    _, err = read_text(tmp_path, text)
    assert err.line == FIRST_FRAME_LINE and "9" in str(err)


def test_blank_lines_between_frames_keep_the_line_count(tmp_path):
    lines = GOOD.splitlines()
    lines.insert(FIRST_FRAME_LINE, "")
    lines[FIRST_FRAME_LINE + 1] = "0 1 2"
    _, err = read_text(tmp_path, "\n".join(lines) + "\n")
    assert err.line == FIRST_FRAME_LINE + 2


def test_an_unclosed_brace_names_its_line(tmp_path):
    text = GOOD.replace("    }\n  }\n}\n", "    }\n}\n")  # the knee's closing brace is gone
    _, err = read_text(tmp_path, text)
    assert err.line == 3 and "unclosed brace" in str(err) and "'hips'" in str(err)


def test_an_unknown_channel_names_its_line(tmp_path):
    _, err = read_text(tmp_path, GOOD.replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                                              "CHANNELS 3 Zrotation Wrotation Yrotation"))
    assert err.line == 9 and "unknown channel 'Wrotation'" in str(err)


def test_a_channel_count_that_disagrees_names_its_line(tmp_path):
    _, err = read_text(tmp_path, GOOD.replace("CHANNELS 3 Z", "CHANNELS 4 Z"))
    assert err.line == 9 and "CHANNELS 4" in str(err)


@pytest.mark.parametrize("said", [2, 4])
def test_frames_disagreeing_with_the_motion_lines_is_a_clear_error(tmp_path, said):
    _, err = read_text(tmp_path, GOOD.replace("Frames: 3", f"Frames: {said}"))
    assert err.line == 17
    assert f"'Frames: {said}' disagrees with the MOTION block, which has 3 frame lines" in str(err)


@pytest.mark.parametrize("text,line,reason", [
    (GOOD.replace("HIERARCHY\n", "HIERARCHIE\n"), 1, "starts with HIERARCHY"),
    (GOOD.replace("MOTION\n", ""), None, "no MOTION line"),
    (GOOD.replace("Frame Time: 0.04", "Frame Time: soon"), 18, "Frame Time: SECONDS"),
    (GOOD.replace("OFFSET 0 -4 0\n    CHANNELS", "OFFSET 0 -4\n    CHANNELS"), 8, "OFFSET needs 3 numbers"),
    (GOOD.replace("  JOINT knee\n  {", "  JOINT knee\n  OFFSET 0 0 0"), 7, "expected '{'"),
])
def test_other_hierarchy_errors(tmp_path, text, line, reason):
    _, err = read_text(tmp_path, text)
    assert err.line == line and reason in str(err)


def test_amass_poses_width_not_a_multiple_of_three_is_named(tmp_path):
    path = tmp_path / "bad.npz"
    np.savez(path, poses=np.zeros((4, 157)), trans=np.zeros((4, 3)), mocap_framerate=60.0)
    with pytest.raises(PoseFileError, match="'poses' has 157 columns, not a multiple of 3"):
        read_amass(path)


@pytest.mark.parametrize("arrays,reason", [
    (dict(trans=np.zeros((4, 3)), mocap_framerate=60.0), "needs an array 'poses'"),
    (dict(poses=np.zeros((4, 120)), mocap_framerate=60.0), "holds 40 joints"),
    (dict(poses=np.zeros((4, 156)), trans=np.zeros((5, 3)), mocap_framerate=60.0), "array 'trans' has shape"),
    (dict(poses=np.zeros((4, 156)), trans=np.zeros((4, 3))), "no frame rate"),
])
def test_other_amass_errors(tmp_path, arrays, reason):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(PoseFileError, match=reason):
        read_amass(path)


def test_blank_lines_after_motion_and_crlf_keep_line_numbers(tmp_path):
    lines = GOOD.splitlines()
    lines.insert(16, "")  # a blank line between MOTION and Frames:
    lines[FIRST_FRAME_LINE + 1] = "0 1 2"
    _, err = read_text(tmp_path, "\r\n".join(lines) + "\r\n")
    assert err.line == FIRST_FRAME_LINE + 2


def test_crlf_and_no_frames_read(tmp_path):
    path = tmp_path / "crlf.bvh"
    path.write_bytes(GOOD.replace("\n", "\r\n").encode())
    assert read_bvh(path).rotations.shape == (3, 2, 4)
    head = GOOD.split("Frames:")[0]
    path.write_text(head + "Frames: 0\nFrame Time: 0.04\n")
    assert read_bvh(path).rotations.shape == (0, 2, 4)
