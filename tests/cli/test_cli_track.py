"""Tests of `jaxpose track`: a short rendered sequence written as a folder of PNGs (known
poses; a full occlusion; recognition replaced by a cheap stand-in so that no program is
compiled), the first frames of `box.mp4` from a given pose, the outputs (JSON, CSV, the
overlay video, the rerun recording, the progress bar) and bad input."""

import csv
import json

import cv2
import numpy as np
import pytest
from helpers import verify_recording

from jaxpose.apps import mesh_geometry, read_ply, render, sample_path, smooth_trajectory
from jaxpose.cli import _track as cli_track
from jaxpose.cli._main import main
from jaxpose.features import write_camera

DATA = sample_path("opencv_pose_box")
MESH = DATA / "box.ply"
BOX = read_ply(MESH)
GEO = mesh_geometry(BOX)
CENTRE = BOX.vertices.mean(axis=0)
K = np.array([[600.0, 0.0, 240.0], [0.0, 600.0, 180.0], [0.0, 0.0, 1.0]])
SIZE = (480, 360)
SHADES = np.array([200.0, 90.0, 150.0, 240.0, 120.0, 60.0])
HIDDEN = (6, 7, 8)
# The box's pose in box.mp4's first frame, from the keypoint path (examples/track_video.py).
BOX_RVEC = [1.91258699, -1.26409631, 0.74108325]
BOX_TVEC = [21.43863207, 0.69211619, 152.12559535]


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """12 frames of the flat-shaded box (turning up to about 2 degrees per frame), all
    of it hidden by a grey rectangle on the frames `HIDDEN`, as PNGs; the camera file;
    the true poses."""
    tmp = tmp_path_factory.mktemp("track")
    R0 = cv2.Rodrigues(np.array([2.2, -0.6, 0.4]))[0]
    t0 = np.array([0.0, 0.0, 80.0]) - R0 @ CENTRE
    Rs, ts = smooth_trajectory(R0, t0, 12, centre=CENTRE, rotation=8.0, translation=2.0, seed=4)
    rng = np.random.default_rng(4)
    folder = tmp / "frames"
    folder.mkdir()
    for i, (R, t) in enumerate(zip(Rs, ts, strict=True)):
        hide = (30, 15, 450, 345) if i in HIDDEN else None
        image = render(GEO, K, None, R, t, SIZE, background=40, supersample=2, shades=SHADES,
                       noise=2.0, rng=rng, occluder=hide)  # fmt: skip
        cv2.imwrite(str(folder / f"frame_{i:03d}.png"), image)
    camera = tmp / "camera.yml"
    write_camera(camera, K)
    pose = tmp / "pose.json"
    rvec = cv2.Rodrigues(Rs[0])[0].ravel()
    pose.write_text(json.dumps({"rvec": rvec.tolist(), "tvec": ts[0].tolist()}))
    return {"folder": folder, "camera": camera, "pose": pose, "Rs": Rs, "ts": ts, "tmp": tmp}


def _stand_in(Rs, ts, asked):
    """Recognition's stand-in: the true pose a little off (about recognition's accuracy
    on these frames), None where the box is hidden."""

    def make(args, mesh, K, dist):
        def reinit(frame, index):
            asked.append(index)
            if index in HIDDEN:
                return None
            nudge = cv2.Rodrigues(np.array([0.003, -0.002, 0.002]))[0]
            return nudge @ Rs[index], ts[index] + [0.2, -0.1, 0.3]

        return reinit

    return make


def _errors(frame, R, t):
    R_found = cv2.Rodrigues(np.array(frame["rvec"]))[0]
    rotation = np.degrees(np.linalg.norm(cv2.Rodrigues(R_found @ R.T)[0]))
    where = R @ CENTRE + t
    distance = np.linalg.norm(R_found @ CENTRE + np.array(frame["tvec"]) - where)
    return rotation, distance / np.linalg.norm(where)


def test_rendered_folder_with_a_full_occlusion(sequence, capsys, monkeypatch):
    asked = []
    monkeypatch.setattr(cli_track, "_reinit", _stand_in(sequence["Rs"], sequence["ts"], asked))
    tmp = sequence["tmp"]
    out = {k: tmp / "out" / f"track.{k}" for k in ("json", "csv", "mp4", "rrd")}
    rc = main(["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
               str(sequence["camera"]), "--init-pose", str(sequence["pose"]),
               "--json", str(out["json"]), "--csv", str(out["csv"]),
               "--overlay", str(out["mp4"]), "--rrd", str(out["rrd"])])  # fmt: skip
    stdout, stderr = capsys.readouterr()
    assert rc == 1  # some frames lost
    frames = json.loads(out["json"].read_text())["frames"]
    assert [f["index"] for f in frames] == list(range(12))
    assert all(set(f) == {"index", "ok", "status", "rvec", "tvec", "error_px", "inliers", "ms"}
               for f in frames)  # fmt: skip
    status = [f["status"] for f in frames]
    assert status[0] == "initialised"
    assert [status[i] for i in HIDDEN] == ["lost"] * 3
    assert all(frames[i]["rvec"] is None and not frames[i]["ok"] for i in HIDDEN)
    assert status[HIDDEN[-1] + 1] == "reinitialised" and asked[0] == HIDDEN[0] + 1
    assert all(s == "tracked" for i, s in enumerate(status) if i not in HIDDEN and i > 0
               and i != HIDDEN[-1] + 1)  # fmt: skip
    for i, f in enumerate(frames):
        if f["ok"]:
            rotation, translation = _errors(f, sequence["Rs"][i], sequence["ts"][i])
            assert rotation <= 0.5 and translation <= 0.005, (i, rotation, translation)
            assert f["inliers"] > 30 and 0 < f["error_px"] < 3 and f["ms"] > 0
    with out["csv"].open() as fh:
        table = list(csv.DictReader(fh))
    assert [r["status"] for r in table] == status
    assert table[HIDDEN[0]]["rvec_x"] == "" and float(table[0]["tvec_z"]) > 0
    video = cv2.VideoCapture(str(out["mp4"]))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 12
    ok, first = video.read()
    video.release()
    assert ok and first.shape == (360, 480, 3)
    assert "12 frames: 1 initialised" in stdout and "3 lost" in stdout
    assert "tracking [" in stderr and "12/12" in stderr
    verify_recording(out["rrd"])
    from rerun.chunk import RrdReader

    entities = {chunk.entity_path for chunk in RrdReader(out["rrd"]).stream()}
    wanted = {"/world/camera/image", "/world/camera/image/edges", "/world/model",
              "/world/trajectory", "/metrics/error_px", "/metrics/inliers", "/metrics/ms",
              "/metrics/rotation_std_deg", "/metrics/translation_std",
              "/status"}  # fmt: skip
    assert wanted <= entities, wanted - entities


def test_first_frame_recognised_and_no_reinit(sequence, capsys, monkeypatch):
    asked = []
    monkeypatch.setattr(cli_track, "_reinit", _stand_in(sequence["Rs"], sequence["ts"], asked))
    argv = ["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
            str(sequence["camera"]), "--frames", "4"]  # fmt: skip
    out = sequence["tmp"] / "first.json"
    assert main([*argv, "--json", str(out)]) == 0
    frames = json.loads(out.read_text())["frames"]
    assert [f["status"] for f in frames] == ["initialised"] + ["tracked"] * 3
    assert asked == [0]
    # Without re-initialisation the box, back where it vanished, is found from the
    # last pose held.
    out = sequence["tmp"] / "none.json"
    rc = main(["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
               str(sequence["camera"]), "--init-pose", str(sequence["pose"]),
               "--no-reinit", "--json", str(out)])  # fmt: skip
    capsys.readouterr()
    assert rc == 1
    status = [f["status"] for f in json.loads(out.read_text())["frames"]]
    assert [status[i] for i in HIDDEN] == ["lost"] * 3
    # Recognition throttled: one try in two frames at most while lost.
    asked.clear()
    rc = main(["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
               str(sequence["camera"]), "--init-pose", str(sequence["pose"]),
               "--reinit-every", "2"])  # fmt: skip
    capsys.readouterr()
    assert asked and all(b - a >= 2 for a, b in zip(asked, asked[1:]))


def test_box_video_from_a_given_pose(tmp_path, capsys):
    pose = tmp_path / "pose.json"
    pose.write_text(json.dumps({"rvec": BOX_RVEC, "tvec": [[x] for x in BOX_TVEC]}))
    out = tmp_path / "box.json"
    rc = main(["track", str(DATA / "box.mp4"), "--model", str(MESH), "--camera",
               str(DATA / "box_video_camera.yml"), "--init-pose", str(pose), "--frames", "10",
               "--no-reinit", "--json", str(out)])  # fmt: skip
    stdout, stderr = capsys.readouterr()
    assert rc == 0, stdout + stderr
    frames = json.loads(out.read_text())["frames"]
    assert len(frames) == 10 and all(f["ok"] for f in frames)
    assert [f["status"] for f in frames] == ["initialised"] + ["tracked"] * 9
    # The box is moved slowly by hand in these frames: the poses stay near the start.
    tvecs = np.array([f["tvec"] for f in frames])
    assert np.all(np.linalg.norm(tvecs - BOX_TVEC, axis=1) < 10)
    assert np.all(np.linalg.norm(np.diff(tvecs, axis=0), axis=1) < 2)
    assert all(f["inliers"] > 100 for f in frames[1:])


def test_bad_input_is_one_line(sequence, tmp_path, capsys):
    camera, pose, folder = (str(sequence[k]) for k in ("camera", "pose", "folder"))
    (tmp_path / "empty").mkdir()
    bad = {
        "not json": "{rvec",
        "no tvec": json.dumps({"rvec": [0, 0, 0]}),
        "short": json.dumps({"rvec": [0, 0], "tvec": [0, 0, 1]}),
        "behind": json.dumps({"rvec": [0, 0, 0], "tvec": [0, 0, -5]}),
    }
    for name, text in bad.items():
        (tmp_path / f"{name}.json").write_text(text)
    (tmp_path / "model.stl").write_text("solid x\n")
    good = ["--model", str(MESH), "--camera", camera, "--init-pose", pose]
    cases = {
        "missing input": ([str(tmp_path / "none.mp4"), *good], "INPUT"),
        "empty folder": ([str(tmp_path / "empty"), *good], "INPUT"),
        "missing model": (
            [folder, "--model", str(tmp_path / "x.ply"), "--camera", camera],
            "--model",
        ),  # fmt: skip
        "model suffix": (
            [folder, "--model", str(tmp_path / "model.stl"), "--camera", camera],
            "--model",
        ),  # fmt: skip
        "missing camera": (
            [folder, "--model", str(MESH), "--camera", str(tmp_path / "c.yml")],
            "--camera",
        ),  # fmt: skip
        "missing pose": (
            [
                folder,
                "--model",
                str(MESH),
                "--camera",
                camera,
                "--init-pose",
                str(tmp_path / "p.json"),
            ],
            "--init-pose",
        ),  # fmt: skip
        "overlay suffix": ([folder, *good, "--overlay", str(tmp_path / "o.avi")], "--overlay"),
        "frames": ([folder, *good, "--frames", "0"], "--frames"),
        "no reinit": (
            [folder, "--model", str(MESH), "--camera", camera, "--no-reinit"],
            "--init-pose",
        ),  # fmt: skip
        "reinit every": ([folder, *good, "--reinit-every", "0"], "--reinit-every"),
        "reinit wait": ([folder, *good, "--reinit-wait", "-1"], "--reinit-wait"),
        "rrd suffix": ([folder, *good, "--rrd", str(tmp_path / "x.txt")], ".rrd"),
        "json dir": ([folder, *good, "--json", str(tmp_path)], "--json"),
        "no camera": ([folder, "--model", str(MESH)], "--camera"),
    }
    for name in bad:
        argv = [folder, "--model", str(MESH), "--camera", camera, "--init-pose",
                str(tmp_path / f"{name}.json")]  # fmt: skip
        cases[f"pose {name}"] = (argv, "--init-pose")
    for case, (argv, needle) in cases.items():
        rc = main(["track", *argv])
        err = capsys.readouterr().err
        assert rc == 2, case
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("jaxpose"), f"{case}: {err}"
        assert needle in err, f"{case}: {err}"


def test_interrupted_run_writes_what_it_tracked(sequence, capsys, monkeypatch):
    # Ctrl-C on the fourth frame (a live camera is stopped so): the three frames tracked
    # are written.
    from jaxpose.features import _video

    iterate = _video.Frames.__iter__

    def stopped(self):
        for i, frame in enumerate(iterate(self)):
            if i == 3:
                raise KeyboardInterrupt
            yield frame

    monkeypatch.setattr(_video.Frames, "__iter__", stopped)
    out = sequence["tmp"] / "stopped.json"
    rc = main(["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
               str(sequence["camera"]), "--init-pose", str(sequence["pose"]), "--no-reinit",
               "--json", str(out)])  # fmt: skip
    stdout = capsys.readouterr().out
    assert rc == 0 and "interrupted after 3 frames" in stdout
    assert [f["status"] for f in json.loads(out.read_text())["frames"]] == [
        "initialised", "tracked", "tracked"]  # fmt: skip


def test_smooth_writes_the_refined_trajectory(sequence, capsys):
    # --smooth on the first six frames (no occlusion): the poses written are refine_track's
    # and the jitter before and after is printed. The rendered box turns about 3 degrees
    # a frame with a second difference of about 2.7 deg/frame^2, far from a constant
    # velocity: with a prior that allows it (given, or by default from the track), the
    # refined poses stay on the true ones.
    argv = ["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
            str(sequence["camera"]), "--init-pose", str(sequence["pose"]), "--no-reinit",
            "--frames", "6"]  # fmt: skip
    plain, smooth = sequence["tmp"] / "plain.json", sequence["tmp"] / "smooth.json"
    table = sequence["tmp"] / "smooth.csv"
    assert main([*argv, "--json", str(plain)]) == 0
    assert "smoothed" not in capsys.readouterr().out
    assert main([*argv, "--smooth", "--smooth-rotation", "3", "--smooth-translation", "0.02",
                 "--json", str(smooth), "--csv", str(table)]) == 0  # fmt: skip
    stdout = capsys.readouterr().out.replace("\n", " ")
    assert "smoothed (refine_track" in stdout and "jitter" in stdout and "->" in stdout
    before = json.loads(plain.read_text())["frames"]
    after = json.loads(smooth.read_text())["frames"]
    assert [f["status"] for f in after] == [f["status"] for f in before]
    assert len(after) == 6 and all(f["ok"] for f in after)
    moved = [np.abs(np.subtract(a["tvec"], b["tvec"])).max() for a, b in zip(after, before)]
    assert max(moved) > 0  # the refined poses, not the tracked ones
    for i, f in enumerate(after):
        rotation, translation = _errors(f, sequence["Rs"][i], sequence["ts"][i])
        assert rotation <= 0.5 and translation <= 0.005, (i, rotation, translation)
        assert np.isfinite(f["error_px"]) and f["error_px"] >= 0
    with table.open() as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["tvec_z"]) for r in rows] == pytest.approx([f["tvec"][2] for f in after])
    # The default: the prior's sigmas from the track, printed.
    assert main([*argv, "--smooth", "--json", str(smooth)]) == 0
    stdout = capsys.readouterr().out.replace("\n", " ")
    assert "prior " in stdout and "deg," in stdout
    for i, f in enumerate(json.loads(smooth.read_text())["frames"]):
        rotation, translation = _errors(f, sequence["Rs"][i], sequence["ts"][i])
        assert rotation <= 0.5 and translation <= 0.005, (i, rotation, translation)
    # A prior that must be positive: one line naming it.
    for option in ("--smooth-rotation", "--smooth-translation"):
        assert main([*argv, "--smooth", option, "0"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and option in err[0]


def test_jitter_of_a_trajectory():
    # A constant motion: a steady frame-to-frame turn and step, no second difference;
    # a lost frame breaks both chains.
    turn = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(1.0)]))[0]
    poses, R, t = [], np.eye(3), np.array([0.0, 0.0, 50.0])
    for _ in range(6):
        poses.append((R, t))
        R, t = turn @ R, t + [0.5, 0.0, 0.0]
    found = cli_track.jitter(poses, np.zeros(3))
    assert found["rotation_deg"] == pytest.approx(1.0)
    assert found["translation"] == pytest.approx(0.5)
    assert found["rotation_2nd_deg"] == pytest.approx(0.0, abs=1e-9)
    assert found["translation_2nd"] == pytest.approx(0.0, abs=1e-9)
    few = cli_track.jitter([poses[0], None, poses[2]], np.zeros(3))
    assert all(np.isnan(v) for v in few.values())


def test_point_is_followed_through_the_sequence(sequence, capsys, monkeypatch):
    # The centre of the face most turned to the camera, clicked on frame 2: its position
    # and pixel on every later frame with a pose, none on the hidden (lost) frames.
    asked = []
    monkeypatch.setattr(cli_track, "_reinit", _stand_in(sequence["Rs"], sequence["ts"], asked))
    Rs, ts = sequence["Rs"], sequence["ts"]
    best, centre = -np.inf, None
    for face in BOX.faces:
        corners = BOX.vertices[list(face)]
        normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        middle = corners.mean(axis=0)
        p = Rs[2] @ middle + ts[2]
        facing = -(Rs[2] @ normal) @ p / (np.linalg.norm(normal) * np.linalg.norm(p))
        if facing > best:
            best, centre = facing, middle
    u, v = (K @ (Rs[2] @ centre + ts[2]))[:2] / (Rs[2] @ centre + ts[2])[2]
    out = sequence["tmp"] / "point"
    rc = main(["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
               str(sequence["camera"]), "--init-pose", str(sequence["pose"]), "--point",
               str(u), str(v), "--point-frame", "2", "--json", str(out / "t.json"), "--csv",
               str(out / "t.csv"), "--overlay", str(out / "t.mp4"), "--rrd",
               str(out / "t.rrd")])  # fmt: skip
    stdout = capsys.readouterr().out.replace("\n", " ")
    assert rc == 1 and "on frame 2: face" in stdout
    frames = json.loads((out / "t.json").read_text())["frames"]
    for i, f in enumerate(frames):
        if i < 2 or not f["ok"]:
            assert f["target"] is None and f["target_px"] is None and f["target_visible"] is None
            assert f["target_std"] is None
            continue
        true = Rs[i] @ centre + ts[i]
        assert np.linalg.norm(np.array(f["target"]) - true) <= 0.005 * np.linalg.norm(true)
        pixel = (K @ true)[:2] / true[2]
        assert np.linalg.norm(np.array(f["target_px"]) - pixel) < 1.5 and f["target_visible"]
        std = np.array(f["target_std"])  # from the frame's pose covariance
        assert np.all(std > 0) and np.linalg.norm(std) < 0.005 * np.linalg.norm(true)
    assert sum(f["target"] is not None for f in frames) == 12 - 2 - len(HIDDEN)
    with (out / "t.csv").open() as fh:
        table = list(csv.DictReader(fh))
    assert table[1]["target_x"] == "" and table[3]["target_visible"] == "1"
    np.testing.assert_allclose(float(table[3]["target_u"]), frames[3]["target_px"][0])
    np.testing.assert_allclose(float(table[3]["target_std_z"]), frames[3]["target_std"][2])
    video = cv2.VideoCapture(str(out / "t.mp4"))  # the target marked (yellow) on frame 3
    for _ in range(4):
        ok, picture = video.read()
    video.release()
    cu, cv = (int(round(x)) for x in frames[3]["target_px"])
    patch = picture[cv - 6 : cv + 7, cu - 6 : cu + 7].reshape(-1, 3).astype(int)
    assert ok and np.any((patch[:, 2] > 180) & (patch[:, 1] > 150) & (patch[:, 0] < 90))
    verify_recording(out / "t.rrd")
    from rerun.chunk import RrdReader

    entities = {chunk.entity_path for chunk in RrdReader(out / "t.rrd").stream()}
    assert {"/world/target", "/world/camera/image/target"} <= entities


def test_point_frame_needs_point_and_a_click_beside_the_box_follows_nothing(sequence, capsys):
    argv = ["track", str(sequence["folder"]), "--model", str(MESH), "--camera",
            str(sequence["camera"])]  # fmt: skip
    assert main([*argv, "--point-frame", "3"]) == 2
    assert "--point-frame needs --point" in capsys.readouterr().err
    out = sequence["tmp"] / "beside.json"
    rc = main([*argv, "--init-pose", str(sequence["pose"]), "--frames", "3", "--point", "2",
               "2", "--json", str(out)])  # fmt: skip
    assert rc == 0 and "meets no face of the model" in capsys.readouterr().out.replace("\n", " ")
    frames = json.loads(out.read_text())["frames"]
    assert [f["target"] for f in frames] == [None] * 3
