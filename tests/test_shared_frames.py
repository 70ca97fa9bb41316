"""Nuisance frames shared between data sets (``Dataset.frames``, manifest and job ``frames``), noise-free."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from kincal.data import Dataset
from kincal.errors import DataFormatError, ShapeError
from kincal.estimation import calibrate, evaluate
from kincal.experiments import build
from kincal.io.datasets import load_dataset, write_dataset
from kincal.io.jobs import load_job
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3
from kincal.params import State
from kincal.robots import load
from kincal.simulate import generate_markers, perturb_robot, random_configurations
from kincal.simulate.generators import generate_dual, random_tracker_pose
from kincal.workflow import run_job

EXACT = 1e-9
FAST = {"n_seeds": 32, "n_steps": 40}


@pytest.fixture(scope="module")
def ur10():
    return load("ur10")


@pytest.fixture(scope="module")
def sessions(ur10):
    """Two marker sessions (3 and 2 markers) of one true UR10 seen by ONE tracker: (true, T_world_tracker, sets)."""
    true = perturb_robot(ur10, "fine", 3)
    T = random_tracker_pose(true, "arm", np.random.default_rng(5))
    sets = {}
    for name, markers, seed in (("a", 3, 6), ("b", 2, 7)):
        ds, truth, _ = generate_markers(true, "arm", n=100, rng=seed, markers=markers, T_world_tracker=T,
                                        n_validation=1)
        sets[name] = (replace(ds, name=name), truth.values["p_tool_marker"])
    return true, T, sets


def _named(ds, **frames):
    return replace(ds, frames=frames)


def _frame_blocks(res, kind="pose"):
    return [b.name for b in res.layout.blocks if b.arm is None and b.kind.name == kind]


def _marker_errors(res, true, T, p_tool_marker, markers_name):
    """Largest error (m) of predicted marker positions in the tracker frame at fresh configurations."""
    q = random_configurations(true["arm"], 50, np.random.default_rng(11), margin=0.05)
    pred = se3.transform_points((se3.inverse(res.extras["tracker"]) @ forward_kinematics(res.robot["arm"], q))[:, None],
                                res.extras[markers_name][None])
    want = se3.transform_points((se3.inverse(T) @ forward_kinematics(true["arm"], q))[:, None], p_tool_marker[None])
    return float(np.max(np.linalg.norm(pred - want, axis=-1)))


# ------------------------------------------------------------------------------------------ (a) one tracker


def test_marker_sessions_sharing_one_tracker(ur10, sessions):
    """One tracker block, truth recovered, and the second session adds only its marker coordinates to the rank
    (its tracker gauge is the first one's: no second arm-with-tracker null space)."""
    true, T, sets = sessions
    (a, pa), (b, pb) = sets["a"], sets["b"]
    res = calibrate(ur10, [_named(a, tracker="tracker"), _named(b, tracker="tracker")], "kinematic")
    assert res.status == "converged"
    assert _frame_blocks(res) == ["tracker"]
    assert "tracker.v_x" in res.layout.names and not any(n.startswith(("a.tracker", "b.tracker"))
                                                         for n in res.layout.names)
    one = calibrate(ur10, [a], "kinematic")
    assert res.identifiability.rank == one.identifiability.rank + pb.size
    assert _marker_errors(res, true, T, pa, "a.markers") < EXACT
    assert _marker_errors(res, true, T, pb, "b.markers") < EXACT


def test_marker_sessions_without_sharing_have_two_trackers(ur10, sessions):
    _, _, sets = sessions
    (a, _), (b, pb) = sets["a"], sets["b"]
    res = calibrate(ur10, [a, b], "kinematic")
    assert _frame_blocks(res) == ["a.tracker", "b.tracker"]
    one = calibrate(ur10, [a], "kinematic")
    assert res.identifiability.rank == one.identifiability.rank + pb.size + 6  # a second tracker gauge


def test_shared_frame_known_in_one_data_set_is_known_in_both(ur10, sessions):
    true, T, sets = sessions
    (a, _), (b, _) = sets["a"], sets["b"]
    known = Dataset(a.kind, a.robot, a.arms, a.q, a.measured, {"T_world_tracker": T}, "a", frames={"tracker": "lab"})
    res = calibrate(ur10, [known, _named(b, tracker="lab")], "kinematic")
    blk = res.layout.block("lab")
    assert not res.layout.free[blk.start: blk.stop].any()  # fixed unless freed by name
    np.testing.assert_array_equal(res.extras["lab"], T)
    res = calibrate(ur10, [known, _named(b, tracker="lab")], ["kinematic", "lab"])
    assert res.layout.free[blk.start: blk.stop].all()


def test_unknown_shared_frame_starts_from_the_first_data_set(ur10, sessions):
    _, _, sets = sessions
    a, b = sets["a"][0], sets["b"][0]
    state = State.from_robot(ur10)
    _, extras, unknown = build([_named(a, tracker="lab"), _named(b, tracker="lab")], state)
    _, alone, _ = build([a], state)
    np.testing.assert_array_equal(extras["lab"], alone["tracker"])
    assert unknown == ["lab", "a.markers", "b.markers"]


# ------------------------------------------------------------------------------------------- (b) one clamp


def test_dual_data_sets_sharing_one_unknown_clamp():
    frida = load("frida")
    full = perturb_robot(frida, "thesis", 7)
    true = Robot(frida.name, {k: frida[k].replace(offsets=full[k].offsets) for k in frida.arms})
    sets = [replace(generate_dual(true, n=30, rng=seed, known_clamp=False, n_validation=1)[0], name=name)
            for name, seed in (("a", 3), ("b", 4))]
    assert _frame_blocks(calibrate(frida, sets, "offsets")) == ["a.clamp", "b.clamp"]
    res = calibrate(frida, [_named(d, clamp="bracket") for d in sets], "offsets")
    assert res.status == "converged"
    assert _frame_blocks(res) == ["bracket"]
    assert res.identifiability.rank == calibrate(frida, sets[:1], "offsets").identifiability.rank
    for arm in ("left", "right"):  # j7 of both arms trade off against the clamp (docs/calibration.md)
        err = [res.estimate(f"{arm}.j{i + 1}.offset").value - true[arm].offsets[i] for i in range(6)]
        assert np.max(np.abs(err)) < EXACT
    fresh, truth, _ = generate_dual(true, n=10, rng=5, known_clamp=True, n_validation=1, explore_options=FAST)
    fresh = replace(fresh, known={"T_toolA_toolB": res.extras["bracket"]}, name="fresh")
    stats = evaluate(res.robot, [fresh])[0]
    assert stats.position_max < EXACT and stats.orientation_max < EXACT


# ---------------------------------------------------------------------------------------------- (c) errors


def test_conflicting_known_values_name_both_data_sets_and_the_frame(ur10, sessions):
    _, T, sets = sessions
    a, b = sets["a"][0], sets["b"][0]
    off = se3.make(np.eye(3), [1e-3, 0, 0]) @ T
    a = replace(a, known={"T_world_tracker": T}, frames={"tracker": "lab"})
    with pytest.raises(DataFormatError, match=r"'a' and 'b' share frame 'lab' \(tracker\).*known\['T_world_tracker'\]"):
        calibrate(ur10, [a, replace(b, known={"T_world_tracker": off}, frames={"tracker": "lab"})], "kinematic")
    close = se3.make(np.eye(3), [1e-12, 0, 0]) @ T  # within 1e-9: one frame
    _, extras, unknown = build([a, replace(b, known={"T_world_tracker": close}, frames={"tracker": "lab"})],
                               State.from_robot(ur10))
    np.testing.assert_array_equal(extras["lab"], T)
    assert "lab" not in unknown


def test_sharing_across_roles_is_an_error(ur10, sessions):
    a = sessions[2]["a"][0]
    clamp = Dataset("clamp", "ur10", ("arm",), {"arm": a.q["arm"][:10]}, name="c", frames={"fixture": "rig"})
    with pytest.raises(DataFormatError, match=r"data set 'c': field frames.fixture: frame 'rig' is the tracker of "
                                              r"data set 'a'; a fixture cannot share a frame with a tracker"):
        build([_named(a, tracker="rig"), clamp], State.from_robot(ur10))
    # nor may a name given explicitly take another role's default name; the error names the data set that named it
    for order in (1, -1):
        with pytest.raises(DataFormatError, match="data set 'a': field frames.tracker: frame 'fixture' is the fixture "
                                                  "of data set 'c'; a tracker cannot share a frame with a fixture"):
            build([replace(clamp, frames={}), _named(a, tracker="fixture")][::order], State.from_robot(ur10))


def test_different_marker_counts_cannot_share_markers(ur10, sessions):
    a, b = sessions[2]["a"][0], sessions[2]["b"][0]
    with pytest.raises(DataFormatError, match=r"'a' and 'b' share frame 'tool_markers' \(markers\).*\(3, 3\) in 'a', "
                                              r"\(2, 3\) in 'b'"):
        build([_named(a, markers="tool_markers"), _named(b, markers="tool_markers")], State.from_robot(ur10))


@pytest.mark.parametrize("frames,message", [
    ({"fixture": "lab"}, r"data set 'a': field frames.fixture: expected a role of kind 'markers' \(tracker, markers\)"),
    ({"tracker": ""}, "data set 'a': field frames.tracker: expected a non-empty frame name"),
    ({"tracker": "lab*"}, "data set 'a': field frames.tracker: expected a non-empty frame name without spaces"),
    ([("tracker", "lab")], "data set 'a': field frames: expected a mapping"),
])
def test_bad_dataset_frames(sessions, frames, message):
    with pytest.raises(ShapeError, match=message):
        replace(sessions[2]["a"][0], frames=frames)


def test_frame_named_like_an_arm_is_an_error(ur10, sessions):
    a = sessions[2]["a"][0]
    with pytest.raises(DataFormatError, match=r"data set 'a': field frames.tracker: expected a name that does not "
                                              r"start with an arm of the model \('arm'"):
        build([_named(a, tracker="arm.tracker")], State.from_robot(ur10))


@pytest.fixture
def manifests(tmp_path, ur10, sessions):
    _, _, sets = sessions
    write_dataset(_named(sets["a"][0], tracker="lab"), tmp_path / "a.yaml", ur10, model="ur10")
    write_dataset(sets["b"][0], tmp_path / "b.yaml", ur10, model="ur10")
    return tmp_path


@pytest.mark.parametrize("frames,field", [
    ({"trackr": "lab"}, "frames.trackr: expected a role of kind 'markers'"),
    ({"tracker": "arm"}, "frames.tracker: expected a name that does not start with an arm"),
    ({"tracker": 3}, "frames.tracker: expected a non-empty frame name"),
    (["lab"], "frames: expected a mapping"),
])
def test_bad_manifest_frames_name_file_and_field(manifests, frames, field):
    path = manifests / "a.yaml"
    content = yaml.safe_load(path.read_text())
    path.write_text(yaml.safe_dump({**content, "frames": frames}))
    with pytest.raises(DataFormatError, match=field) as err:
        load_dataset(path)
    assert str(err.value).startswith(f"{path}: ")


def _job(d, data, name="job.yaml"):
    p = d / name
    p.write_text(yaml.safe_dump({"format": "kincal-job", "version": 1, "model": "ur10", "data": data,
                                 "free": "kinematic"}))
    return p


@pytest.mark.parametrize("frames,field", [
    ({"fixture": "lab"}, r"data\[1\]: field frames.fixture: expected a role of kind 'markers'"),
    ({"tracker": ""}, r"data\[1\]: field frames.tracker: expected a non-empty frame name"),
    ("lab", r"data\[1\]: field frames: expected a mapping"),
])
def test_bad_job_frames_name_file_and_field(manifests, frames, field):
    p = _job(manifests, ["a.yaml", {"manifest": "b.yaml", "frames": frames}])
    with pytest.raises(DataFormatError, match=field) as err:
        load_job(p)
    assert str(err.value).startswith(f"{p}: ")


# ----------------------------------------------------------------------------------------- (d) round trips


def test_manifest_round_trip(tmp_path, ur10, sessions):
    a = sessions[2]["a"][0]
    path = write_dataset(_named(a, tracker="lab", markers="tool_markers"), tmp_path / "a.yaml", ur10, model="ur10")
    assert yaml.safe_load(path.read_text())["frames"] == {"tracker": "lab", "markers": "tool_markers"}
    back = load_dataset(path)
    assert dict(back.frames) == {"tracker": "lab", "markers": "tool_markers"}
    again = write_dataset(back, tmp_path / "again.yaml", ur10, model="ur10")
    assert yaml.safe_load(again.read_text())["frames"] == yaml.safe_load(path.read_text())["frames"]
    assert dict(back.subset(slice(0, 5)).frames) == dict(back.frames)
    plain = write_dataset(a, tmp_path / "plain.yaml", ur10, model="ur10")
    assert "frames" not in yaml.safe_load(plain.read_text()) and not load_dataset(plain).frames


def test_job_frames_add_to_and_override_the_manifests(manifests, ur10):
    job = load_job(_job(manifests, ["a.yaml", {"manifest": "b.yaml", "frames": {"tracker": "lab"}}]))
    assert [dict(d.frames) for d in job.datasets] == [{"tracker": "lab"}, {"tracker": "lab"}]
    res = run_job(job)
    assert res.status == "converged" and _frame_blocks(res) == ["lab"]
    # written back as manifests, the job's names stay with the data sets
    back = [load_dataset(write_dataset(d, manifests / "out" / f"{d.name}.yaml", ur10, model="ur10"))
            for d in job.datasets]
    assert [dict(d.frames) for d in back] == [{"tracker": "lab"}, {"tracker": "lab"}]
    job = load_job(_job(manifests, [{"manifest": "a.yaml", "frames": {"tracker": "other"}}, "b.yaml"], "j2.yaml"))
    assert [dict(d.frames) for d in job.datasets] == [{"tracker": "other"}, {}]
