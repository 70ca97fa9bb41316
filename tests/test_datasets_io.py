"""Data set files (CSV + YAML manifest): round trip, units, and errors naming file, row and column."""

import numpy as np
import pytest

from kincal.errors import DataFormatError
from kincal.io import csvtable
from kincal.io.datasets import load_dataset, write_dataset, write_simulation
from kincal.robots import load
from kincal.simulate.generators import generate_dual, generate_markers, generate_plate, generate_pose
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import perturb_robot

FAST = {"n_seeds": 32, "n_steps": 40}


@pytest.fixture(scope="module")
def frida():
    return load("frida")


@pytest.fixture(scope="module")
def dual(frida):
    ds, truth, val = generate_dual(perturb_robot(frida, "fine", rng=1), n=12, rng=2, noise=Noise(joint=1e-4),
                                   explore_options=FAST)
    return ds, truth, val


def test_dual_round_trip_is_exact(tmp_path, frida, dual):
    ds, truth, val = dual
    paths = write_simulation(tmp_path, ds, truth, val, frida)
    back = load_dataset(paths["data"])  # model 'frida' resolved from the manifest
    assert back.kind == "dual" and back.arms == ("left", "right") and back.robot == "frida"
    for a in ds.arms:
        np.testing.assert_array_equal(back.q[a], ds.q[a])
    np.testing.assert_array_equal(back.known["T_toolA_toolB"], ds.known["T_toolA_toolB"])
    assert back.meta["noise"]["joint_rad"] == 1e-4
    assert (tmp_path / "truth" / "robot.yaml").exists() and (tmp_path / "truth" / "q_true.csv").exists()
    assert "q_true" not in (tmp_path / "data.csv").read_text()  # truth is never mixed into the data
    v = load_dataset(paths["validation.left"])
    assert v.kind == "pose" and v.size == 100


def test_degrees_and_millimetres(tmp_path, frida):
    ds, _, _ = generate_markers(perturb_robot(load("ur10"), "fine", rng=1), n=5, rng=3, known_markers=True)
    ur10 = load("ur10")
    m = write_dataset(ds, tmp_path / "m.yaml", ur10, model="ur10", angle="deg", length="mm")
    text = (tmp_path / "m.csv").read_text().splitlines()
    assert text[0].startswith("arm.shoulder_pan,") and "m3.z" in text[0]
    back = load_dataset(m)
    np.testing.assert_allclose(back.q["arm"], ds.q["arm"], atol=1e-12)
    np.testing.assert_allclose(back.measured["p_tracker_marker"], ds.measured["p_tracker_marker"], atol=1e-12)
    np.testing.assert_allclose(back.known["p_tool_marker"], ds.known["p_tool_marker"], atol=1e-15)


def test_pose_and_plate_round_trip(tmp_path, frida):
    ds, _, _ = generate_pose(perturb_robot(load("ur10"), "fine", rng=1), n=6, rng=3, known_tracker=True)
    back = load_dataset(write_dataset(ds, tmp_path / "p.yaml", load("ur10"), model="ur10"))
    np.testing.assert_allclose(back.measured["T_tracker_tool"], ds.measured["T_tracker_tool"], atol=1e-14)
    ds, _, _ = generate_plate(perturb_robot(frida, "fine", rng=1), "right", n=8, rng=3, candidates=5,
                              explore_options=FAST)
    back = load_dataset(write_dataset(ds, tmp_path / "plate.yaml", frida))
    np.testing.assert_array_equal(back.measured["fixture"], ds.measured["fixture"])
    np.testing.assert_array_equal(back.known["T_plate_fixture"], ds.known["T_plate_fixture"])


def test_writing_never_overwrites(tmp_path, frida, dual):
    ds = dual[0]
    write_dataset(ds, tmp_path / "d.yaml", frida)
    before = (tmp_path / "d.csv").read_text()
    with pytest.raises(DataFormatError, match="refusing to overwrite"):
        write_dataset(ds, tmp_path / "d.yaml", frida)
    assert (tmp_path / "d.csv").read_text() == before
    write_dataset(ds, tmp_path / "d.yaml", frida, overwrite=True)


@pytest.fixture
def written(tmp_path, frida, dual):
    m = write_dataset(dual[0], tmp_path / "d.yaml", frida)
    return m, tmp_path / "d.csv"


def _edit_csv(path, fn):
    lines = path.read_text().splitlines()
    fn(lines)
    path.write_text("\n".join(lines) + "\n")


def test_missing_column(written):
    m, c = written

    def drop(lines):
        for i, line in enumerate(lines):
            lines[i] = ",".join(v for k, v in enumerate(line.split(",")) if k != 9)  # right.j3

    _edit_csv(c, drop)
    with pytest.raises(DataFormatError, match=r"d\.csv: line 1, column 'right\.j3': missing"):
        load_dataset(m)


def test_nan_value(written):
    m, c = written

    def nan(lines):
        v = lines[4].split(",")
        v[3] = "nan"
        lines[4] = ",".join(v)

    _edit_csv(c, nan)
    msg = r"d\.csv: line 5, column 'left\.j4': expected a finite number, found 'nan'"
    with pytest.raises(DataFormatError, match=msg):
        load_dataset(m)


def test_wrong_unit_name(written):
    m, _ = written
    m.write_text(m.read_text().replace("angle: rad", "angle: degree"))
    with pytest.raises(DataFormatError, match=r"d\.yaml: units\.angle: unknown angle unit 'degree'"):
        load_dataset(m)


def test_row_with_too_few_values(written):
    m, c = written

    def short(lines):
        lines[3] = ",".join(lines[3].split(",")[:10])

    _edit_csv(c, short)
    with pytest.raises(DataFormatError, match=r"d\.csv: line 4, column 'right\.j4': row has 10 values"):
        load_dataset(m)


def test_comments_keep_line_numbers_and_bad_text(written):
    m, c = written

    def edit(lines):
        lines.insert(1, "# a comment written by hand")
        v = lines[3].split(",")
        v[0] = "1.2.3"
        lines[3] = ",".join(v)

    _edit_csv(c, edit)
    with pytest.raises(DataFormatError, match=r"line 4, column 'left\.j1': expected a number, found '1\.2\.3'"):
        load_dataset(m)


def test_manifest_errors(written):
    m, _ = written
    good = m.read_text()
    m.write_text(good.replace("kind: dual", "kind: laser"))
    with pytest.raises(DataFormatError, match="kind: expected one of"):
        load_dataset(m)
    m.write_text(good.replace("model: frida", "model: nosuchrobot"))
    with pytest.raises(DataFormatError, match="model: .*no built-in robot"):
        load_dataset(m)
    m.write_text(good.replace("arms: [left, right]", "arms: [left, middle]"))
    with pytest.raises(DataFormatError, match="arms: model 'frida' has no arm 'middle'"):
        load_dataset(m)
    # the written manifest states its noise already: replace it (a repeated key is itself an error)
    m.write_text("\n".join(ln for ln in good.splitlines() if not ln.startswith(("noise:", "  joint_", "  position_",
                                                                                   "  orientation_", "  backlash_")))
                 + "\nnoise: {joint_sigma_furlong: 1}\n")
    with pytest.raises(DataFormatError, match="noise.joint_sigma_furlong"):
        load_dataset(m)


def test_hand_written_clamp_data_set(tmp_path):
    (tmp_path / "c.yaml").write_text(
        "format: kincal-dataset\nversion: 1\nkind: clamp\nmodel: ur10\narms: [arm]\ndata: c.csv\n"
        "units: {angle: deg, length: mm}\n"
        "known:\n  T_world_fixture: {xyz: [500, 0, 300], rpy: [180, 0, 90]}\n"
        "noise: {joint_deg: 0.01}\n"
    )
    (tmp_path / "c.csv").write_text(
        "arm.shoulder_pan,arm.shoulder_lift,arm.elbow,arm.wrist_1,arm.wrist_2,arm.wrist_3\n"
        "0,-90,90,0,90,0\n10,-80,85,5,90,1\n"
    )
    ds = load_dataset(tmp_path / "c.yaml")
    np.testing.assert_allclose(ds.q["arm"][0], np.deg2rad([0, -90, 90, 0, 90, 0]))
    np.testing.assert_allclose(ds.known["T_world_fixture"][:3, 3], [0.5, 0.0, 0.3])
    assert ds.meta["noise"]["joint_rad"] == pytest.approx(np.deg2rad(0.01))


def test_csv_read_in_chunks_keeps_line_numbers_and_checks(tmp_path, monkeypatch):
    """Chunked reading (io/csvtable.py): rows across chunk boundaries, comments and blank lines keep the file's
    line numbers; quoted cells and spaces go through the csv module; every check names file, line, column."""
    monkeypatch.setattr(csvtable, "CHUNK_LINES", 4)
    p = tmp_path / "t.csv"
    rows = [f"{i}.5,{-i}e-3,{i}" for i in range(20)]
    p.write_text("\ufeffa,b,k\n# note\n" + "\n".join(rows[:7]) + "\n\n , ,\n" + '"7.5", -7e-3 ,7\n'
                 + "\n".join(rows[8:]) + "\n")
    t = csvtable.read_table(p, integer={"k"})
    assert t.header == ["a", "b", "k"] and t.values.shape == (20, 3)
    np.testing.assert_array_equal(t.take(["k"])[:, 0], np.arange(20))
    np.testing.assert_array_equal(t.values[:, 1], [float(f"{-i}e-3") for i in range(20)])
    assert list(t.lines[:8]) == [3, 4, 5, 6, 7, 8, 9, 12]
    for bad, match in (("1e999", r"line 20, column 'b': expected a finite number, found '1e999'"),
                       ("3_0", r"line 20, column 'b': expected a number, found '3_0'")):
        p.write_text("a,b,k\n" + "\n".join(rows[:18]) + f"\n1,{bad},2\n")
        with pytest.raises(DataFormatError, match=match):
            csvtable.read_table(p, integer={"k"})
    p.write_text("a,b,k\n1,2,3.0\n")
    with pytest.raises(DataFormatError, match=r"line 2, column 'k': expected an integer, found '3\.0'"):
        csvtable.read_table(p, integer={"k"})
