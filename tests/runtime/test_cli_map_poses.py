"""`litevloc map build --poses` on a small simulated recording: the SLAM never reads the
ground truth (garbage ground truth gives the same map), the pose sources and their errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.cli.main import main
from litevloc.hw.messages import GroundTruthPose
from litevloc.hw.streams.mcap_io import McapSource, record_messages
from litevloc.pipelines.evaluation.trajectory import write_tum
from litevloc.pipelines.topomap.io import load_map

pytestmark = pytest.mark.slow
# cheap models: ORB features and mutual nearest neighbours (the SLAM's logic, not the models, is under test)
CHEAP = ["--set", "models.extractor=orb", "--set", "models.matcher=mnn"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("poses")
    rec = d / "office.mcap"
    assert main(["sim", "record", "office", "--pass", "map", "--seed", "3", "--duration", "6", "-o", str(rec)]) == 0
    return rec


def _rewrite(src: Path, dst: Path, gt: str) -> Path:
    """The recording with its ground truth kept, replaced by random poses, or removed."""
    rng = np.random.default_rng(7)

    def msgs():  # type: ignore[no-untyped-def]
        for m in McapSource(src):
            if isinstance(m, GroundTruthPose):
                if gt == "drop":
                    continue
                if gt == "garbage":
                    m = GroundTruthPose(m.t_ns, make_T(so3_exp(rng.normal(size=3)), rng.normal(0, 50, 3)), m.index)
            yield m

    record_messages(msgs(), dst)
    return dst


def test_slam_never_reads_the_ground_truth(recording: Path, tmp_path: Path) -> None:
    garbage = _rewrite(recording, tmp_path / "garbage.mcap", "garbage")
    robot = _rewrite(recording, tmp_path / "robot.mcap", "drop")
    assert main(["map", "build", str(garbage), "--poses", "slam", "-o", str(tmp_path / "a"), "--json",
                 str(tmp_path / "a.json"), *CHEAP]) == 0
    # no ground truth in the recording: auto means slam
    assert main(["map", "build", str(robot), "-o", str(tmp_path / "b"), "--json", str(tmp_path / "b.json"),
                 *CHEAP]) == 0
    a, b = load_map(tmp_path / "a"), load_map(tmp_path / "b")
    assert a.n_nodes == b.n_nodes >= 3
    assert np.array_equal(a.T_map_camera, b.T_map_camera) and np.array_equal(a.frame_index, b.frame_index)
    ja, jb = json.loads((tmp_path / "a.json").read_text()), json.loads((tmp_path / "b.json").read_text())
    assert ja["poses"] == jb["poses"] == "slam"
    # the garbage is read only after the build, for the errors: and they show it
    assert ja["slam"]["evaluation"]["keyframe_ate_m"] > 1.0
    assert jb["slam"]["evaluation"]["reference"].startswith("none")
    for key in ("odometry_source", "loops", "seconds", "faults", "warnings", "up"):
        assert key in jb["slam"]
    assert set(jb["slam"]["seconds"]) == {"front_end", "loop_search", "optimisation", "map_write"}


def test_pose_sources(recording: Path, tmp_path: Path) -> None:
    robot = _rewrite(recording, tmp_path / "robot.mcap", "drop")
    # asked for ground truth the recording does not have: a clear error, exit 2
    assert main(["map", "build", str(robot), "--poses", "ground-truth", "-o", str(tmp_path / "x"), *CHEAP]) == 2
    assert main(["map", "build", str(robot), "--poses", "odometry", "-o", str(tmp_path / "odo"), "--json",
                 str(tmp_path / "odo.json"), *CHEAP]) == 0
    assert json.loads((tmp_path / "odo.json").read_text())["poses"] == "odometry"
    # a trajectory file: the recording's own ground truth as a TUM file of the camera
    gt = [(m.t_ns, m.T_world_camera) for m in McapSource(recording) if isinstance(m, GroundTruthPose)]
    tum = tmp_path / "traj.txt"
    keep = gt[: len(gt) // 2]  # half the recording: the other frames are outside it, skipped and counted
    write_tum(tum, np.array([t * 1e-9 for t, _ in keep]), np.stack([T for _, T in keep]))
    assert main(["map", "build", str(robot), "--poses", str(tum), "-o", str(tmp_path / "f"), "--json",
                 str(tmp_path / "f.json"), *CHEAP]) == 0
    js = json.loads((tmp_path / "f.json").read_text())
    assert js["poses"] == "file" and js["frames_without_pose"] >= len(gt) - len(keep) - 1
    m = load_map(tmp_path / "f")
    by_t = dict(gt)
    for t, T in zip(m.t_ns, m.T_map_camera, strict=True):
        assert np.allclose(T, by_t[int(t)], atol=1e-6)
    assert main(["map", "build", str(robot), "--poses", "nonsense", "-o", str(tmp_path / "y")]) == 2


def test_faulted_recording_is_bridged_and_reported(recording: Path, tmp_path: Path) -> None:
    """The small simulated pass with an odometry gap (1.0-2.2 s), a camera blackout (2.8-3.6 s) and a
    2 m odometry jump at 4.5 s: every fault in the report, every keyframe in the map, no bent map."""
    from litevloc.base.geometry import make_T
    from litevloc.hw.messages import Odometry, RgbdFrame

    def msgs():  # type: ignore[no-untyped-def]
        for m in McapSource(recording):
            t = m.t_ns * 1e-9
            if isinstance(m, Odometry):
                if 1.0 <= t < 2.2:
                    continue
                if t >= 4.5:
                    m = Odometry(m.t_ns, make_T(np.eye(3), np.array([2.0, 0.0, 0.0])) @ m.T_odom_base)
            if isinstance(m, RgbdFrame) and 2.8 <= t < 3.6:
                continue
            yield m

    rec = tmp_path / "faulted.mcap"
    record_messages(msgs(), rec)
    assert main(["map", "build", str(rec), "--poses", "slam", "-o", str(tmp_path / "m"), "--json",
                 str(tmp_path / "m.json"), *CHEAP]) == 0
    s = json.loads((tmp_path / "m.json").read_text())["slam"]
    kinds = {f["kind"] for f in s["faults"]}
    assert {"odometry gap", "odometry jump"} <= kinds
    assert s["frames_tracked"] > 0 and s["keyframes_left_out"] == 0
    assert s["evaluation"]["keyframe_ate_m"] < 0.05


def test_a_ground_truth_build_decodes_the_colour_of_its_keyframes_only(recording: Path, tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """Pass 1 needs depth and poses alone; pass 2 decodes the keyframes' colour. A keyframe whose
    colour does not decode is still refused, naming the frame."""
    import dataclasses

    from litevloc.hw.messages import EncodedRgbdFrame, RgbdFrame

    decoded: list[int] = []
    decode = EncodedRgbdFrame.decode

    def counting(self: EncodedRgbdFrame, *a: object) -> RgbdFrame:
        decoded.append(self.index)
        return decode(self, *a)  # type: ignore[arg-type]

    monkeypatch.setattr(EncodedRgbdFrame, "decode", counting)
    assert main(["map", "build", str(recording), "--poses", "ground-truth", "-o", str(tmp_path / "gt"), *CHEAP]) == 0
    m = load_map(tmp_path / "gt")
    assert sorted(decoded) == sorted(int(i) for i in m.frame_index)
    first = int(m.frame_index[0])

    def cut() -> object:  # the first keyframe's JPEG cut short
        for msg in McapSource(recording):
            if isinstance(msg, RgbdFrame) and msg.index == first:
                assert msg.color_jpeg is not None
                msg = dataclasses.replace(msg, color_jpeg=msg.color_jpeg[:-64])
            yield msg

    bad = tmp_path / "bad.mcap"
    record_messages(cut(), bad)
    assert main(["map", "build", str(bad), "--poses", "ground-truth", "-o", str(tmp_path / "bad"), *CHEAP]) == 2
