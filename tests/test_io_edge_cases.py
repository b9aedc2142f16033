"""Pose files at the edges: numbers next to powers of ten, headers that are not EuRoC's, times
beyond nanoseconds or int64, degenerate rotations, broken arrays and unwritable outputs."""

import os
import signal
from decimal import Decimal

import numpy as np
import pytest
import torch

import torchquat
from torchquat import cli
from torchquat.io import PoseFileError, Poses, atomic_output, convert_file, detect_format, read_poses, write_poses
from torchquat.io.numtext import format_floats, format_rows


def test_values_next_to_powers_of_ten_read_back_with_their_exponent():
    # the double-double's high part can round onto 1e7 or 1e8 while the product is below it:
    # 1e-16, 1e23 and 1e203 were written 10x too large (9.9999999999999998e-16)
    values = []
    for k in range(-300, 290):
        x = float(f"1e{k}")
        values += [x, *np.nextafter(x, np.inf) * np.ones(1), *np.nextafter(x, 0) * np.ones(1)]
        for _ in range(3):
            values += [np.nextafter(values[-2], np.inf), np.nextafter(values[-1], 0)]
    values = np.array(values)
    words = format_rows([format_floats(values[:, None])]).decode().split()
    np.testing.assert_array_equal(np.array(words, dtype=np.float64), values)
    assert max(len(w.split("e")[0].lstrip("-").replace(".", "").strip("0")) for w in words) <= 17


def _write(path, text: str):
    path.write_text(text)
    return path


def test_a_csv_whose_header_starts_with_hash_but_is_not_euroc_is_a_plain_csv(tmp_path):
    src = _write(tmp_path / "poses.csv", "#timestamp,x,y,z,qx,qy,qz,qw\n1,1,2,3,0.6,0,0,0.8\n")
    assert detect_format(src) == "csv"  # (it was read as EuRoC: time 1 ns, the quaternion w-first)
    poses = read_poses(src)
    assert poses.timestamps.tolist() == [1.0]
    torch.testing.assert_close(poses.to("quat").rotations, torch.tensor([[0.8, 0.6, 0.0, 0.0]], dtype=torch.float64))


def test_euroc_style_names_in_another_order_are_refused_not_read_w_first(tmp_path):
    src = _write(tmp_path / "poses.csv", "#timestamp,p_x,p_y,p_z,q_x,q_y,q_z,q_w\n1,1,2,3,0.6,0,0,0.8\n")
    with pytest.raises(PoseFileError, match="unrecognised CSV header"):
        read_poses(src)
    with pytest.raises(PoseFileError, match="column 5 'q_x' where EuRoC has q_w") as info:
        read_poses(src, format="euroc")
    assert info.value.line == 1


def test_euroc_headers_in_euroc_order_are_still_euroc(tmp_path):
    real = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_x\n"
    src = _write(tmp_path / "gt.csv", real + "1403715524907143168,1,2,3,0.8,0.6,0,0,9\n")
    assert detect_format(src) == "euroc"
    assert read_poses(src).timestamps_ns.tolist() == [1403715524907143168]
    out = tmp_path / "again.csv"
    write_poses(out, read_poses(src), "euroc")  # (our own header)
    assert detect_format(out) == "euroc"


def test_a_degenerate_6d_row_is_an_error_naming_its_line(tmp_path):
    src = _write(tmp_path / "r6.csv", "r6_1,r6_2,r6_3,r6_4,r6_5,r6_6\n1,0,0,0,1,0\n1,0,0,2,0,0\n")
    out = tmp_path / "out.tum"
    with pytest.raises(PoseFileError, match="zero or collinear") as info:
        convert_file(src, out)  # (NaN was written, with exit status 0)
    assert info.value.line == 3 and not out.exists()


@pytest.mark.parametrize("chunk_size", [1, 2, 100])
def test_a_time_with_ten_decimals_leaves_its_neighbours_exact_in_any_chunk(tmp_path, chunk_size):
    # one long timestamp used to drop the exact nanoseconds of its whole chunk
    times = ["1403715524.000000001", "1403715524.123456789", "1403715524.5000000006", "1403715524.9999999994"]
    src = _write(tmp_path / "t.tum", "".join(f"{t} 1 2 3 0 0 0 1\n" for t in times))
    out = tmp_path / "t.csv"
    convert_file(src, out, to="euroc", chunk_size=chunk_size)
    ns = [int(line.split(",")[0]) for line in out.read_text().splitlines()[1:]]
    assert ns == [int((Decimal(t) * 10**9).to_integral_value(rounding="ROUND_HALF_UP")) for t in times]


def test_times_beyond_int64_nanoseconds_are_kept_as_seconds_or_refused(tmp_path):
    src = _write(tmp_path / "late.tum", "9300000000.5 1 2 3 0 0 0 1\n1403715524907143168 1 2 3 0 0 0 1\n")
    out = tmp_path / "late_out.tum"
    convert_file(src, out)
    assert [float(line.split()[0]) for line in out.read_text().splitlines()[1:]] == [9300000000.5, 1403715524907143168.0]
    with pytest.raises(ValueError, match="does not fit"):  # (they wrapped around to negative times)
        convert_file(src, tmp_path / "late.csv", to="euroc")
    euroc = _write(tmp_path / "big.csv", "#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n1,0,0,0,1,0,0,0\n"
                   "99999999999999999999,0,0,0,1,0,0,0\n")
    with pytest.raises(PoseFileError, match="does not fit int64") as info:
        read_poses(euroc)
    assert info.value.line == 3


@pytest.mark.parametrize("suffix", [".npz", ".npy"])
@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 truncated", b"not numpy"])
def test_unreadable_arrays_are_pose_file_errors(tmp_path, suffix, content):
    src = tmp_path / f"broken{suffix}"
    src.write_bytes(content)
    with pytest.raises(PoseFileError, match=f"not a readable \\{suffix} file"):
        read_poses(src)


@pytest.mark.parametrize("chunk_size", [2, 10_000])
@pytest.mark.parametrize("name, value", [("position", np.zeros((5, 3))), ("timestamp", np.arange(6.0)),
                                         ("timestamp_ns", np.arange(3))])
def test_npz_arrays_of_other_lengths_are_refused(tmp_path, chunk_size, name, value):
    # (with small chunks the extra rows were dropped silently)
    arrays = {"rotation": np.tile([1.0, 0, 0, 0], (4, 1)), "representation": np.array("quat"), name: value}
    np.savez(tmp_path / "mismatch.npz", **arrays)
    with pytest.raises(PoseFileError, match=f"array '{name}' has shape"):
        convert_file(tmp_path / "mismatch.npz", tmp_path / "out.tum", chunk_size=chunk_size)


@pytest.mark.parametrize("chunk_size", [1, 3, 10_000])
def test_lines_of_spaces_are_blank_lines(tmp_path, chunk_size):
    src = _write(tmp_path / "spaces.tum", "1 1 2 3 0 0 0 1\n   \n\t \n2 1 2 3 0 0 0 1\n")
    assert convert_file(src, tmp_path / "out.csv", chunk_size=chunk_size) == 2


@pytest.mark.parametrize("where", ["missing folder", "a folder"])
def test_an_unwritable_output_is_named_before_anything_is_read(tmp_path, where):
    out = tmp_path / "no" / "out.tum" if where == "missing folder" else tmp_path / "out.tum"
    if where == "a folder":
        out.mkdir()
    with pytest.raises(PoseFileError) as info:
        convert_file(torchquat_sample(), out)
    assert info.value.path == str(out) and ".tmp" not in str(info.value)


def torchquat_sample():
    return os.path.join(os.path.dirname(__file__), "..", "examples", "data", "sample_trajectory.tum")


def test_degrees_with_a_target_that_is_not_euler_is_refused(tmp_path, capsys):
    assert cli.main(["convert", torchquat_sample(), str(tmp_path / "q.csv"), "--to", "quat", "--degrees"]) == 2
    assert "--degrees applies to Euler angles only" in capsys.readouterr().err
    assert not (tmp_path / "q.csv").exists()


def test_sigterm_during_a_conversion_leaves_out_and_no_temporary_file(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out.tum"
    out.write_text("ORIGINAL\n")

    def stopped_while_writing(src, dst, **_):
        with atomic_output(dst) as stream:
            stream.write(b"partial")
            os.kill(os.getpid(), signal.SIGTERM)  # as `timeout` or a job scheduler sends it
        raise AssertionError("not reached")

    def outside(signum, frame):  # (without the command's own handler: fail, rather than kill pytest)
        raise AssertionError("SIGTERM reached the handler outside the command")

    monkeypatch.setattr("torchquat.io.convert_file", stopped_while_writing)
    previous = signal.signal(signal.SIGTERM, outside)
    try:
        assert cli.main(["convert", torchquat_sample(), str(out)]) == 130
        assert signal.getsignal(signal.SIGTERM) is outside  # (restored)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert "interrupted" in capsys.readouterr().err
    assert out.read_text() == "ORIGINAL\n" and os.listdir(tmp_path) == ["out.tum"]


def test_poses_round_trip_through_npz_with_every_array(tmp_path):
    q = torchquat.random_quat(5, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    poses = Poses(q, "quat", positions=torch.zeros(5, 3, dtype=torch.float64), timestamps=np.arange(5.0),
                  timestamps_ns=np.arange(5) * 10**9)
    write_poses(tmp_path / "p.npz", poses)
    back = read_poses(tmp_path / "p.npz")
    assert back.timestamps_ns.tolist() == poses.timestamps_ns.tolist()
    torch.testing.assert_close(back.rotations, q, rtol=0, atol=0)


@pytest.mark.parametrize("token", ["1_000", "\u0663", "\uff11"])  # (Python's float takes them, loadtxt does not)
def test_a_token_only_python_reads_is_named_with_its_line(tmp_path, token):
    src = tmp_path / "odd.tum"
    src.write_text(f"1 1 2 3 0 0 0 1\n2 1 2 {token} 0 0 0 1\n", encoding="utf-8")
    with pytest.raises(PoseFileError, match="not a number") as info:
        read_poses(src)
    assert info.value.line == 2


@pytest.mark.parametrize("name, text", [("bom.tum", "# comment\n1 1 2 3 0 0 0 1\n"),
                                        ("bom.csv", "timestamp,x,y,z,qw,qx,qy,qz\n1,1,2,3,1,0,0,0\n"),
                                        ("bom_euroc.csv", "#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n1,1,2,3,1,0,0,0\n")])
def test_a_utf8_byte_order_mark_is_skipped(tmp_path, name, text):
    # (spreadsheets write one: the header or comment was then taken for data)
    src = tmp_path / name
    src.write_bytes(b"\xef\xbb\xbf" + text.encode())
    poses = read_poses(src)
    assert len(poses) == 1 and poses.positions.tolist() == [[1.0, 2.0, 3.0]]


def test_kitti_to_kitti_says_nothing_about_lost_timestamps_and_tum_to_kitti_does(tmp_path):
    from torchquat.io import Report
    kitti = tmp_path / "in.kitti"
    kitti.write_text("1 0 0 1 0 1 0 2 0 0 1 3\n" * 3)
    for src, lost in ((kitti, False), (torchquat_sample(), True)):
        report = Report()
        convert_file(src, tmp_path / "out.kitti", report=report)
        assert any("timestamps are not written" in line for line in report.lines()) == lost


@pytest.mark.parametrize("preamble", ["# exported by a tool, version 2\n# frame: world\n", "\n# one comment\n\n"])
@pytest.mark.parametrize("hash_header", [False, True])
def test_comment_lines_before_a_csv_header_are_skipped(tmp_path, preamble, hash_header):
    # the first comment was taken as the header ("unrecognised CSV header 'exported by a tool'")
    header = ("#" if hash_header else "") + "timestamp,x,y,z,qx,qy,qz,qw\n"
    src = _write(tmp_path / "poses.csv", preamble + header + "1.5,1,2,3,0.6,0,0,0.8\n2,1,2,3,0,0,0,1\n")
    assert detect_format(src) == "csv"
    poses = read_poses(src)
    assert poses.timestamps.tolist() == [1.5, 2.0]
    torch.testing.assert_close(poses.to("quat").rotations,
                               torch.tensor([[0.8, 0.6, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]], dtype=torch.float64))


def test_comment_lines_before_a_euroc_header_are_skipped(tmp_path):
    header = "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n"
    data = "1403715524907143168,1,2,3,0.8,0.6,0,0\n"
    src = _write(tmp_path / "gt.csv", "# recorded in the machine hall\n" + header + data)
    assert detect_format(src) == "euroc"
    poses = read_poses(src)
    assert poses.timestamps_ns.tolist() == [1403715524907143168]
    torch.testing.assert_close(poses.rotations, torch.tensor([[0.8, 0.6, 0.0, 0.0]], dtype=torch.float64))


def test_a_euroc_header_without_hash_is_stepped_over(tmp_path):
    src = _write(tmp_path / "gt.csv", "timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n1403715524907143168,1,2,3,0.8,0.6,0,0\n")
    assert detect_format(src) == "euroc"
    assert read_poses(src).timestamps_ns.tolist() == [1403715524907143168]  # (was "not a number" on line 1)


def test_csv_errors_name_the_header_line_and_a_missing_header(tmp_path):
    src = _write(tmp_path / "a.csv", "# about\n\ntimestamp,x,y,z,qw,qx,qy,qzz\n1,1,2,3,1,0,0,0\n")
    with pytest.raises(PoseFileError, match="unrecognised CSV header") as info:
        read_poses(src)
    assert info.value.line == 3
    src = _write(tmp_path / "b.csv", "\n0.5,1,2,3\n")
    with pytest.raises(PoseFileError, match="needs a header naming its columns") as info:
        read_poses(src, format="csv")
    assert info.value.line == 2
    src = _write(tmp_path / "c.csv", "# c\ntimestamp,qw,qx,qy,qz\n0.5,1,0,0,0\n0.6,1,0,0,zz\n")
    with pytest.raises(PoseFileError, match="zz") as info:
        read_poses(src)
    assert info.value.line == 4


@pytest.mark.parametrize("name, fmt", [("out.npz", "tum"), ("out.npy", "kitti"), ("out.csv", "tum"),
                                       ("out.txt", "euroc"), ("out.kitti", "tum"), ("out.tum", "euroc")])
def test_pose_formats_are_not_written_under_another_formats_extension(tmp_path, name, fmt):
    # `--to tum` into out.npz wrote TUM text that every reader took for a NumPy archive
    poses = Poses(torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64), "quat", timestamps=np.array([1.0]))
    with pytest.raises(PoseFileError, match="would be read back as"):
        write_poses(tmp_path / name, poses, format=fmt)
    src = _write(tmp_path / "in.tum", "1 0 0 0 0 0 0 1\n")
    assert cli.main(["convert", str(src), str(tmp_path / name), "--to", fmt]) == 2
    assert not (tmp_path / name).exists()


def test_pose_formats_under_their_own_or_unknown_extensions_round_trip(tmp_path):
    poses = Poses(torch.tensor([[0.8, 0.6, 0.0, 0.0]], dtype=torch.float64), "quat", timestamps=np.array([1.0]))
    for name, fmt in [("a.txt", "tum"), ("b.txt", "kitti"), ("c.csv", "euroc"), ("d.dat", "tum")]:
        write_poses(tmp_path / name, poses, format=fmt)
        back = read_poses(tmp_path / name, format=fmt)
        torch.testing.assert_close(back.to("quat").rotations, poses.rotations)


def test_python_api_messages_do_not_speak_only_of_command_line_options(tmp_path):
    poses = Poses(torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64), "quat")
    with pytest.raises(PoseFileError, match="written to a plain file: its name must end in") as info:
        write_poses(tmp_path / "x.tum", poses, representation="euler:ZYX")
    assert "--to" not in str(info.value)
    with pytest.raises(PoseFileError, match="format= in Python"):
        read_poses(_write(tmp_path / "x.dat", "1 0 0 0 0 0 0 1\n"))


def test_a_failed_rename_names_the_output_not_the_temporary_file(tmp_path, monkeypatch, capsys):
    import torchquat.io.files as files

    def refused(src, dst):  # as os.replace fails: its message names both files
        raise PermissionError(13, "Permission denied", src, None, dst)

    out = tmp_path / "out.tum"
    monkeypatch.setattr(files.os, "replace", refused)
    assert cli.main(["convert", torchquat_sample(), str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{out}: could not be replaced: Permission denied" in err and ".tmp" not in err
    assert os.listdir(tmp_path) == []
    with pytest.raises(PoseFileError, match="could not be replaced") as caught:
        with atomic_output(out) as stream:
            stream.write(b"x")
    assert caught.value.path == str(out) and isinstance(caught.value.__cause__, PermissionError)
