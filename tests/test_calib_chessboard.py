"""`sdvl calibrate` on the real OpenCV chessboard photos: accuracy, bad images, too few views,
video input with near-duplicate frames."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from calib.camera_yaml import load_camera
from calib.formats import read_camera_file
from sdvl.cli import main

BOARD = ["--cols", "9", "--rows", "6", "--square", "0.025"]


@pytest.fixture(scope="module")
def chessboard(data_dir):
    folder = data_dir / "calib_opencv_chessboard"
    images = sorted(str(p) for p in folder.glob("left*.jpg"))
    reference, _ = read_camera_file(folder / "left_intrinsics.yml")
    return images, reference


def calibrate(args: list[str], capsys) -> tuple[int, dict | None, str]:
    code = main(["calibrate", *args, *BOARD, "--json"])
    captured = capsys.readouterr()
    report = json.loads(captured.out) if code == 0 else None
    return code, report, captured.err


def test_real_chessboard_matches_opencv_within_one_percent(chessboard, tmp_path, capsys):
    images, reference = chessboard
    out = tmp_path / "camera.yaml"
    code, report, _ = calibrate([*images, "--out", str(out)], capsys)
    assert code == 0
    camera = load_camera(out)
    for name in ("fx", "fy", "cx", "cy"):
        got, want = getattr(camera, name), getattr(reference, name)
        assert abs(got - want) <= 0.01 * want, f"{name} {got:.2f} vs OpenCV's {want:.2f}"
    assert report["rms_px"] < 0.5
    assert len(report["views"]) + len(report["rejected_outliers"]) == len(images)
    assert all(v["rms_px"] < 0.5 for v in report["views"])
    assert "top-left" in report["areas_needing_views"]  # the sample photos never go there
    assert (tmp_path / "camera_coverage.png").stat().st_size > 0


def bad_images(images: list[str], data_dir, folder) -> dict[str, str]:
    """Files that must be skipped -> the words their reason must contain."""
    sharp = cv2.imread(images[0], cv2.IMREAD_GRAYSCALE)
    shifted = cv2.warpAffine(cv2.imread(images[2], cv2.IMREAD_GRAYSCALE),
                             np.float32([[1, 0, -200], [0, 1, 0]]), (640, 480),
                             borderMode=cv2.BORDER_CONSTANT, borderValue=128)
    texture = cv2.resize(cv2.imread(str(data_dir / "textures" / "aero1.jpg"),
                                    cv2.IMREAD_GRAYSCALE), (640, 480))
    files = {"blurred.png": (cv2.GaussianBlur(sharp, (0, 0), 3.0), "too blurred"),
             "cut_off.png": (shifted, "cut off"),
             "no_board.png": (texture, "no board found")}
    expected = {}
    for name, (image, words) in files.items():
        cv2.imwrite(str(folder / name), image)
        expected[str(folder / name)] = words
    (folder / "notes.png").write_text("not an image")
    expected[str(folder / "notes.png")] = "not an image"
    expected[str(folder / "missing.png")] = "file not found"
    return expected


def test_bad_images_are_named_and_skipped(chessboard, data_dir, tmp_path, capsys):
    images, _ = chessboard
    expected = bad_images(images, data_dir, tmp_path)
    code, report, err = calibrate([*images, *expected, "--out", str(tmp_path / "c.yaml")],
                                  capsys)
    assert code == 0
    skipped = {s["name"]: s["reason"] for s in report["skipped"]}
    assert set(skipped) == set(expected)
    for name, words in expected.items():
        assert words in skipped[name]
        assert sum(name in line for line in err.splitlines()) == 1, f"{name} not one line"
    assert len(report["views"]) + len(report["rejected_outliers"]) == len(images)


def test_too_few_views_says_how_many_more(chessboard, tmp_path, capsys):
    images, _ = chessboard
    code, _, err = calibrate([*images[:5], "--out", str(tmp_path / "c.yaml")], capsys)
    assert code == 2
    assert "only 5 good view(s)" in err and "3 more needed" in err
    assert "Traceback" not in err and not (tmp_path / "c.yaml").exists()


def test_video_keeps_a_frame_only_when_the_board_moved(chessboard, tmp_path, capsys):
    images, reference = chessboard
    video = tmp_path / "board.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (640, 480))
    for path in images:
        for _ in range(3):
            writer.write(cv2.imread(path))
    writer.release()
    saved = tmp_path / "views"
    code, report, err = calibrate(["--video", str(video), "--out", str(tmp_path / "c.yaml"),
                                   "--save-views", str(saved), "--min-move", "0.01"], capsys)
    assert code == 0
    assert "board did not move 26" in err
    assert len(report["views"]) + len(report["rejected_outliers"]) == len(images)
    assert len(list(saved.glob("*.png"))) == len(images)
    camera = load_camera(tmp_path / "c.yaml")
    assert abs(camera.fx - reference.fx) <= 0.02 * reference.fx


@pytest.mark.parametrize("args, words", [
    (["--device", "97"], "cannot open camera device 97"),
    (["--video", "/nonexistent/board.mp4"], "video file not found"),
    ([], "give board images, or --video FILE, or --device N"),
])
def test_input_problems_are_one_line(args, words, capsys):
    assert main(["calibrate", *args, *BOARD]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]


def test_board_size_is_required(chessboard, capsys):
    assert main(["calibrate", chessboard[0][0]]) == 2
    assert "--cols, --rows, --square" in capsys.readouterr().err
